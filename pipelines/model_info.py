"""Parameter counts per module of the SeeU model (trainable vs frozen), next to MVSplat's 12.0 M
(`seeu model-info`), and optionally the tensor shapes of one forward pass.

Counting needs no pretrained weights: the frozen semantic encoder is built with random weights (same
architecture, same parameter count); BLIP-2's ~1.1 B frozen parameters are counted on the meta device
(no memory) unless the shapes are asked for.

Example:
    from pipelines.model_info import ModelInfoConfig, model_info

    info = model_info(ModelInfoConfig(preset="cpu_small", refiner="unet"))
    info["total_trainable"], info["modules"]["backbone"]      # {"trainable": ..., "frozen": ...}
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from seeu_data.errors import SeeUError
from seeu_data.limits import MAX_IMAGE_SIDE, check_range
from seeu_data.settings import parse_dims, setting

MVSPLAT_PARAMS = 12.0e6  # REFERENCE.md: MVSplat's total
PRESETS = ("paper", "cpu_small", "tiny", "mvsplat")


@dataclass(frozen=True)
class ModelInfoConfig:
    """preset: a SeeUConfig preset; refiner / condition / sh_degree / depth_candidates: overrides (None:
    the preset's); shapes: run one CPU forward pass on random 2-view inputs of `size` (None: the preset's)
    (H, W) and report the intermediate shapes; json_out: also write the result there."""

    preset: str = setting("paper", "model preset", choices=PRESETS)
    refiner: str | None = setting(None, "override the refiner (ablation)", choices=("none", "unet", "transformer"))
    condition: str | None = setting(None, "override the condition (ablation)", choices=("cls", "cea", "clip", "blip2"))
    sh_degree: int | None = setting(None, "override the SH degree")
    depth_candidates: int | None = setting(None, "override the number of depth candidates D")
    shapes: bool = setting(False, "run one forward pass and print intermediate shapes")
    size: tuple[int, int] | None = setting(  # (H, W)
        None, "image size for --shapes, e.g. 64 or 64x96 (default: the preset's)", parse=parse_dims, metavar="HxW"
    )
    json_out: Path | None = setting(None, "also write the counts as JSON", flag="--json", metavar="PATH")

    def check(self) -> None:
        if self.preset not in PRESETS:
            raise SeeUError(f"--preset must be one of {', '.join(PRESETS)}, got {self.preset!r}")
        for side in self.size or ():
            check_range(side, "--size", 1, MAX_IMAGE_SIDE)


def encoder_name(cfg) -> str:
    """The frozen encoder behind the condition: DINOv3 (cls / cea), CLIP or BLIP-2."""
    return {"clip": cfg.clip_backbone, "blip2": f"{cfg.blip2_model} (ViT-g + Q-Former)"}.get(
        cfg.condition, cfg.semantic_backbone
    )


def model_info(cfg: ModelInfoConfig) -> dict:
    """{"preset", "config" (SeeUConfig as a dict), "modules": {name: {"trainable", "frozen"}},
    "total_trainable", "total_frozen", "mvsplat_total", "shapes": {what: [dims]} (empty without
    `cfg.shapes`), "semantic": the frozen encoder's name or None}."""
    from contextlib import nullcontext

    import torch

    from seeu_model.config import SeeUConfig
    from seeu_model.seeu import SeeU, parameter_counts

    cfg.check()
    overrides: dict = {"semantic_pretrained": False, "semantic_weights": None}  # counting needs no weights
    if cfg.refiner:
        overrides["refiner"] = cfg.refiner
    if cfg.condition:
        overrides["condition"] = cfg.condition
    if cfg.sh_degree is not None:
        overrides["sh_degree"] = cfg.sh_degree
    if cfg.depth_candidates is not None:
        overrides["num_depth_candidates"] = cfg.depth_candidates
    model_cfg = SeeUConfig.preset(cfg.preset, **overrides)
    torch.manual_seed(0)
    meta = model_cfg.condition == "blip2" and not cfg.shapes  # count BLIP-2's ~1.1 B frozen parameters unallocated
    if meta:
        from seeu_model.semantic import blip2_random_init_on_meta
    with blip2_random_init_on_meta() if meta else nullcontext():
        model = SeeU(model_cfg)
    counts = parameter_counts(model)
    shapes = {}
    if cfg.shapes:
        h, w = cfg.size or (model_cfg.image_size, model_cfg.image_size)
        b, v = 1, 2
        c2w = torch.eye(4).repeat(b, v, 1, 1)
        c2w[:, 1, 0, 3] = 0.2
        intr = torch.tensor([[1.0, 0, 0.5], [0, 1.0, 0.5], [0, 0, 1]]).repeat(b, v, 1, 1)
        ctx = {
            "image": torch.rand(b, v, 3, h, w),
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
    info = {
        "preset": cfg.preset,
        "config": model_cfg.to_dict(),
        "modules": {k: {"trainable": t, "frozen": f} for k, (t, f) in counts.items()},
        "total_trainable": sum(t for t, _ in counts.values()),
        "total_frozen": sum(f for _, f in counts.values()),
        "mvsplat_total": MVSPLAT_PARAMS,
        "shapes": shapes,
    }
    if cfg.json_out is not None:  # written where it is named (a device such as /dev/stdout too): no rename
        from seeu_data.store.arrow_io import naming_os_errors

        with naming_os_errors(cfg.json_out), open(cfg.json_out, "w") as fh:
            json.dump(info, fh, indent=2)
    info["semantic"] = encoder_name(model_cfg) if model_cfg.needs_semantic else None
    return info
