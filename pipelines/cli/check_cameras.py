"""Check that a dataset's cameras agree with its images (epipolar geometry of SIFT matches).

PATH: a posed-frames folder (manifest.json), a nerfstudio transforms.json (or its folder), a COLMAP
model folder (cameras.bin/.txt; images from --images, else the images/ folder beside sparse/), or
pixelSplat chunks (*.torch, or a folder holding train/ or test/). For a few frame pairs per scene,
SIFT matches are compared with the epipolar lines of the stored cameras (Sampson error, pixels).
Exit 0: consistent (median under --max-error). Exit 1: not (or a convention fix fits 3x better),
with the likely cause when a common convention mistake fits (c2w/w2c swapped, OpenGL axes, pixel vs normalised intrinsics, principal
point, transposed rotations). Exit 2: PATH is not a dataset. Also notes scenes the pixelSplat /
MVSplat RE10K loader would skip (views not 360x640, field of view above 100 degrees), suggests
near/far from the points (the SfM points ingest kept, else the triangulated matches; the rule of
seeu ingest, and the rescale that fits the RE10K 1 / 100) and warns when the stored ones clip them.

Examples:
  seeu check-cameras data/posed/clip
  seeu check-cameras scene/transforms.json --out check/ --pairs 5
  seeu check-cameras scene/sparse/0 --images scene/images
"""

from __future__ import annotations

import argparse
from pathlib import Path

from pipelines.cli.options import add_max_pixels, max_pixels
from seeu_data.camera_check import MAX_ERROR_PX, MAX_SCENES, PAIRS_PER_SCENE


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("path", type=Path, help="dataset: posed frames, transforms.json, COLMAP model or pixelSplat chunks")
    p.add_argument(
        "--pairs", type=int, default=PAIRS_PER_SCENE, help=f"frame pairs matched per scene (default {PAIRS_PER_SCENE})"
    )
    p.add_argument(
        "--max-error",
        type=float,
        default=MAX_ERROR_PX,
        metavar="PX",
        help=f"largest median Sampson error (pixels) of consistent cameras (default {MAX_ERROR_PX})",
    )
    p.add_argument("--max-scenes", type=int, default=MAX_SCENES, help=f"scenes checked at most (default {MAX_SCENES})")
    p.add_argument("--images", type=Path, help="a COLMAP model's image folder (default: images/ beside sparse/)")
    p.add_argument("--out", type=Path, help="write check.json and epipolar.png (a pair with its epipolar lines) here")
    add_max_pixels(p)


def run(args: argparse.Namespace) -> int:
    from seeu_data.camera_check import CameraCheckConfig, check_cameras

    cfg = CameraCheckConfig(
        path=args.path,
        pairs=args.pairs,
        max_error=args.max_error,
        max_scenes=args.max_scenes,
        images=args.images,
        out=args.out,
        max_pixels=max_pixels(args),
    )
    rep = check_cameras(cfg)
    for s in rep["scenes"]:
        if s["verdict"] == "unchecked":
            line = f"  {s['scene_id']}: unchecked ({s['reason']})"
        else:
            line = (
                f"  {s['scene_id']}: {s['verdict']}, median Sampson error {s['median_error_px']:.2f} px "
                f"(p90 {s['p90_error_px']:.2f}) over {s['matches']} matches in {len(s['pairs'])} pairs"
            )
        print(line)
        if s.get("cause_text"):
            print(f"    cause: {s['cause_text']}; fix: {s['suggestion']}")
        nf = s.get("near_far")
        if nf:
            stored = f"stored {nf['stored'][0]:g} / {nf['stored'][1]:g}" if nf["stored"] else "none stored"
            print(
                f"    near/far from {nf['points']} {nf['source'].replace('_', ' ')}: {nf['near']:.3g} / {nf['far']:.3g} "
                f"({stored}; for the RE10K 1 / 100 scale the poses by {nf['re10k_scale']:.3g})"
            )
            if nf["stored_clips"]:
                print(f"    warning: the stored near/far clip the points ({nf['stored_clips']})")
        if s["peer_loader_skips"]:
            print(f"    note: the pixelSplat/MVSplat RE10K loader would skip it ({'; '.join(s['peer_loader_skips'])})")
    for s in rep["skipped"]:
        print(f"  {s['scene_id']}: not read ({s['reason']})")
    print(
        f"{rep['verdict'].upper()} {rep['path']} ({rep['kind']}): median Sampson error {rep['median_error_px']:.2f} px "
        f"(threshold {rep['max_error_px']:g} px)"
    )
    if rep["cause"]:
        print(f"cause: {rep['cause']}")
    if rep["figure"]:
        print(f"epipolar lines: {rep['figure']}")
    return 0 if rep["verdict"] == "consistent" else 1
