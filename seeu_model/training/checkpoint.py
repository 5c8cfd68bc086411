"""Training checkpoints: atomic writes (temp + rename), every N steps, the last K kept.

A checkpoint ``ckpt-{step:08d}.pt`` is one ``torch.save`` dict:

```
{"format": "seeu-train-checkpoint", "version": 1, "step": int, "epoch": int,
 "config": TrainConfig as dict, "model_config": dict (SeeUConfig fields),
 "model": trainable state dict (frozen sub-modules, e.g. DINOv3, are not stored),
 "optimizer": ..., "scheduler": ..., "loader": loader.state_dict(),
 "rng": {"torch": ..., "cuda": [...], "numpy": ..., "python": ...}, "metrics": {...}}
```
"""

from __future__ import annotations

import io
import os
import random
import re
from pathlib import Path
from typing import Any

import numpy as np
import torch

from seeu_data.arrow_io import atomic_write_bytes
from seeu_data.errors import SeeUError

FORMAT = "seeu-train-checkpoint"
VERSION = 1
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
    return {
        "torch": torch.get_rng_state(),
        "cuda": torch.cuda.get_rng_state_all() if torch.cuda.is_available() else [],
        "numpy": np.random.get_state(),
        "python": random.getstate(),
    }


def set_rng_state(state: dict) -> None:
    torch.set_rng_state(state["torch"])
    if state.get("cuda") and torch.cuda.is_available() and len(state["cuda"]) == torch.cuda.device_count():
        torch.cuda.set_rng_state_all(state["cuda"])
    np.random.set_state(state["numpy"])
    random.setstate(state["python"])


def trainable_state_dict(model: torch.nn.Module) -> dict[str, torch.Tensor]:
    """Parameters that require grad plus all buffers (frozen pretrained trunks are left out)."""
    frozen = {n for n, p in model.named_parameters() if not p.requires_grad}
    return {k: v.detach().cpu() for k, v in model.state_dict().items() if k not in frozen}


def save_checkpoint(directory: str | Path, step: int, payload: dict[str, Any], keep: int) -> Path:
    """Write ``ckpt-{step}.pt`` atomically, then delete all but the newest `keep` checkpoints."""
    path = checkpoint_path(directory, step)
    buf = io.BytesIO()
    torch.save({"format": FORMAT, "version": VERSION, "step": step, **payload}, buf)
    atomic_write_bytes(path, buf.getvalue())
    for old in list_checkpoints(directory)[:-keep]:
        old.unlink(missing_ok=True)
    return path


def load_checkpoint(path: str | Path) -> dict:
    """Read a checkpoint written by `save_checkpoint` (or a directory: its newest checkpoint)."""
    p = Path(path)
    if p.is_dir():
        latest = latest_checkpoint(p)
        if latest is None:
            raise SeeUError("no checkpoint (ckpt-*.pt) in this directory", p)
        p = latest
    if not p.is_file():
        raise SeeUError("checkpoint not found", p)
    try:
        ckpt = torch.load(p, map_location="cpu", weights_only=False)
    except Exception as exc:  # noqa: BLE001 - a truncated/corrupt file
        raise SeeUError(f"not a readable checkpoint ({type(exc).__name__})", p) from None
    if not isinstance(ckpt, dict) or ckpt.get("format") != FORMAT:
        raise SeeUError("not a SeeU training checkpoint", p)
    if int(ckpt.get("version", 0)) > VERSION:
        raise SeeUError(f"checkpoint version {ckpt.get('version')} is newer than this toolkit reads ({VERSION})", p)
    ckpt["path"] = str(p)
    return ckpt


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
