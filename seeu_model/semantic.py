"""Frozen semantic encoders (paper §3.2.1): a DINOv3 ViT through timm, and CLIP's image tower for the
condition ablation. Weights come from the hub name, or from a local file for offline use; a clear
`SeeUError` says what is missing otherwise. Random initialisation happens only when asked
(``pretrained=False``), which the tests and the CPU demo use.

The encoders are frozen: parameters have ``requires_grad=False``, the module stays in eval mode
even under ``model.train()``, its forward runs under ``torch.no_grad()``, and `SeeU.trainable_state_dict`
leaves its weights out of checkpoints.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from seeu_data.errors import SeeUError


def create_timm_model(name: str, weights: str | None, pretrained: bool, what: str, flag: str,
                      **kwargs: Any) -> nn.Module:
    """Build a timm model with pretrained weights from ``weights`` (a local file), the hub, or (only when
    ``pretrained`` is False and no file is given) random initialisation. Raises SeeUError when weights
    cannot be loaded. ``flag`` names the config field / CLI option that supplies the file."""
    try:
        import timm
    except ImportError as exc:  # pragma: no cover - timm is a core dependency here
        raise SeeUError(f"the {what} needs the 'timm' package (pip install timm): {exc}") from exc
    if name not in timm.list_models(pretrained=False) and name.split(".")[0] not in timm.list_models():
        raise SeeUError(f"unknown timm model {name!r} for the {what}")
    if weights is not None:
        path = Path(weights)
        if not path.is_file():
            raise SeeUError(f"{what} weights file not found (given by {flag})", path)
        try:
            return timm.create_model(name, pretrained=True, pretrained_cfg_overlay=dict(file=str(path)), **kwargs)
        except Exception as exc:
            first = str(exc).splitlines()[0] if str(exc) else ""
            raise SeeUError(f"cannot load {what} weights for {name!r} from this file: {type(exc).__name__}: {first}",
                            path) from exc
    if not pretrained:
        return timm.create_model(name, pretrained=False, **kwargs)
    try:
        return timm.create_model(name, pretrained=True, **kwargs)
    except Exception as exc:
        first = str(exc).splitlines()[0] if str(exc) else ""
        raise SeeUError(
            f"cannot load pretrained {what} weights {name!r} from the Hugging Face hub "
            f"({type(exc).__name__}: {first[:160]}). Download the checkpoint once (e.g. model.safetensors of "
            f"https://huggingface.co/timm/{name}; DINOv3 weights are gated under the DINOv3 license) and pass "
            f"{flag}=PATH; random initialisation (semantic_pretrained=False) is for tests only"
        ) from exc


class FrozenModule(nn.Module):
    """Base class: all parameters frozen, always in eval mode."""

    def freeze(self) -> None:
        for p in self.parameters():
            p.requires_grad_(False)
        super().train(False)

    def train(self, mode: bool = True) -> "FrozenModule":  # noqa: ARG002 - stays in eval mode
        return super().train(False)


class FrozenViTEncoder(FrozenModule):
    """A frozen timm ViT (DINOv3 by default): images (B, V, 3, H, W) in [0, 1] ->
    cls (B, V, D) and patch features (B, V, D, H'/p, W'/p), where H', W' are H, W rounded to
    multiples of the patch size p (bilinear resize when needed). ImageNet-normalised input."""

    def __init__(self, name: str, weights: str | None = None, pretrained: bool = True,
                 model_kwargs: dict[str, Any] | None = None):
        super().__init__()
        self.name = name
        self.model = create_timm_model(name, weights, pretrained, "semantic encoder", "semantic_weights",
                                       **(model_kwargs or {}))
        cfg = getattr(self.model, "pretrained_cfg", {}) or {}
        mean = cfg.get("mean", (0.485, 0.456, 0.406))
        std = cfg.get("std", (0.229, 0.224, 0.225))
        self.register_buffer("mean", torch.tensor(mean).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(std).view(1, 3, 1, 1), persistent=False)
        patch = getattr(self.model, "patch_embed", None)
        self.patch_size = int(patch.patch_size[0]) if patch is not None else 16
        self.embed_dim = int(self.model.embed_dim)
        self.num_prefix_tokens = int(getattr(self.model, "num_prefix_tokens", 1))
        self.freeze()

    @torch.no_grad()
    def forward(self, images: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        b, v, _, h, w = images.shape
        p = self.patch_size
        gh, gw = max(1, round(h / p)), max(1, round(w / p))
        x = images.reshape(b * v, 3, h, w).float()
        if (gh * p, gw * p) != (h, w):
            x = F.interpolate(x, size=(gh * p, gw * p), mode="bilinear", align_corners=False, antialias=True)
        x = (x - self.mean) / self.std
        tokens = self.model.forward_features(x)  # (BV, prefix + gh*gw, D)
        cls = tokens[:, 0]
        patches = tokens[:, self.num_prefix_tokens:].transpose(1, 2).reshape(b * v, -1, gh, gw)
        return cls.reshape(b, v, -1), patches.reshape(b, v, -1, gh, gw)


class FrozenCLIPImageEncoder(FrozenModule):
    """CLIP's frozen image tower through timm (the paper's "CLIP embedding" ablation):
    images (B, V, 3, H, W) in [0, 1] -> projected image embeddings (B, V, D_clip), input resized to the
    model's native resolution (224 for ViT-B/16) and CLIP-normalised."""

    def __init__(self, name: str, weights: str | None = None, pretrained: bool = True,
                 model_kwargs: dict[str, Any] | None = None):
        super().__init__()
        self.model = create_timm_model(name, weights, pretrained, "CLIP image encoder", "clip_weights",
                                       **(model_kwargs or {}))
        cfg = getattr(self.model, "pretrained_cfg", {}) or {}
        self.input_size = tuple(cfg.get("input_size", (3, 224, 224))[1:])
        self.register_buffer("mean", torch.tensor(cfg.get("mean", (0.4815, 0.4578, 0.4082))).view(1, 3, 1, 1),
                             persistent=False)
        self.register_buffer("std", torch.tensor(cfg.get("std", (0.2686, 0.2613, 0.2758))).view(1, 3, 1, 1),
                             persistent=False)
        self.embed_dim = int(getattr(self.model, "num_classes", 0) or self.model.num_features)
        self.freeze()

    @torch.no_grad()
    def forward(self, images: torch.Tensor) -> torch.Tensor:
        b, v, _, h, w = images.shape
        x = images.reshape(b * v, 3, h, w).float()
        x = F.interpolate(x, size=self.input_size, mode="bilinear", align_corners=False, antialias=True)
        return self.model((x - self.mean) / self.std).reshape(b, v, -1)
