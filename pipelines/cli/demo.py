"""Run the whole toolkit on the built-in synthetic clip and leave a report with pictures to look at.

Stages (each resumable: a re-run with the same options reuses every finished stage; --force redoes):
  1. synth   two synthetic clips with exact ground truth: the training clip (--seed) and a held-out
             clip of an unseen scene (--heldout-seed: other textures and box layout)  -> OUT/clip/
  2. ingest  pose both with COLMAP SfM (pycolmap) into posed chunks; the ingest reports compare the
             poses with the ground truth                                             -> OUT/posed/
  3. build   context-target triples at the training size: OUT/shards/train from the training clip
             (extrap sampling with half the targets inside the pair: interpolation + extrapolation),
             OUT/shards/eval_interp and OUT/shards/eval_extrap from the held-out clip only, and
             contact sheets                                                          -> OUT/shards/
  4. train   the demo preset (configs/demo.json: the cpu_small SeeU) for --steps steps on CPU -> OUT/run/
  5. eval    PSNR / SSIM (/ LPIPS when the VGG weights are there) on the held-out shards, of the
             initial model (the exact weights training starts from) and of the trained one -> OUT/eval/
  6. render  interpolated and extrapolated camera paths (PNG frames, MP4) and the Gaussians (.ply)
             from a held-out example                                                 -> OUT/render/
  7. report  OUT/report.md: stage timings, SfM accuracy, shard counts, trajectory plot, contact
             sheet, training curve, renders next to ground truth, metrics table (init vs trained).

About 5 minutes on 2 idle CPU cores with the defaults (SfM ~1 min, training ~3 min; more on a busy
machine). Training length: --steps.

Examples:
  seeu demo --out out/demo
  seeu demo --out out/demo --steps 800          # train longer (re-uses synth, ingest and build)
  seeu demo --out out/quick --frames 36 --size 180x320 --steps 60 --image-size 32
"""

from __future__ import annotations

import argparse

from pipelines.cli.config_flags import add_config_flags, config_from_args
from pipelines.cli.options import add_force, add_progress, shared_values

SHARED_FLAGS = {"force": "force", "progress": "progress"}  # the shared flags and the DemoConfig fields they set


def add_arguments(p: argparse.ArgumentParser) -> None:
    from pipelines.demo import DemoConfig

    add_config_flags(p, DemoConfig)
    add_force(p)
    add_progress(p)


def run(args: argparse.Namespace) -> int:
    from pipelines.demo import DemoConfig, demo

    result = demo(config_from_args(DemoConfig, args, **shared_values(args, SHARED_FLAGS)))
    r = result["stages"]
    mean = r["eval"]["mean"]
    print(
        f"\nHeld-out PSNR {mean['init_psnr']:.2f} dB at initialisation -> {mean['trained_psnr']:.2f} dB trained "
        f"({mean['gain_psnr_db']:+.2f} dB) after {r['train']['step']} steps; demo took "
        f"{result['seconds']:.0f} s this run."
    )
    rows = [
        (
            result["report"],
            "the report: timings, SfM accuracy, shards, training curve, renders vs ground truth, metrics",
        ),
        (r["eval"]["metrics_json"], "held-out metrics, initial vs trained"),
        (r["render"]["extrap_mp4"], "novel views along an extrapolated camera path"),
        (r["render"]["ply"], "the predicted 3D Gaussians (standard 3DGS .ply)"),
    ]
    width = max(len(str(p)) for p, _ in rows)
    print("Look at:")
    for p, what in rows:
        print(f"  {str(p):<{width}}  {what}")
    return 0
