"""Progress of a long stage: a tqdm bar on a terminal, and a heartbeat line on stderr when there is none.

    with StageProgress("seeu ingest: walk", bar=sys.stderr.isatty(), heartbeat_s=10) as prog:
        prog.stage("decode", total=90, unit="frames")
        for ...: prog.advance()
        prog.stage("sfm match", total=300, unit="pairs")
        prog.set(120)
        prog.set_total(250)        # the plan shrank: fewer pairs left to do

The heartbeat (a daemon thread) prints `seeu ingest: walk: sfm match 120/250 pairs, 40 s, ETA 30 s`
every `heartbeat_s` seconds, so a long run in CI or a log file is never silent; `heartbeat_s=0` turns
it off. The ETA is the stage's own rate so far (elapsed in the stage / done) times what is left. A count
never exceeds its total (`set` stops at the total).
"""

from __future__ import annotations

import sys
import threading
import time

from seeu_data.interrupts import raise_if_terminated


class StageProgress:
    def __init__(self, label: str, bar: bool = False, heartbeat_s: float = 0.0, stream=None):
        self.label = label
        self.bar_enabled = bar
        self.heartbeat_s = float(heartbeat_s)
        self.stream = stream
        self.name, self.done, self.unit = "", 0, ""
        self.total: int | None = None
        self.t0 = self.stage_t0 = time.monotonic()
        self._bar = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = None
        if self.heartbeat_s > 0:
            self._thread = threading.Thread(target=self._beat, daemon=True)
            self._thread.start()

    def status(self) -> str:
        """`<label>: <stage> <done>/<total> <unit>, <elapsed> s[, ETA <left>]` (the heartbeat line)."""
        with self._lock:
            now = time.monotonic()
            unit = f" {self.unit}" if self.unit else ""
            count = f" {self.done}/{self.total}{unit}" if self.total else (f" {self.done}{unit}" if self.done else "")
            line = f"{self.label}: {self.name or 'starting'}{count}, {now - self.t0:.0f} s"
            if self.total and 0 < self.done < self.total:
                line += f", ETA {_duration((now - self.stage_t0) / self.done * (self.total - self.done))}"
            return line

    def _beat(self) -> None:
        while not self._stop.wait(self.heartbeat_s):
            print(self.status(), file=self.stream or sys.stderr, flush=True)

    def stage(self, name: str, total: int | None = None, unit: str = "") -> None:
        """Begin stage `name` of `total` units (`unit`: "frames", "images", "pairs", ...; None: unknown)."""
        with self._lock:
            self.name, self.total, self.done, self.unit = name, total, 0, unit
            self.stage_t0 = time.monotonic()
        if self.bar_enabled:
            from tqdm import tqdm

            if self._bar is not None:
                self._bar.close()
            desc = f"{self.label.split(': ')[-1]} {name}"
            self._bar = tqdm(total=total, desc=desc, unit=f" {unit}" if unit else "it", leave=False)

    def set(self, done: int) -> None:
        """`done` units of the stage are done (at most its total)."""
        raise_if_terminated()  # a SIGTERM whose exception a library swallowed (seeu_data/interrupts.py)
        with self._lock:
            if self.total is not None:
                done = min(done, self.total)
            step, self.done = done - self.done, done
        if self._bar is not None and step:
            self._bar.update(step)

    def set_total(self, total: int) -> None:
        """The stage's total changed (a plan that grew or shrank as it went), never below what is done."""
        with self._lock:
            self.total = max(total, self.done)
        if self._bar is not None:
            self._bar.total = self.total
            self._bar.refresh()

    def advance(self, n: int = 1) -> None:
        self.set(self.done + n)

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    def __enter__(self) -> StageProgress:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _duration(seconds: float) -> str:
    """`45 s`, `3 min 20 s`, `1 h 05 min`."""
    s = int(round(seconds))
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60:02d} s"
    return f"{s // 3600} h {s % 3600 // 60:02d} min"
