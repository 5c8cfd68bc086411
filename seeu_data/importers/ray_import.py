"""Ray engine for `seeu import --engine ray`: the inputs read on a Ray cluster, the output written here.

Each resumable unit of an import (a pixelSplat chunk, a DL3DV scene, a DTU scan, a RE10K camera file
with its frames) is read by one Ray task: the unit's own `read()` and the scene check, returning its
scenes and skips. `importers.common.write_import` takes the results in unit order and writes them with
the local engine's writer, so the posed files and manifest are byte-identical to a local import, and it
resumes through the same journal. Tasks run at most `window` units ahead of the writer (default: the
cluster's CPUs), so the results held in the object store stay bounded.

A task whose node dies is run again elsewhere (Ray retries it; a result lost with its node is made
again from the task), so a node killed mid-run loses nothing; a killed driver resumes on the next run
from its journal. The inputs must be where every node sees them under the same paths (a shared file
system); the output is written by the driver only.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence

from seeu_data.importers.read_ahead import in_order, run_unit

TASK_RETRIES = 3  # a task lost with its node is run again this many times


def read_units(reads: Sequence[Callable[[], list]], address: str | None, window: int | None = None) -> Iterator[list]:
    """Run every `reads[i]()` (a unit's checked items, as a list) as a Ray task; yield the lists in
    order, at most `window` tasks ahead of the one yielded. Raises SeeUError when Ray cannot be
    reached; a task's own exception is raised here."""
    import ray

    from seeu_data.ray_cluster import ensure_ray

    ensure_ray(address)
    task = ray.remote(run_unit).options(name="seeu-import-unit", max_retries=TASK_RETRIES, num_cpus=1)
    ahead = window or max(1, int(ray.cluster_resources().get("CPU", 1)))
    # interrupted: no task goes on reading for nobody
    yield from in_order(reads, lambda read: task.remote(read), ray.get, ahead, cancel=ray.cancel)
