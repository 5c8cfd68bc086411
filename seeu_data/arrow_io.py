"""File IO: Arrow IPC files (uncompressed) and other outputs written to a temporary name and renamed
when complete; JSON inputs read with a one-line error.

Durability: every write is atomic (temporary name, rename when complete, manifests written last with
bytes + sha256 per file), so a crash, Ctrl-C or kill never leaves a half-written file under its final
name. fsync is a parameter of every writer here (`fsync=True`: the file is fsynced before its rename);
the commands' `--fsync` flag reaches it through their configs. Without it data reaches the page cache
and a file torn by a power loss is caught by its manifest sha256 (`read_manifest(verify=True)`,
`seeu validate`, the size/sha256 checks before a resume keeps a file).

IPC files are written by pyarrow's own writer into a sink that hashes (sha256) every buffer it writes,
so the manifest's (bytes, sha256) come in the same pass, without reading the file back. The hash runs
on a thread of the sink's own, fed the written buffers in order (`_Sha256Thread`).
"""

from __future__ import annotations

import bisect
import hashlib
import json
import mmap
import os
import queue
import threading
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator, Sequence

import numpy as np
import pyarrow as pa

from .errors import SeeUError

# An encoded value (image) as the writers take it: bytes, or a view (a memoryview, a numpy uint8 view
# into a memory-mapped input) that must not change until it is written.
BytesLike = bytes | bytearray | memoryview | np.ndarray

# No compression: encoded images don't compress and compression makes random reads 10-100x slower.
_WRITE_OPTIONS = pa.ipc.IpcWriteOptions(compression=None)
_HASH_SLICE = 8 << 20  # bytes written (and handed to the hash thread) at a time


def tmp_path_for(path: Path) -> Path:
    return path.with_name(f".{path.name}.{os.getpid()}.tmp")


def _fsync_file(path: Path) -> None:
    with open(path, "rb") as fh:
        os.fsync(fh.fileno())


@contextmanager
def naming_os_errors(path: str | Path) -> Iterator[None]:
    """Within the block, an OSError that names no file (a failed `write`: ENOSPC, EIO, ...) is
    re-raised naming `path`, so the one-line error says which file could not be written."""
    try:
        yield
    except OSError as exc:
        if exc.filename is None and exc.errno is not None:
            raise OSError(exc.errno, exc.strerror or os.strerror(exc.errno), str(path)) from exc
        raise


@contextmanager
def atomic_path(path: str | Path, fsync: bool = False) -> Iterator[Path]:
    """A temporary name beside `path` for a writer that takes a file name (torch.save, ...).

    When the block succeeds the file is renamed to `path` (fsynced first when `fsync`); when it
    raises, it is removed.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = tmp_path_for(path)
    try:
        with naming_os_errors(path):
            yield tmp
            if fsync:
                _fsync_file(tmp)
            os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def atomic_write_bytes(path: str | Path, data: bytes, fsync: bool = False) -> None:
    with atomic_path(path, fsync) as tmp:
        tmp.write_bytes(data)


def atomic_write_text(path: str | Path, text: str, fsync: bool = False) -> None:
    atomic_write_bytes(path, text.encode("utf-8"), fsync)


def _byte_view(value: BytesLike) -> memoryview:
    """A flat view of `value`'s bytes (no copy)."""
    return memoryview(value).cast("B")  # type: ignore[arg-type]  # numpy's stubs lack the buffer protocol


def _offsets(views: list[memoryview]) -> np.ndarray:
    """Offsets (int64, len(views) + 1) of `views` laid end to end; SeeUError past a binary column's 2 GB."""
    offsets = np.zeros(len(views) + 1, dtype=np.int64)
    np.cumsum([v.nbytes for v in views], out=offsets[1:])
    if offsets[-1] >= 2**31:
        raise SeeUError(
            f"{offsets[-1] / 1e9:.1f} GB of values in one binary column, over the 2 GB its 32-bit offsets allow"
        )
    return offsets


def binary_array(values: Sequence[BytesLike]) -> pa.BinaryArray:
    """A binary array of bytes-like `values` (bytes, memoryviews, numpy uint8 views), copied once into one buffer."""
    views = [_byte_view(v) for v in values]
    offsets = _offsets(views)
    data = pa.py_buffer(b"".join(views))
    return pa.BinaryArray.from_buffers(pa.binary(), len(views), [None, pa.py_buffer(offsets.astype(np.int32)), data])


class _Views:
    """Encoded values (bytes-like views) that a binary column stands for, without their bytes being
    copied: `column` is a binary array over anonymous memory that is never touched (it reads as zeros
    and costs no memory); when pyarrow's writer hands the sink that column's data buffer, or a slice of
    it, the sink writes the views instead (`pieces`)."""

    def __init__(self, views: Sequence[BytesLike]):
        self.views = [_byte_view(v) for v in views]
        starts = _offsets(self.views)
        self.total = int(starts[-1])
        self.starts = starts.tolist()
        private = {"flags": mmap.MAP_PRIVATE, "prot": mmap.PROT_READ} if hasattr(mmap, "MAP_PRIVATE") else {}
        self._memory = mmap.mmap(-1, max(self.total, 1), **private)
        data = pa.py_buffer(self._memory)[: self.total]
        self.base = data.address
        self.column = pa.BinaryArray.from_buffers(
            pa.binary(), len(self.views), [None, pa.py_buffer(starts.astype(np.int32)), data]
        )
        self.covered = 0  # the sink has written the column's bytes [0, covered) from the views, in order

    def pieces(self, buffer: pa.Buffer) -> list[memoryview] | None:
        """The views (cut at the ends) that `buffer` stands for; None when it is not (a slice of) the column's data."""
        start = buffer.address - self.base
        end = start + buffer.size
        if not (0 <= start and end <= self.total and buffer.size):
            return None
        if start <= self.covered:  # pyarrow pads a batch's slice with the bytes after it, when there are any
            self.covered = max(self.covered, end)
        out = []
        i = bisect.bisect_right(self.starts, start) - 1
        while start < end:
            view, lo = self.views[i], self.starts[i]
            a, b = start - lo, min(end - lo, view.nbytes)
            if b > a:
                out.append(view[a:b])
            start = lo + b
            i += 1
        return out


class _Sha256Thread:
    """sha256 of the buffers given to `add`, in order, computed on a thread of its own.

    Why a thread: hashing as fast as the writes go (~1.3 GB/s here) on the writer's thread made a quiet
    2-core machine's `seeu build` 0.51 s instead of 0.35 s (1.49x; benchmarks/RESULTS.md); hashlib
    releases the GIL while it hashes, so the second core takes it. The sink adds memoryviews of what it
    writes (each keeps its bytes alive) and waits (`wait`) before each write call returns, so a view of
    the caller's memory is never read after the call and memory stays bounded by one call's data.
    """

    def __init__(self) -> None:
        self._sha256 = hashlib.sha256()
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._run, name="seeu-sha256", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while (item := self._queue.get()) is not None:
            if isinstance(item, threading.Event):
                item.set()
            else:
                self._sha256.update(item)

    def add(self, data) -> None:
        self._queue.put(data)

    def wait(self) -> None:
        """Return once every buffer added so far is hashed."""
        if self._thread.is_alive():
            done = threading.Event()
            self._queue.put(done)
            done.wait()

    def stop(self) -> None:
        if self._thread.is_alive():
            self._queue.put(None)
            self._thread.join()

    def hexdigest(self) -> str:
        self.stop()
        return self._sha256.hexdigest()


class _HashingSink:
    """Raw write-only file object (for `pa.PythonFile`) that writes to `path` and hashes (sha256)
    every byte it writes; with `views` set, the column those stand for is written from them."""

    def __init__(self, path: Path):
        self._fh = open(path, "wb")  # buffered: pyarrow's many small metadata writes go out together
        self._sha256 = _Sha256Thread()
        self.size = 0
        self.closed = False
        self.views: _Views | None = None

    def _write(self, view: memoryview) -> None:
        """The one place where bytes reach the file: in slices of at most _HASH_SLICE bytes, each hashed
        (on the hash thread) while the next is written."""
        for start in range(0, view.nbytes, _HASH_SLICE):
            piece = view[start : start + _HASH_SLICE]
            self._fh.write(piece)
            self._sha256.add(piece)
        self.size += view.nbytes

    def write(self, data) -> int:
        if self.views is not None and isinstance(data, pa.Buffer):
            pieces = self.views.pieces(data)
            if pieces is not None:
                for piece in pieces:
                    self._write(piece)
                return data.size
        view = memoryview(data).cast("B")
        self._write(view)
        return view.nbytes

    def wait_hashed(self) -> None:
        self._sha256.wait()

    def hexdigest(self) -> str:
        return self._sha256.hexdigest()

    def tell(self) -> int:
        return self.size

    def flush(self) -> None:
        self._fh.flush()

    def writable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return False

    def fsync(self) -> None:
        self._fh.flush()
        os.fsync(self._fh.fileno())

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self._sha256.stop()
            self._fh.close()


class AtomicIpcWriter:
    """An Arrow IPC *file* writer (pyarrow's, uncompressed) on a temporary name, hashing as it writes.

    `write(table or batch)` as pyarrow's writer; `close()` finishes the file, fsyncs it when `fsync`,
    renames it to `path` and returns `(bytes, sha256)` (also kept as `.size` / `.sha256`). `abort()`
    removes the partial file. As a context manager: the file is closed when the block succeeds and
    removed when it raises.
    """

    def __init__(self, path: str | Path, schema: pa.Schema, fsync: bool = False):
        self.path = Path(path)
        self.fsync = fsync
        self.tmp = tmp_path_for(self.path)
        self.size = 0
        self.sha256: str | None = None
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with naming_os_errors(self.path):
            self._raw = _HashingSink(self.tmp)
        try:
            with naming_os_errors(self.path):
                self._sink = pa.PythonFile(self._raw, mode="w")
                self._writer = pa.ipc.new_file(self._sink, schema, options=_WRITE_OPTIONS)
        except BaseException:
            self.abort()
            raise

    def write(self, data: pa.Table | pa.RecordBatch, max_chunksize: int | None = None) -> None:
        """Append a table (cut into record batches of at most `max_chunksize` rows) or one record batch."""
        try:
            with naming_os_errors(self.path):
                if isinstance(data, pa.Table):
                    self._writer.write_table(data, max_chunksize=max_chunksize)
                else:
                    self._writer.write_batch(data)
        finally:
            self._raw.wait_hashed()  # nothing of `data` is read after this returns

    def write_with_views(
        self,
        views: Sequence[BytesLike],
        make: Callable[[pa.BinaryArray], pa.Table | pa.RecordBatch],
        max_chunksize: int | None = None,
    ) -> None:
        """`write(make(column))`, where `column` is a binary array of the bytes-like `views` (bytes,
        memoryviews, numpy uint8 views into a memory-mapped input) whose bytes are not copied in
        memory: the sink writes each view into the file where pyarrow writes the column's data.

        `column` only stands for the views (its own memory reads as zeros): use it only to build the
        table or batch that `make` returns, which must hold every value of it, and keep no reference
        to either.
        """
        # The one trick kept in this writer (benchmarks/RESULTS.md, plain I/O): copying the images into
        # the shard's column first made `seeu build` 1.36x slower (1.25x copying per batch), 1.39x
        # slower than the code before the plain I/O; from their views they are copied once, by write.
        stand_in = _Views(views)
        self._raw.views = stand_in
        try:
            self.write(make(stand_in.column), max_chunksize)
        finally:
            self._raw.views = None
        if stand_in.covered != stand_in.total:  # never a file with the stand-in's zeros in it
            raise SeeUError(
                f"pyarrow {pa.__version__} did not hand the sink the column's data as it is (bytes 0..{stand_in.covered} "
                f"of {stand_in.total} seen); this writer cannot write it without a copy",
                self.path,
            )

    def close(self) -> tuple[int, str]:
        """Finish the file and put it in place; return (bytes, sha256)."""
        try:
            with naming_os_errors(self.path):
                self._writer.close()
                if self.fsync:
                    self._raw.fsync()
                self._sink.close()  # closes self._raw too (pa.PythonFile closes its file object)
                os.replace(self.tmp, self.path)
        except BaseException:
            self.abort()
            raise
        self.size, self.sha256 = self._raw.size, self._raw.hexdigest()
        return self.size, self.sha256

    def abort(self) -> None:
        """Abandon the unfinished file: close it and remove it."""
        try:
            self._raw.close()
        except OSError:
            pass  # the buffered tail could not be written either: the file goes anyway
        finally:
            self.tmp.unlink(missing_ok=True)

    def __enter__(self) -> "AtomicIpcWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


def write_table(
    path: str | Path, table: pa.Table, max_chunksize: int | None = None, fsync: bool = False
) -> tuple[int, str]:
    """Write a whole table atomically as an Arrow IPC file; return (bytes, sha256) of the file."""
    with AtomicIpcWriter(path, table.schema, fsync=fsync) as writer:
        writer.write(table, max_chunksize=max_chunksize)
    assert writer.sha256 is not None
    return writer.size, writer.sha256


def open_ipc_file(path: str | Path, memory_map: bool = True) -> pa.ipc.RecordBatchFileReader:
    """Open an Arrow IPC file for random access (memory-mapped by default)."""
    path = Path(path)
    if not path.exists():
        raise SeeUError("file not found", path)
    try:
        source = pa.memory_map(str(path), "r") if memory_map else pa.OSFile(str(path), "rb")
        reader = pa.ipc.open_file(source)
        _ = reader.schema.names  # every name decodes (a flipped byte there is a UnicodeDecodeError later)
        return reader
    except (pa.ArrowInvalid, OSError, UnicodeDecodeError) as exc:
        raise SeeUError(f"not a readable Arrow IPC file (truncated or corrupt?): {exc}".splitlines()[0], path) from None


def read_table(path: str | Path, memory_map: bool = True) -> pa.Table:
    return open_ipc_file(path, memory_map).read_all()


def sha256_file(path: str | Path, chunk: int = 1 << 22) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        while block := fh.read(chunk):
            digest.update(block)
    return digest.hexdigest()


def read_json(path: str | Path, what: str = ""):
    """Parse a JSON file; SeeUError naming the file (and `what` it is) when it is not valid JSON."""
    path = Path(path)
    try:
        return json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise SeeUError(f"{what} is not valid JSON ({exc})" if what else f"not valid JSON ({exc})", path) from None
