"""File IO: Arrow IPC files (uncompressed) and other outputs written to a temporary name and renamed
when complete; JSON inputs read with a one-line error.

Durability: every write is atomic (temporary name, rename when complete, manifests written last with
bytes + sha256 per file), so a crash, Ctrl-C or kill never leaves a half-written file under its final
name. fsync is a parameter of every writer here (`fsync=True`: the file is fsynced before its rename);
the commands' `--fsync` flag reaches it through their configs. Without it data reaches the page cache
and a file torn by a power loss is caught by its manifest sha256 (`read_manifest(verify=True)`,
`seeu validate`, the size/sha256 checks before a resume keeps a file).

IPC files are written by pyarrow's own writer into a buffered sink; the manifest's sha256 of each file
is computed while it is written, on a thread of its own that trails the writes through the page cache
(`_TrailingSha256`), so the file is not read again from disk and the writer does not wait for it.
"""

from __future__ import annotations

import bisect
import hashlib
import io
import mmap
import os
import threading
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pyarrow as pa

from seeu_data.errors import SeeUError

# An encoded value (image) as the writers take it: bytes, or a view (a memoryview, a numpy uint8 view
# into a memory-mapped input) that must not change until it is written.
BytesLike = bytes | bytearray | memoryview | np.ndarray

# No compression: encoded images don't compress and compression makes random reads 10-100x slower.
_WRITE_OPTIONS = pa.ipc.IpcWriteOptions(compression=None)
_WRITE_BUFFER = 4 << 20  # bytes collected before a write reaches the file (fewer, larger page-cache writes)
_HASH_RANGE = 8 << 20  # bytes of a file hashed in one call (mapped from the page cache)


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


class _TrailingSha256:
    """sha256 of a file while it is being written, computed on a thread of its own from the file's
    pages: the writer reports how many bytes have reached the file (`advance`); the thread maps each
    whole `_HASH_RANGE` behind that from the page cache and hashes it in one call; `hexdigest()`
    waits for the rest. The thread reads the file through its own descriptor, never the writer's
    buffers, so the writer never waits for it and a finished file's hash can still be running while
    the next file is written.

    Why: a hash the writer waits for makes `seeu build` and `seeu import` 1.3-1.5x slower on 2 cores;
    hashlib releases the GIL, so a trailing thread's hash runs on the second core (benchmarks/RESULTS.md,
    Triple build).
    """

    def __init__(self, path: Path):
        self._fd = os.open(path, os.O_RDONLY)
        self._cond = threading.Condition()
        self._written = 0
        self._closed = False
        self._error: BaseException | None = None
        self._sha256 = hashlib.sha256()
        self._thread = threading.Thread(target=self._run, name="seeu-sha256", daemon=True)
        self._thread.start()

    def advance(self, written: int) -> None:
        """The file's first `written` bytes are written (they may be hashed)."""
        with self._cond:
            if written // _HASH_RANGE > self._written // _HASH_RANGE:  # a whole range more to hash
                self._cond.notify()
            self._written = written

    def _run(self) -> None:
        done = 0  # a multiple of _HASH_RANGE until the last range (offsets of mapped ranges stay aligned)
        try:
            while True:
                with self._cond:
                    while not self._closed and self._written - done < _HASH_RANGE:
                        self._cond.wait()
                    last = self._closed
                    end = self._written if last else done + (self._written - done) // _HASH_RANGE * _HASH_RANGE
                while done < end:
                    size = min(_HASH_RANGE, end - done)
                    with mmap.mmap(self._fd, size, access=mmap.ACCESS_READ, offset=done) as pages:
                        self._sha256.update(pages)
                    done += size
                if last:
                    return
        except BaseException as exc:  # raised again by hexdigest, on the writer's thread
            self._error = exc
        finally:
            os.close(self._fd)

    def stop(self) -> None:
        """No more bytes: hash what is left and end the thread."""
        with self._cond:
            self._closed = True
            self._cond.notify()
        self._thread.join()

    def hexdigest(self) -> str:
        self.stop()
        if self._error is not None:
            raise self._error
        return self._sha256.hexdigest()


class _HashingSink:
    """Raw write-only file object (for `pa.PythonFile`) that writes to `path` through a buffer of
    `_WRITE_BUFFER` bytes and hashes (sha256) the file as it grows (`_TrailingSha256`); with `views`
    set, the column those stand for is written from them."""

    def __init__(self, path: Path):
        self._fh = io.BufferedWriter(io.FileIO(path, "wb"), _WRITE_BUFFER)
        try:
            self.sha256 = _TrailingSha256(path)
        except BaseException:
            self._fh.close()
            raise
        self.size = 0
        self.closed = False
        self.views: _Views | None = None

    def _write(self, view: memoryview) -> None:
        """The one place where bytes reach the file."""
        self._fh.write(view)
        self.size += view.nbytes
        self.sha256.advance(self._fh.raw.tell())  # what left the buffer

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

    def tell(self) -> int:
        return self.size

    def flush(self) -> None:
        self._fh.flush()
        self.sha256.advance(self.size)

    def writable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return False

    def fsync(self) -> None:
        self.flush()
        os.fsync(self._fh.fileno())

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self._fh.close()
            self.sha256.advance(self.size)  # only once every byte is in the file: the hash maps no page past its end


class AtomicIpcWriter:
    """An Arrow IPC *file* writer (pyarrow's, uncompressed) on a temporary name, hashing as it writes.

    `write(table or batch)` as pyarrow's writer; `close()` finishes the file, fsyncs it when `fsync`,
    renames it to `path` and returns its size in bytes (also `.size`); `sha256()` returns its sha256,
    waiting for the hash, which trails the writes and may still be running after `close()`. `abort()`
    removes the partial file. As a context manager: the file is closed when the block succeeds and
    removed when it raises.
    """

    def __init__(self, path: str | Path, schema: pa.Schema, fsync: bool = False):
        self.path = Path(path)
        self.fsync = fsync
        self.tmp = tmp_path_for(self.path)
        self.size = 0
        self.path.parent.mkdir(parents=True, exist_ok=True)
        try:
            with naming_os_errors(self.path):
                self._raw = _HashingSink(self.tmp)
        except BaseException:
            self.tmp.unlink(missing_ok=True)  # created before its hash could start (EMFILE, ...)
            raise
        try:
            with naming_os_errors(self.path):
                self._sink = pa.PythonFile(self._raw, mode="w")
                self._writer = pa.ipc.new_file(self._sink, schema, options=_WRITE_OPTIONS)
        except BaseException:
            self.abort()
            raise

    def write(self, data: pa.Table | pa.RecordBatch, max_chunksize: int | None = None) -> None:
        """Append a table (cut into record batches of at most `max_chunksize` rows) or one record batch."""
        with naming_os_errors(self.path):
            if isinstance(data, pa.Table):
                self._writer.write_table(data, max_chunksize=max_chunksize)
            else:
                self._writer.write_batch(data)

    def write_with_views(
        self,
        views: Sequence[BytesLike],
        make: Callable[[pa.BinaryArray], pa.Table | pa.RecordBatch],
        max_chunksize: int | None = None,
    ) -> pa.Table | pa.RecordBatch:
        """`write(make(column))`, where `column` is a binary array of the bytes-like `views` (bytes,
        memoryviews, numpy uint8 views into a memory-mapped input) whose bytes are not copied into a
        new column: the sink writes each view into the file where pyarrow writes the column's data.
        Returns what `make` returned, for its `num_rows` and `nbytes`.

        `column` only stands for the views (its own memory reads as zeros): use it only to build the
        table or batch that `make` returns, which must hold every value of it, and read no value of
        either.
        """
        # Images go from their views through the write buffer, never copied into the column first: that
        # copy makes `seeu build` about 1.36x slower and `seeu import pixelsplat` 1.1-1.25x slower.
        stand_in = _Views(views)
        self._raw.views = stand_in
        try:
            made = make(stand_in.column)
            self.write(made, max_chunksize)
        finally:
            self._raw.views = None
        if stand_in.covered != stand_in.total:  # never a file with the stand-in's zeros in it
            raise SeeUError(
                f"pyarrow {pa.__version__} did not hand the sink the column's data as it is (bytes 0..{stand_in.covered} "
                f"of {stand_in.total} seen); this writer cannot write it without a copy",
                self.path,
            )
        return made

    def close(self) -> int:
        """Finish the file and put it in place; return its size in bytes."""
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
        self.size = self._raw.size
        return self.size

    def sha256(self) -> str:
        """The sha256 of the file `close()` put in place (waits for the hash to finish)."""
        with naming_os_errors(self.path):
            return self._raw.sha256.hexdigest()

    def abort(self) -> None:
        """Abandon the unfinished file: close it and remove it."""
        try:
            self._raw.close()
        except OSError:
            pass  # the buffered tail could not be written either: the file goes anyway
        finally:
            self._raw.sha256.stop()
            self.tmp.unlink(missing_ok=True)

    def __enter__(self) -> AtomicIpcWriter:
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
    return writer.size, writer.sha256()


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
