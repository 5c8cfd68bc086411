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
from pathlib import Path

from pipelines.cli.options import add_max_pixels, add_progress, max_pixels, progress_wanted
from seeu_data.settings import parse_dims


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--checkpoint", required=True, help="a ckpt-*.pt file or a directory (its newest checkpoint)")
    parser.add_argument(
        "--data", required=True, help="evaluation triple shards (seeu build --mode eval, or interp/extrap)"
    )
    parser.add_argument(
        "--out", type=Path, default=None, metavar="OUT", help="output directory (default: RUN/eval/<data name>)"
    )
    parser.add_argument("--batch-size", type=int, default=1)
    parser.add_argument("--image-size", default=None, metavar="HxW", help="default: the training image size")
    parser.add_argument("--max-samples", type=int, default=0, help="evaluate at most N samples (0: all)")
    parser.add_argument("--warmup", type=int, default=2, help="batches run before timing starts")
    parser.add_argument("--lpips-weights", default=None, metavar="PATH", help="torchvision's vgg16-397923af.pth")
    parser.add_argument("--no-lpips", action="store_true", help="skip LPIPS (reported as null)")
    parser.add_argument("--device", default=None, help="cpu or cuda (default: cuda when available)")
    parser.add_argument("--rasterizer", default=None, help="auto | torch | gsplat (default: the training config's)")
    parser.add_argument("--num-workers", type=int, default=0)
    parser.add_argument(
        "--depth-gt",
        default=None,
        metavar="DIR",
        help="ground-truth depth maps DIR/<scene_id>/<frame_index:06d>.npy|.pfm -> depth RMSE",
    )
    parser.add_argument(
        "--points-gt",
        default=None,
        metavar="DIR",
        help="ground-truth points DIR/<scene_id>/points.npy|.ply [+ obs_mask.npz] -> DTUeval Chamfer",
    )
    parser.add_argument(
        "--geometry-scale",
        type=float,
        default=1.0,
        help="multiply predicted points by this before Chamfer (DTU: 200 -> mm)",
    )
    add_progress(parser)
    add_max_pixels(parser)


def run(args: argparse.Namespace) -> int:
    from pipelines.evaluate import EvalConfig, evaluate

    summary = evaluate(
        EvalConfig(
            checkpoint=args.checkpoint,
            data=args.data,
            out=args.out,
            batch_size=args.batch_size,
            image_size=parse_dims(args.image_size, "--image-size") if args.image_size else None,
            max_samples=args.max_samples,
            warmup=args.warmup,
            lpips=not args.no_lpips,
            lpips_weights=args.lpips_weights,
            device=args.device,
            rasterizer=args.rasterizer,
            num_workers=args.num_workers,
            progress=progress_wanted(args),
            depth_gt=args.depth_gt,
            points_gt=args.points_gt,
            geometry_scale=args.geometry_scale,
            max_pixels=max_pixels(args),
        )
    )
    print(json.dumps({k: summary[k] for k in ("metrics", "timing", "out")}, indent=2))
    return 0
