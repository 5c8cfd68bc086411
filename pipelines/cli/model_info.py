"""Parameter counts per module of the SeeU model (trainable vs frozen), next to MVSplat's 12.0 M.

Example:
    seeu model-info                                   # the paper's model (DINOv3 ViT-B/16, CGT, CEA)
    seeu model-info --preset cpu_small --refiner unet --condition cls
    seeu model-info --condition blip2                 # BLIP-2 condition (needs pip install -e '.[blip2]')
    seeu model-info --json counts.json

Counting needs no pretrained weights: the frozen semantic encoder is built with random weights
(same architecture, same parameter count); BLIP-2's ~1.1 B frozen parameters are counted on the meta
device (no memory) unless --shapes needs them. Add --shapes to run one CPU forward pass on random
2-view inputs and print the tensor shapes of the intermediate results.
"""

from __future__ import annotations

import argparse

from pipelines.cli.config_flags import add_config_flags, config_from_args

SHARED_FLAGS: dict[str, str] = {}  # every flag comes from a `setting` of ModelInfoConfig


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from pipelines.model_info import ModelInfoConfig

    add_config_flags(parser, ModelInfoConfig)


def _fmt(n: int) -> str:
    return f"{n / 1e6:8.3f} M"


def run(args: argparse.Namespace) -> int:
    from pipelines.model_info import ModelInfoConfig, model_info

    info = model_info(config_from_args(ModelInfoConfig, args))
    c = info["config"]
    print(
        f"SeeU ({args.preset}): refiner={c['refiner']} condition={c['condition']} D={c['num_depth_candidates']} "
        f"s={c['downsample']} SH degree {c['sh_degree']}"
        + (f" semantic={info['semantic']}" if info["semantic"] else "")
    )
    print(f"{'module':<22}{'trainable':>12}{'frozen':>12}")
    for name, n in info["modules"].items():
        print(f"{name:<22}{_fmt(n['trainable']):>12}{_fmt(n['frozen']):>12}")
    total_t = info["total_trainable"]
    print(f"{'total':<22}{_fmt(total_t):>12}{_fmt(info['total_frozen']):>12}")
    print(
        f"MVSplat (reference):  {info['mvsplat_total'] / 1e6:.1f} M parameters in total (all trainable); "
        f"SeeU trainable / MVSplat = {total_t / info['mvsplat_total']:.2f}"
    )
    for k, s in info["shapes"].items():
        print(f"  {k:<18} {s}")
    return 0
