"""One shard spec -> one shard file: the task every `seeu build` engine runs (local pool, Ray).

`build.py` plans and cuts the specs and writes the manifest; `ray_build.py` maps the same task over
a Ray cluster. Both import it from here, so neither engine module imports the other's driver.
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

from .arrow_io import set_fsync, write_table_async
from .errors import SeeUError
from .manifest import FileEntry
from .triples import build_shard_table


def materialise(spec: dict, out_dir: str, commit: bool = True, wait_hash: bool = True) -> dict:
    """Write one shard; return its manifest entry, or {"error": message}.

    The shard's sha256 is computed while it is written (`arrow_io.write_table_async`). With
    `commit=False` the shard is left at `pending_path` (`"pending": True`): the caller calls
    `commit_pending`. With `wait_hash=False` (in-process callers only) the entry's sha256 is None and
    `"sha256_future"` gives it once the hasher has caught up. (Which shards a re-run keeps is
    decided before, on the driver: `resumable_shard`.)
    """
    out = Path(out_dir)
    path = out / spec["file"]
    try:
        table = build_shard_table(spec, deferred_images=True)
        size, digest = write_table_async(path, table, max_chunksize=spec["rows_per_batch"], commit=commit)
        # with wait_hash=False the sha256 is filled in by the caller once its future is done
        entry = FileEntry(path.name, table.num_rows, size, digest.result() if wait_hash else None)  # type: ignore[arg-type]
    except SeeUError as exc:
        return {"index": spec["index"], "error": str(exc)}
    result = {
        "index": spec["index"],
        "entry": asdict(entry),
        "resumed": False,
        "pending": not commit,
        "plan_sha256": spec["plan_sha256"],
    }
    if not wait_hash:
        result["sha256_future"] = digest
    return result


def materialise_json(args: tuple[str, str, bool]) -> dict:
    """Process-pool entry: (spec as JSON, out_dir, fsync policy) -> `materialise(..., commit=False)`."""
    set_fsync(args[2])  # the driver's policy (a forked worker has it already; spawned ones do not)
    return materialise(json.loads(args[0]), args[1], commit=False)
