"""Train SeeU on triple shards (single process, or many with torchrun).

Examples:
  seeu train --data data/re10k/train --val data/re10k/test --config configs/re10k_paper.json --out runs/re10k
  seeu train --data out/shards/interp --config configs/cpu_small.json --out runs/cpu optim.max_steps=200
  seeu train --data ... --config ... --out runs/re10k --resume          # continue from the newest checkpoint
  seeu train --data ... --config configs/re10k_paper.json --out runs/ft --init-from runs/mvsplat/checkpoints
  torchrun --nproc_per_node=8 -m pipelines.cli train --data ... --config configs/re10k_paper.json --out runs/ddp
  (multi-node: torchrun --nnodes=N --node_rank=R --rdzv_endpoint=HOST:PORT --nproc_per_node=G -m pipelines.cli train ...)

Overrides are `section.key=value` after the options (optim.lr=1e-4 data.batch_size=4 model.refiner=unet
loss.lpips_weight=0). Writes OUT/config.json, OUT/checkpoints/ckpt-*.pt (atomic, last K kept),
OUT/tb (TensorBoard: losses, PSNR, lr, rendered vs ground-truth images, validation), OUT/train_summary.json
and OUT/cache (the loader's shard verification stamps and object-storage downloads; $SEEU_CACHE_DIR instead when set).
LPIPS(VGG) needs torchvision's vgg16-397923af.pth in $TORCH_HOME/hub/checkpoints or --lpips-weights PATH;
--no-lpips trains with MSE only.
A step whose loss, gradients or weights hold NaN/inf stops the run (exit 2, one line naming the step and
the batch's samples; no checkpoint holding a non-finite value is ever written), or with
--on-nonfinite skip-batch drops that batch's update and goes on. Checkpoints read by --resume and
--init-from (and by eval / render) must hold finite tensors of the model's shapes.
"""

from __future__ import annotations

import argparse
import json

from pipelines.cli.options import add_out, add_progress
from seeu_model.training.config import MAX_CONSECUTIVE_SKIPS, NONFINITE_POLICIES, TrainConfig


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--data", required=True, help="training triple shards (directory or object-storage URL)")
    parser.add_argument("--val", default=None, help="validation triple shards (evaluated every log.val_every steps)")
    parser.add_argument(
        "--config",
        default=None,
        help="config file, or a shipped preset by name: re10k_paper, cpu_small, cpu_tiny, demo (configs/*.json)",
    )
    add_out(parser, "run directory (checkpoints, TensorBoard, config)")
    parser.add_argument(
        "--resume",
        nargs="?",
        const=True,
        default=None,
        metavar="CKPT",
        help="continue from the newest checkpoint in OUT (or from CKPT)",
    )
    parser.add_argument(
        "--init-from",
        default=None,
        metavar="CKPT",
        help="start from the weights (and model config) of a SeeU checkpoint, e.g. one written by "
        "`seeu convert-checkpoint mvsplat`; step, optimizer and schedule start afresh",
    )
    parser.add_argument("--lpips-weights", default=None, metavar="PATH", help="torchvision's vgg16-397923af.pth")
    parser.add_argument("--no-lpips", action="store_true", help="train with MSE only (loss.lpips_weight=0)")
    parser.add_argument("--device", default=None, help="cpu, cuda, cuda:1 (default: this rank's GPU, else CPU)")
    parser.add_argument("--max-steps", type=int, default=None, help="shortcut for optim.max_steps=N")
    parser.add_argument(
        "--on-nonfinite",
        choices=NONFINITE_POLICIES,
        default=None,
        help="a step whose loss, gradients or weights hold NaN/inf: stop = exit 2 naming the step and the "
        "batch's samples, the last good checkpoint stays the newest; skip-batch = drop that batch's update "
        f"and go on ({MAX_CONSECUTIVE_SKIPS} such batches in a row stop the run as well; weights that went "
        f"non-finite always stop). Default: the config's on_nonfinite ({TrainConfig.on_nonfinite})",
    )
    add_progress(parser)
    parser.add_argument("overrides", nargs="*", metavar="KEY=VALUE", help="config overrides, e.g. optim.lr=1e-4")


def run(args: argparse.Namespace) -> int:
    from pipelines.train import TrainRunConfig, train

    result = train(
        TrainRunConfig(
            data=args.data,
            out=args.out,
            config=args.config,
            overrides=tuple(args.overrides),
            max_steps=args.max_steps,
            val=args.val,
            resume=args.resume,
            init_from=args.init_from,
            lpips=not args.no_lpips,
            lpips_weights=args.lpips_weights,
            device=args.device,
            progress=args.progress,  # None: the config's log.progress (default: on a terminal)
            on_nonfinite=args.on_nonfinite,  # None: the config's on_nonfinite (default: stop)
        )
    )
    if result.get("rank", 0) == 0:
        print(json.dumps({k: result[k] for k in ("step", "checkpoint", "steps_per_s", "final")}, indent=2))
    return 0
