"""Run the paper's ablations with equal budgets and write one comparison table.

Examples:
  seeu ablate --config configs/cpu_small.json --data out/shards/extrap --eval out/shards/eval --out runs/ablate
  seeu ablate --config configs/re10k_paper.json --data re10k/train_ext45 --eval re10k/test_extrap \
      --variants full,no_refiner,unet,cls,clip,blip2 --ext-data 0=re10k/train_ext0 --ext-data 90=re10k/train_ext90 \
      --out runs/ablate model.clip_weights=/weights/clip_b16.safetensors model.blip2_weights=/weights/blip2-image
  seeu ablate ... --posed out/posed --ext-ranges 0,45,90        # build the extrapolation-range shards here

Variants (paper tables 4-6): `full` (Conditional Gaussian Transformer + CEA), `no_refiner`
("w/o Refinement"), `unet` ("w/ UNet Backbone"), `cls` (DINOv3 class embedding), `clip` (CLIP
embedding; needs its weights), `blip2` (BLIP-2 embedding: ViT-g + Q-Former query tokens; needs
`pip install -e '.[blip2]'` and its weights, from the hub `model.blip2_model=REPO` or offline
`model.blip2_weights=DIR`), and `ext<N>` (the full model trained on shards whose extrapolated targets
reach N frames outside the context pair; from --ext-data N=PATH or built from --posed).
Every variant uses the same config, seed, steps, batch size and schedule (equal budgets), is
evaluated on the same --eval shards, and lands in OUT/ablation.md and OUT/ablation.csv (deltas
against `full`). Finished variants are reused on a re-run (delete OUT/<variant> to redo one).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from pipelines.cli.config_flags import add_config_flags, config_from_args
from pipelines.cli.options import add_out, add_progress

# The shared flags (pipelines/cli/options.py) and the AblateConfig fields they set; every other flag
# comes from a `setting` of AblateConfig. --progress is passed on as given (None: the config's
# log.progress, default on a terminal).
SHARED_FLAGS = {"out": "out", "progress": "progress"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from pipelines.ablate import AblateConfig

    add_config_flags(parser, AblateConfig)
    add_out(parser, "output directory: one run per variant (OUT/<variant>), ablation.md and ablation.csv")
    add_progress(parser)


def run(args: argparse.Namespace) -> int:
    from pipelines.ablate import AblateConfig, ablate

    rows = ablate(config_from_args(AblateConfig, args, out=args.out, progress=args.progress))
    print((Path(args.out) / "ablation.md").read_text())
    return 0 if rows else 1
