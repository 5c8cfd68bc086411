"""An import's units read ahead of its writer, in order: in local worker processes (`--workers`) or
as Ray tasks (`--engine ray`, `importers.ray_import`).

Each unit's read runs there: its scenes read, checked and their view overlap measured
(`common.read_checked`), most of an import's CPU time (a DL3DV scene: 300 frames, 2.3 s, nearly all
of it the overlap). The writer takes the results in unit order, so the output is byte-identical to a
read in one process, and resumes through the same journal. At most `ahead` units are read or held
beyond the one the writer takes, so memory stays bounded.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any


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


def read_in_processes(reads: Sequence[Callable[[], list]], workers: int, where: str | Path) -> Iterator[list]:
    """`in_order` over `workers` forked processes (`process_pool.ForkedPool`: a worker killed is one line)."""
    from seeu_data.process_pool import ForkedPool

    with ForkedPool(workers, "import", where, kept="finished files are kept") as pool:
        yield from in_order(reads, lambda read: pool.submit(run_unit, read), lambda f: f.result(), 2 * workers)
