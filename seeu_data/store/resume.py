"""Resume: what a re-run may keep, and the sweep of what it may not. One mechanism for ingest,
import, build and the demo.

A *unit* is a piece of work whose output a re-run keeps when it is complete and was made from the
same inputs and settings: a stage of ingest or of the demo, a shard of `seeu build`, a posed file
of an import.

- Stamps: `stamp_of(key)` is the sha256 of `key`'s canonical JSON, where `key` holds what the unit
  is made from (settings, input fingerprints, the stamps of the units it reads, so a change
  upstream invalidates everything downstream). `file_fingerprint` / `files_fingerprint` are cheap
  input fingerprints (size and modification time).
- `Journal`: the completed units of one output, one JSON object per line, each
  `{"unit": name, "stamp": ..., ...what the unit made}`, appended as a unit completes (one write
  per line: an interruption tears at most the last line, which is ignored). `reset` rewrites it
  atomically; users reset it to what a previous run completed *before* they touch the output, so
  that an interrupted re-run loses nothing either. Each record is checked again before its output
  is kept (`file_intact`): by default from the file's size and modification time against those
  recorded when it was put in place (`file_stat`), the recorded sha256 taken as it is, so a re-run
  with nothing to do reads no file's content; with `verify` (the commands' `--verify`, e.g. after a
  power loss without `--fsync`) the file is hashed again.
- `sweep(directory, outputs, keep)`: removes the partial writes of an interrupted run and the
  outputs that no completed unit claims.
- `StageCache`: the stages of a pipeline on a journal (`stages.jsonl` in its work directory): a
  stage is reused when the journal holds it with the same stamp and its outputs exist; otherwise its
  record is dropped, its directory emptied, it runs, and its record is appended.
  `claim_dir` serves units that resume inside themselves (a training run continues from its newest
  checkpoint when its directory was started with the same stamp).

Where each user keeps its journal:

    seeu ingest   OUT/.work/<scene>/stages.jsonl    stages decode, sfm (`StageCache`)
    seeu demo     OUT/.stages/stages.jsonl          stages synth .. render (`StageCache`)
    seeu build    OUT/.build-progress.jsonl         one unit per shard; removed once the manifest is written
    seeu import   OUT/.import-progress.jsonl        one unit per posed file; removed once the manifest is written

Example::

    cache = StageCache(work_dir, force=False)
    result, reused = cache.run("decode", {"input": fp, "stride": 2}, lambda: decode(d), directory=d)
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import threading
import time
from collections.abc import Callable, Collection, Iterable
from pathlib import Path

from seeu_data.errors import SeeUError
from seeu_data.store.arrow_io import atomic_write_text, sha256_file
from seeu_data.store.json_file import parse_json

STAGES_JOURNAL = "stages.jsonl"
CLAIM_NAME = ".stamp"  # in a directory given to a unit that resumes inside itself (`claim_dir`)


def stamp_of(key: object) -> str:
    """sha256 (hex) of `key`'s canonical JSON: what a unit was made from."""
    return hashlib.sha256(json.dumps(key, sort_keys=True, default=str).encode()).hexdigest()


def file_fingerprint(path: str | Path) -> str:
    """`size:mtime_ns` of a file ("missing" when absent): changes when the file is replaced or edited."""
    try:
        st = os.stat(path)
    except OSError:
        return "missing"
    return f"{st.st_size}:{st.st_mtime_ns}"


def files_fingerprint(paths: Iterable[str | Path]) -> str:
    """One fingerprint for the files a unit reads (`file_fingerprint` of each, with its path, in
    order): changes when any of them is replaced, edited, appears, disappears or the list changes."""
    h = hashlib.sha256()
    for p in paths:
        h.update(f"{p}={file_fingerprint(p)}\n".encode())
    return h.hexdigest()


def file_stat(path: str | Path) -> int:
    """The modification time (ns) to record with a file as it is put in place, for `file_intact`."""
    return os.stat(path).st_mtime_ns


def file_intact(path: Path, size: int, sha256: str, mtime_ns: int | None = None, verify: bool = False) -> bool:
    """True when `path` still is the recorded file: its size, then its modification time against the
    recorded `mtime_ns` (the recorded sha256 is then trusted: nothing is read), else, and always with
    `verify`, its sha256 (a file torn by a power loss without fsync can keep its size and mtime, not
    its hash)."""
    try:
        st = path.stat()
    except OSError:
        return False
    if st.st_size != size:
        return False
    if not verify and mtime_ns is not None and st.st_mtime_ns == mtime_ns:
        return True
    return sha256_file(path) == sha256


class Journal:
    """An append-only record of the completed units of one output (a JSON-lines file); with `fsync`
    every record reaches the disk before `add` / `reset` returns (the outputs' `--fsync`)."""

    def __init__(self, path: str | Path, fsync: bool = False):
        self.path = Path(path)
        self.fsync = fsync
        self._lock = threading.Lock()

    def read(self) -> list[dict]:
        """The records in the order they were written, up to the first line that is not a complete
        record (a torn last line); [] when there is no journal."""
        records: list[dict] = []
        try:
            text = self.path.read_text(errors="replace")
        except FileNotFoundError:
            return records
        for line in text.splitlines():
            try:
                rec = parse_json(line, "journal line", self.path)
            except SeeUError:
                break
            if not isinstance(rec, dict) or not isinstance(rec.get("unit"), str):
                break
            records.append(rec)
        return records

    def reset(self, records: Iterable[dict]) -> None:
        """Replace the journal with `records`, atomically."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(self.path, "".join(json.dumps(r) + "\n" for r in records), self.fsync)

    def add(self, record: dict) -> None:
        """Append one completed unit (`record["unit"]` names it); safe from several threads."""
        line = json.dumps(record) + "\n"
        with self._lock, open(self.path, "a") as fh:  # one write per line: a torn last line is ignored
            fh.write(line)
            if self.fsync:
                fh.flush()
                os.fsync(fh.fileno())

    def remove(self) -> None:
        self.path.unlink(missing_ok=True)


def sweep(directory: Path, outputs: str, keep: Collection[str]) -> list[str]:
    """Remove from `directory` the files matching the glob `outputs` that no completed unit claims
    (names not in `keep`), and the partial writes of an interrupted run: hidden temporaries named
    after an output, `.NAME.*` (`arrow_io`'s `.NAME.PID.tmp` and `.NAME.pending`). Returns the
    names of the outputs removed, sorted."""
    removed = []
    for p in sorted(directory.glob(outputs)):
        if p.name not in keep:
            p.unlink(missing_ok=True)
            removed.append(p.name)
    for p in directory.glob(f".{outputs}.*"):
        p.unlink(missing_ok=True)
    return removed


def _empty_dir(directory: Path) -> None:
    if directory.is_dir():
        shutil.rmtree(directory)
    elif directory.exists():
        directory.unlink()
    directory.mkdir(parents=True)


def claim_dir(directory: Path, stamp: str, force: bool = False) -> bool:
    """Give `directory` to the unit with `stamp`, for a unit that resumes inside itself. True: the
    directory already holds that unit's partial work (kept); False: it was emptied (or made) and
    stamped for it (always so with `force`)."""
    mark = directory / CLAIM_NAME
    try:
        if not force and mark.read_text().strip() == stamp:
            return True
    except OSError:
        pass
    _empty_dir(directory)
    atomic_write_text(mark, stamp + "\n")
    return False


class StageCache:
    """Resumable stages of one pipeline run, recorded in `work_dir/stages.jsonl`.

    Each record: `{"unit": stage, "stamp": stamp_of(key), "key": key, "seconds": s, "result": r}`,
    `result` being the stage function's JSON-able result, `seconds` how long it took when it ran.
    `force=True` redoes every stage. `timings` holds the seconds spent on each stage in this run,
    `reused` whether it was reused, `records` the records of the stages run or reused. `fsync`: the
    journal's records are fsynced (`Journal`).
    """

    def __init__(self, work_dir: str | Path, force: bool = False, fsync: bool = False):
        self.work_dir = Path(work_dir)
        self.force = force
        self.journal = Journal(self.work_dir / STAGES_JOURNAL, fsync)
        self.timings: dict[str, float] = {}
        self.reused: dict[str, bool] = {}
        self.records: dict[str, dict] = {}

    def stage_dir(self, name: str) -> Path:
        """A directory of the stage's own under the work directory (pass it to `run` as `directory`)."""
        return self.work_dir / name

    def stamp(self, name: str) -> str:
        """The stamp of a stage run or reused in this run (for the keys of the stages that read it)."""
        return self.records[name]["stamp"]

    def lookup(
        self,
        name: str,
        key: dict,
        outputs: Callable[[dict], Iterable[str | Path]] | None = None,
        directory: Path | None = None,
    ) -> dict | None:
        """The record of stage `name` when it completed with `key` and `directory` and every path
        `outputs(result)` names still exist; None otherwise (and always with `force`)."""
        if self.force:
            return None
        stamp = stamp_of(key)
        found = None
        for rec in self.journal.read():
            if rec["unit"] == name:
                found = rec
        if found is None or found.get("stamp") != stamp or "result" not in found:
            return None
        paths = list(outputs(found["result"])) if outputs is not None else []
        if directory is not None:
            paths.append(directory)
        return found if all(Path(p).exists() for p in paths) else None

    def run(
        self,
        name: str,
        key: dict,
        fn: Callable[[], dict],
        directory: Path | None = None,
        outputs: Callable[[dict], Iterable[str | Path]] | None = None,
    ) -> tuple[dict, bool]:
        """Reuse stage `name` (see `lookup`) or run `fn()`; returns (result, reused).

        `directory`: the stage's own output directory, emptied before `fn` runs and removed when it
        fails with an OSError (disk full, read-only: no half-written stage left taking space).
        """
        t0 = time.perf_counter()
        found = self.lookup(name, key, outputs, directory)
        if found is not None:
            self.timings[name] = time.perf_counter() - t0
            self.reused[name] = True
            self.records[name] = found
            return found["result"], True
        # forget the stage before its output changes: an interruption from here on redoes it
        self.journal.reset(r for r in self.journal.read() if r["unit"] != name)
        if directory is not None:
            _empty_dir(directory)
        try:
            result = fn()
        except OSError:
            if directory is not None:
                shutil.rmtree(directory, ignore_errors=True)
            raise
        seconds = time.perf_counter() - t0
        record = {"unit": name, "stamp": stamp_of(key), "key": key, "seconds": seconds, "result": result}
        self.journal.add(json.loads(json.dumps(record, default=str)))
        self.timings[name] = seconds
        self.reused[name] = False
        self.records[name] = record
        return result, False
