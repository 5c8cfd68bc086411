"""Process-group set-up for torchrun (single node or multi-node) and plain single-process runs.

``torchrun --nproc_per_node=G [--nnodes=N --node_rank=R --rdzv_endpoint=HOST:PORT] -m pipelines.cli train ...``
sets RANK / WORLD_SIZE / LOCAL_RANK / MASTER_ADDR / MASTER_PORT; `setup_distributed` reads them and
joins the group with NCCL on CUDA, gloo on CPU. Without them it is a no-op (world size 1).

Watchdog (`Watchdog`, started by `seeu train` on every rank of a run of more than one): a collective
waits for every rank, up to the process group's timeout (30 minutes), so one frozen rank (stopped,
swapping, cut off) held the others for half an hour. Each rank's watchdog thread adds 1 to its own
counter in the rendezvous store (MASTER_ADDR:MASTER_PORT, the TCPStore torchrun or rank 0 serves)
every `interval` seconds and reads the others'. A rank whose counter has not moved for `timeout_s`
(`seeu train --rank-timeout`) has stopped: the watchdog of every other rank ends its process (exit 2,
`os._exit`: the main thread waits inside a collective and cannot unwind), the lowest such rank
printing the one line `rank N stopped responding: no heartbeat for T s ...`. A silent rank on the same
machine that is stopped (SIGSTOP, Ctrl-Z: state T in /proc) is killed by the first watchdog to see it
(`kill_if_stopped_here`: each rank records where it runs and its pid in the store); else torchrun ends
it (SIGTERM, then SIGKILL 30 s later: a stopped process made everyone wait those 30 s). A store that
stops answering (its host frozen or gone) ends the run the same way. Long work of one rank (rank 0's
validation) does not stop its thread: only a stopped process does.

A rank that died makes the others' next collective fail at once; `Watchdog.dead_peer` names it (the
rank whose counter stopped), so the survivors exit 2 with `rank N died` instead of an internal error.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import timedelta
from pathlib import Path

import torch
import torch.distributed as dist


@dataclass
class DistInfo:
    rank: int = 0
    world_size: int = 1
    local_rank: int = 0
    device: torch.device = torch.device("cpu")
    initialized_here: bool = False

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    @property
    def enabled(self) -> bool:
        return self.world_size > 1


def pick_device(local_rank: int = 0, device: str | None = None) -> torch.device:
    """`device` if given ("cpu", "cuda", "cuda:1"), else this process's GPU, else the CPU."""
    if device:
        return torch.device(device)
    if torch.cuda.is_available():
        return torch.device("cuda", local_rank % torch.cuda.device_count())
    return torch.device("cpu")


def setup_distributed(device: str | None = None, backend: str | None = None, timeout_s: float = 1800.0) -> DistInfo:
    """Join the process group described by the torchrun environment (or the one already initialised)."""
    if dist.is_available() and dist.is_initialized():
        local = int(os.environ.get("LOCAL_RANK", dist.get_rank()))
        return DistInfo(dist.get_rank(), dist.get_world_size(), local, pick_device(local, device), False)
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return DistInfo(device=pick_device(0, device))
    rank = int(os.environ["RANK"])
    local = int(os.environ.get("LOCAL_RANK", rank))
    dev = pick_device(local, device)
    if dev.type == "cuda":
        torch.cuda.set_device(dev)
    backend = backend or ("nccl" if dev.type == "cuda" else "gloo")
    dist.init_process_group(backend, rank=rank, world_size=world, timeout=timedelta(seconds=timeout_s))
    return DistInfo(rank, world, local, dev, True)


def cleanup_distributed(info: DistInfo) -> None:
    if info.initialized_here and dist.is_initialized():
        dist.destroy_process_group()


def all_gather_objects(obj, info: DistInfo) -> list:
    """[obj of rank 0, obj of rank 1, ...] (a one-element list without a process group)."""
    if not info.enabled:
        return [obj]
    out = [None] * info.world_size
    dist.all_gather_object(out, obj)
    return out


def barrier(info: DistInfo) -> None:
    if info.enabled:
        dist.barrier()


def _all_reduce(value: float, dtype: torch.dtype, op, info: DistInfo) -> torch.Tensor:
    """`value` reduced with `op` over the ranks, as a one-element tensor on the CPU or the NCCL device."""
    t = torch.tensor([value], dtype=dtype)
    if dist.get_backend() == "nccl":
        t = t.to(info.device)
    dist.all_reduce(t, op=op)
    return t


def mean_across(value: float, info: DistInfo) -> float:
    """Average a Python float over the ranks (for logging)."""
    if not info.enabled:
        return value
    return float(_all_reduce(value, torch.float64, dist.ReduceOp.SUM, info).item()) / info.world_size


def max_across(value: int, info: DistInfo) -> int:
    """The largest of an integer over the ranks (a decision every rank must take alike)."""
    if not info.enabled:
        return value
    return int(_all_reduce(value, torch.int64, dist.ReduceOp.MAX, info).item())


class Watchdog:
    """Heartbeats of every rank through the rendezvous store (see the module docstring).

    `on_silent(rank, seconds, report)` is called (on the watchdog thread) when rank `rank` has not
    beaten for `seconds`; `report`: whether this rank is the one to print the line. The default prints
    it (`seeu train: error: ...`) and ends the process with exit status 2."""

    def __init__(
        self,
        info: DistInfo,
        timeout_s: float,
        on_silent: Callable[[int, float, bool], None] | None = None,
        interval_s: float | None = None,
    ):
        self.info, self.timeout_s = info, float(timeout_s)
        self.interval_s = interval_s if interval_s is not None else min(5.0, max(0.2, self.timeout_s / 10))
        self.on_silent = on_silent or _end_run
        self.store = dist.TCPStore(
            os.environ["MASTER_ADDR"],
            int(os.environ["MASTER_PORT"]),
            is_master=False,
            timeout=timedelta(seconds=max(1.0, self.timeout_s)),
            wait_for_workers=False,
        )
        now = time.monotonic()
        self.counts = [-1] * info.world_size
        self.changed = [now] * info.world_size  # when each rank's counter last moved (this clock)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="seeu-rank-watchdog", daemon=True)

    def start(self) -> Watchdog:
        self.store.set(f"seeu/where/{self.info.rank}", f"{_machine()} {os.getpid()}")
        self._beat()
        self._thread.start()
        return self

    def stop(self) -> None:
        """End the heartbeats and wait for the thread: a daemon thread still inside a store call when the
        interpreter exits aborts the process ("terminate called without an active exception", SIGABRT)."""
        self._stop.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(self.timeout_s + self.interval_s)

    def _beat(self) -> None:
        """Add one to this rank's counter and read every rank's (`add 0` reads without waiting)."""
        now = time.monotonic()
        for r in range(self.info.world_size):
            count = int(self.store.add(f"seeu/beat/{r}", 1 if r == self.info.rank else 0))
            if count != self.counts[r]:
                self.counts[r], self.changed[r] = count, now

    def silent(self, seconds: float) -> list[int]:
        """The ranks (not this one) whose counter has not moved for `seconds`."""
        now = time.monotonic()
        return [r for r in range(self.info.world_size) if r != self.info.rank and now - self.changed[r] >= seconds]

    def _run(self) -> None:
        while not self._stop.wait(self.interval_s):
            try:
                self._beat()
            except Exception:  # the store's host stopped answering within the timeout
                if not self._stop.is_set():  # not rank 0 closing the store at the end of the run
                    self.on_silent(-1, self.timeout_s, True)
                return
            silent = self.silent(self.timeout_s)
            if silent:
                alive = [r for r in range(self.info.world_size) if r not in silent]
                for r in silent:
                    self.kill_if_stopped_here(r)
                self.on_silent(silent[0], self.timeout_s, self.info.rank == min(alive))
                return

    def kill_if_stopped_here(self, rank: int) -> bool:
        """SIGKILL `rank`'s process if it runs on this machine (same kernel boot and pid namespace) and is
        stopped; whether it was."""
        try:
            if not self.store.check([f"seeu/where/{rank}"]):
                return False
            where, pid = self.store.get(f"seeu/where/{rank}").decode().rsplit(" ", 1)
            if where != _machine():
                return False
            stat = Path(f"/proc/{int(pid)}/stat").read_text()
            if stat[stat.rindex(")") + 2] not in "Tt":
                return False
            os.kill(int(pid), signal.SIGKILL)
            return True
        except (OSError, ValueError, RuntimeError):
            return False

    def dead_peer(self, wait_s: float | None = None) -> int | None:
        """After a collective failed: the rank that stopped beating (dead), waiting up to `wait_s`
        (default three intervals) for its counter to fall behind; None when every rank still beats."""
        deadline = time.monotonic() + (3 * self.interval_s if wait_s is None else wait_s)
        while True:
            silent = self.silent(2 * self.interval_s)
            if silent or time.monotonic() >= deadline:
                return silent[0] if silent else None
            time.sleep(self.interval_s / 2)


def _machine() -> str:
    """This kernel boot and pid namespace: processes that share it can signal each other by pid."""
    try:
        boot = Path("/proc/sys/kernel/random/boot_id").read_text().strip()
        return f"{boot}/{os.stat('/proc/self/ns/pid').st_ino}"
    except OSError:
        return f"{os.uname().nodename}?"  # no /proc: never matched as "here" by another machine's rank


def silent_rank_line(rank: int, seconds: float) -> str:
    """What the watchdog prints for a rank (-1: the rendezvous store) that stopped responding."""
    who = f"rank {rank}" if rank >= 0 else "the rendezvous store (MASTER_ADDR:MASTER_PORT)"
    return (
        f"{who} stopped responding: no heartbeat for {seconds:g} s (frozen, stopped or cut off?); the run "
        "ends on every rank (resume with --resume; --rank-timeout sets the wait)"
    )


def _end_run(rank: int, seconds: float, report: bool) -> None:
    if report:
        print(f"seeu train: error: {silent_rank_line(rank, seconds)}", file=sys.stderr, flush=True)
    os._exit(2)
