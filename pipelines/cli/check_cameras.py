"""Check that a dataset's cameras agree with its images (epipolar geometry of SIFT matches).

PATH: a posed-frames folder (manifest.json), a nerfstudio transforms.json (or its folder), a COLMAP
model folder (cameras.bin/.txt; images from --images, else the images/ folder beside sparse/), or
pixelSplat chunks (*.torch, or a folder holding train/ or test/). For a few frame pairs per scene,
those that overlap most (the view-overlap table; however the frames are numbered or named), SIFT
matches (ratio test, mutual, RANSAC inliers) are compared with the epipolar lines of the stored
cameras (Sampson error, pixels); check.json lists the pairs used.
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

from pipelines.cli.config_flags import add_config_flags, config_from_args
from pipelines.cli.options import add_max_pixels, shared_values

SHARED_FLAGS = {"max_pixels": "max_pixels"}  # the shared flags and the CameraCheckConfig fields they set


def add_arguments(p: argparse.ArgumentParser) -> None:
    from seeu_data.camera_check import CameraCheckConfig

    add_config_flags(p, CameraCheckConfig)
    add_max_pixels(p)


def run(args: argparse.Namespace) -> int:
    from seeu_data.camera_check import CameraCheckConfig, check_cameras

    cfg = config_from_args(CameraCheckConfig, args, **shared_values(args, SHARED_FLAGS))
    rep = check_cameras(cfg)
    for s in rep["scenes"]:
        if s["verdict"] == "unchecked":
            line = f"  {s['scene_id']}: unchecked ({s['reason']})"
        else:
            overlaps = ", ".join(f"{d['overlap']:.2f}" for d in s["pair_details"] if d["used"])
            line = (
                f"  {s['scene_id']}: {s['verdict']}, median Sampson error {s['median_error_px']:.2f} px "
                f"(p90 {s['p90_error_px']:.2f}) over {s['matches']} inlier matches in {len(s['pairs'])} pairs "
                f"(overlap {overlaps}, from {s['overlap_method']})"
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
