"""Training checkpoints: atomic writes (temp + rename), every N steps, the last K kept.

A checkpoint ``ckpt-{step:08d}.pt`` is one ``torch.save`` dict of tensors and plain containers only
(dict, list, tuple, str, int, float, bool, None), so it is read with ``torch.load(weights_only=True)``
(`seeu_model.safe_load`): a file that needs any other object is refused before anything is built.

```
{"format": "seeu-train-checkpoint", "version": 3, "step": int, "digest": sha256 hex (see below),
 "config": TrainConfig as dict, "model_config": dict (SeeUConfig fields),
 "model": trainable state dict (frozen sub-modules, e.g. DINOv3, are not stored),
 "optimizer": ..., "scheduler": ..., "loader": loader.state_dict() (integers),
 "rng": {"torch": ByteTensor, "cuda": [ByteTensor], "numpy": [name, int64 tensor (624,), pos, has_gauss,
         cached_gaussian], "python": random.getstate()}, ...}
```

Every tensor of a checkpoint is finite: `save_checkpoint` refuses to write one holding NaN or inf,
and `load_checkpoint` (every reader: eval, render, demo, --resume, --init-from) refuses to read one;
`check_tensors` is that check, and with the model's state it also checks every shape.

A checkpoint carries a digest of its contents (`payload_digest`: sha256 over every tensor's name,
dtype, shape and bytes and every other value's name and repr, in order), computed when it is written
and checked by `load_checkpoint` before anything else looks at it: a damaged file (one flipped bit
in a weight) is one line, `checkpoint damaged: its tensors do not match the digest written with
them`, exit 2, never a different model evaluated without a warning. Versions 1 and 2 carry none and
are read without this check.

Version 1 stored numpy's RNG state as a numpy array; v1 files are still read, with exactly the numpy
globals that array needs allow-listed (array reconstruction and the uint32 dtype, nothing callable
beyond them).
"""

from __future__ import annotations

import hashlib
import io
import os
import random
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch

from seeu_data.errors import SeeUError
from seeu_data.store.arrow_io import atomic_write_bytes
from seeu_model.safe_load import safe_torch_load

FORMAT = "seeu-train-checkpoint"
VERSION = 3  # 3: the digest
# what a v1 checkpoint's numpy RNG state (a uint32 array) needs beyond tensors and plain containers
_reconstruct = (getattr(np, "_core", None) or np.core).multiarray._reconstruct
_V1_NUMPY_GLOBALS = [
    _reconstruct,
    (_reconstruct, "numpy.core.multiarray._reconstruct"),  # numpy 2 / 1 name
    np.ndarray,
    np.dtype,
    np.dtypes.UInt32DType,
]
_NAME = re.compile(r"^ckpt-(\d{8})\.pt$")


def checkpoint_path(directory: str | Path, step: int) -> Path:
    return Path(directory) / f"ckpt-{step:08d}.pt"


def list_checkpoints(directory: str | Path) -> list[Path]:
    """Complete checkpoints in `directory`, oldest first (temporary files are ignored)."""
    d = Path(directory)
    if not d.is_dir():
        return []
    return sorted(p for p in d.iterdir() if _NAME.match(p.name))


def latest_checkpoint(directory: str | Path) -> Path | None:
    found = list_checkpoints(directory)
    return found[-1] if found else None


def rng_state() -> dict:
    numpy_state = np.random.get_state(legacy=True)
    assert isinstance(numpy_state, tuple)  # the global RandomState is MT19937: the legacy tuple
    return {
        "torch": torch.get_rng_state(),
        "cuda": torch.cuda.get_rng_state_all() if torch.cuda.is_available() else [],
        "numpy": _numpy_state_plain(numpy_state),
        "python": random.getstate(),
    }


def set_rng_state(state: dict) -> None:
    torch.set_rng_state(state["torch"])
    if state.get("cuda") and torch.cuda.is_available() and len(state["cuda"]) == torch.cuda.device_count():
        torch.cuda.set_rng_state_all(state["cuda"])
    name, keys, pos, has_gauss, cached = state["numpy"]
    np.random.set_state(
        (str(name), np.asarray(keys, dtype=np.int64).astype(np.uint32), int(pos), int(has_gauss), float(cached))
    )
    py = state["python"]
    random.setstate((py[0], tuple(py[1]), py[2]))


def _numpy_state_plain(state: tuple) -> list:
    """numpy's legacy RNG state as a list of plain values and an int64 tensor (weights-only loadable)."""
    name, keys, pos, has_gauss, cached = state
    return [str(name), torch.from_numpy(np.asarray(keys, dtype=np.int64)), int(pos), int(has_gauss), float(cached)]


def trainable_state_dict(model: torch.nn.Module) -> dict[str, torch.Tensor]:
    """Parameters that require grad plus all buffers (frozen pretrained trunks are left out)."""
    frozen = {n for n, p in model.named_parameters() if not p.requires_grad}
    return {k: v.detach().cpu() for k, v in model.state_dict().items() if k not in frozen}


def first_nonfinite(tree: Any, prefix: str = "") -> str | None:
    """The dotted name of the first floating-point tensor in a nested dict/list/tuple that holds a NaN
    or an infinity (e.g. ``model.backbone.stem.0.weight``, ``optimizer.state.3.exp_avg``), or None."""
    if isinstance(tree, torch.Tensor):
        if (tree.is_floating_point() or tree.is_complex()) and not bool(torch.isfinite(tree).all()):
            return prefix or "<tensor>"
        return None
    if isinstance(tree, Mapping):
        items: Any = tree.items()
    elif isinstance(tree, (list, tuple)):
        items = enumerate(tree)
    else:
        return None
    for key, value in items:
        found = first_nonfinite(value, f"{prefix}.{key}" if prefix else str(key))
        if found is not None:
            return found
    return None


def check_tensors(
    tree: Any, where: str | Path | None, model_state: Mapping[str, torch.Tensor] | None = None, prefix: str = ""
) -> None:
    """The one check of a checkpoint's tensors before anything uses them: every floating-point tensor
    of `tree` (a checkpoint dict, or its ``model`` state dict) is finite; with `model_state` (the
    model's ``state_dict()``) `tree` is a state dict of tensors and each one the model has is of the
    model's shape. Raises SeeUError naming `where` (the file) and the first offending tensor
    (``prefix.name``, e.g. ``model.backbone.stem.0.weight``)."""
    if model_state is not None and (
        not isinstance(tree, Mapping) or not all(isinstance(v, torch.Tensor) for v in tree.values())
    ):
        raise SeeUError(f"checkpoint {prefix or 'model'!r} is not a state dict of tensors", where)
    bad = first_nonfinite(tree, prefix)
    if bad is not None:
        raise SeeUError(
            f"checkpoint tensor {bad} holds NaN or inf values (a diverged run?): refused; "
            "use an earlier checkpoint of the run",
            where,
        )
    for name, value in tree.items() if model_state is not None else ():
        own = model_state.get(name)  # type: ignore[union-attr]
        if own is not None and tuple(value.shape) != tuple(own.shape):
            raise SeeUError(
                f"checkpoint tensor {prefix + '.' if prefix else ''}{name} has shape {tuple(value.shape)}, "
                f"the model's is {tuple(own.shape)}: the checkpoint weights do not match its model config "
                "(was the config edited, or are these the weights of another model?)",
                where,
            )


def payload_digest(tree: Any) -> str:
    """sha256 (hex) of a checkpoint's contents: every tensor's dotted name, dtype, shape and bytes, every
    other leaf's name and repr, in the order of the (nested) dicts, lists and tuples. The top-level
    "digest" and "path" entries are left out (the digest itself; the path `load_checkpoint` adds)."""
    h = hashlib.sha256()

    def walk(node: Any, name: str) -> None:
        if isinstance(node, torch.Tensor):
            t = node.detach().cpu().contiguous().reshape(-1)
            h.update(f"{name}:{t.dtype}:{tuple(node.shape)}\n".encode())
            h.update(t.view(torch.uint8).numpy().tobytes() if t.numel() else b"")
        elif isinstance(node, Mapping):
            items = [(k, v) for k, v in node.items() if name or k not in ("digest", "path")]
            h.update(f"{name}:{type(node).__name__}{len(items)}\n".encode())
            for key, value in items:
                walk(value, f"{name}.{key}")
        elif isinstance(node, (list, tuple)):
            h.update(f"{name}:{type(node).__name__}{len(node)}\n".encode())
            for i, value in enumerate(node):
                walk(value, f"{name}.{i}")
        else:
            h.update(f"{name}={node!r}\n".encode())

    walk(tree, "")
    return h.hexdigest()


def save_checkpoint(directory: str | Path, step: int, payload: dict[str, Any], keep: int) -> Path:
    """Write ``ckpt-{step}.pt`` atomically, then delete all but the newest `keep` checkpoints.
    A payload holding a non-finite tensor is refused (SeeUError) before anything is written."""
    path = checkpoint_path(directory, step)
    bad = first_nonfinite(payload)
    if bad is not None:
        raise SeeUError(f"refusing to write a checkpoint whose tensor {bad} holds NaN or inf values", path)
    buf = io.BytesIO()
    content = {"format": FORMAT, "version": VERSION, "step": step, **payload}
    torch.save({**content, "digest": payload_digest(content)}, buf)
    atomic_write_bytes(path, buf.getvalue())
    for old in list_checkpoints(directory)[:-keep]:
        old.unlink(missing_ok=True)
    return path


def load_checkpoint(path: str | Path) -> dict:
    """Read a checkpoint written by `save_checkpoint` (or a directory: its newest checkpoint).
    Refused (SeeUError naming the file): a file that is not one, contents that do not match their
    digest (version 3), a negative step, a non-finite tensor."""
    p = Path(path)
    if p.is_dir():
        latest = latest_checkpoint(p)
        if latest is None:
            raise SeeUError("no checkpoint (ckpt-*.pt) in this directory", p)
        p = latest
    ckpt = safe_torch_load(p, "checkpoint", allow=_V1_NUMPY_GLOBALS)
    if not isinstance(ckpt, dict) or ckpt.get("format") != FORMAT:
        raise SeeUError("not a SeeU training checkpoint", p)
    for key in ("step", "config", "model"):
        if key not in ckpt:
            raise SeeUError(f"not a complete SeeU training checkpoint (no {key!r})", p)
    if (
        not isinstance(ckpt.get("version", 0), int)
        or not isinstance(ckpt["step"], int)
        or isinstance(ckpt["step"], bool)
        or not isinstance(ckpt["config"], dict)
        or not isinstance(ckpt["model"], dict)
    ):
        raise SeeUError("not a valid SeeU training checkpoint (version, step, config or model of the wrong type)", p)
    if int(ckpt.get("version", 0)) > VERSION:
        raise SeeUError(f"checkpoint version {ckpt.get('version')} is newer than this toolkit reads ({VERSION})", p)
    if (int(ckpt.get("version", 0)) >= 3 or "digest" in ckpt) and ckpt.get("digest") != payload_digest(ckpt):
        raise SeeUError(
            "checkpoint damaged: its contents do not match the digest written with them (a flipped bit, a "
            "bad copy or disk?); use another checkpoint of the run",
            p,
        )
    if ckpt["step"] < 0:
        raise SeeUError(f"checkpoint step {ckpt['step']} is negative: not a checkpoint a run wrote", p)
    check_tensors(ckpt, p)
    ckpt["path"] = str(p)
    return ckpt


def load_model_state(model: torch.nn.Module, state: dict[str, torch.Tensor], where: str | None = None) -> None:
    """Load a `model_state_for_checkpoint` dict; parameters of frozen modules may be absent. Every
    tensor must be finite and of the model's shape (`checkpoint.check_tensors`)."""
    check_tensors(state, where, model.state_dict(), prefix="model")
    try:
        missing, unexpected = model.load_state_dict(state, strict=False)
    except RuntimeError as exc:  # e.g. dtype/shape problems load_state_dict finds itself
        raise SeeUError(f"checkpoint weights do not fit the model ({str(exc).splitlines()[0][:200]})", where) from None
    listed = getattr(model, "frozen_prefixes", None)  # SeeU names its frozen modules; any nn.Module loads
    frozen_prefixes = tuple(listed()) if callable(listed) else ()
    frozen = {n for n, p in model.named_parameters() if not p.requires_grad}
    missing = [m for m in missing if m not in frozen and not (frozen_prefixes and m.startswith(frozen_prefixes))]
    if missing or unexpected:
        raise SeeUError(
            f"checkpoint does not match the model (missing {missing[:3]}, unexpected {list(unexpected)[:3]}):"
            " was it trained with another model config?",
            where,
        )


def unlink_stale_temporaries(directory: str | Path) -> None:
    """Remove temporaries left by a crashed writer (``.ckpt-*.pt.<pid>.tmp``)."""
    d = Path(directory)
    if d.is_dir():
        for p in d.glob(".ckpt-*.tmp"):
            try:
                pid = int(p.name.rsplit(".", 2)[-2])
            except ValueError:
                continue
            if pid != os.getpid():
                p.unlink(missing_ok=True)
