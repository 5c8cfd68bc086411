"""Build the SeeU model from a config section and adapt it to the loops.

The ``model`` section of a training config holds ``SeeUConfig`` fields plus an optional
``preset`` ("paper", "cpu_small", "tiny"): ``{"preset": "cpu_small", "refiner": "unet"}``.
Checkpoints store the resolved ``SeeUConfig`` as a dict, so eval / render rebuild the same model.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import nn

from seeu_data.errors import SeeUError


def resolve_model_config(section: dict[str, Any]):
    """``{"preset": name, **fields}`` -> SeeUConfig (SeeUError on unknown fields or values)."""
    from seeu_model.config import SeeUConfig

    section = dict(section or {})
    preset = section.pop("preset", "paper")
    try:
        return SeeUConfig.preset(preset, **section)
    except (TypeError, ValueError) as exc:
        raise SeeUError(f"model config: {exc}") from None


def build_model(section: dict[str, Any]) -> tuple[nn.Module, dict]:
    """The SeeU model for a config section, and its full config as a dict (stored in checkpoints)."""
    from seeu_model.seeu import SeeU

    mcfg = resolve_model_config(section)
    return SeeU(mcfg), mcfg.to_dict()


def model_from_checkpoint(ckpt: dict, device: torch.device | str = "cpu", **model_overrides: Any) -> nn.Module:
    """Rebuild the model stored in a training checkpoint (frozen pretrained parts are loaded from
    their own weights, as in training) and load its trained state. Puts it in eval mode."""
    from seeu_model.config import SeeUConfig

    cfg_dict = dict(ckpt.get("model_config") or {})
    cfg_dict.update(model_overrides)
    try:
        mcfg = SeeUConfig(**cfg_dict)
    except (TypeError, ValueError) as exc:
        raise SeeUError(f"checkpoint model config is not valid for this toolkit: {exc}", ckpt.get("path")) from None
    from seeu_model.seeu import SeeU

    model = SeeU(mcfg)
    missing, unexpected = model.load_state_dict(ckpt["model"], strict=False)
    frozen = {n for n, p in model.named_parameters() if not p.requires_grad}
    missing = [m for m in missing if m not in frozen]
    if missing or unexpected:
        raise SeeUError(f"checkpoint does not match the model (missing {missing[:3]}, unexpected {unexpected[:3]})",
                        ckpt.get("path"))
    return model.to(device).eval()


def target_color(output: Any) -> torch.Tensor:
    """The rendered target views (B, T, 3, H, W) from a model forward output."""
    if isinstance(output, torch.Tensor):
        return output
    for attr in ("color", "render", "target", "rendered"):
        value = output.get(attr) if isinstance(output, dict) else getattr(output, attr, None)
        if value is None:
            continue
        if isinstance(value, torch.Tensor):
            return value
        return target_color(value)
    raise TypeError(f"cannot find the rendered target colours in a {type(output).__name__}")


def render_fn(model: nn.Module, batch: dict) -> torch.Tensor:
    """Training forward: ``model(batch)`` -> rendered target views (B, T, 3, H, W)."""
    return target_color(model(batch))


def encode_context(model: nn.Module, context: dict):
    """Encoder half: context views -> Gaussians (B, N, ...)."""
    return model.encode(context)


def render_gaussians(gaussians, target: dict, backend: str = "auto", model: nn.Module | None = None):
    """Renderer half: Gaussians -> RenderOutput of the target cameras (B, T, ...)."""
    if model is not None and hasattr(model, "render"):
        return model.render(gaussians, target)
    from seeu_model.rasterizer import rasterize

    h, w = target["image"].shape[-2:]
    return rasterize(gaussians, target["cam_to_world"], target["intrinsics"], w, h, backend=backend)
