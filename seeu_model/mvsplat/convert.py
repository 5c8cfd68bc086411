"""Convert an MVSplat Lightning checkpoint into a SeeU checkpoint (``encoder: "mvsplat"``).

Reading is safe: the file is opened with ``torch.load(weights_only=True)``, which builds tensors and
plain containers only. Lightning checkpoints often also pickle other objects (hyper-parameters as
OmegaConf containers, paths, callbacks' state); every such global is replaced by an inert stand-in class
that records its arguments and runs nothing, and only ``state_dict`` is kept, whose values must be tensors.

Keys: ``encoder.*`` are MVSplat's encoder (mapped one by one by `keymap.map_key`), ``losses.*`` its
training loss networks (LPIPS' VGG; ignored), anything else is unexpected. The result reports every
key as mapped, missing, unexpected or ignored; a file without MVSplat's encoder keys is refused.
"""

from __future__ import annotations

import zipfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from seeu_data.errors import SeeUError

from .keymap import map_key, shape_from_state

IGNORED_PREFIXES = ("losses.",)


def _stand_in(name: str) -> type:
    """An inert class standing in for the pickled global `name`: it accepts any construction and state."""

    def _new(cls, *args, **kwargs):
        obj = object.__new__(cls)
        obj.__dict__["_args"] = args
        return obj

    def _setstate(self, state):
        self.__dict__["_state"] = state

    return type(
        f"StandIn[{name}]",
        (),
        {"__new__": _new, "__init__": lambda self, *a, **k: None, "__setstate__": _setstate, "__module__": __name__},
    )


def read_lightning_state_dict(path: str | Path) -> dict[str, torch.Tensor]:
    """A Lightning checkpoint file -> its ``state_dict`` (tensors only), without executing pickled code."""
    p = Path(path)
    if not p.is_file():
        raise SeeUError("checkpoint not found", p)
    if not zipfile.is_zipfile(p):
        raise SeeUError("not a PyTorch checkpoint (expected torch.save's zip format)", p)
    try:
        unsafe = torch.serialization.get_unsafe_globals_in_checkpoint(str(p))
        stand_ins: list[Callable[..., Any] | tuple[Callable[..., Any], str]] = [(_stand_in(n), n) for n in unsafe]
        with torch.serialization.safe_globals(stand_ins):
            ckpt = torch.load(p, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - any unreadable / refused file: one line, no traceback
        raise SeeUError(
            f"not a readable checkpoint ({type(exc).__name__}: {str(exc).splitlines()[0][:120]})", p
        ) from None
    state = ckpt.get("state_dict") if isinstance(ckpt, dict) else None
    if not isinstance(state, dict):
        raise SeeUError("not an MVSplat checkpoint: no 'state_dict' (a Lightning checkpoint is expected)", p)
    bad = [k for k, v in state.items() if not isinstance(k, str) or not isinstance(v, torch.Tensor)]
    if bad:
        raise SeeUError(f"not an MVSplat checkpoint: state_dict entries that are not tensors: {bad[:3]}", p)
    return dict(state)


@dataclass
class ConversionReport:
    """What happened to every key. mapped: (MVSplat key, SeeU key, shape)."""

    mapped: list[tuple[str, str, tuple[int, ...]]] = field(default_factory=list)
    missing: list[str] = field(default_factory=list)  # SeeU keys nothing was mapped onto
    unexpected: list[str] = field(default_factory=list)  # checkpoint keys with no place in SeeU
    ignored: list[str] = field(default_factory=list)  # training-only keys (the loss networks)

    def lines(self) -> list[str]:
        out = [f"mapped {mv} -> {ours} {list(shape)}" for mv, ours, shape in self.mapped]
        out += [f"missing {k}" for k in self.missing]
        out += [f"unexpected {k}" for k in self.unexpected]
        out += [f"ignored {k}" for k in self.ignored]
        return out

    def summary(self) -> str:
        return (
            f"{len(self.mapped)} keys mapped, {len(self.missing)} missing, {len(self.unexpected)} unexpected, "
            f"{len(self.ignored)} ignored (training losses)"
        )


def convert_state_dict(state: dict[str, torch.Tensor], where=None):
    """MVSplat's Lightning ``state_dict`` -> (SeeUConfig, SeeU state dict, ConversionReport).

    The encoder structure is read off the weights' shapes (`keymap.shape_from_state`); the SeeU state dict
    is checked against a freshly built model of that configuration (names and shapes)."""
    from seeu_model.config import SeeUConfig
    from seeu_model.seeu import SeeU

    encoder = {k[len("encoder.") :]: v for k, v in state.items() if k.startswith("encoder.")}
    if "backbone.backbone.conv1.weight" not in encoder or "depth_predictor.to_gaussians.2.weight" not in encoder:
        raise SeeUError(
            "not an MVSplat checkpoint: no MVSplat encoder weights (encoder.backbone.*, "
            "encoder.depth_predictor.*) in its state_dict",
            where,
        )
    try:
        shape = shape_from_state(encoder)
    except (KeyError, IndexError, ValueError) as exc:
        raise SeeUError(f"not an MVSplat checkpoint of a known structure (no {exc})", where) from None
    cfg = SeeUConfig.mvsplat(
        num_depth_candidates=shape.num_depth_candidates,
        sh_degree=shape.sh_degree,
        mv_layers=shape.transformer_layers,
        mv_ffn_ratio=shape.ffn_ratio,
        mvsplat_cnn_channels=shape.cnn_channels,
        mvsplat_feature_dim=shape.feature_dim,
        mvsplat_cost_unet_channels=shape.cost_unet_channels,
        mvsplat_cost_unet_levels=len(shape.cost_unet_mult),
        mvsplat_cost_unet_attention=shape.cost_unet_attention,
        mvsplat_depth_unet_channels=shape.depth_unet_channels,
        mvsplat_depth_unet_levels=len(shape.depth_unet_mult),
        mvsplat_depth_unet_attention=shape.depth_unet_attention,
    )
    expected = {k: tuple(v.shape) for k, v in SeeU(cfg).state_dict().items()}
    report = ConversionReport()
    out: dict[str, torch.Tensor] = {}
    for key, value in state.items():
        if key.startswith(IGNORED_PREFIXES):
            report.ignored.append(key)
            continue
        ours = map_key(key[len("encoder.") :]) if key.startswith("encoder.") else None
        target = f"mvsplat.{ours}" if ours else None
        if target is None or target not in expected or expected[target] != tuple(value.shape):
            report.unexpected.append(key)
            continue
        out[target] = value.detach().clone().float()
        report.mapped.append((key, target, tuple(value.shape)))
    report.missing = [k for k in expected if k not in out]
    return cfg, out, report


def convert_checkpoint(
    path: str | Path, out_dir: str | Path, allow_incomplete: bool = False
) -> tuple[Path, ConversionReport]:
    """Read an MVSplat checkpoint safely, convert it and write ``out_dir/ckpt-00000000.pt`` (a SeeU
    checkpoint that `seeu eval` / `seeu render` run and `seeu train --init-from` starts from)."""
    from seeu_model.training.checkpoint import list_checkpoints, save_checkpoint
    from seeu_model.training.config import TrainConfig

    if list_checkpoints(out_dir):
        raise SeeUError("already holds SeeU checkpoints (ckpt-*.pt); choose a new directory", out_dir)
    state = read_lightning_state_dict(path)
    cfg, model_state, report = convert_state_dict(state, where=path)
    if (report.missing or report.unexpected) and not allow_incomplete:
        raise SeeUError(
            f"not converted: {report.summary()} (first: "
            f"{(report.missing + report.unexpected)[0]}); --allow-incomplete writes it anyway",
            path,
        )
    model_section = {k: v for k, v in cfg.to_dict().items() if k.startswith(("mvsplat_",))}
    model_section.update(
        preset="mvsplat",
        num_depth_candidates=cfg.num_depth_candidates,
        sh_degree=cfg.sh_degree,
        mv_layers=cfg.mv_layers,
        mv_ffn_ratio=cfg.mv_ffn_ratio,
    )
    train_cfg = TrainConfig(name="mvsplat", model=model_section)
    payload = {
        "epoch": 0,
        "config": train_cfg.to_dict(),
        "model_config": cfg.to_dict(),
        "model": model_state,
        "metrics": {},
        "converted_from": {
            "format": "mvsplat-lightning",
            "path": str(Path(path).resolve()),
            "report": report.summary(),
        },
    }
    written = save_checkpoint(out_dir, 0, payload, keep=1)
    return written, report
