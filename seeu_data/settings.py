"""Settings: a config field declared once, with what its command-line flag needs, and the parsers for
values written on the command line.

A stage's config is a frozen dataclass. A field declared with `setting(default, help, ...)` is a user
setting: `pipelines/cli/config_flags.py` makes its flag (`--max-features` for `max_features`), its help
with the default taken from this declaration, and reads it back into the config. Nested configs
(a dataclass-typed field with a `default_factory`) are walked, their settings flattened into the same
flags. A field declared without `setting` is internal (a constant of the method, not a flag).

Example:
    @dataclass(frozen=True)
    class SelectConfig:
        stride: int = setting(1, "keep every N-th decoded frame")
        target_frames: int | None = setting(None, "then keep this many frames, evenly spaced (default: all)")

Parsers (`parse_*`) take the text and the flag's name and raise SeeUError naming the flag, so a bad
value is one line and exit 2 wherever it is parsed.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Sequence
from dataclasses import MISSING, field
from pathlib import Path
from typing import Any

from seeu_data.errors import SeeUError
from seeu_data.limits import MAX_IMAGE_SIDE, MAX_PIXELS_CEILING, MAX_VIDEO_SIDE, check_range

Parser = Callable[[str, str], Any]

_BYTE_UNITS = {"": 1, "b": 1, "kb": 10**3, "mb": 10**6, "gb": 10**9, "kib": 1 << 10, "mib": 1 << 20, "gib": 1 << 30}


def setting(
    default: Any = MISSING,
    help: str = "",
    *,
    flag: str | None = None,
    metavar: str | None = None,
    choices: Sequence[str] | None = None,
    parse: Parser | None = None,
    positional: bool = False,
    many: bool = False,
    optional: bool = False,
    required: bool = False,
    aliases: Sequence[str] = (),
    exclusive: str | None = None,
    const: Any = None,
) -> Any:
    """A config field that is a user setting (see the module docstring).

    flag: the flag when it is not `--<name-with-dashes>` (a bool whose default is True gets `--no-<name>`;
    `flag` names another inverting flag, e.g. `--keep-applied-transform` for `undo_applied_transform`);
    parse: text -> value (`parse_*` below), for values that are not a plain int/float/str/Path;
    positional / many / optional: a positional argument (`many`: one or more, a tuple; `optional`: it may
    be left out, `many` and `optional`: zero or more); `many` on a flag: the flag may be repeated, each value parsed, a tuple of them;
    required: a flag that must be given (on `exclusive` settings: one of the group must be given);
    aliases: more names of the flag (`-V`); exclusive: a group name, settings sharing it may not be given together;
    const: the flag may be given without a value, which then is `const` (`--resume` = True, `--resume CKPT`).
    `help` says what the value does; the default is appended from `default` (None: say in `help` what
    happens, e.g. "(default: all)").
    """
    meta = {
        "help": help,
        "flag": flag,
        "metavar": metavar,
        "choices": tuple(choices) if choices is not None else None,
        "parse": parse,
        "positional": positional,
        "many": many,
        "optional": optional,
        "required": required,
        "aliases": tuple(aliases),
        "exclusive": exclusive,
        "const": const,
    }
    if default is MISSING:
        return field(metadata=meta)
    return field(default=default, metadata=meta)


def parse_dims(text: str, flag: str, minimum: int = 1, maximum: int = MAX_IMAGE_SIDE) -> tuple[int, int]:
    """'256x384' -> (256, 384), '256' -> (256, 256): two sizes in the order written (the one size
    parser), each in minimum..maximum (`check_range`; image sides: at most `MAX_IMAGE_SIDE`). Every
    image size on the command line is written HxW (`--size`, `--image-size`, `--resize`)."""
    m = re.fullmatch(r"\s*(\d{1,18})\s*(?:[xX,]\s*(\d{1,18}))?\s*", str(text))
    if not m:
        raise SeeUError(f"{flag} {text!r} is not two sizes AxB (e.g. 256x256)")
    a, b = int(m.group(1)), int(m.group(2) or m.group(1))
    return check_range(a, flag, minimum, maximum), check_range(b, flag, minimum, maximum)


def parse_video_dims(text: str, flag: str) -> tuple[int, int]:
    """`parse_dims` for a synthetic video's HxW (`seeu synth/demo --size`): sides 16..MAX_VIDEO_SIDE."""
    return parse_dims(text, flag, minimum=16, maximum=MAX_VIDEO_SIDE)


def parse_megabytes(text: str, flag: str) -> int:
    """'100', '0.5' (megabytes) -> bytes; not a finite number: 0 (the stage's range check names the flag)."""
    try:
        value = float(text)
    except ValueError:
        raise SeeUError(f"{flag} {text!r} is not a number of megabytes (e.g. 100)") from None
    return int(value * 1e6) if math.isfinite(value) else 0


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


def parse_scene_ids(text: str, flag: str = "--scenes") -> list[str]:
    """`parse_scene_list`, sorted: the scene ids to export."""
    return sorted(parse_scene_list(text, flag) or ())


def parse_int_pair(text: str, flag: str) -> tuple[int, int]:
    """'12,80' -> (12, 80): two integers (e.g. `--distance-frames A,B`)."""
    try:
        a, b = (int(v) for v in str(text).split(","))
    except ValueError:
        raise SeeUError(f"{flag} {text!r} is not two integers A,B (e.g. 0,90)") from None
    return a, b


def parse_indices(text: str, flag: str) -> tuple[int, ...]:
    """'10,40' -> (10, 40): frame indices (non-negative integers) separated by commas (`--context`)."""
    parts = [p.strip() for p in str(text).split(",")]
    if not all(p.isdigit() and len(p) <= 18 for p in parts):
        raise SeeUError(f"{flag} {text!r} is not frame indices I,J (e.g. 0,30)")
    return tuple(int(p) for p in parts)


def parse_int_list(text: str, flag: str) -> tuple[int, ...]:
    """'1,8,21' (or 'scan1,scan8') -> (1, 8, 21)."""
    try:
        values = tuple(int(s) for s in str(text).replace("scan", "").split(",") if s.strip())
    except ValueError:
        values = ()
    if not values:
        raise SeeUError(f"{flag} {text!r} is not a list of integers (e.g. 1,8,21)")
    return values


def parse_names(text: str, flag: str) -> tuple[str, ...]:
    """'full, unet' -> ('full', 'unet'): names separated by commas (`--variants`; the stage checks them)."""
    return tuple(v.strip() for v in str(text).split(",") if v.strip())


def parse_frame_counts(text: str, flag: str) -> tuple[int, ...]:
    """'0,45,90' -> (0, 45, 90) (`--ext-ranges`)."""
    try:
        return tuple(int(x) for x in str(text).split(",") if x.strip())
    except ValueError:
        raise SeeUError(f"{flag} {text!r} is not a list of frame counts (e.g. 0,45,90)") from None


def parse_int_path(text: str, flag: str) -> tuple[int, str]:
    """'45=PATH' -> (45, 'PATH'): a count and a path (one `--ext-data N=PATH`)."""
    n, _, path = str(text).partition("=")
    if not n.strip().isdigit() or not path:
        raise SeeUError(f"{flag} {text!r} is not N=PATH")
    return int(n), path


def parse_pixels(text: str, flag: str = "--max-pixels") -> int:
    """'64000000', '1e8' -> a pixel count in 1..MAX_PIXELS_CEILING (`--max-pixels`)."""
    try:
        value = int(float(text)) if re.fullmatch(r"\s*[0-9.eE+]+\s*", str(text)) else 0
    except (ValueError, OverflowError):
        value = 0
    if value <= 0:
        raise SeeUError(f"{flag} {text!r} is not a positive number of pixels (e.g. 64000000, 1e8)")
    return check_range(value, flag, 1, MAX_PIXELS_CEILING)
