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
nerfstudio scene; recorded size and sha256 still matching) are kept, only the other inputs are read.
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

Paths read from input files (index.json chunk names, COLMAP image names, nerfstudio file_paths)
must stay inside their dataset folder: an entry leading outside (../x, an absolute path, a link) is
skipped and counted; colmap and nerfstudio take --allow-outside-paths where that is intended.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from pipelines.cli.options import (
    add_fsync,
    add_max_pixels,
    add_out,
    add_progress,
    max_pixels,
    parse_scene_list,
    progress_wanted,
)
from seeu_data.errors import SeeUError


def add_arguments(p: argparse.ArgumentParser) -> None:
    common = argparse.ArgumentParser(add_help=False)
    add_out(common, "output posed-frames directory")
    common.add_argument(
        "--verify-decode", action="store_true", help="fully decode every image (slow); default: header + trailer check"
    )
    common.add_argument("--strict", action="store_true", help="fail on the first bad scene instead of skipping it")
    add_progress(common)
    add_fsync(common)
    add_max_pixels(common)
    sub = p.add_subparsers(dest="format", metavar="FORMAT", required=True)

    f = sub.add_parser("pixelsplat", parents=[common], help="RE10K / ACID / DTU pixelSplat chunks")
    f.add_argument("root", type=Path, help="dataset dir holding train/ and test/ (or a stage dir)")
    f.add_argument("--stage", choices=["train", "test"], default="train")
    f.add_argument("--scenes", help="keep only these scene keys: a,b,c or @file.txt")
    f.add_argument(
        "--dataset",
        choices=["re10k", "acid", "dtu"],
        default="re10k",
        help="near/far preset (re10k/acid 1/100, dtu 2.125/4.525) and the name kept in the meta",
    )
    f.add_argument("--near", type=float)
    f.add_argument("--far", type=float)
    f.set_defaults(source_config=pixelsplat_source)

    f = sub.add_parser("re10k", parents=[common], help="raw RealEstate10K / ACID text files + frames")
    f.add_argument("--cameras", type=Path, required=True, help="directory of <scene>.txt camera files")
    f.add_argument(
        "--frames",
        type=Path,
        required=True,
        help="directory of <scene>/<timestamp_us>.{png,jpg} frames (as the download scripts leave them)",
    )
    f.add_argument("--scenes", help="keep only these scenes: a,b,c or @file.txt")
    f.add_argument("--dataset", choices=["re10k", "acid"], default="re10k")
    f.add_argument("--near", type=float, default=1.0)
    f.add_argument("--far", type=float, default=100.0)
    f.add_argument(
        "--allow-missing-frames",
        action="store_true",
        help="drop frames whose image is missing instead of skipping the scene",
    )
    f.set_defaults(source_config=re10k_source)

    f = sub.add_parser("dtu", parents=[common], help="DTU in the MVSNet layout")
    f.add_argument("root", type=Path, help="directory holding Cameras/ and Rectified/")
    f.add_argument("--scans", help="scan numbers, e.g. 1,8,21 (default: every Rectified/scanN_train)")
    f.add_argument("--lighting", type=int, default=3, help="lighting index of the rectified images (default 3)")
    f.add_argument("--scale", type=float, default=1 / 200, help="translation scale (default 1/200, as MVSplat)")
    f.add_argument("--near", type=float, default=2.125)
    f.add_argument("--far", type=float, default=4.525)
    f.set_defaults(source_config=dtu_source)

    f = sub.add_parser("colmap", parents=[common], help="a COLMAP model and its images")
    f.add_argument("model", type=Path, help="model directory (cameras/images/points3D .bin or .txt)")
    f.add_argument("--images", type=Path, required=True, help="image directory the model's names are relative to")
    f.add_argument("--scene-id", help="scene id (default: derived from the model path)")
    f.add_argument(
        "--no-undistort",
        action="store_true",
        help="refuse distorted camera models instead of undistorting with pycolmap",
    )
    f.add_argument(
        "--allow-outside-paths",
        action="store_true",
        help="read image names that lead outside --images (../x.jpg, absolute, links); "
        "default: such images are dropped and counted",
    )
    f.add_argument("--near", type=float, help="near plane (default: from the 3D points' depths)")
    f.add_argument("--far", type=float, help="far plane (default: from the 3D points' depths)")
    f.set_defaults(source_config=colmap_source)

    f = sub.add_parser("nerfstudio", parents=[common], help="a nerfstudio / NeRF transforms.json")
    f.add_argument("transforms", type=Path, help="transforms.json")
    f.add_argument("--scene-id", help="scene id (default: the folder name)")
    f.add_argument(
        "--keep-applied-transform",
        action="store_true",
        help="keep nerfstudio's world frame (default: undo applied_transform, i.e. the original, e.g. COLMAP, world)",
    )
    f.add_argument(
        "--skip-missing",
        action="store_true",
        help="drop frames whose image is missing (counted in the report) instead of skipping the scene",
    )
    f.add_argument(
        "--no-undistort",
        action="store_true",
        help="refuse frames with lens distortion (k1, k2, k3, k4, p1, p2) instead of undistorting them",
    )
    f.add_argument(
        "--allow-outside-paths",
        action="store_true",
        help="read file_paths that lead outside the JSON's folder (../x.png, absolute, links); "
        "default: such frames are dropped and counted",
    )
    f.add_argument("--near", type=float, help="near plane (default: from a seeu export, else 0.1)")
    f.add_argument("--far", type=float, help="far plane (default: from a seeu export, else 100)")
    f.set_defaults(source_config=nerfstudio_source)

    from seeu_data.importers.dl3dv import DEFAULT_RESOLUTION, DL3DV_NEAR_FAR, RESOLUTIONS

    f = sub.add_parser("dl3dv", parents=[common], help="DL3DV-10K scenes (release or benchmark layout)")
    f.add_argument("root", type=Path, help="folder of <subset>/<hash>/transforms.json or <hash>/nerfstudio/")
    f.add_argument(
        "--resolution",
        choices=list(RESOLUTIONS),
        default=DEFAULT_RESOLUTION,
        help="frames read: "
        + ", ".join(f"{k} = {v}/" for k, v in RESOLUTIONS.items())
        + f" (default {DEFAULT_RESOLUTION})",
    )
    f.add_argument(
        "--exclude",
        help="scene hashes left out: a,b,c or @file.txt (one per line), e.g. the 140 DL3DV-Benchmark hashes",
    )
    f.add_argument(
        "--undistort",
        action="store_true",
        help="undistort the frames with transforms.json's k1, k2, p1, p2 (default: ignored, as DepthSplat)",
    )
    f.add_argument("--near", type=float, default=DL3DV_NEAR_FAR[0], help=f"near plane (default {DL3DV_NEAR_FAR[0]:g})")
    f.add_argument("--far", type=float, default=DL3DV_NEAR_FAR[1], help=f"far plane (default {DL3DV_NEAR_FAR[1]:g})")
    f.set_defaults(source_config=dl3dv_source)


def pixelsplat_source(args: argparse.Namespace):
    from seeu_data.importers.pixelsplat import PixelSplatImportConfig

    return PixelSplatImportConfig(
        root=args.root,
        stage=args.stage,
        scenes=parse_scene_list(args.scenes),
        dataset=args.dataset,
        near=args.near,
        far=args.far,
        verify_decode=args.verify_decode,
        max_pixels=max_pixels(args),
    )


def re10k_source(args: argparse.Namespace):
    from seeu_data.importers.re10k_text import Re10kTextImportConfig

    return Re10kTextImportConfig(
        cameras_dir=args.cameras,
        frames_dir=args.frames,
        scenes=parse_scene_list(args.scenes),
        dataset=args.dataset,
        near=args.near,
        far=args.far,
        allow_missing_frames=args.allow_missing_frames,
        verify_decode=args.verify_decode,
        max_pixels=max_pixels(args),
    )


def parse_scans(text: str | None) -> list[int] | None:
    """`--scans 1,8,21` (or scan1,scan8) -> [1, 8, 21]; None: every scan."""
    if text is None:
        return None
    try:
        return [int(s) for s in text.replace("scan", "").split(",") if s.strip()]
    except ValueError:
        raise SeeUError(f"--scans {text!r} is not a list of scan numbers (e.g. 1,8,21)") from None


def dtu_source(args: argparse.Namespace):
    from seeu_data.importers.dtu import DtuImportConfig

    return DtuImportConfig(
        root=args.root,
        scans=parse_scans(args.scans),
        lighting=args.lighting,
        scale=args.scale,
        near=args.near,
        far=args.far,
        verify_decode=args.verify_decode,
        max_pixels=max_pixels(args),
    )


def colmap_source(args: argparse.Namespace):
    from seeu_data.importers.colmap import ColmapImportConfig

    return ColmapImportConfig(
        model_dir=args.model,
        images_dir=args.images,
        scene_id=args.scene_id,
        undistort=not args.no_undistort,
        near=args.near,
        far=args.far,
        verify_decode=args.verify_decode,
        max_pixels=max_pixels(args),
        allow_outside_paths=args.allow_outside_paths,
    )


def nerfstudio_source(args: argparse.Namespace):
    from seeu_data.importers.nerfstudio import NerfstudioImportConfig

    return NerfstudioImportConfig(
        transforms=args.transforms,
        scene_id=args.scene_id,
        undo_applied_transform=not args.keep_applied_transform,
        near=args.near,
        far=args.far,
        verify_decode=args.verify_decode,
        max_pixels=max_pixels(args),
        undistort=not args.no_undistort,
        skip_missing=args.skip_missing,
        allow_outside_paths=args.allow_outside_paths,
    )


def dl3dv_source(args: argparse.Namespace):
    from seeu_data.importers.dl3dv import Dl3dvImportConfig

    return Dl3dvImportConfig(
        root=args.root,
        resolution=args.resolution,
        exclude=parse_scene_list(args.exclude, "--exclude"),
        near=args.near,
        far=args.far,
        undistort=args.undistort,
        verify_decode=args.verify_decode,
        max_pixels=max_pixels(args),
    )


def run(args: argparse.Namespace) -> int:
    from pipelines.import_data import ImportConfig, import_dataset

    cfg = ImportConfig(
        source=args.source_config(args),
        out=args.out,
        strict=args.strict,
        progress=progress_wanted(args),
        fsync=args.fsync,
    )
    report = import_dataset(cfg)
    print(report.summary_line(args.out))
    return 0
