"""The local engine's worker processes (`seeu build`, `seeu import`): a forked pool that ends with
its command and says which worker died.

    with ForkedPool(workers, "build", out_dir) as pool:
        futures = [pool.submit(fn, arg) for arg in args]
        ...                                   # a worker killed: SeeUError, one line, exit 2

Workers are forked, so they inherit the imported modules (spawn or forkserver re-import numpy, cv2
and torch: seconds per worker), with OpenCV single-threaded (`image_ops.single_threaded_cv2`) and
SIGTERM raising (`interrupts.quiet_worker`). Any exception leaving the block (Ctrl-C, SIGTERM, an
error) ends every worker first (`interrupts.end_pool`); a worker that died (the out-of-memory
killer, kill -9) is `SeeUError("<who> worker 1 (pid N) died (killed by SIGKILL: out of memory?);
re-run the same command to resume", where)`.
"""

from __future__ import annotations

import multiprocessing as mp
import os
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from contextlib import ExitStack
from pathlib import Path

from seeu_data.errors import SeeUError
from seeu_data.interrupts import end_pool, ended_workers, quiet_worker


class ForkedPool:
    """`workers` forked processes; `who` and `where` name the command and its output in errors,
    `kept` says what a re-run keeps ("finished shards are kept")."""

    def __init__(self, workers: int, who: str, where: str | Path, kept: str = ""):
        self.workers, self.who, self.where, self.kept = workers, who, where, kept
        self._started: list = []  # the pool's processes (forked as the first tasks are submitted)
        self._stack = ExitStack()

    def __enter__(self) -> ForkedPool:
        from seeu_data.image_ops import single_threaded_cv2

        ctx = mp.get_context("fork" if "fork" in mp.get_all_start_methods() else "spawn")
        self._stack.enter_context(single_threaded_cv2())  # forked with it: setting it in a child can deadlock
        self.pool = self._stack.enter_context(
            ProcessPoolExecutor(max_workers=self.workers, mp_context=ctx, initializer=quiet_worker)
        )
        return self

    def submit(self, fn, *args) -> Future:
        future = self.pool.submit(fn, *args)
        if len(self._started) < self.workers:
            self._started = sorted(mp.active_children(), key=lambda p: p.pid or 0)
        return future

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc is not None:
            end_pool(self.pool)  # no worker outlives the command
        self._stack.close()
        if isinstance(exc, BrokenProcessPool):
            kept = f" ({self.kept})" if self.kept else ""
            raise SeeUError(
                f"{self.who} {ended_workers(self._started)}; re-run the same command to resume{kept}", self.where
            ) from None


def default_workers(resize: bool = False, cores: int | None = None) -> int:
    """Local engine processes for this machine (or one of `cores` cores): one per core, at most 8, except
    when copying images (an import, a build without resize) on up to 4 cores, where one process was faster
    (measured on 2 cores: a build with two processes took 1.0-1.2x the time of one)."""
    cores = cores or os.cpu_count() or 1
    return 1 if not resize and cores <= 4 else max(1, min(8, cores))
