"""A bounded background prefetcher for the importers.

`prefetch` runs an importer (reading image files or chunks, header checks, conversion) in a
background thread a few scenes ahead of the writer; file reads, hashlib and file writes release the
GIL, so reading the next scene overlaps writing and hashing this one.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Generator, Iterable
from typing import TypeVar

T = TypeVar("T")

_DONE = object()


def prefetch(items: Iterable[T], max_items: int = 2) -> Generator[T, None, None]:
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
