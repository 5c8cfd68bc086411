"""Import a public dataset or your own posed scenes as posed frames (tables + manifest.json).

Formats:
  pixelsplat DIR        RE10K / ACID / DTU chunks (DIR/{train,test}/*.torch + index.json)
  re10k                 raw RealEstate10K / ACID text files + frames named by timestamp
  dtu DIR               DTU in the MVSNet layout (Cameras/train, Rectified/scanN_train, ...)
  colmap MODEL_DIR      a COLMAP model (binary or text) + its image folder
  nerfstudio JSON       a nerfstudio / NeRF transforms.json
  dl3dv ROOT            DL3DV-10K (<subset>/<hash>/ release or <hash>/nerfstudio/ benchmark layout)

Scenes with bad input (an image that fails to decode, missing frames, frame/camera count mismatch,
non-finite or non-orthonormal poses) are skipped, counted and named in the manifest's report.

A re-run resumes: output files already complete for the same options and unchanged inputs
(pixelsplat chunks, re10k camera files with their frames, dtu scans, dl3dv scenes, the colmap or
nerfstudio scene; still of the size and mtime recorded with their sha256, or of that sha256 with
--verify) are kept, only the other inputs are read: a re-run with nothing to do reads no file.
Writes are atomic (temporary name, rename, manifest last); --fsync also fsyncs
every file before its rename, for durability across a power loss.

Examples:
  seeu import pixelsplat datasets/re10k --stage test --out data/posed/re10k_test
  seeu import pixelsplat datasets/dtu --stage test --dataset dtu --out data/posed/dtu_chunks
  seeu import re10k --cameras RealEstate10K/test --frames dataset/test --out data/posed/re10k_raw
  seeu import dtu datasets/dtu_training --scans 1,8,21 --out data/posed/dtu
  seeu import colmap scene/sparse/0 --images scene/images --out data/posed/scene
  seeu import nerfstudio scene/transforms.json --out data/posed/scene
  seeu import nerfstudio scene/transforms.json --skip-missing --out data/posed/scene
  seeu import dl3dv DL3DV-480P --resolution 480p --exclude @benchmark_hashes.txt --out data/posed/dl3dv
  seeu import dl3dv /shared/DL3DV-480P --engine ray --ray-address auto --out /shared/posed/dl3dv

Paths read from input files (index.json chunk names, COLMAP image names, nerfstudio file_paths)
must stay inside their dataset folder: an entry leading outside (../x, an absolute path, a link) is
skipped and counted; colmap and nerfstudio take --allow-outside-paths where that is intended.
"""

from __future__ import annotations

import argparse

from pipelines.cli.config_flags import add_config_flags, config_from_args
from pipelines.cli.options import add_force, add_fsync, add_out, add_progress, shared_values

SHARED_FLAGS = {"out": "out", "force": "force", "progress": "progress", "fsync": "fsync"}  # -> ImportConfig fields


def add_arguments(p: argparse.ArgumentParser) -> None:
    from pipelines.import_data import IMPORTERS, ImportConfig

    common = argparse.ArgumentParser(add_help=False)
    add_out(common, "output posed-frames directory")
    add_config_flags(common, ImportConfig)
    add_force(common, also=" (every posed file is written anew)")
    add_progress(common)
    add_fsync(common)
    sub = p.add_subparsers(dest="format", metavar="FORMAT", required=True)
    for name, (source_cls, help_text) in IMPORTERS.items():
        f = sub.add_parser(name, parents=[common], help=help_text)
        add_config_flags(f, source_cls)
        f.set_defaults(source_cls=source_cls)


def run(args: argparse.Namespace) -> int:
    from pipelines.import_data import ImportConfig, import_dataset

    source = config_from_args(args.source_cls, args)
    cfg = config_from_args(ImportConfig, args, source=source, **shared_values(args, SHARED_FLAGS))
    report = import_dataset(cfg)
    print(report.summary_line(args.out))
    return 0
