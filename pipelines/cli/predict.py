"""Predict 3D Gaussians and novel views of your own posed scene with a trained checkpoint.

Examples:
  seeu predict data/posed/clip --checkpoint runs/re10k/checkpoints --out out/predict
  seeu predict data/posed/clip --checkpoint runs/mvsplat-re10k/checkpoints --context 10,40 --out out/p
  seeu predict data/posed/re10k --scene 5aca87f95a9412c6 --checkpoint ckpt-00300000.pt --auto-context --out out/p

POSED_SCENE is a posed-frames directory (`seeu ingest` or `seeu import` output); --scene picks one
of its scenes when it holds several. Context frames: --context I,J (frame indices 0..N-1 of the
scene, two or more) or --auto-context (the default): by the scene's view overlap, the pair that best
covers the scene's views among those overlapping at least `seeu build`'s --min-overlap default
(whatever the frames' order or names; a warning when no pair does), with the extrapolated path
shortened to where the contexts still see something. The frames are resized
to cover the model's input size and centre-cropped (intrinsics updated), with the scene's near/far,
as `seeu render --cameras` does. Writes OUT/gaussians.ply (3DGS layout) with OUT/cameras.json and
OUT/gaussians.json, OUT/frames/{interp,extrap}_NNN.png (the path from the first to the last context
camera: t in [0, 1], and [-e, 1+e] with e = --extrapolate), OUT/context.png and OUT/predict.json
(written last); prints one summary line. A converted MVSplat checkpoint (`seeu convert-checkpoint`)
works the same way.
"""

from __future__ import annotations

import argparse
import sys

from pipelines.cli.config_flags import add_config_flags, config_from_args
from pipelines.cli.options import add_max_pixels, add_out, shared_values

SHARED_FLAGS = {"out": "out", "max_pixels": "max_pixels"}  # the shared flags and the PredictConfig fields they set


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from pipelines.predict import PredictConfig

    add_config_flags(parser, PredictConfig)
    add_out(parser, "output directory")
    add_max_pixels(parser)


def run(args: argparse.Namespace) -> int:
    from pipelines.predict import PredictConfig, predict

    rep = predict(config_from_args(PredictConfig, args, **shared_values(args, SHARED_FLAGS)))
    auto = rep.get("auto_context")
    if auto and auto.get("warning"):
        print(f"seeu predict: warning: {auto['warning']}", file=sys.stderr)
    if auto and auto["extrapolate"]["used"] < auto["extrapolate"]["requested"]:
        print(
            f"seeu predict: note: extrapolated path shortened to e = {auto['extrapolate']['used']:g} "
            f"(beyond it the contexts share less than {auto['floor']:g} with the view)",
            file=sys.stderr,
        )
    print(
        f"predicted {rep['num_gaussians']} Gaussians of scene {rep['scene_id']} from frames "
        f"{','.join(map(str, rep['context_frames']))} ({rep['context_rule']}) at {rep['image_hw'][0]}x"
        f"{rep['image_hw'][1]}, {rep['interp']['frames']} interpolated + {rep['extrap']['frames']} extrapolated "
        f"views -> {args.out} (predict.json)"
    )
    return 0
