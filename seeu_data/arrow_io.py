"""File IO: Arrow IPC files (uncompressed) and other outputs written to a temporary name, fsynced and
renamed when complete; JSON inputs read with a one-line error.

Every IPC file written here is hashed while it is written: `AtomicIpcWriter` feeds the bytes it
writes to a sha256 (large buffers on a helper thread, overlapping the write; hashlib and file writes
both release the GIL), so the manifest's (bytes, sha256) come without reading the file back.
"""

from __future__ import annotations

import hashlib
import json
import os
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

import pyarrow as pa

from .errors import SeeUError

# No compression: encoded images don't compress and compression makes random reads 10-100x slower.
_WRITE_OPTIONS = pa.ipc.IpcWriteOptions(compression=None)
_BIG_WRITE = 1 << 20  # buffers at least this large are hashed on the helper thread


def tmp_path_for(path: Path) -> Path:
    return path.with_name(f".{path.name}.{os.getpid()}.tmp")


def pending_path(path: Path) -> Path:
    """Where a file written with `commit=False` waits, complete but not yet durable, until `commit_pending`."""
    return path.with_name(f".{path.name}.pending")


def _fsync_replace(src: Path, dst: Path) -> None:
    """Make the written file `src` durable, then rename it to `dst` (the atomic step)."""
    with open(src, "rb") as fh:
        os.fsync(fh.fileno())
    os.replace(src, dst)


def commit_pending(path: Path) -> None:
    """fsync the pending file of `path` and rename it into place."""
    _fsync_replace(pending_path(path), path)


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """A temporary name beside `path` for a writer that takes a file name (torch.save, ...).

    When the block succeeds the file is fsynced and renamed to `path`; when it raises, it is removed.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = tmp_path_for(path)
    try:
        yield tmp
        _fsync_replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


class _HashingFile:
    """Raw write-only file object that feeds every written buffer to a sha256 (used through pa.PythonFile).

    A large buffer is hashed in a helper thread while the main thread writes it. The call returns
    only when both are done: the buffer's memory is only guaranteed alive during the call. (Starting
    write-back early with sync_file_range was measured and made the import slower: it moves the
    kernel's write-back work into this thread.)
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

    def close(self, sync: bool = False) -> None:
        if not self.closed:
            try:
                if sync:
                    os.fsync(self._fh.fileno())
            finally:
                self._fh.close()
                self._pool.shutdown(wait=True)
                self.closed = True


class AtomicIpcWriter:
    """An Arrow IPC *file* writer (uncompressed) on a temporary name, hashing the bytes as it writes.

    `write_batch` / `write_table` as pyarrow's writer; `close()` finishes the file, fsyncs it,
    renames it to `path` and returns `(bytes, sha256)` (also kept as `.size` / `.sha256`). With
    `commit=False` the finished file is left at `pending_path(path)` and the caller calls
    `commit_pending(path)` later (`seeu build` does that on a background thread, so the disk flush
    overlaps building the next shard). `abort()` removes the partial file. As a context manager: the
    file is closed when the block succeeds and removed when it raises. The bytes equal those of any
    pyarrow IPC file writer with the same options.
    """

    def __init__(self, path: str | Path, schema: pa.Schema, commit: bool = True):
        self.path = Path(path)
        self.commit = commit
        self.tmp = tmp_path_for(self.path) if commit else pending_path(self.path)
        self.size = 0
        self.sha256: str | None = None
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._raw = _HashingFile(self.tmp)
        try:
            self._sink = pa.PythonFile(self._raw, mode="w")
            self._writer = pa.ipc.new_file(self._sink, schema, options=_WRITE_OPTIONS)
        except BaseException:
            self.abort()
            raise

    def write_batch(self, batch: pa.RecordBatch) -> None:
        self._writer.write_batch(batch)

    def write_table(self, table: pa.Table, max_chunksize: int | None = None) -> None:
        self._writer.write_table(table, max_chunksize=max_chunksize)

    def close(self) -> tuple[int, str]:
        """Finish the file and put it in place (or leave it pending); return (bytes, sha256)."""
        try:
            self._writer.close()
            self._sink.close()
            self._raw.close(sync=self.commit)
            if self.commit:
                os.replace(self.tmp, self.path)
        except BaseException:
            self.abort()
            raise
        self.size, self.sha256 = self._raw.size, self._raw.sha256.hexdigest()
        return self.size, self.sha256

    def abort(self) -> None:
        """Abandon the unfinished file: close it and remove it."""
        try:
            self._raw.close()
        finally:
            self.tmp.unlink(missing_ok=True)

    def __enter__(self) -> "AtomicIpcWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


atomic_ipc_writer = AtomicIpcWriter  # `with atomic_ipc_writer(path, schema) as w: w.write_table(...)`


def write_table(path: str | Path, table: pa.Table, max_chunksize: int | None = None,
                commit: bool = True) -> tuple[int, str]:
    """Write a whole table atomically as an Arrow IPC file; return (bytes, sha256) of the file."""
    with AtomicIpcWriter(path, table.schema, commit=commit) as writer:
        writer.write_table(table, max_chunksize=max_chunksize)
    return writer.size, writer.sha256


def open_ipc_file(path: str | Path, memory_map: bool = True) -> pa.ipc.RecordBatchFileReader:
    """Open an Arrow IPC file for random access (memory-mapped by default)."""
    path = Path(path)
    if not path.exists():
        raise SeeUError("file not found", path)
    try:
        source = pa.memory_map(str(path), "r") if memory_map else pa.OSFile(str(path), "rb")
        return pa.ipc.open_file(source)
    except (pa.ArrowInvalid, OSError) as exc:
        raise SeeUError(f"not a readable Arrow IPC file (truncated or corrupt?): {exc}".splitlines()[0], path) from None


def read_table(path: str | Path, memory_map: bool = True) -> pa.Table:
    return open_ipc_file(path, memory_map).read_all()


def sha256_file(path: str | Path, chunk: int = 1 << 22) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        while block := fh.read(chunk):
            digest.update(block)
    return digest.hexdigest()


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def atomic_write_text(path: str | Path, text: str) -> None:
    atomic_write_bytes(path, text.encode("utf-8"))


def read_json(path: str | Path, what: str = ""):
    """Parse a JSON file; SeeUError naming the file (and `what` it is) when it is not valid JSON."""
    path = Path(path)
    try:
        return json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise SeeUError(f"{what} is not valid JSON ({exc})" if what else f"not valid JSON ({exc})", path) from None
