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
  seeu demo --out out/quick --frames 36 --size 320x180 --steps 60 --image-size 32
"""

from __future__ import annotations

import argparse
from pathlib import Path

from pipelines.cli.options import add_force, add_out, add_progress, progress_wanted
from seeu_data.settings import parse_dims


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_out(p, "output directory (default out/demo)", default=Path("out/demo"))
    g = p.add_argument_group("synthetic clips")
    g.add_argument("--frames", type=int, default=72, help="frames per synthetic clip (default 72)")
    g.add_argument("--size", default="480x270", metavar="WxH", help="clip size WIDTHxHEIGHT (default 480x270)")
    g.add_argument("--seed", type=int, default=0, help="scene seed of the training clip (default 0)")
    g.add_argument(
        "--heldout-seed",
        type=int,
        default=None,
        help="scene seed of the held-out evaluation clip (default: --seed + 100)",
    )
    g = p.add_argument_group("training data and model")
    g.add_argument(
        "--image-size",
        default="64",
        metavar="HxW",
        help="training/evaluation image size, built into the shards (default 64 = 64x64)",
    )
    g.add_argument(
        "--train-samples", type=int, default=256, help="training triples drawn per posed chunk (default 256)"
    )
    g.add_argument(
        "--eval-samples", type=int, default=8, help="held-out triples per evaluation set, interp and extrap (default 8)"
    )
    g.add_argument(
        "--config",
        default="demo",
        help="training preset: a shipped preset's name or a config file (default demo = configs/demo.json)",
    )
    g.add_argument(
        "--steps",
        type=int,
        default=None,
        help="training steps (default: the preset's optim.max_steps; demo.json: 300, ~3 min on an idle 2-core CPU)",
    )
    g.add_argument(
        "--lpips-weights",
        default=None,
        metavar="PATH",
        help="torchvision's vgg16-397923af.pth for LPIPS (default: the torch hub cache; "
        "LPIPS is skipped when it is missing)",
    )
    g.add_argument("--render-frames", type=int, default=30, help="frames per rendered camera path (default 30)")
    add_force(p)
    add_progress(p)


def run(args: argparse.Namespace) -> int:
    from pipelines.demo import DemoConfig, demo
    from seeu_data.limits import MAX_VIDEO_SIDE

    result = demo(
        DemoConfig(
            out=args.out,
            frames=args.frames,
            size=parse_dims(
                args.size, "--size", minimum=16, maximum=MAX_VIDEO_SIDE
            ),  # WIDTHxHEIGHT, as video sizes are written
            seed=args.seed,
            heldout_seed=args.heldout_seed,
            image_size=parse_dims(args.image_size, "--image-size", minimum=16),
            train_samples=args.train_samples,
            eval_samples=args.eval_samples,
            config=args.config,
            steps=args.steps,
            lpips_weights=args.lpips_weights,
            render_frames=args.render_frames,
            force=args.force,
            progress=progress_wanted(args),
        )
    )
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
