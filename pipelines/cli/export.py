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
import math
import sys
from pathlib import Path

from pipelines.cli.options import add_max_pixels, add_out, add_progress, max_pixels, progress_wanted
from seeu_data.exporters.pixelsplat import PEER_MAX_FOV_DEG, PEERS, RESIZE_AUTO
from seeu_data.limits import MAX_CHUNK_BYTES
from seeu_data.settings import parse_dims, parse_scene_list

PEER_SIZES = ", ".join(f"{p}: " + " or ".join(f"{h}x{w}" for h, w in r.sizes) for p, r in PEERS.items())


def add_arguments(p: argparse.ArgumentParser) -> None:
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("dataset", type=Path, help="posed-frames directory (holds manifest.json)")
    add_out(common, "output directory")
    common.add_argument("--scenes", help="export only these scene ids: a,b,c or @file.txt")
    add_progress(common)
    add_max_pixels(common)
    sub = p.add_subparsers(dest="format", metavar="FORMAT", required=True)
    f = sub.add_parser("pixelsplat", parents=[common], help="pixelSplat / MVSplat chunks + index.json")
    f.add_argument("--stage", choices=["train", "test"], default="test")
    f.add_argument(
        "--chunk-mb",
        type=float,
        default=100.0,
        help=f"image megabytes per chunk (peers: 100; at most {MAX_CHUNK_BYTES / 1e6:g})",
    )
    f.add_argument(
        "--resize",
        metavar="HxW|auto|none",
        default=RESIZE_AUTO,
        help="resize every frame to cover HxW and crop the centre (the peers' crop, intrinsics updated, JPEG "
        f"re-encoded; frames already that size kept as stored); default {RESIZE_AUTO}: each scene to its "
        f"peer's size, {PEERS['dl3dv'].hw[0]}x{PEERS['dl3dv'].hw[1]} (DepthSplat) for scenes from seeu import "
        f"dl3dv, else {PEERS['re10k'].hw[0]}x{PEERS['re10k'].hw[1]} (the RE10K peers); 'none' keeps every frame as stored",
    )
    f.add_argument(
        "--size-check",
        choices=["warn", "refuse"],
        default="warn",
        help=f"scenes the peers' loaders would skip (frames not their size, {PEER_SIZES}; field of view > "
        f"{PEER_MAX_FOV_DEG:g} deg): warn in one line (default) or refuse the export (exit 2)",
    )
    f = sub.add_parser("nerfstudio", parents=[common], help="nerfstudio transforms.json + image files")


def parse_resize(text: str) -> tuple[int, int] | str | None:
    """--resize: "none" -> None, "auto" -> RESIZE_AUTO, "HxW" -> (H, W)."""
    word = text.strip().lower()
    if word in ("none", RESIZE_AUTO):
        return None if word == "none" else RESIZE_AUTO
    return parse_dims(text, "--resize")


def run(args: argparse.Namespace) -> int:
    from seeu_data.store.dataset_check import check_dataset
    from seeu_data.store.posed import SCHEMA, PosedDataset

    check_dataset(args.dataset, check_sha=False, max_pixels=max_pixels(args), expect_schema=SCHEMA)
    dataset = PosedDataset(args.dataset)
    scenes = parse_scene_list(args.scenes)
    scene_ids = None if scenes is None else sorted(scenes)
    progress = progress_wanted(args)
    if args.format == "pixelsplat":
        from seeu_data.exporters.pixelsplat import PixelSplatExportConfig, export_pixelsplat

        cfg = PixelSplatExportConfig(
            out=args.out,
            stage=args.stage,
            chunk_bytes=int(args.chunk_mb * 1e6) if math.isfinite(args.chunk_mb) else 0,
            scenes=scene_ids,
            resize=parse_resize(args.resize),
            size_check=args.size_check,
        )
        s = export_pixelsplat(dataset, cfg, progress=progress)
        print(f"exported {s['scenes']} scenes in {s['chunks']} chunks to {s['directory']}")
        if s["scenes_peers_skip"]:
            print(
                f"seeu export: warning: the peers' loaders would skip {s['scenes_peers_skip']} of {s['scenes']} "
                f"scenes (first: {s['peers_skip'][0]})",
                file=sys.stderr,
            )
    else:
        from seeu_data.exporters.nerfstudio import NerfstudioExportConfig, export_nerfstudio

        s = export_nerfstudio(dataset, NerfstudioExportConfig(out=args.out, scenes=scene_ids), progress=progress)
        print(f"exported {s['scenes']} scenes ({s['frames']} frames) as nerfstudio folders under {args.out}")
    return 0
