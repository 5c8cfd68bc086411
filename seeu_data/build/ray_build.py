"""Ray Data engine for `seeu build --engine ray`: the same shard specs, the same materialise function.

The driver plans (indices only) and cuts shard specs exactly as the local engine does; Ray Data maps
`shard_task.materialise` over the specs (one spec per block; rows carry the `ShardSpec` and the
`ShardResult` as JSON strings, so Arrow never has to infer a type for them: the only place they are
dicts). Each task writes `shard-XXXXX.arrow` atomically under its deterministic name (fsynced first
with `BuildConfig.fsync`) and returns its manifest entry; the driver records it in the
build's journal and writes the manifest last. The output directory and
the posed inputs must be on a file system every node sees (or the same path on each node).
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path

from seeu_data.build.shard_task import ShardResult, materialise
from seeu_data.build.triples import ShardSpec
from seeu_data.ray_cluster import ensure_ray


def ray_task(row: dict) -> dict:
    """One shard: a Ray Data row (the spec as JSON) -> its `ShardResult` as JSON."""
    import cv2

    cv2.setNumThreads(1)  # Ray schedules one task per CPU
    spec = ShardSpec.from_dict(json.loads(row["spec"]))
    return {"result": json.dumps(materialise(spec, row["out_dir"], bool(row["fsync"])).as_dict())}


def run_ray(
    specs: list[ShardSpec],
    out_dir: str,
    address: str | None,
    bar,
    on_shard: Callable[[ShardResult], None] | None = None,
    fsync: bool = False,
) -> list[ShardResult]:
    """Materialise every spec on the Ray cluster; results in spec order. `on_shard(result)` is called
    for each shard written, as it arrives (the task has renamed the shard into place by then)."""
    import ray

    ensure_ray(address)
    # Ray Data re-reads its logging level whenever a dataset runs; its INFO and WARNING lines (one
    # per dataset, and a notice that its own progress bars are off) would interleave with ours.
    # Failures still raise. RAY_DATA_LOG_LEVEL set by the user wins.
    os.environ.setdefault("RAY_DATA_LOG_LEVEL", "ERROR")
    ctx = ray.data.DataContext.get_current()
    ctx.enable_progress_bars = False
    items = [{"spec": json.dumps(s.as_dict()), "out_dir": str(Path(out_dir).resolve()), "fsync": fsync} for s in specs]
    ds = ray.data.from_items(items, override_num_blocks=len(items)).map(ray_task, num_cpus=1)
    results = []
    for row in ds.iter_rows():
        result = ShardResult.from_dict(json.loads(row["result"]))
        results.append(result)
        if on_shard is not None and result.entry is not None:
            on_shard(result)
        bar.update(result.entry.rows if result.entry is not None else 0)
    return sorted(results, key=lambda r: r.index)
