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

from pipelines.cli.options import add_out
from seeu_data.settings import parse_dims


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--checkpoint", required=True, help="a ckpt-*.pt file or a directory (its newest checkpoint)")
    src = parser.add_mutually_exclusive_group(required=True)
    src.add_argument("--data", help="triple shards to take the context views from")
    src.add_argument("--cameras", help="JSON with your own context images and cameras (see above)")
    parser.add_argument("--sample", default="0", help="with --data: sample index (in manifest order) or sample_id")
    add_out(parser, "output directory")
    parser.add_argument("--frames", type=int, default=30, help="frames per path (default 30)")
    parser.add_argument(
        "--extrapolate", type=float, default=0.5, help="extrapolated path runs from t=-e to 1+e (default 0.5)"
    )
    parser.add_argument("--fps", type=float, default=10.0)
    parser.add_argument("--image-size", default=None, metavar="HxW", help="default: the training image size")
    parser.add_argument("--device", default=None)
    parser.add_argument("--rasterizer", default=None, help="auto | torch | gsplat")


def run(args: argparse.Namespace) -> int:
    from pipelines.render import RenderConfig, render

    report = render(
        RenderConfig(
            checkpoint=args.checkpoint,
            out=args.out,
            data=args.data,
            sample=args.sample,
            cameras=args.cameras,
            frames=args.frames,
            extrapolate=args.extrapolate,
            fps=args.fps,
            image_size=parse_dims(args.image_size, "--image-size") if args.image_size else None,
            device=args.device,
            rasterizer=args.rasterizer,
        )
    )
    print(json.dumps(report, indent=2))
    return 0
