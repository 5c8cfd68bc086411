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
import json


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--preset", default="paper", choices=["paper", "cpu_small", "tiny", "mvsplat"], help="model preset"
    )
    parser.add_argument("--refiner", choices=["none", "unet", "transformer"], help="override the refiner (ablation)")
    parser.add_argument(
        "--condition", choices=["cls", "cea", "clip", "blip2"], help="override the condition (ablation)"
    )
    parser.add_argument("--sh-degree", type=int, help="override the SH degree")
    parser.add_argument("--depth-candidates", type=int, help="override the number of depth candidates D")
    parser.add_argument("--shapes", action="store_true", help="run one forward pass and print intermediate shapes")
    parser.add_argument("--size", type=int, default=None, help="image size for --shapes (default: the preset's)")
    parser.add_argument("--json", metavar="PATH", help="also write the counts as JSON")


MVSPLAT_PARAMS = 12.0e6  # REFERENCE.md: MVSplat's total


def _fmt(n: int) -> str:
    return f"{n / 1e6:8.3f} M"


def _encoder_name(cfg) -> str:
    """The frozen encoder behind the condition: DINOv3 (cls / cea), CLIP or BLIP-2."""
    return {"clip": cfg.clip_backbone, "blip2": f"{cfg.blip2_model} (ViT-g + Q-Former)"}.get(
        cfg.condition, cfg.semantic_backbone
    )


def run(args: argparse.Namespace) -> int:
    import torch

    from contextlib import nullcontext

    from seeu_model.config import SeeUConfig
    from seeu_model.seeu import SeeU, parameter_counts

    overrides = {"semantic_pretrained": False, "semantic_weights": None}  # counting needs no weights
    if args.refiner:
        overrides["refiner"] = args.refiner
    if args.condition:
        overrides["condition"] = args.condition
    if args.sh_degree is not None:
        overrides["sh_degree"] = args.sh_degree
    if args.depth_candidates is not None:
        overrides["num_depth_candidates"] = args.depth_candidates
    cfg = SeeUConfig.preset(args.preset, **overrides)
    torch.manual_seed(0)
    meta = cfg.condition == "blip2" and not args.shapes  # count BLIP-2's ~1.1 B frozen parameters unallocated
    if meta:
        from seeu_model.semantic import blip2_random_init_on_meta
    with blip2_random_init_on_meta() if meta else nullcontext():
        model = SeeU(cfg)
    counts = parameter_counts(model)

    print(
        f"SeeU ({args.preset}): refiner={cfg.refiner} condition={cfg.condition} D={cfg.num_depth_candidates} "
        f"s={cfg.downsample} SH degree {cfg.sh_degree}"
        + (f" semantic={_encoder_name(cfg)}" if cfg.needs_semantic else "")
    )
    print(f"{'module':<22}{'trainable':>12}{'frozen':>12}")
    for name, (trainable, frozen) in counts.items():
        print(f"{name:<22}{_fmt(trainable):>12}{_fmt(frozen):>12}")
    total_t = sum(t for t, _ in counts.values())
    total_f = sum(f for _, f in counts.values())
    print(f"{'total':<22}{_fmt(total_t):>12}{_fmt(total_f):>12}")
    print(
        f"MVSplat (reference):  {MVSPLAT_PARAMS / 1e6:.1f} M parameters in total (all trainable); "
        f"SeeU trainable / MVSplat = {total_t / MVSPLAT_PARAMS:.2f}"
    )

    shapes = {}
    if args.shapes:
        size = args.size or cfg.image_size
        b, v = 1, 2
        c2w = torch.eye(4).repeat(b, v, 1, 1)
        c2w[:, 1, 0, 3] = 0.2
        intr = torch.tensor([[1.0, 0, 0.5], [0, 1.0, 0.5], [0, 0, 1]]).repeat(b, v, 1, 1)
        ctx = {
            "image": torch.rand(b, v, 3, size, size),
            "cam_to_world": c2w,
            "intrinsics": intr,
            "near": torch.ones(b, v),
            "far": torch.full((b, v), 100.0),
        }
        with torch.no_grad():
            enc = model.eval().encode_all(ctx)
        shapes = {
            "context image": list(ctx["image"].shape),
            "cost volume": list(enc.cost.shape),
            "coarse depth": list(enc.coarse_depth.shape),
            "entropy": list(enc.entropy.shape),
            "latent tokens": list(enc.latent.shape),
            "condition tokens": None if enc.condition is None else list(enc.condition.shape),
            "gaussian means": list(enc.gaussians.means.shape),
            "gaussian sh": list(enc.gaussians.sh.shape),
        }
        for k, s in shapes.items():
            print(f"  {k:<18} {s}")

    if args.json:
        from seeu_data.arrow_io import naming_os_errors

        with naming_os_errors(args.json), open(args.json, "w") as fh:
            json.dump(
                {
                    "preset": args.preset,
                    "config": cfg.to_dict(),
                    "modules": {k: {"trainable": t, "frozen": f} for k, (t, f) in counts.items()},
                    "total_trainable": total_t,
                    "total_frozen": total_f,
                    "mvsplat_total": MVSPLAT_PARAMS,
                    "shapes": shapes,
                },
                fh,
                indent=2,
            )
    return 0
