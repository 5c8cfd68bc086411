"""A posed-frames writer that hashes while it writes, and a bounded background prefetcher.

`HashingPosedWriter` is `PosedDatasetWriter` (same files, same atomic rename, same manifest) except
that each file's sha256 is computed from the bytes as they are written, instead of by reading the
finished file back. hashlib and file writes release the GIL, so together with `prefetch` (chunk
reading and conversion in a background thread) the hashing overlaps with reading the next chunk:
this is what keeps `seeu import pixelsplat` at the speed of `torch.load` on a 2-core machine.
"""

from __future__ import annotations

import hashlib
import os
import queue
import threading
from pathlib import Path
from typing import Iterable, Iterator, TypeVar

import pyarrow as pa

from ..arrow_io import tmp_path_for
from ..manifest import FileEntry
from ..posed import SCHEMA, PosedDatasetWriter
from ..schema import arrow_schema

T = TypeVar("T")
_WRITE_OPTIONS = pa.ipc.IpcWriteOptions(compression=None)


_BIG_WRITE = 1 << 20


class _HashingFile:
    """Raw file object that feeds every written buffer to a sha256 (used through pa.PythonFile).

    A large buffer is hashed in a helper thread while the main thread writes it (both release the
    GIL). The call returns only when both are done: the buffer's memory is only guaranteed alive
    during the call. (Starting write-back early with sync_file_range was measured and made the
    import slower: it moves the kernel's write-back work into this thread.)
    """

    def __init__(self, path: Path):
        from concurrent.futures import ThreadPoolExecutor

        self._fh = open(path, "wb", buffering=0)
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="seeu-sha256")
        self.sha256 = hashlib.sha256()
        self.size = 0
        self.closed = False

    def write(self, data) -> int:
        view = memoryview(data).cast("B")
        hashing = self._pool.submit(self.sha256.update, view) if view.nbytes >= _BIG_WRITE else None
        if hashing is None:
            self.sha256.update(view)
        written = 0
        try:
            while written < view.nbytes:
                written += self._fh.write(view[written:])
        finally:
            if hashing is not None:
                hashing.result()
        self.size += view.nbytes
        return written

    def flush(self) -> None:
        pass

    def tell(self) -> int:
        return self.size

    def writable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return False

    def close(self) -> None:
        if not self.closed:
            try:
                os.fsync(self._fh.fileno())
            finally:
                self._fh.close()
                self._pool.shutdown(wait=True)
                self.closed = True


class HashingPosedWriter(PosedDatasetWriter):
    """PosedDatasetWriter whose per-file sha256 is computed during the write (see module doc)."""

    def _open(self) -> None:
        self._path = self.out_dir / f"{self.prefix}-{len(self.files):05d}.arrow"
        self._tmp = tmp_path_for(self._path)
        self._raw = _HashingFile(self._tmp)
        self._sink = pa.PythonFile(self._raw, mode="w")
        self._writer = pa.ipc.new_file(self._sink, arrow_schema(SCHEMA), options=_WRITE_OPTIONS)
        self._ctx = self  # non-None marks an open file for the base class
        self._rows = 0
        self._bytes = 0

    def _finish_file(self) -> None:
        if self._ctx is None:
            return
        self._writer.close()
        self._sink.close()
        self._raw.close()
        os.replace(self._tmp, self._path)
        assert self._path is not None
        self.files.append(FileEntry(str(self._path.relative_to(self.out_dir)), int(self._rows),
                                    self._path.stat().st_size, self._raw.sha256.hexdigest()))
        self._ctx = self._writer = None

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        elif self._ctx is not None:  # abandon the unfinished file
            try:
                self._raw.close()
            finally:
                self._tmp.unlink(missing_ok=True)
                self._ctx = self._writer = None


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
