"""An import's units read ahead of its writer, in order: in local worker processes (`--workers`) or
as Ray tasks (`--engine ray`, `importers.ray_import`).

Each unit's read runs there: its scenes read, checked and their view overlap measured
(`common.read_checked`), most of an import's CPU time (a DL3DV scene: 300 frames, 1 s, most
of it the overlap). The writer takes the results in unit order, so the output is byte-identical to a
read in one process, and resumes through the same journal. At most `ahead` units are read or held
beyond the one the writer takes, so memory stays bounded.

A worker process hands a unit's images over in a file (`spill`), not through the pool's pipe: the
writer maps the file and copies each image once, into the output. The writer's one process bounds an
import on many cores; a DL3DV scene's 73 MB of frames cost it 0.24 s through the pipe, 0.12 s this
way (32 scenes, 8 workers on 16 cores: 6.9 -> 4.7 s, `benchmarks/ab.py dl3dv`).
"""

from __future__ import annotations

import mmap
import os
import shutil
import tempfile
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

from seeu_data.store.posed import PosedScene

SPILL_DIR = ".import-spill"  # in the output folder while worker processes read; removed at the end


def in_order(
    reads: Sequence[Callable[[], list]],
    submit: Callable[[Callable[[], list]], Any],
    result: Callable[[Any], list],
    ahead: int,
    cancel: Callable[[Any], None] | None = None,
) -> Iterator[list]:
    """`result(submit(read))` of every read, yielded in order, at most `ahead` submitted beyond the one
    yielded; on the way out (an error, the consumer gone) `cancel` each handle still pending."""
    todo, pending = iter(reads), deque[Any]()

    def more() -> None:
        read = next(todo, None)
        if read is not None:
            pending.append(submit(read))

    for _ in range(max(1, ahead)):
        more()
    try:
        while pending:
            done = result(pending.popleft())
            more()
            yield done
    finally:
        if cancel is not None:
            for handle in pending:
                cancel(handle)


def run_unit(read: Callable[[], list]) -> list:
    return read()


def spill(items: list, folder: Path) -> tuple[str | None, list, list[list[int]]]:
    """In a worker: the images of `items`' scenes written, one after another, to a new file in `folder`;
    returns (its path, the items with no images, each scene's image sizes). `unspill` undoes it."""
    scenes = [item for item in items if isinstance(item, PosedScene)]
    if not scenes:
        return None, items, []
    fd, path = tempfile.mkstemp(dir=folder, suffix=".bin")
    sizes = []
    with os.fdopen(fd, "wb") as fh:
        for scene in scenes:
            sizes.append([fh.write(image) for image in scene.images])  # type: ignore[arg-type]  # numpy stubs: no buffer protocol
            scene.images = []
    return path, items, sizes


def unspill(path: str | None, items: list, sizes: list[list[int]]) -> list:
    """In the writer: `items` with their images again, as views into the mapped file (removed at once;
    the map lives as long as the views)."""
    if path is None:
        return items
    with open(path, "rb") as fh:
        os.unlink(path)
        view = memoryview(mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)) if sum(map(sum, sizes)) else b""
    scenes = iter(item for item in items if isinstance(item, PosedScene))
    start = 0
    for scene, scene_sizes in zip(scenes, sizes):
        scene.images = []
        for size in scene_sizes:
            scene.images.append(view[start : start + size])
            start += size
    return items


def read_spilled(read: Callable[[], list], folder: Path) -> tuple[str | None, list, list[list[int]]]:
    return spill(read(), folder)


def read_in_processes(reads: Sequence[Callable[[], list]], workers: int, where: str | Path) -> Iterator[list]:
    """`in_order` over `workers` forked processes (`process_pool.ForkedPool`: a worker killed is one
    line), the images handed over in files (`spill`) in `where`/SPILL_DIR."""
    from seeu_data.process_pool import ForkedPool

    folder = Path(where) / SPILL_DIR
    shutil.rmtree(folder, ignore_errors=True)  # left by a run that was killed
    folder.mkdir(parents=True)
    try:
        with ForkedPool(workers, "import", where, kept="finished files are kept") as pool:
            yield from in_order(
                reads,
                lambda read: pool.submit(read_spilled, read, folder),
                lambda future: unspill(*future.result()),
                2 * workers,
            )
    finally:
        shutil.rmtree(folder, ignore_errors=True)
