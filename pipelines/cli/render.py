"""Render novel views and export the Gaussians (.ply) from a trained checkpoint.

Examples:
  seeu render --checkpoint runs/cpu/checkpoints --data out/shards/eval --sample 0 --out out/render
  seeu render --checkpoint runs/re10k/checkpoints --cameras my_views.json --out out/mine --frames 60

Context views come from a triple shard example (`--data`, `--sample` index or sample_id) or from
your own images with cameras (`--cameras FILE.json`):

  {"near": 0.5, "far": 100.0,
   "frames": [{"image": "left.jpg",  "cam_to_world": [[...4x4...]], "intrinsics_norm": [fx/W, fy/H, cx/W, cy/H]},
              {"image": "right.jpg", "cam_to_world": [[...]], "K": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]}]}

(OpenCV camera-to-world; intrinsics normalised or as a pixel K of the image as stored; image paths
relative to the JSON file.) Images are resized and centre-cropped to the model's input size with
the intrinsics updated. The camera path goes from the first to the last context camera (rotation
along the geodesic, centre on the line): `interp` covers t in [0, 1], `extrap` t in
[-e, 1 + e] with e = --extrapolate. Writes OUT/frames/{interp,extrap}_NNN.png, OUT/interp.mp4,
OUT/extrap.mp4, OUT/gaussians.ply (standard 3DGS layout) with OUT/cameras.json (the 3DGS viewers'
camera layout) and OUT/gaussians.json (SH degree, count), OUT/context.png, OUT/targets.png
(shard examples: ground truth over rendering) and OUT/render.json (written last).
"""

from __future__ import annotations

import argparse
import json

from pipelines.cli.config_flags import add_config_flags, config_from_args
from pipelines.cli.options import add_max_pixels, add_out, shared_values

SHARED_FLAGS = {"out": "out", "max_pixels": "max_pixels"}  # the shared flags and the RenderConfig fields they set


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from pipelines.render import RenderConfig

    add_config_flags(parser, RenderConfig)
    add_out(parser, "output directory")
    add_max_pixels(parser)


def run(args: argparse.Namespace) -> int:
    from pipelines.render import RenderConfig, render

    report = render(config_from_args(RenderConfig, args, **shared_values(args, SHARED_FLAGS)))
    print(json.dumps(report, indent=2))
    return 0
