"""Export posed frames to the formats peer tools read.

Formats:
  pixelsplat DATASET    chunks + index.json for the pixelSplat / MVSplat / DepthSplat loaders
                        (OUT/STAGE/000000.torch ...; same keys and dtypes as the public RE10K and
                        DepthSplat DL3DV chunks; DL3DV scenes keyed by their hash, 270x480)
  nerfstudio DATASET    OUT/<scene_id>/images/*.jpg|png + transforms.json (OpenGL camera-to-world)

Examples:
  seeu export pixelsplat data/posed/scene --out datasets/my_re10k --stage test
  seeu export pixelsplat data/posed/phone --out datasets/mine --size-check refuse
  seeu export pixelsplat data/posed/scene --out datasets/native --resize none   # frames as stored
  seeu export pixelsplat data/posed/dl3dv --out datasets/dl3dv --stage test     # DepthSplat's DL3DV
  seeu export nerfstudio data/posed/scene --out exports/ns --scenes scene0
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from pipelines.cli.config_flags import add_config_flags, config_from_args
from pipelines.cli.options import add_max_pixels, add_out, add_progress, max_pixels, progress_wanted, shared_values

# Every flag but these comes from a `setting` of the format's export config; `--out` sets its `out`,
# the others say what is read (the dataset, checked under --max-pixels) and whether bars are shown.
SHARED_FLAGS = {"out": "out"}
OWN_FLAGS = ("dataset", "progress", "max_pixels")


def _formats() -> dict[str, tuple[type, str]]:
    from seeu_data.exporters.nerfstudio import NerfstudioExportConfig
    from seeu_data.exporters.pixelsplat import PixelSplatExportConfig

    return {
        "pixelsplat": (PixelSplatExportConfig, "pixelSplat / MVSplat chunks + index.json"),
        "nerfstudio": (NerfstudioExportConfig, "nerfstudio transforms.json + image files"),
    }


def add_arguments(p: argparse.ArgumentParser) -> None:
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("dataset", type=Path, help="posed-frames directory (holds manifest.json)")
    add_out(common, "output directory")
    add_progress(common)
    add_max_pixels(common)
    sub = p.add_subparsers(dest="format", metavar="FORMAT", required=True)
    for name, (cls, help_text) in _formats().items():
        f = sub.add_parser(name, parents=[common], help=help_text)
        add_config_flags(f, cls)
        f.set_defaults(export_cls=cls)


def run(args: argparse.Namespace) -> int:
    from seeu_data.store.dataset_check import check_dataset
    from seeu_data.store.posed import SCHEMA, PosedDataset

    check_dataset(args.dataset, check_sha=False, max_pixels=max_pixels(args), expect_schema=SCHEMA)
    dataset = PosedDataset(args.dataset)
    cfg = config_from_args(args.export_cls, args, **shared_values(args, SHARED_FLAGS))
    progress = progress_wanted(args)
    if args.format == "pixelsplat":
        from seeu_data.exporters.pixelsplat import export_pixelsplat

        s = export_pixelsplat(dataset, cfg, progress=progress)
        print(f"exported {s['scenes']} scenes in {s['chunks']} chunks to {s['directory']}")
        if s["scenes_peers_skip"]:
            print(
                f"seeu export: warning: the peers' loaders would skip {s['scenes_peers_skip']} of {s['scenes']} "
                f"scenes (first: {s['peers_skip'][0]})",
                file=sys.stderr,
            )
    else:
        from seeu_data.exporters.nerfstudio import export_nerfstudio

        s = export_nerfstudio(dataset, cfg, progress=progress)
        print(f"exported {s['scenes']} scenes ({s['frames']} frames) as nerfstudio folders under {args.out}")
    return 0
