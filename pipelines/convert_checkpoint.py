"""The checkpoint conversion stage (`seeu convert-checkpoint`): a released checkpoint of another model
as a SeeU checkpoint.

`convert(ConvertConfig(format="mvsplat", checkpoint=..., out=...))` reads the checkpoint without running
code stored in it (seeu_model/mvsplat/convert.py), writes OUT/ckpt-00000000.pt and
OUT/conversion-report.txt (every key: mapped, missing, unexpected or ignored) and returns the
checkpoint's path, the report and the report's path.

Example:
    from pipelines.convert_checkpoint import ConvertConfig, convert

    written, report, report_path = convert(ConvertConfig(format="mvsplat", checkpoint="re10k.ckpt", out="runs/mv"))
    report.summary()
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from seeu_data.settings import setting

FORMATS = ("mvsplat",)  # the models whose checkpoints convert


@dataclass(frozen=True, kw_only=True)
class ConvertConfig:
    """One conversion: `format` one of FORMATS, `checkpoint` its file, `out` a new directory;
    `allow_incomplete` writes the checkpoint even with missing or unexpected keys (they are listed)."""

    format: str = setting(help="the checkpoint's model", positional=True, choices=FORMATS)
    checkpoint: str | Path = setting(help="the checkpoint file to convert (e.g. MVSplat's re10k.ckpt)", positional=True)
    out: str | Path
    allow_incomplete: bool = setting(
        False, "write the checkpoint even with missing or unexpected keys (they are listed)"
    )


def convert(cfg: ConvertConfig) -> tuple[Path, Any, Path]:
    """Convert `cfg.checkpoint` into `cfg.out`; returns (checkpoint written, ConversionReport, report path)."""
    from seeu_data.store.arrow_io import atomic_write_bytes
    from seeu_model.mvsplat.convert import convert_checkpoint

    written, report = convert_checkpoint(cfg.checkpoint, cfg.out, allow_incomplete=cfg.allow_incomplete)
    report_path = Path(cfg.out) / "conversion-report.txt"
    atomic_write_bytes(report_path, ("\n".join(report.lines()) + "\n").encode())
    return written, report, report_path
