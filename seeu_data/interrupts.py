"""SIGTERM as an exception, and ending child processes on the way out.

    with sigterm_raises():        # SIGTERM raises Terminated here, as SIGINT raises KeyboardInterrupt
        ...                       # so finally blocks and context managers run (children are ended)

Python's default SIGTERM kills the process without running any cleanup: a child (the SfM process,
pool workers) outlives it, and the next run collides with it. Under `sigterm_raises` the first
SIGTERM raises `Terminated` in the main thread and later ones are ignored while the cleanup runs.
`end_process` / `end_pool` are what the cleanup calls: children are killed and reaped before the
parent goes on. `seeu` (pipelines/cli) installs it around every command; ingest's worker processes
install it too (`raise_on_sigterm`), so a terminated worker ends its own SfM child.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import signal
import subprocess
import threading
import time
from collections.abc import Iterator
from concurrent.futures import Executor

# seconds a terminated pool worker gets to end its own children before it is killed
_WORKER_GRACE_S = 5.0


class Terminated(BaseException):
    """SIGTERM arrived (under `sigterm_raises`); a BaseException like KeyboardInterrupt."""


def _raise_terminated(signum, frame) -> None:
    signal.signal(signal.SIGTERM, signal.SIG_IGN)  # the cleanup this starts is not cut short by a second one
    raise Terminated(signum)


def raise_on_sigterm() -> None:
    """Make SIGTERM raise `Terminated` in this process (main thread only; a pool initializer)."""
    signal.signal(signal.SIGTERM, _raise_terminated)


@contextlib.contextmanager
def sigterm_raises() -> Iterator[None]:
    """SIGTERM raises `Terminated` inside the block; the previous handler is restored after it."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def end_process(proc: subprocess.Popen) -> None:
    """Kill `proc` (SIGKILL: nothing in it can delay its end) and reap it."""
    if proc.poll() is None:
        with contextlib.suppress(OSError):
            proc.kill()
    proc.wait()


def end_pool(pool: Executor, grace_s: float = _WORKER_GRACE_S) -> None:
    """Stop a process pool at once: cancel what has not started, SIGTERM the worker processes (all
    multiprocessing children of this process), kill the ones still alive `grace_s` later, reap all."""
    pool.shutdown(wait=False, cancel_futures=True)
    children = multiprocessing.active_children()
    for p in children:
        p.terminate()
    deadline = time.monotonic() + grace_s
    for p in children:
        p.join(max(0.0, deadline - time.monotonic()))
        if p.is_alive():
            p.kill()
            p.join()
