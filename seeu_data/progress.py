"""Progress of a long stage: a tqdm bar on a terminal, and a heartbeat line on stderr when there is none.

    with StageProgress("seeu ingest: walk", bar=sys.stderr.isatty(), heartbeat_s=10) as prog:
        prog.stage("decode", total=90)
        for ...: prog.advance()
        prog.stage("sfm extract", total=36)
        prog.set(12)

The heartbeat (a daemon thread) prints `seeu ingest: walk: sfm match 12/36, 40 s` every `heartbeat_s`
seconds, so a long run in CI or a log file is never silent; `heartbeat_s=0` turns it off.
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
        self.name, self.done = "", 0
        self.total: int | None = None
        self.t0 = time.monotonic()
        self._bar = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = None
        if self.heartbeat_s > 0:
            self._thread = threading.Thread(target=self._beat, daemon=True)
            self._thread.start()

    def status(self) -> str:
        """`<label>: <stage> <done>/<total>, <elapsed> s` (the heartbeat line)."""
        with self._lock:
            count = f" {self.done}/{self.total}" if self.total else (f" {self.done}" if self.done else "")
            return f"{self.label}: {self.name or 'starting'}{count}, {time.monotonic() - self.t0:.0f} s"

    def _beat(self) -> None:
        while not self._stop.wait(self.heartbeat_s):
            print(self.status(), file=self.stream or sys.stderr, flush=True)

    def stage(self, name: str, total: int | None = None) -> None:
        with self._lock:
            self.name, self.total, self.done = name, total, 0
        if self.bar_enabled:
            from tqdm import tqdm

            if self._bar is not None:
                self._bar.close()
            self._bar = tqdm(total=total, desc=f"{self.label.split(': ')[-1]} {name}", leave=False)

    def set(self, done: int) -> None:
        raise_if_terminated()  # a SIGTERM whose exception a library swallowed (seeu_data/interrupts.py)
        with self._lock:
            step, self.done = done - self.done, done
        if self._bar is not None and step:
            self._bar.update(step)

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
