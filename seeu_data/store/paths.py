"""Paths read from files: the one containment rule.

A path a dataset file names (a manifest's `files[].path` and `scenes[].file`, a pixelSplat
`index.json` chunk name, a nerfstudio `file_path`, a COLMAP image name) is resolved against the
directory it is relative to and must stay inside it: `../../elsewhere/x`, an absolute path, or a
symbolic link leading out of the directory is refused. Only the importers whose real inputs need
it (nerfstudio, COLMAP: images kept beside the dataset or linked from elsewhere) offer
`--allow-outside-paths`; manifests and index files never leave their directory.
"""

from __future__ import annotations

import posixpath
from pathlib import Path

from seeu_data.errors import SeeUError


class OutsidePathError(SeeUError):
    """A path read from a file leads outside its dataset directory."""


def contained_path(
    root: str | Path, name: str, what: str, source: str | Path | None = None, allow_outside: bool = False
) -> Path:
    """`root / name`, resolved (`..` and symbolic links followed); OutsidePathError naming `source`
    (the file that holds `name`; default `root`) unless it stays inside `root` or `allow_outside`.

    `what` says what `name` is, for the message ("manifest entry", "index.json entry", ...).
    """
    root_p = Path(root)
    if not isinstance(name, str) or not name or "\0" in name:
        raise SeeUError(f"{what} {name!r} is not a usable relative path", source or root_p)
    path = root_p / name
    if allow_outside:
        return path
    resolved_root = root_p.resolve()
    resolved = path.resolve()
    if resolved != resolved_root and not resolved.is_relative_to(resolved_root):
        raise OutsidePathError(
            f"{what} {name!r} leads outside {root_p} (to {resolved}); paths in dataset files "
            "must stay inside their directory",
            source or root_p,
        )
    return path


def contained_key(name: str, what: str, source: str | Path) -> str:
    """A relative object-storage key (`a/b.arrow`) as given, checked without a file system: no
    absolute key, no `..` that leaves the prefix (OutsidePathError naming `source` otherwise)."""
    if not isinstance(name, str) or not name or "\0" in name:
        raise SeeUError(f"{what} {name!r} is not a usable relative path", source)
    norm = posixpath.normpath(name.replace("\\", "/"))
    if name.startswith(("/", "\\")) or norm == ".." or norm.startswith("../") or "://" in name:
        raise OutsidePathError(
            f"{what} {name!r} leads outside its dataset; paths in dataset files must stay inside their directory",
            source,
        )
    return name
