"""Evaluate a checkpoint: PSNR / SSIM / LPIPS by the peers' protocol, timing and peak memory.

Examples:
  seeu eval --checkpoint runs/re10k/checkpoints --data data/re10k/test_eval --out runs/re10k/eval
  seeu eval --checkpoint runs/cpu/checkpoints/ckpt-00000300.pt --data out/shards/extrap --no-lpips

Protocol (as pixelSplat / MVSplat / SeeU compute it): renders and ground truth clipped to [0, 1];
PSNR per image from its MSE; SSIM with an 11-pixel Gaussian window (sigma 1.5) as scikit-image
computes it; LPIPS(VGG) on [0, 1] inputs. Each metric is averaged over the targets of a scene, then
over scenes (summary.json also has the plain mean over all targets). Encoder (context -> Gaussians)
and renderer (Gaussians -> target views) are timed separately per sample after `--warmup` batches;
peak memory is CUDA's max allocated, or the process's peak RSS on CPU.
With ground truth (DTU, synthetic): --depth-gt gives the depth RMSE of the rendered expected depth
per target; --points-gt the DTUeval Chamfer distance (accuracy / completeness / overall, thinned to
0.2, distances < 20, observation mask when given) of the Gaussian centres with opacity >= 0.5.
Shards built from DTU imported with `seeu import dtu` need neither: the ground-truth paths the
importer records in the scene meta (Depths/*.pfm in mm, Points/stl, ObsMask/Plane .mat) are found
through the shards' manifest and used automatically (depth RMSE in scene units, Chamfer in mm).
Writes OUT/per_scene.csv, OUT/per_target.csv (OUT/chamfer.csv) and OUT/summary.json (written last).
"""

from __future__ import annotations

import argparse
import json

from pipelines.cli.config_flags import add_config_flags, config_from_args
from pipelines.cli.options import add_max_pixels, add_progress, shared_values

# The shared flags (pipelines/cli/options.py) and the EvalConfig fields they set; every other flag comes
# from a `setting` of EvalConfig.
SHARED_FLAGS = {"progress": "progress", "max_pixels": "max_pixels"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from pipelines.evaluate import EvalConfig

    add_config_flags(parser, EvalConfig)
    add_progress(parser)
    add_max_pixels(parser)


def run(args: argparse.Namespace) -> int:
    from pipelines.evaluate import EvalConfig, evaluate

    summary = evaluate(config_from_args(EvalConfig, args, **shared_values(args, SHARED_FLAGS)))
    keys = ("metrics", "by_overlap", "timing", "out") if summary.get("by_overlap") else ("metrics", "timing", "out")
    print(json.dumps({k: summary[k] for k in keys}, indent=2))
    return 0
