"""The one way the toolkit reads a torch pickle file: no code runs from a file we read.

`safe_torch_load(path, what)` is ``torch.load(weights_only=True)``: the restricted unpickler builds
tensors, plain containers (dict, list, tuple, str, int, float, bool, None, OrderedDict) and the
few torch types they need, plus the globals named in ``allow`` (nothing else). A file that needs
any other global (``os.system``, ``builtins.open``, a class of another project) is refused with
one line naming the first such global; the restricted unpickler stops at that global, before any
object of it is built or called. Every ``torch.load`` of seeu_model/ and pipelines/ goes through
here (training checkpoints, ``--lpips-weights``, semantic encoder weights, BLIP-2 ``.bin`` shards).
"""

from __future__ import annotations

import pickle
import re
import warnings
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import torch

from seeu_data.errors import SeeUError

_GLOBAL = re.compile(r"(?:Unsupported global: (?:GLOBAL )?|unsupported GLOBAL )([\w.]+)")


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0][:200] if text else type(exc).__name__


def refused_global(exc: BaseException) -> str | None:
    """The disallowed global a weights-only load stopped at (e.g. "posix.system"), if it says so."""
    m = _GLOBAL.search(str(exc))
    return m.group(1) if m else None


def safe_torch_load(path: str | Path, what: str, *, allow: Iterable[Any] = (), mmap: bool = False) -> Any:
    """Read a torch-saved file without running code from it. Raises SeeUError (one line, naming
    `path`) when the file is missing, unreadable, or needs objects other than tensors, plain
    containers and `allow` (objects, e.g. ``numpy.dtype``, as for `torch.serialization.safe_globals`)."""
    p = Path(path)
    if not p.is_file():
        raise SeeUError(f"{what} not found", p)
    try:
        with torch.serialization.safe_globals(list(allow)), warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "Detected pickle protocol 4 ..." of foreign pickles
            return torch.load(p, map_location="cpu", weights_only=True, mmap=mmap)
    except pickle.UnpicklingError as exc:
        name = refused_global(exc)
        if name is not None:
            raise SeeUError(
                f"refused: this {what} needs objects other than tensors and plain containers ({name}); "
                "only weights-only files are loaded (no code runs from a file we read)",
                p,
            ) from None
        raise SeeUError(f"not a readable {what} (not a weights-only torch file)", p) from None
    except Exception as exc:  # noqa: BLE001 - a truncated / corrupt / foreign file
        raise SeeUError(f"not a readable {what} ({type(exc).__name__}: {_first_line(exc)})", p) from None
