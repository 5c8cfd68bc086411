"""One writer per output directory: an advisory lock on `OUT/.lock` (fcntl.flock, never waits).

    with out_lock("data/shards/train"):          # a second process here gets a one-line SeeUError
        ...                                      # naming the holder's pid (the CLI: exit 2)

    @locks_output(lambda cfg: cfg.out)           # the same around a stage function
    def build(cfg): ...

The kernel drops a flock when its process dies, so a `.lock` left by a crashed or killed run is
simply taken over; the pid written in it (after the lock is taken) only names the holder in the
message. The file is removed again when the holder leaves cleanly (its content is never trusted).
A directory the lock had to create is removed again when nothing was written into it (a stage that
refuses its input leaves no empty OUT behind). When OUT cannot be made (its parent is a file, no
permission) no lock is taken and the stage reports the problem itself. The lock is re-entrant within
a process (`seeu demo` holds OUT while its stages write into it). Linux/macOS only (fcntl).
"""

from __future__ import annotations

import contextlib
import fcntl
import functools
import os
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import ParamSpec, TypeVar

from seeu_data.errors import SeeUError

LOCK_NAME = ".lock"

P = ParamSpec("P")
R = TypeVar("R")

# resolved directory -> how many `out_lock`s of this process hold it
_held: dict[Path, int] = {}


def lock_holder(directory: str | Path) -> int | None:
    """The pid written in `directory/.lock` (None when there is none or it is not a number)."""
    try:
        text = (Path(directory) / LOCK_NAME).read_text(errors="replace").strip()
    except OSError:
        return None
    return int(text) if text.isdigit() else None


def _missing_ancestors(directory: Path) -> list[Path]:
    """`directory` and its ancestors that do not exist yet, deepest first."""
    missing = []
    p = directory
    while not p.exists() and p != p.parent:
        missing.append(p)
        p = p.parent
    return missing


def _take(path: Path) -> int:
    """Open and flock `path` (non-blocking); the fd, or SeeUError naming the holder."""
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            pid = lock_holder(path.parent)
            who = f"pid {pid}" if pid is not None else "another process"
            raise SeeUError(
                f"another seeu process ({who}) is writing to this directory; wait for it to finish or choose another --out",
                path.parent,
            ) from None
        except BaseException:
            os.close(fd)
            raise
        # The holder before us may have removed the file while we waited to lock it: lock the file that is there.
        try:
            same = os.fstat(fd).st_ino == os.stat(path).st_ino
        except FileNotFoundError:
            same = False
        if same:
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
            return fd
        os.close(fd)


@contextlib.contextmanager
def out_lock(directory: str | Path) -> Iterator[None]:
    """Hold `directory/.lock` while the block writes into `directory` (made when missing)."""
    directory = Path(directory)
    if directory.exists() and not directory.is_dir():
        yield  # not a directory: the stage says so itself
        return
    made = _missing_ancestors(directory)
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError:
        yield  # cannot be made: the stage reports it
        return
    key = directory.resolve()
    if _held.get(key):
        _held[key] += 1
        try:
            yield
        finally:
            _held[key] -= 1
        return
    path = directory / LOCK_NAME
    try:
        fd = _take(path)
    except BaseException:
        _remove_made(made)
        raise
    _held[key] = 1
    try:
        yield
    finally:
        del _held[key]
        with contextlib.suppress(OSError):
            path.unlink()  # while still held: a process that opened it before retries (`_take`)
        os.close(fd)
        _remove_made(made)


def _remove_made(made: list[Path]) -> None:
    for p in made:  # deepest first; stops at the first that holds anything
        try:
            p.rmdir()
        except OSError:
            return


def locks_output(where: Callable[..., str | Path | None]) -> Callable[[Callable[P, R]], Callable[P, R]]:
    """Decorate a stage function so it runs under `out_lock(where(*args, **kwargs))` (no lock when None)."""

    def wrap(fn: Callable[P, R]) -> Callable[P, R]:
        @functools.wraps(fn)
        def run(*args: P.args, **kwargs: P.kwargs) -> R:
            directory = where(*args, **kwargs)
            if directory is None:
                return fn(*args, **kwargs)
            with out_lock(directory):
                return fn(*args, **kwargs)

        return run

    return wrap
