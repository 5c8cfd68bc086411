"""A bounded background prefetcher for the importers.

`prefetch` runs an importer (chunk reading and conversion) in a background thread a few scenes
ahead of the writer; the posed-frames writer hashes the bytes as it writes them
(`seeu_data.arrow_io.AtomicIpcWriter`), and hashlib and file writes release the GIL, so hashing
and writing overlap with reading the next chunk: this is what keeps `seeu import pixelsplat` at the
speed of `torch.load` on a 2-core machine.
"""

from __future__ import annotations

import queue
import threading
from typing import Iterable, Iterator, TypeVar

T = TypeVar("T")

_DONE = object()


def prefetch(items: Iterable[T], max_items: int = 2) -> Iterator[T]:
    """Iterate `items` in a background thread, at most `max_items` ahead (bounded memory).

    Exceptions raised by the producer are re-raised in the consumer; closing the returned
    generator stops the producer.
    """
    q: queue.Queue = queue.Queue(maxsize=max_items)
    stop = threading.Event()

    def produce() -> None:
        try:
            for item in items:
                while not stop.is_set():
                    try:
                        q.put(item, timeout=0.1)
                        break
                    except queue.Full:
                        continue
                if stop.is_set():
                    return
            q.put(_DONE)
        except BaseException as exc:  # handed to the consumer
            q.put(exc)

    thread = threading.Thread(target=produce, name="seeu-import-prefetch", daemon=True)
    thread.start()
    try:
        while True:
            item = q.get()
            if item is _DONE:
                return
            if isinstance(item, BaseException):
                raise item
            yield item
    finally:
        stop.set()
        while thread.is_alive():
            try:
                q.get_nowait()
            except queue.Empty:
                thread.join(0.05)
