"""One shard spec -> one shard file: the task every `seeu build` engine runs (local pool, Ray).

`build.py` plans and cuts the specs (`triples.ShardSpec`), keeps what a previous run completed and
writes the manifest; `ray_build.py` maps the same task over a Ray cluster. Both import it from here.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

from seeu_data.build.triples import ShardSpec, write_shard
from seeu_data.errors import SeeUError
from seeu_data.store.manifest import FileEntry


@dataclass
class ShardResult:
    """What one shard of a build came to: its manifest `entry`, or the `error` that stopped it.

    `resumed`: kept from a previous run. `as_dict` / `from_dict`: its JSON form, for the Ray
    engine's rows.
    """

    index: int
    plan_sha256: str
    entry: FileEntry | None = None
    error: str | None = None
    resumed: bool = False

    def as_dict(self) -> dict:
        return {
            "index": self.index,
            "plan_sha256": self.plan_sha256,
            "entry": asdict(self.entry) if self.entry is not None else None,
            "error": self.error,
            "resumed": self.resumed,
        }

    @classmethod
    def from_dict(cls, d: dict) -> ShardResult:
        entry = FileEntry(**d["entry"]) if d.get("entry") is not None else None
        return cls(d["index"], d["plan_sha256"], entry, d.get("error"), d["resumed"])


def materialise(spec: ShardSpec, out_dir: str, fsync: bool = False) -> ShardResult:
    """Write one shard (`triples.write_shard`: in place, fsynced before its rename when `fsync`); return
    its manifest entry, or the error (a SeeUError's message). (Which shards a re-run keeps is decided
    before, on the driver: `resumable_shard`.)"""
    path = Path(out_dir) / spec.file
    try:
        rows, size, sha256 = write_shard(spec, path, fsync)
    except SeeUError as exc:
        return ShardResult(spec.index, spec.plan_sha256, error=str(exc))
    return ShardResult(spec.index, spec.plan_sha256, FileEntry(path.name, rows, size, sha256))
