"""The options many `seeu` commands share, each defined once with one meaning.

Shared flags (`add_*`): `--out` (where the command writes), `--force` (redo every stage instead of
resuming), `--progress` / `--no-progress` (progress bars even when stderr is not a terminal / none;
default: bars on a terminal), `--fsync` (fsync every output file before its rename), `--max-pixels N`
(largest image a command reads, `limits.MAX_PIXELS`); `shared_values` reads them back, keyed by the
config field each one sets. Every other flag is a `setting` of the command's config.

The value parsers (`parse_dims`, `parse_bytes`, ...) are in seeu_data/settings.py, beside `setting`,
the declaration flags are generated from (pipelines/cli/config_flags.py).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any, Protocol

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
    """The `--max-pixels` value (`limits.MAX_PIXELS` when not given), parsed by `settings.parse_pixels`."""
    from seeu_data.limits import MAX_PIXELS
    from seeu_data.settings import parse_pixels

    text = getattr(args, "max_pixels", None)
    return MAX_PIXELS if text is None else parse_pixels(text, "--max-pixels")


def shared_values(args: argparse.Namespace, flags: dict[str, str]) -> dict[str, Any]:
    """The shared flags' values for `config_from_args`, keyed by the config field each sets (`flags`:
    the flag's dest -> the field's dotted path, e.g. {"out": "out", "force": "run.force"}); --progress
    read by `progress_wanted`, --max-pixels by `max_pixels`."""
    readers = {"progress": progress_wanted, "max_pixels": max_pixels}
    return {path: readers[dest](args) if dest in readers else getattr(args, dest) for dest, path in flags.items()}
