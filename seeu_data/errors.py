"""User-facing errors: one clear line naming the file and the problem; the CLI exits non-zero."""

from __future__ import annotations

import errno
import os
from pathlib import Path


class SeeUError(Exception):
    """An error caused by the user's input or environment, reported as one line without a traceback."""

    def __init__(self, message: str, path: str | Path | None = None):
        self.path = None if path is None else str(path)
        super().__init__(f"{self.path}: {message}" if self.path else message)


# What an OSError's errno means for the user (the system's own text follows in parentheses).
_OS_PROBLEMS = {
    errno.ENOSPC: "cannot write: no space left on the device",
    errno.EDQUOT: "cannot write: disk quota exceeded",
    errno.EROFS: "cannot write: the file system is read-only",
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
    errno.EISDIR: "is a directory, a file is needed here",
    errno.ENOENT: "not found",
    errno.ENAMETOOLONG: "name too long",
    errno.EMFILE: "too many open files",
    errno.EIO: "input/output error (failing disk or network file system?)",
}


def os_error_line(exc: OSError) -> str:
    """`PATH: <what> (errno text)` for an OSError (the path left out when the error names none).

    An existing file where a directory is needed (`--out` naming a file, a file in the way of a
    sub-directory: EEXIST / ENOTDIR) is reported at that file.
    """
    text = exc.strerror or str(exc)
    path = exc.filename
    what = _OS_PROBLEMS.get(exc.errno or 0, "operating-system error")
    if exc.errno in (errno.EEXIST, errno.ENOTDIR) and path is not None:
        p = Path(os.fsdecode(path))
        for candidate in (p, *p.parents):
            if candidate.is_file():
                path, what = candidate, "is a file, a directory is needed here"
                break
        else:
            what = "already exists" if exc.errno == errno.EEXIST else "a path component is not a directory"
    return f"{os.fsdecode(path)}: {what} ({text})" if path is not None else f"{what} ({text})"
