"""User-facing errors: one clear line naming the file and the problem; the CLI exits non-zero."""

from __future__ import annotations

from pathlib import Path


class SeeUError(Exception):
    """An error caused by the user's input or environment, reported as one line without a traceback."""

    def __init__(self, message: str, path: str | Path | None = None):
        self.path = None if path is None else str(path)
        super().__init__(f"{self.path}: {message}" if self.path else message)
