"""Build the SeeU model from a config section and adapt it to the loops.

The ``model`` section of a training config holds ``SeeUConfig`` fields plus an optional
``preset`` ("paper", "cpu_small", "tiny"): ``{"preset": "cpu_small", "refiner": "unet"}``.
Checkpoints store the resolved ``SeeUConfig`` as a dict, so eval / render rebuild the same model.
"""

from __future__ import annotations

import inspect
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import torch
from torch import nn

from seeu_data.errors import SeeUError

if TYPE_CHECKING:
    from seeu_model.gaussians import Gaussians


# The loops take any nn.Module; these are the optional methods they use when a model has them (SeeU does).
@runtime_checkable
class HasTrainableState(Protocol):
    def trainable_state_dict(self) -> Mapping[str, torch.Tensor]: ...


@runtime_checkable
class HasFrozenParts(Protocol):
    def frozen_prefixes(self) -> list[str]: ...


@runtime_checkable
class GaussianEncoder(Protocol):
    def encode(self, context: dict) -> Gaussians: ...


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
    their own weights, as in training) and load its trained state. Puts it in eval mode
    (`SeeU.from_checkpoint_dict`)."""
    from seeu_model.seeu import SeeU

    return SeeU.from_checkpoint_dict(ckpt, device, **model_overrides)


def _frozen_is_random(model_config: dict) -> bool:
    """True when the frozen encoders were randomly initialised (tests / CPU demo): their weights
    cannot be re-created from a file, so checkpoints must carry them."""
    return (
        model_config.get("semantic_pretrained") is False
        and not model_config.get("semantic_weights")
        and not model_config.get("clip_weights")
        and not model_config.get("blip2_weights")
    )


def model_state_for_checkpoint(model: nn.Module, model_config: dict) -> dict[str, torch.Tensor]:
    """What a checkpoint stores: the trainable state (frozen pretrained encoders are left out; they
    are reloaded from their weights), or everything when the frozen encoders are random."""
    if _frozen_is_random(model_config) or not isinstance(model, HasTrainableState):
        if isinstance(model, HasTrainableState):
            return {k: v.detach().cpu() for k, v in model.state_dict().items()}
        from seeu_model.training.checkpoint import trainable_state_dict

        return trainable_state_dict(model)
    return {k: v.detach().cpu() for k, v in model.trainable_state_dict().items()}


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


def make_render_fn(backend: str = "auto"):
    """Training forward: ``model(batch)`` -> rendered target views (B, T, 3, H, W)."""

    def render_fn(model: nn.Module, batch: dict) -> torch.Tensor:
        inner = getattr(model, "module", model)  # DDP wraps the model
        if "backend" in inspect.signature(inner.forward).parameters:
            return target_color(model(batch, backend=backend))
        return target_color(model(batch))

    return render_fn


def encode_context(model: nn.Module, context: dict) -> Gaussians:
    """Encoder half: context views -> Gaussians (B, N, ...)."""
    if not isinstance(model, GaussianEncoder):
        raise TypeError(f"{type(model).__name__} has no encode(context) method")
    return model.encode(context)


def render_gaussians(gaussians, target: dict, backend: str = "auto"):
    """Renderer half: Gaussians -> RenderOutput of the target cameras (B, T, ...), black background
    (as `SeeU.forward` renders in training)."""
    from seeu_model.rasterizer import rasterize

    h, w = target["image"].shape[-2:]
    return rasterize(gaussians, target["cam_to_world"], target["intrinsics"], w, h, backend=backend)
