"""Resumable pipeline stages: each stage's output directory carries a stamp of its inputs.

    cache = StageCache(work_dir, force=False)
    result, reused = cache.run("decode", key={"input": fingerprint, "stride": 2}, fn=lambda d: {...})

A stage is reused when `<work_dir>/<name>/stamp.json` exists and its key hash equals the new key's
(the key holds the input fingerprint, the parameters and the upstream stage's hash, so a change
upstream invalidates everything downstream). Otherwise the directory is emptied, `fn(dir)` runs,
and the stamp (holding fn's JSON result) is written last and atomically, so an interrupted stage
is redone on the next run; a stage failing with an OSError (disk full, read-only) is removed. `force=True` redoes every stage.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import time
from pathlib import Path
from typing import Callable

from .arrow_io import atomic_write_text

STAMP = "stamp.json"


def key_hash(key: dict) -> str:
    return hashlib.sha256(json.dumps(key, sort_keys=True, default=str).encode()).hexdigest()


class StageCache:
    def __init__(self, work_dir: str | Path, force: bool = False):
        self.work_dir = Path(work_dir)
        self.force = force
        self.timings: dict[str, float] = {}
        self.reused: dict[str, bool] = {}

    def stage_dir(self, name: str) -> Path:
        return self.work_dir / name

    def lookup(self, name: str, key: dict) -> dict | None:
        """The stored result of stage `name` if it is complete and was made with `key`."""
        stamp = self.stage_dir(name) / STAMP
        if self.force or not stamp.exists():
            return None
        try:
            doc = json.loads(stamp.read_text())
        except (OSError, json.JSONDecodeError):
            return None
        return doc["result"] if doc.get("key_hash") == key_hash(key) else None

    def run(self, name: str, key: dict, fn: Callable[[Path], dict]) -> tuple[dict, bool]:
        """Reuse or (re)run stage `name`; returns (result, reused)."""
        t0 = time.perf_counter()
        found = self.lookup(name, key)
        if found is not None:
            self.timings[name] = time.perf_counter() - t0
            self.reused[name] = True
            return found, True
        d = self.stage_dir(name)
        if d.exists():
            shutil.rmtree(d)
        d.mkdir(parents=True)
        try:
            result = fn(d)
        except OSError:  # disk full, read-only, ...: no half-written stage left taking space
            shutil.rmtree(d, ignore_errors=True)
            raise
        elapsed = time.perf_counter() - t0
        atomic_write_text(
            d / STAMP,
            json.dumps(
                {"stage": name, "key_hash": key_hash(key), "key": key, "elapsed_s": elapsed, "result": result},
                default=str,
            ),
        )
        self.timings[name] = elapsed
        self.reused[name] = False
        return result, False
