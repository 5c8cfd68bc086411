"""Predict 3D Gaussians and novel views of your own posed scene with a trained checkpoint.

Examples:
  seeu predict data/posed/clip --checkpoint runs/re10k/checkpoints --out out/predict
  seeu predict data/posed/clip --checkpoint runs/mvsplat-re10k/checkpoints --context 10,40 --out out/p
  seeu predict data/posed/re10k --scene 5aca87f95a9412c6 --checkpoint ckpt-00300000.pt --auto-context --out out/p

POSED_SCENE is a posed-frames directory (`seeu ingest` or `seeu import` output); --scene picks one
of its scenes when it holds several. Context frames: --context I,J (frame indices 0..N-1 of the
scene, two or more) or --auto-context (the default): the widest gap the build sampler's default
interpolation setting draws (45 frames, at most N-1), centred in the scene. The frames are resized
to cover the model's input size and centre-cropped (intrinsics updated), with the scene's near/far,
as `seeu render --cameras` does. Writes OUT/gaussians.ply (3DGS layout) with OUT/cameras.json and
OUT/gaussians.json, OUT/frames/{interp,extrap}_NNN.png (the path from the first to the last context
camera: t in [0, 1], and [-e, 1+e] with e = --extrapolate), OUT/context.png and OUT/predict.json
(written last); prints one summary line. A converted MVSplat checkpoint (`seeu convert-checkpoint`)
works the same way.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from pipelines.cli.options import add_max_pixels, add_out, max_pixels
from pipelines.predict import EXTRAPOLATE, FRAMES
from seeu_data.errors import SeeUError
from seeu_data.settings import parse_dims


def parse_context(text: str) -> tuple[int, ...]:
    """'10,40' -> (10, 40): frame indices (non-negative integers) separated by commas."""
    parts = [p.strip() for p in str(text).split(",")]
    if not all(p.isdigit() and len(p) <= 18 for p in parts):
        raise SeeUError(f"--context {text!r} is not frame indices I,J (e.g. 0,30)")
    return tuple(int(p) for p in parts)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scene_dir", type=Path, metavar="POSED_SCENE", help="posed-frames directory (manifest.json)")
    parser.add_argument("--checkpoint", required=True, help="a ckpt-*.pt file or a directory (its newest checkpoint)")
    parser.add_argument("--scene", help="scene id (default: the directory's only scene)")
    pick = parser.add_mutually_exclusive_group()
    pick.add_argument("--context", metavar="I,J", help="context frame indices (0..N-1)")
    pick.add_argument("--auto-context", action="store_true", help="pick the context pair (the default; rule above)")
    add_out(parser, "output directory")
    parser.add_argument("--frames", type=int, default=FRAMES, help=f"views per path (default {FRAMES})")
    parser.add_argument(
        "--extrapolate",
        type=float,
        default=EXTRAPOLATE,
        help=f"extrapolated path runs from t=-e to 1+e (default {EXTRAPOLATE})",
    )
    parser.add_argument("--image-size", default=None, metavar="HxW", help="default: the training image size")
    parser.add_argument("--device", default=None, help="default: cuda when available")
    parser.add_argument("--rasterizer", default=None, help="auto | torch | gsplat (default: the training config's)")
    add_max_pixels(parser)


def run(args: argparse.Namespace) -> int:
    from pipelines.predict import PredictConfig, predict

    rep = predict(
        PredictConfig(
            scene_dir=args.scene_dir,
            checkpoint=args.checkpoint,
            out=args.out,
            scene=args.scene,
            context=parse_context(args.context) if args.context else None,
            frames=args.frames,
            extrapolate=args.extrapolate,
            image_size=parse_dims(args.image_size, "--image-size") if args.image_size else None,
            device=args.device,
            rasterizer=args.rasterizer,
            max_pixels=max_pixels(args),
        )
    )
    print(
        f"predicted {rep['num_gaussians']} Gaussians of scene {rep['scene_id']} from frames "
        f"{','.join(map(str, rep['context_frames']))} ({rep['context_rule']}) at {rep['image_hw'][0]}x"
        f"{rep['image_hw'][1]}, {rep['interp']['frames']} interpolated + {rep['extrap']['frames']} extrapolated "
        f"views -> {args.out} (predict.json)"
    )
    return 0
