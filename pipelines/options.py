"""Values given on the command line, one parser for each kind (shared by every `seeu` command).

Each raises SeeUError naming the flag, so a bad value is one line and exit 2 wherever it is parsed.
Flags take these values as strings; the command's `run` parses them while it builds its config.
"""

from __future__ import annotations

import re
from pathlib import Path

from seeu_data.errors import SeeUError

_BYTE_UNITS = {"": 1, "b": 1, "kb": 10**3, "mb": 10**6, "gb": 10**9, "kib": 1 << 10, "mib": 1 << 20, "gib": 1 << 30}


def parse_dims(text: str, flag: str, minimum: int = 1) -> tuple[int, int]:
    """'256x384' -> (256, 384), '256' -> (256, 256): two sizes in the order written. Image sizes are
    written HxW (`--image-size`, `--resize`, `--size` of ingest/export); video frame sizes WIDTHxHEIGHT,
    as video sizes are (`seeu synth --size 640x360`)."""
    m = re.fullmatch(r"\s*(\d+)\s*(?:[xX,]\s*(\d+))?\s*", str(text))
    if not m:
        raise SeeUError(f"{flag} {text!r} is not two sizes AxB (e.g. 256x256)")
    a, b = int(m.group(1)), int(m.group(2) or m.group(1))
    if min(a, b) < minimum:
        raise SeeUError(f"{flag} {text!r}: sizes must be " + ("positive" if minimum <= 1 else f"at least {minimum}"))
    return a, b


def parse_bytes(text: str, flag: str) -> int:
    """'128MB', '64MiB', '1e6' -> bytes (positive)."""
    m = re.fullmatch(r"\s*([0-9.eE+]+)\s*([a-zA-Z]*)\s*", str(text))
    try:
        value = int(float(m.group(1)) * _BYTE_UNITS[m.group(2).lower()]) if m else 0
    except (KeyError, ValueError):
        value = 0
    if value <= 0:
        raise SeeUError(f"{flag} {text!r} is not a positive size (e.g. 128MB, 64MiB)")
    return value


def parse_scene_list(text: str | None, flag: str = "--scenes") -> frozenset[str] | None:
    """`a,b,c` or `@file` (one id per line) -> set of scene ids (None: all)."""
    if text is None:
        return None
    if text.startswith("@"):
        path = Path(text[1:])
        if not path.exists():
            raise SeeUError(f"{flag}: scene list file not found", path)
        items = [line.strip() for line in path.read_text().splitlines()]
    else:
        items = [s.strip() for s in text.split(",")]
    items = [s for s in items if s]
    if not items:
        raise SeeUError(f"{flag}: empty scene list {text!r}")
    return frozenset(items)
