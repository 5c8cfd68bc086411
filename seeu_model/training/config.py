"""Typed training configuration, preset files and ``key=value`` overrides.

A config file is JSON (``configs/*.json``, shipped in the wheel as ``seeu_model/presets/``, a symbolic
link to it, and usable by name: ``--config re10k_paper``; YAML too when PyYAML is installed) holding any subset
of the sections below; missing keys keep their defaults. Overrides address fields with dots:
``optim.lr=1e-4 data.batch_size=4 model.refiner=unet loss.lpips_weight=0``. The ``model`` section
is passed through to ``SeeUConfig`` (its fields are the model's, checked when the model is built).

Defaults follow the paper (appendix A: AdamW, batch 8, 300k iterations, 256x256, loss
MSE + 0.05 LPIPS); what the paper leaves open (learning rate, warm-up, clipping) follows MVSplat,
which SeeU builds on (Adam 2e-4 with cosine decay, 2k warm-up steps, gradient clip 0.5).
"""

from __future__ import annotations

import dataclasses
import json
import math
import typing
from dataclasses import asdict, dataclass, field, fields
from importlib.resources import files
from pathlib import Path
from typing import Any

from seeu_data.errors import SeeUError
from seeu_data.limits import (
    MAX_BATCH_SIZE,
    MAX_IMAGE_SIDE,
    MAX_LEARNING_RATE,
    MAX_PIXELS,
    MAX_PIXELS_CEILING,
    MAX_SAMPLES,
    MAX_SEED,
    MAX_STEPS,
    MAX_WORKERS,
    check_range,
)
from seeu_data.store.json_file import check_nesting, parse_json, read_document, read_json, too_deep_error

PRESETS_DIR = files("seeu_model") / "presets"
# What a step whose loss, gradients or weights are not finite (NaN / inf) does (TrainConfig.on_nonfinite):
# "stop": exit 2 naming the step and the batch's samples, nothing saved from that step on (the last good
# checkpoint stays the newest); "skip-batch": that batch's update is not applied and the run goes on,
# until MAX_CONSECUTIVE_SKIPS batches in a row were skipped (then it stops as "stop" does). Weights that
# became non-finite in an optimizer step cannot be restored: that always stops.
NONFINITE_POLICIES = ("stop", "skip-batch")
MAX_CONSECUTIVE_SKIPS = 20


@dataclass
class DataConfig:
    """Loader settings. image_size: (H, W) after resize/centre-crop."""

    batch_size: int = 8  # per process and micro-batch (effective batch = batch_size x world size x optim.accumulate)
    image_size: tuple[int, int] = (256, 256)
    num_workers: int = 2
    seed: int = 0
    flip: bool = True  # horizontal flip with p = 0.5 (pose mirrored)
    val_batch_size: int = 1
    val_max_samples: int = 16  # validation samples per validation pass (0: all)
    max_pixels: int = MAX_PIXELS  # largest image (width x height) the loader decodes (seeu validate --max-pixels)


@dataclass
class OptimConfig:
    """AdamW with linear warm-up then cosine decay to ``lr * min_lr_ratio`` at ``max_steps``."""

    lr: float = 2e-4
    betas: tuple[float, float] = (0.9, 0.999)
    eps: float = 1e-8
    weight_decay: float = 0.01
    warmup_steps: int = 2000
    max_steps: int = 300_000
    min_lr_ratio: float = 0.0
    grad_clip: float = 0.5  # max global grad norm; 0 = off
    accumulate: int = 1  # micro-batches per optimizer step (gradient accumulation; effective_batch.py)


@dataclass
class LossConfig:
    """MSE + lpips_weight * LPIPS(VGG); lpips_weight = 0 switches LPIPS off (no VGG weights needed)."""

    lpips_weight: float = 0.05
    lpips_weights: str | None = None  # path to torchvision's vgg16-397923af.pth (default: torch hub cache)
    lpips_random_trunk: bool = False  # tests only: LPIPS with a random VGG trunk


@dataclass
class CheckpointConfig:
    every: int = 5000  # steps between checkpoints (the last step is always saved)
    keep: int = 3  # keep the last K checkpoints


@dataclass
class LogConfig:
    every: int = 50  # scalars (loss, PSNR, lr, it/s) to TensorBoard
    image_every: int = 1000  # rendered vs ground-truth image grid
    val_every: int = 5000  # validation pass (when --val is given); 0 = only at the end
    progress: bool | None = None  # tqdm bar; None = only on a TTY


@dataclass
class TrainConfig:
    name: str = "seeu"
    model: dict[str, Any] = field(default_factory=dict)  # SeeUConfig fields
    data: DataConfig = field(default_factory=DataConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    checkpoint: CheckpointConfig = field(default_factory=CheckpointConfig)
    log: LogConfig = field(default_factory=LogConfig)
    precision: str = "auto"  # "auto" (bf16 autocast on CUDA, fp32 on CPU) | "bf16" (CUDA or CPU autocast) | "fp32"
    rasterizer: str = "auto"  # "auto" | "torch" | "gsplat"
    seed: int = 0  # model init and training RNG
    on_nonfinite: str = "stop"  # one of NONFINITE_POLICIES: a non-finite loss / gradient / weight

    def to_dict(self) -> dict:
        return asdict(self)


# ------------------------------------------------------------------------------------------------
# Building from dicts / files / overrides
# ------------------------------------------------------------------------------------------------


def _coerce(value: Any, tp: Any, where: str) -> Any:
    """Convert a JSON/CLI value to the annotated type `tp`; raise SeeUError when impossible."""
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if tp is Any:
        return value
    if origin in (typing.Union, getattr(__import__("types"), "UnionType", None)):
        if value is None and type(None) in args:
            return None
        errors = []
        for a in args:
            if a is type(None):
                continue
            try:
                return _coerce(value, a, where)
            except SeeUError as exc:
                errors.append(str(exc))
        raise SeeUError(f"config {where}: cannot use {value!r} ({'; '.join(errors)})")
    if origin is tuple:
        if isinstance(value, str):
            value = [v for v in value.replace("x", ",").split(",") if v.strip()]
        if not isinstance(value, (list, tuple)) or len(value) != len(args):
            raise SeeUError(f"config {where}: expected {len(args)} values, got {value!r}")
        return tuple(_coerce(v, a, where) for v, a in zip(value, args))
    if origin is dict or tp is dict:
        if not isinstance(value, dict):
            raise SeeUError(f"config {where}: expected a mapping, got {value!r}")
        return dict(value)
    if tp is bool:
        if isinstance(value, bool):
            return value
        if isinstance(value, str) and value.lower() in ("1", "true", "yes", "on", "0", "false", "no", "off"):
            return value.lower() in ("1", "true", "yes", "on")
        raise SeeUError(f"config {where}: expected true/false, got {value!r}")
    if tp is int:
        if isinstance(value, bool):
            raise SeeUError(f"config {where}: expected an integer, got {value!r}")
        try:
            f = float(value)
        except (TypeError, ValueError):
            raise SeeUError(f"config {where}: expected an integer, got {value!r}") from None
        if not math.isfinite(f) or f != int(f):
            raise SeeUError(f"config {where}: expected an integer, got {value!r}")
        return int(f)
    if tp is float:
        if isinstance(value, bool):
            raise SeeUError(f"config {where}: expected a number, got {value!r}")
        try:
            f = float(value)
        except (TypeError, ValueError):
            raise SeeUError(f"config {where}: expected a number, got {value!r}") from None
        if not math.isfinite(f):
            raise SeeUError(f"config {where}: expected a finite number, got {value!r}")
        return f
    if tp is str:
        if not isinstance(value, (str, int, float)):
            raise SeeUError(f"config {where}: expected a string, got {value!r}")
        return str(value)
    return value


def _build(cls: type, data: dict, where: str) -> Any:
    if not isinstance(data, dict):
        raise SeeUError(f"config {where or 'root'}: expected a mapping, got {type(data).__name__}")
    hints = typing.get_type_hints(cls)
    known = {f.name for f in fields(cls)}
    data = {k: v for k, v in data.items() if not str(k).startswith("_")}  # "_comment" keys
    unknown = sorted(set(data) - known)
    if unknown:
        raise SeeUError(
            f"config {where or 'root'}: unknown key(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}"
        )
    kwargs = {}
    for f in fields(cls):
        if f.name not in data:
            continue
        tp = hints[f.name]
        key = f"{where}.{f.name}" if where else f.name
        if isinstance(tp, type) and dataclasses.is_dataclass(tp):
            kwargs[f.name] = _build(tp, data[f.name], key)
        else:
            kwargs[f.name] = _coerce(data[f.name], tp, key)
    return cls(**kwargs)


def config_from_dict(data: dict) -> TrainConfig:
    cfg = _build(TrainConfig, data, "")
    validate(cfg)
    return cfg


def _parse_scalar(text: str, what: str = "override value") -> Any:
    """CLI override value: JSON when it parses (numbers, true/false, null, lists), else the string."""
    try:
        return parse_json(text, what)
    except SeeUError:
        if text.lstrip()[:1] in ("[", "{"):  # meant as a JSON list or mapping: its error stands
            raise
        return text


def apply_overrides(data: dict, overrides: list[str]) -> dict:
    """Apply ``a.b.c=value`` overrides to a nested dict (in place; returns it)."""
    for item in overrides:
        if "=" not in item:
            raise SeeUError(f"override {item!r} is not key=value (e.g. optim.lr=1e-4)")
        key, text = item.split("=", 1)
        parts = key.strip().split(".")
        node = data
        for p in parts[:-1]:
            node = node.setdefault(p, {})
            if not isinstance(node, dict):
                raise SeeUError(f"override {item!r}: {p} is not a section")
        node[parts[-1]] = _parse_scalar(text, f"override {key.strip()}")
    return data


def preset_names() -> list[str]:
    """Names of the shipped presets (`configs/*.json`, package data `seeu_model/presets/`)."""
    return sorted(p.name[: -len(".json")] for p in PRESETS_DIR.iterdir() if p.name.endswith(".json"))


def resolve_config(path_or_preset: str | Path) -> Path:
    """A config file path as given, or a shipped preset by name (``re10k_paper`` or ``re10k_paper.json``)."""
    path = Path(path_or_preset)
    if path.is_file():
        return path
    name = path.name[: -len(".json")] if path.name.endswith(".json") else path.name
    if path.parent == Path(".") and name in preset_names():
        return Path(str(PRESETS_DIR / f"{name}.json"))
    raise SeeUError(f"config file not found, and not a preset name ({', '.join(preset_names())})", path)


def read_config_file(path: str | Path) -> dict:
    """A config file's sections (JSON, or YAML with PyYAML), bounded in size and depth as every JSON document."""
    path = resolve_config(path)
    if path.suffix in (".yaml", ".yml"):
        try:
            import yaml
        except ImportError:
            raise SeeUError("YAML configs need PyYAML (pip install pyyaml), or use the .json preset", path) from None
        text = read_document(path, "config file")
        try:
            data = check_nesting(yaml.safe_load(text) or {}, "config file", path)
        except RecursionError:
            raise too_deep_error("config file", path) from None
        except yaml.YAMLError as exc:
            raise SeeUError(f"not valid YAML: {str(exc).splitlines()[0]}", path) from None
    else:
        data = read_json(path, "config file")
    if not isinstance(data, dict):
        raise SeeUError("a config file must hold a mapping of sections", path)
    return data


def load_config(path: str | Path | None = None, overrides: list[str] | None = None) -> TrainConfig:
    """Defaults <- preset file <- overrides, validated. Errors name the file or the override."""
    data = read_config_file(path) if path is not None else {}
    apply_overrides(data, list(overrides or []))
    try:
        return config_from_dict(data)
    except SeeUError as exc:
        if path is not None and exc.path is None:
            raise SeeUError(str(exc), path) from None
        raise


def validate(cfg: TrainConfig) -> None:
    """Value checks of a built config (types and finiteness are checked by `_coerce`); one line each.
    Sizes and counts are checked by `check_range` against the limits of `seeu_data.limits`."""
    o, d, c, lg = cfg.optim, cfg.data, cfg.checkpoint, cfg.log
    counts = [
        ("data.batch_size", d.batch_size, 1, MAX_BATCH_SIZE),
        ("data.image_size", d.image_size[0], 1, MAX_IMAGE_SIDE),
        ("data.image_size", d.image_size[1], 1, MAX_IMAGE_SIDE),
        ("data.num_workers", d.num_workers, 0, MAX_WORKERS),
        ("data.seed", d.seed, 0, MAX_SEED),
        ("data.val_batch_size", d.val_batch_size, 1, MAX_BATCH_SIZE),
        ("data.max_pixels", d.max_pixels, 1, MAX_PIXELS_CEILING),
        ("data.val_max_samples", d.val_max_samples, 0, MAX_SAMPLES),
        ("optim.max_steps", o.max_steps, 1, MAX_STEPS),
        ("optim.warmup_steps", o.warmup_steps, 0, MAX_STEPS),
        ("optim.accumulate", o.accumulate, 1, MAX_BATCH_SIZE),
        ("checkpoint.every", c.every, 1, MAX_STEPS),
        ("checkpoint.keep", c.keep, 1, MAX_STEPS),
        ("log.every", lg.every, 1, MAX_STEPS),
        ("log.image_every", lg.image_every, 1, MAX_STEPS),
        ("log.val_every", lg.val_every, 0, MAX_STEPS),
        ("seed", cfg.seed, 0, MAX_SEED),
    ]
    for name, value, lo, hi in counts:
        check_range(value, f"config {name}", lo, hi)
    checks = [
        (0 < o.lr <= MAX_LEARNING_RATE, f"optim.lr must be in (0, {MAX_LEARNING_RATE:g}], got {o.lr:g}"),
        (0 <= o.min_lr_ratio <= 1, "optim.min_lr_ratio must be in [0, 1]"),
        (all(0 <= b < 1 for b in o.betas), "optim.betas must be in [0, 1)"),
        (o.eps > 0, "optim.eps must be > 0"),
        (o.weight_decay >= 0, "optim.weight_decay must be >= 0"),
        (o.grad_clip >= 0, "optim.grad_clip must be >= 0 (0 = off)"),
        (cfg.loss.lpips_weight >= 0, "loss.lpips_weight must be >= 0"),
    ]
    for ok, message in checks:
        if not ok:
            raise SeeUError(f"config {message}")
    if cfg.precision not in ("auto", "bf16", "fp32"):
        raise SeeUError(f"config precision: {cfg.precision!r} is not auto, bf16 or fp32")
    if cfg.rasterizer not in ("auto", "torch", "gsplat", "dense"):
        raise SeeUError(f"config rasterizer: {cfg.rasterizer!r} is not auto, torch, gsplat or dense")
    if cfg.on_nonfinite not in NONFINITE_POLICIES:
        raise SeeUError(f"config on_nonfinite: {cfg.on_nonfinite!r} is not {' or '.join(NONFINITE_POLICIES)}")


def save_config(cfg: TrainConfig, path: str | Path) -> None:
    from seeu_data.store.arrow_io import atomic_write_text

    atomic_write_text(path, json.dumps(cfg.to_dict(), indent=2) + "\n")
