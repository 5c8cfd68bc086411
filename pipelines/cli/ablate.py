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

from pipelines.ablate import DEFAULT_VARIANTS, MODEL_VARIANTS
from pipelines.cli.options import add_out, add_progress
from seeu_data.errors import SeeUError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", required=True, help="the shared training config (equal budget for all)")
    parser.add_argument("--data", required=True, help="training shards of the model variants")
    parser.add_argument("--eval", required=True, dest="eval_data", help="evaluation shards (same for every variant)")
    add_out(parser, "output directory: one run per variant (OUT/<variant>), ablation.md and ablation.csv")
    parser.add_argument(
        "--variants",
        default=",".join(DEFAULT_VARIANTS),
        help=f"comma list of {', '.join(MODEL_VARIANTS)} (default {','.join(DEFAULT_VARIANTS)})",
    )
    parser.add_argument(
        "--ext-data",
        action="append",
        default=[],
        metavar="N=PATH",
        help="training shards with extrapolation range N frames (adds variant extN)",
    )
    parser.add_argument("--posed", default=None, help="posed frames to build the extrapolation-range shards from")
    parser.add_argument("--ext-ranges", default="0,45,90", help="with --posed: ranges to build (default 0,45,90)")
    parser.add_argument("--max-eval-samples", type=int, default=0)
    parser.add_argument("--lpips-weights", default=None, metavar="PATH")
    parser.add_argument("--no-lpips", action="store_true", help="MSE-only training and no LPIPS in the table")
    parser.add_argument("--device", default=None)
    add_progress(parser)
    parser.add_argument("overrides", nargs="*", metavar="KEY=VALUE", help="config overrides for every variant")


def parse_ext_data(items: list[str]) -> dict[int, str]:
    """`--ext-data N=PATH` (repeated) -> {N: PATH}."""
    ext: dict[int, str] = {}
    for item in items:
        n, _, path = item.partition("=")
        if not n.strip().isdigit() or not path:
            raise SeeUError(f"--ext-data {item!r} is not N=PATH")
        ext[int(n)] = path
    return ext


def run(args: argparse.Namespace) -> int:
    from pipelines.ablate import AblateConfig, ablate

    try:
        ranges = tuple(int(x) for x in args.ext_ranges.split(",") if x.strip()) if args.posed else ()
    except ValueError:
        raise SeeUError(f"--ext-ranges {args.ext_ranges!r} is not a list of frame counts (e.g. 0,45,90)") from None
    rows = ablate(
        AblateConfig(
            config=args.config,
            data=args.data,
            eval_data=args.eval_data,
            out=args.out,
            variants=tuple(v.strip() for v in args.variants.split(",") if v.strip()),
            ext_data=parse_ext_data(args.ext_data),
            posed=args.posed,
            ext_ranges=ranges,
            overrides=tuple(args.overrides),
            max_eval_samples=args.max_eval_samples,
            lpips=not args.no_lpips,
            lpips_weights=args.lpips_weights,
            device=args.device,
            progress=args.progress,  # None: the config's log.progress (default: on a terminal)
        )
    )
    print((Path(args.out) / "ablation.md").read_text())
    return 0 if rows else 1
