"""SIGTERM as an exception, and ending child processes on the way out.

    with sigterm_raises():        # SIGTERM raises Terminated here, as SIGINT raises KeyboardInterrupt
        ...                       # so finally blocks and context managers run (children are ended)

Python's default SIGTERM kills the process without running any cleanup: a child (the SfM process,
pool workers) outlives it, and the next run collides with it. Under `sigterm_raises` the first
SIGTERM raises `Terminated` in the main thread and later ones are ignored while the cleanup runs.
`end_process` / `end_pool` are what the cleanup calls: children are killed and reaped before the
parent goes on (a child started in its own session, as the SfM child is, is ended with its whole
process group: its mapping processes too). `seeu` (pipelines/cli) installs it first thing, before
any command's imports, so a SIGTERM at any moment ends the command with its one line.

A library may swallow the exception (one raised inside a lazy import that catches everything), or
Python may (one raised in a fork's callback or a `__del__`: its "Exception ignored in" report is kept
off stderr for `Terminated`). The SIGTERM is still recorded (`terminated()`), long work stops at its
next progress point (`raise_if_terminated`, called by `progress.StageProgress` and the build's shard
loop), and `seeu` exits 143 with the one line whatever the command did after it.

Pool workers run `quiet_worker` first: Ctrl-C is the parent's to handle (it reaches the whole process
group; the parent then ends its pools), and SIGTERM raises `Terminated`, a `SystemExit`, so a worker
ends its own children and exits without printing a traceback.

A worker that died (killed, out of memory) is one line, not an internal error: `died` words it from
the exit status (`worker 2 (pid 4242) died (killed by SIGKILL: out of memory?)`), `worker_death` reads
it from the loader's error (PyTorch's DataLoader names the pid and the signal), `ended_workers` from
a broken process pool; the command exits 2 and resumes when run again.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from concurrent.futures import Executor

# seconds a terminated pool worker gets to end its own children before it is killed
_WORKER_GRACE_S = 5.0


class Terminated(SystemExit):
    """SIGTERM arrived (under `sigterm_raises`); like KeyboardInterrupt, no `Exception`. A `SystemExit`
    (code 143), so a process it ends untended (a pool worker) exits without a traceback."""

    def __init__(self, signum: int = signal.SIGTERM):
        super().__init__(128 + signum)


_received: list[int] = []  # the SIGTERMs this process got under `sigterm_raises` / `quiet_worker`


def _raise_terminated(signum, frame) -> None:
    signal.signal(signal.SIGTERM, signal.SIG_IGN)  # the cleanup this starts is not cut short by a second one
    _received.append(signum)
    raise Terminated(signum)


def _quiet_unraisable(previous):
    """`sys.unraisablehook` that says nothing of a `Terminated` (recorded in `_received`), `previous` for the rest."""

    def hook(unraisable) -> None:
        if not isinstance(unraisable.exc_value, Terminated):
            previous(unraisable)

    return hook


def terminated() -> bool:
    """Whether a SIGTERM arrived (even if a library swallowed the `Terminated` it raised)."""
    return bool(_received)


def raise_if_terminated() -> None:
    """Raise `Terminated` again when a SIGTERM arrived: long work calls it at its progress points."""
    if _received:
        raise Terminated(_received[0])


def end_with_parent() -> None:
    """This process is killed (SIGKILL) when its parent ends (Linux; elsewhere nothing): a child must not outlive the
    command, and one the cleanup missed would hold the command's stdout and stderr open after it exits (a worker
    forked while a SIGTERM'd `seeu build` unwound kept a caller reading them waiting 120 s in CI). A child whose
    parent ended before this call exits at once."""
    if not sys.platform.startswith("linux"):
        return
    import ctypes

    ctypes.CDLL(None).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    if os.getppid() == 1:  # re-parented to init: the parent had ended already
        os._exit(1)


def quiet_worker() -> None:
    """Pool initializer: SIGINT ignored (the parent ends the pool), SIGTERM raises `Terminated`, killed when the
    parent ends (`end_with_parent`)."""
    end_with_parent()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _raise_terminated)
    sys.unraisablehook = _quiet_unraisable(sys.unraisablehook)


@contextlib.contextmanager
def sigterm_raises() -> Iterator[None]:
    """SIGTERM raises `Terminated` inside the block; the previous handler is restored after it."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    if signal.getsignal(signal.SIGTERM) is not _raise_terminated:
        _received.clear()  # a new command (tests run several in one process)
    previous = signal.signal(signal.SIGTERM, _raise_terminated)
    previous_hook = sys.unraisablehook
    sys.unraisablehook = _quiet_unraisable(previous_hook)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)
        sys.unraisablehook = previous_hook


def died(who: str, exitcode: int | None) -> str:
    """`WHO died (killed by SIGKILL: out of memory?)` / `(exit status 3)` for a process's exit status."""
    if exitcode is not None and exitcode < 0:
        try:
            name = signal.Signals(-exitcode).name
        except ValueError:
            name = f"signal {-exitcode}"
        hint = ": out of memory?" if -exitcode == signal.SIGKILL else ""
        return f"{who} died (killed by {name}{hint})"
    return f"{who} died (exit status {exitcode})" if exitcode is not None else f"{who} died"


_DATALOADER_DEATH = re.compile(
    r"DataLoader worker \(pid(?:\(s\))? ([\d, ]+)\) (?:is killed by signal: ([^.]+)|exited unexpectedly(?: with exit code (-?\d+))?)"
)


def worker_death(exc: BaseException) -> str | None:
    """The one line for PyTorch's "DataLoader worker (pid N) is killed by signal: Killed." (and "exited
    unexpectedly"), found in `exc` or the exceptions it arose from (PyTorch's SIGCHLD handler raises it
    wherever the main thread is, e.g. while a read from that worker fails), or None."""
    seen: list[BaseException] = []
    m = None
    while exc is not None and exc not in seen and m is None:
        seen.append(exc)
        m = _DATALOADER_DEATH.search(str(exc))
        exc = exc.__cause__ or exc.__context__  # type: ignore[assignment]
    if m is None:
        return None
    pids, signame, code = m.groups()
    who = f"loader worker (pid {pids.strip()})"
    if signame:
        return f"{who} died (killed by signal: {signame.strip()}); re-run to resume (train: --resume)"
    return died(who, int(code) if code else None) + "; re-run to resume (train: --resume)"


def ended_workers(workers: list) -> str:
    """`worker 1 (pid 4242) died (killed by SIGKILL: ...)` for the pool's processes `workers`
    (multiprocessing.Process, in start order) that ended abnormally, but those the broken pool ended
    itself (SIGTERM); a general line when none is known."""
    ended_by_pool = (None, 0, 128 + signal.SIGTERM, -signal.SIGTERM)
    found = [
        died(f"worker {i} (pid {p.pid})", p.exitcode) for i, p in enumerate(workers) if p.exitcode not in ended_by_pool
    ]
    return "; ".join(found) or "a worker process died (killed, or out of memory?)"


def end_process(proc: subprocess.Popen) -> None:
    """Kill `proc` (SIGKILL: nothing in it can delay its end) and reap it; a `proc` started in a session
    of its own (`start_new_session=True`) with its whole process group, the processes it started too."""
    if proc.poll() is None:
        with contextlib.suppress(OSError):
            if os.getpgid(proc.pid) == proc.pid:
                os.killpg(proc.pid, signal.SIGKILL)
            else:
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
