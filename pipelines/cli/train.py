"""Train SeeU on triple shards (single process, or many with torchrun).

Examples:
  seeu train --data data/re10k/train --val data/re10k/test --config configs/re10k_paper.json --out runs/re10k
  seeu train --data out/shards/interp --config configs/cpu_small.json --out runs/cpu optim.max_steps=200
  seeu train --data ... --config ... --out runs/re10k --resume          # continue from the newest checkpoint
  seeu train --data ... --config configs/re10k_paper.json --out runs/ft --init-from runs/mvsplat/checkpoints
  torchrun --nproc_per_node=8 -m pipelines.cli train --data ... --config configs/re10k_paper.json --out runs/ddp
  torchrun --nproc_per_node=2 -m pipelines.cli train ... --config re10k_paper --keep-effective-batch   # 2 x 4 = 8
  (multi-node: torchrun --nnodes=N --node_rank=R --rdzv_endpoint=HOST:PORT --nproc_per_node=G -m pipelines.cli train ...)

Overrides are `section.key=value` after the options (optim.lr=1e-4 data.batch_size=4 model.refiner=unet
loss.lpips_weight=0). Writes OUT/config.json, OUT/checkpoints/ckpt-*.pt (atomic, last K kept),
OUT/tb (TensorBoard: losses, PSNR, lr, rendered vs ground-truth images, validation), OUT/train_summary.json
and OUT/cache (the loader's shard verification stamps and object-storage downloads; $SEEU_CACHE_DIR instead when set).
The effective batch (data.batch_size per process x processes x optim.accumulate) is printed at the start
and stored in every checkpoint; --keep-effective-batch keeps the config's (written for one device).
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

from pipelines.cli.config_flags import add_config_flags, config_from_args
from pipelines.cli.options import add_out, add_progress

# The shared flags (pipelines/cli/options.py) and the TrainRunConfig fields they set; every other flag
# comes from a `setting` of TrainRunConfig. --progress is passed on as given (None: the config's
# log.progress, default on a terminal).
SHARED_FLAGS = {"out": "out", "progress": "progress"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from pipelines.train import TrainRunConfig

    add_config_flags(parser, TrainRunConfig)
    add_out(parser, "run directory (checkpoints, TensorBoard, config)")
    add_progress(parser)


def run(args: argparse.Namespace) -> int:
    from pipelines.train import TrainRunConfig, train

    result = train(config_from_args(TrainRunConfig, args, out=args.out, progress=args.progress))
    if result.get("rank", 0) == 0:
        print(json.dumps({k: result[k] for k in ("step", "checkpoint", "steps_per_s", "final")}, indent=2))
    return 0
