"""Ray engine for `seeu ingest --engine ray`: one scene per Ray task, the same `ingest_scene` as the local engine.

    results = ingest_on_ray(sources, cfg, scene_fn=ingest_scene, address="auto")

`pipelines.ingest.ingest` calls it for `IngestConfig(engine="ray")`. Each task runs
`scene_fn(source, cfg)` (pipelines/ingest.py `ingest_scene`, into cfg.out) and reserves `max(cfg.sfm.threads, cfg.sfm.map_threads)` CPUs, the COLMAP threads it will use. A re-run
resumes the way the local engine does: every scene keeps its stages under OUT/.work/<scene>/ with a
stamp of their inputs (`seeu_data.store.resume.StageCache`), so a completed scene reuses decode and SfM
and only rewrites its posed files (the same bytes), while a failed or interrupted one redoes what
it lacks. Results come back as the tasks finish; a scene that fails is reported in one line and
the others go on.

Tasks run in other processes, maybe on other machines: each works in the driver's working directory,
so paths mean there what they mean to the driver (relative ones included) and the reports record them
as the local engine does. Every node must see the inputs, OUT and that directory under the same paths
(a shared file system).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any


@dataclass(frozen=True)
class SceneResult:
    """One scene's outcome (either engine): its report (also OUT/<scene>/report.json) or its one-line error."""

    name: str
    report: dict | None = None
    error: str | None = None


def task_cpus(threads: int, map_threads: int) -> int:
    """CPUs one scene task reserves: the most COLMAP threads any of its stages uses."""
    from seeu_data.errors import SeeUError

    if threads < 1 or map_threads < 1:
        raise SeeUError(
            "--engine ray needs positive --threads and --map-threads (the CPUs each scene task reserves), "
            f"got {threads} and {map_threads}"
        )
    return max(threads, map_threads)


def _scene_task(scene_fn: Callable, source, cfg, cwd: str) -> tuple:
    """Ray task body: (report, None) or (None, error line) for the errors a user can act on (`cfg`
    carries the driver's settings, `fsync` included)."""
    from seeu_data.errors import SeeUError, os_error_line

    own_cwd = os.getcwd()
    try:
        os.chdir(cwd)  # a worker runs one task at a time; restored below
    except OSError:
        return None, f"{source.name}: the driver's working directory {cwd} is not on this node (give absolute paths)"
    try:
        return scene_fn(source, cfg), None
    except SeeUError as exc:
        return None, str(exc)
    except OSError as exc:
        return None, os_error_line(exc)
    finally:
        os.chdir(own_cwd)


def _failure_line(name: str, exc: BaseException) -> str:
    """One line for a task that died (an unexpected exception, a crashed or killed worker)."""
    import ray

    cause = exc.cause if isinstance(exc, ray.exceptions.RayTaskError) else exc
    text = (str(cause).strip().splitlines() or [""])[0]
    return f"{name}: internal error in the Ray task: {type(cause).__name__}: {text} (see the Ray worker logs)"


def ingest_on_ray(
    sources: list,
    cfg: Any,
    scene_fn: Callable,
    address: str | None = None,
    on_result: Callable[[SceneResult], None] | None = None,
    progress: bool = False,
) -> list[SceneResult]:
    """Ingest every source (`seeu_data.ingest.video.SceneSource`) as one Ray task; results in `sources` order.

    `cfg`: the `IngestConfig` every scene uses (`out`, `force`; its `sfm.threads` and `sfm.map_threads` set the
    CPUs per task).
    `scene_fn`: the local engine's `ingest_scene`. `address`: a running cluster ('host:port', 'auto');
    None starts a local instance (or uses the one this process already has). The connection is made
    before OUT is created. `on_result` is called with each scene's result as its task finishes.
    Raises SeeUError when Ray cannot be reached.
    """
    cpus = task_cpus(cfg.sfm.threads, cfg.sfm.map_threads)  # a bad value: one line before Ray starts
    import ray
    from tqdm import tqdm

    from seeu_data.ray_cluster import ensure_ray

    ensure_ray(address)
    Path(cfg.out).mkdir(parents=True, exist_ok=True)
    task = ray.remote(_scene_task).options(num_cpus=cpus, name="seeu-ingest-scene")
    cwd = os.getcwd()
    pending = {task.remote(scene_fn, s, cfg, cwd): s.name for s in sources}
    results: dict[str, SceneResult] = {}
    with tqdm(total=len(sources), desc="scenes", disable=not progress) as bar:
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            name = pending.pop(done[0])
            try:
                report, error = ray.get(done[0])
            except ray.exceptions.RayError as exc:
                report, error = None, _failure_line(name, exc)
            results[name] = SceneResult(name, report, error)
            if on_result is not None:
                on_result(results[name])
            bar.update()
    return [results[s.name] for s in sources]
