"""The one way the toolkit reads a JSON document a user hands it: bounded in size and depth.

Manifests, configs, cameras files, transforms.json, evaluation indices and journals are read through
`read_json` (a file) or `parse_json` (text already in memory). A document over `MAX_JSON_BYTES`, or
nested deeper than `MAX_JSON_DEPTH`, or not valid JSON is one SeeUError line naming the file and the
limit; never a RecursionError or a MemoryError. Our own documents nest 6 deep at most.

Example:
    from seeu_data.store.json_file import read_json
    doc = read_json("data/posed/clip/manifest.json", "manifest")
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from seeu_data.errors import SeeUError

MAX_JSON_BYTES = 256 * 1024 * 1024  # a transforms.json of 100k frames is ~60 MB
MAX_JSON_DEPTH = 64


def _depth_exceeds(doc: Any, limit: int) -> bool:
    """Whether containers nest deeper than `limit` (iterative: no recursion on hostile input)."""
    stack = [(doc, 1)]
    while stack:
        node, depth = stack.pop()
        if isinstance(node, dict):
            node = list(node.values())
        if isinstance(node, list):
            if depth > limit:
                return True
            stack.extend((child, depth + 1) for child in node if isinstance(child, (dict, list)))
    return False


def check_nesting(doc: Any, what: str = "JSON", path: str | Path | None = None) -> Any:
    """`doc` unchanged, or SeeUError when its containers nest deeper than `MAX_JSON_DEPTH` (also used
    for a parsed YAML config)."""
    if _depth_exceeds(doc, MAX_JSON_DEPTH):
        raise too_deep_error(what, path)
    return doc


def too_deep_error(what: str, path: str | Path | None = None) -> SeeUError:
    """The error of a document nested deeper than `MAX_JSON_DEPTH` (or one its parser recursed too deep on)."""
    return SeeUError(
        f"{what} nests deeper than {MAX_JSON_DEPTH} levels (not a file this toolkit writes or reads)", path
    )


def _too_large(what: str, size: int, path: str | Path | None) -> SeeUError:
    return SeeUError(f"{what} is {size} bytes, over the {MAX_JSON_BYTES} bytes a JSON or YAML document may have", path)


def parse_json(text: str | bytes, what: str = "JSON", path: str | Path | None = None) -> Any:
    """Parse JSON text; SeeUError (naming `path` and `what`) when invalid, too large or too deep."""
    if len(text) > MAX_JSON_BYTES:
        raise _too_large(what, len(text), path)
    try:
        doc = json.loads(text)
    except RecursionError:
        raise too_deep_error(what, path) from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise SeeUError(f"{what} is not valid JSON ({exc})", path) from None
    return check_nesting(doc, what, path)


def read_document(path: str | Path, what: str = "JSON") -> bytes:
    """The bytes of a document file (JSON or YAML), SeeUError when missing or over `MAX_JSON_BYTES`."""
    path = Path(path)
    if not path.is_file():
        raise SeeUError(f"{what} is not a regular file" if path.exists() else f"{what} not found", path)
    size = path.stat().st_size
    if size > MAX_JSON_BYTES:
        raise _too_large(what, size, path)
    return path.read_bytes()


def read_json(path: str | Path, what: str = "JSON") -> Any:
    """Read and parse a JSON file under the size and depth bounds (see the module docstring)."""
    return parse_json(read_document(path, what), what, path)
