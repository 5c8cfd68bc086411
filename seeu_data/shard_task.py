"""One shard spec -> one shard file: the task every `seeu build` engine runs (local pool, Ray).

`build.py` plans and cuts the specs (`triples.ShardSpec`), keeps what a previous run completed and
writes the manifest; `ray_build.py` maps the same task over a Ray cluster. Both import it from here.
"""

from __future__ import annotations

from concurrent.futures import Future
from dataclasses import asdict, dataclass
from pathlib import Path

from .arrow_io import set_fsync, write_table_async
from .errors import SeeUError
from .manifest import FileEntry
from .triples import ShardSpec, build_shard_table


@dataclass
class ShardResult:
    """What one shard of a build came to: its manifest `entry`, or the `error` that stopped it.

    `resumed`: kept from a previous run. `pending`: written at `arrow_io.pending_path`, not yet
    renamed into place (`commit_pending`). `sha256_future` (in-process only): the entry's sha256,
    None in `entry` until the hasher has caught up. `as_dict` / `from_dict`: its JSON form, for the
    Ray engine's rows.
    """

    index: int
    plan_sha256: str
    entry: FileEntry | None = None
    error: str | None = None
    resumed: bool = False
    pending: bool = False
    sha256_future: Future | None = None

    def as_dict(self) -> dict:
        return {
            "index": self.index,
            "plan_sha256": self.plan_sha256,
            "entry": asdict(self.entry) if self.entry is not None else None,
            "error": self.error,
            "resumed": self.resumed,
            "pending": self.pending,
        }

    @classmethod
    def from_dict(cls, d: dict) -> ShardResult:
        entry = FileEntry(**d["entry"]) if d.get("entry") is not None else None
        return cls(d["index"], d["plan_sha256"], entry, d.get("error"), d["resumed"], d["pending"])


def materialise(spec: ShardSpec, out_dir: str, commit: bool = True, wait_hash: bool = True) -> ShardResult:
    """Write one shard; its manifest entry, or the error (a SeeUError's message).

    The shard's sha256 is computed while it is written (`arrow_io.write_table_async`). With
    `commit=False` the shard is left at `pending_path` (`pending`): the caller calls
    `commit_pending`. With `wait_hash=False` (in-process callers only) the entry's sha256 is None
    until `sha256_future` gives it. (Which shards a re-run keeps is decided before, on the driver:
    `resumable_shard`.)
    """
    path = Path(out_dir) / spec.file
    try:
        table = build_shard_table(spec, deferred_images=True)
        size, digest = write_table_async(path, table, max_chunksize=spec.rows_per_batch, commit=commit)
        # with wait_hash=False the sha256 is filled in by the caller once its future is done
        entry = FileEntry(path.name, table.num_rows, size, digest.result() if wait_hash else None)  # type: ignore[arg-type]
    except SeeUError as exc:
        return ShardResult(spec.index, spec.plan_sha256, error=str(exc))
    return ShardResult(
        spec.index, spec.plan_sha256, entry, pending=not commit, sha256_future=None if wait_hash else digest
    )


def materialise_in_pool(spec: ShardSpec, out_dir: str, fsync: bool) -> ShardResult:
    """Process-pool entry: `materialise(spec, out_dir, commit=False)` under the driver's fsync policy."""
    set_fsync(fsync)  # the driver's policy (a forked worker has it already; spawned ones do not)
    return materialise(spec, out_dir, commit=False)
