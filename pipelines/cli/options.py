"""The options many `seeu` commands share, each defined once with one meaning, and one parser per
kind of value given on the command line.

Shared flags (`add_*`): `--out` (where the command writes), `--force` (redo every stage instead of
resuming), `--progress` / `--no-progress` (progress bars even when stderr is not a terminal / none;
default: bars on a terminal), `--fsync` (fsync every output file before its rename), `--workers N`
(worker processes, 1..MAX_WORKERS), `--max-pixels N` (largest image a command reads, `limits.MAX_PIXELS`).

Value parsers (`parse_*`) raise SeeUError naming the flag, so a bad value is one line and exit 2
wherever it is parsed. Flags take these values as strings; the command's `run` parses them while it
builds the stage's config.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path
from typing import Any, Protocol

from seeu_data.errors import SeeUError
from seeu_data.limits import MAX_IMAGE_SIDE, MAX_WORKERS, check_range

_BYTE_UNITS = {"": 1, "b": 1, "kb": 10**3, "mb": 10**6, "gb": 10**9, "kib": 1 << 10, "mib": 1 << 20, "gib": 1 << 30}


# ------------------------------------------------------------------------------------------------
# Shared flags
# ------------------------------------------------------------------------------------------------


class Flags(Protocol):
    """What the `add_*` helpers add to: a parser or an argument group."""

    def add_argument(self, *args: Any, **kwargs: Any) -> Any: ...


def add_out(p: Flags, help: str, default: Path | None = None) -> None:
    """`--out PATH`: where the command writes (required unless a `default` is given)."""
    p.add_argument("--out", type=Path, required=default is None, default=default, metavar="OUT", help=help)


def add_force(p: Flags, also: str = "") -> None:
    """`--force`: redo every stage instead of resuming (`also`: what else it allows, for the help)."""
    p.add_argument("--force", action="store_true", help="redo every stage instead of resuming" + also)


def add_progress(p: Flags) -> None:
    """`--progress` / `--no-progress`; read back with `progress_wanted` (or passed on as None/True/False)."""
    p.add_argument(
        "--progress",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="show progress bars even when stderr is not a terminal (--no-progress: none; default: on a terminal)",
    )


def progress_wanted(args: argparse.Namespace) -> bool:
    """Whether to show progress bars: --progress yes, --no-progress no, neither: when stderr is a terminal."""
    return sys.stderr.isatty() if args.progress is None else bool(args.progress)


def add_fsync(p: Flags) -> None:
    """`--fsync`: durable writes (the stage configs' `fsync` field)."""
    p.add_argument(
        "--fsync",
        action="store_true",
        help="fsync every output file before its rename (durable across a power loss; slower). Default: "
        "atomic renames only, a torn file is caught by the manifest sha256 (seeu validate)",
    )


def add_max_pixels(p: Flags) -> None:
    """`--max-pixels N`: the largest image (width x height) the command reads; read back with `max_pixels`."""
    from seeu_data.limits import MAX_PIXELS

    p.add_argument(
        "--max-pixels",
        default=None,
        metavar="N",
        help=f"refuse images whose header declares more than N pixels (width x height; default {MAX_PIXELS:,}, "
        "64 MP): a tiny file declaring 60000x60000 would make later stages allocate gigabytes",
    )


def max_pixels(args: argparse.Namespace) -> int:
    """The `--max-pixels` value (`limits.MAX_PIXELS` when not given); SeeUError unless an integer in
    1..MAX_PIXELS_CEILING."""
    from seeu_data.limits import MAX_PIXELS, MAX_PIXELS_CEILING, check_range

    text = getattr(args, "max_pixels", None)
    if text is None:
        return MAX_PIXELS
    try:
        value = int(float(text)) if re.fullmatch(r"\s*[0-9.eE+]+\s*", str(text)) else 0
    except ValueError:
        value = 0
    if value <= 0:
        raise SeeUError(f"--max-pixels {text!r} is not a positive number of pixels (e.g. 64000000, 1e8)")
    return check_range(value, "--max-pixels", 1, MAX_PIXELS_CEILING)


def add_workers(p: Flags, what: str, default: int | None) -> None:
    """`--workers N`: worker processes (`what` they do and the default, for the help); checked 1..MAX_WORKERS
    by the stage."""
    p.add_argument(
        "--workers", type=int, default=default, metavar="N", help=f"worker processes (at most {MAX_WORKERS}): {what}"
    )


# ------------------------------------------------------------------------------------------------
# Value parsers
# ------------------------------------------------------------------------------------------------


def parse_dims(text: str, flag: str, minimum: int = 1, maximum: int = MAX_IMAGE_SIDE) -> tuple[int, int]:
    """'256x384' -> (256, 384), '256' -> (256, 256): two sizes in the order written (the one size
    parser), each in minimum..maximum (`check_range`; image sides: at most `MAX_IMAGE_SIDE`). Image
    sizes are written HxW (`--image-size`, `--resize`, `--size` of ingest/export); a video's frame size
    WIDTHxHEIGHT, as video sizes are (`seeu synth --size 640x360`, at most `MAX_VIDEO_SIDE`)."""
    m = re.fullmatch(r"\s*(\d{1,18})\s*(?:[xX,]\s*(\d{1,18}))?\s*", str(text))
    if not m:
        raise SeeUError(f"{flag} {text!r} is not two sizes AxB (e.g. 256x256)")
    a, b = int(m.group(1)), int(m.group(2) or m.group(1))
    return check_range(a, flag, minimum, maximum), check_range(b, flag, minimum, maximum)


def parse_bytes(text: str, flag: str) -> int:
    """'128MB', '64MiB', '1e6' -> bytes (positive)."""
    m = re.fullmatch(r"\s*([0-9.eE+]+)\s*([a-zA-Z]*)\s*", str(text))
    try:
        value = int(float(m.group(1)) * _BYTE_UNITS[m.group(2).lower()]) if m else 0
    except (KeyError, ValueError, OverflowError):
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
