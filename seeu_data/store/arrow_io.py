"""File IO: Arrow IPC files (uncompressed) and other outputs written to a temporary name and renamed
when complete; JSON inputs read with a one-line error.

Durability: every write is atomic (temporary name, rename when complete, manifests written last with
bytes + sha256 per file), so a crash, Ctrl-C or kill never leaves a half-written file under its final
name. fsync is a parameter of every writer here (`fsync=True`: the file is fsynced before its rename);
the commands' `--fsync` flag reaches it through their configs. Without it data reaches the page cache
and a file torn by a power loss is caught by its manifest sha256 (`read_manifest(verify=True)`,
`seeu validate`, and `--verify` on the re-runs of import and build, which otherwise keep a file from
its recorded size, mtime and sha256).

IPC files are written by pyarrow's own writer into a plain file; the manifest's sha256 of each file is
that of the finished file (`hashlib.file_digest`, read back from the page cache) before its rename.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import BinaryIO

import numpy as np
import pyarrow as pa

from seeu_data.errors import SeeUError

# An encoded value (image) as `binary_array` takes it: bytes, or a view (a memoryview, a numpy uint8
# view into a memory-mapped input).
BytesLike = bytes | bytearray | memoryview | np.ndarray

# `binary_array`: bytes or values copied between two calls of `release` (small images: the kernel maps the
# 64 kB around each one read)
_RELEASE_BYTES, _RELEASE_VALUES = 64 << 20, 1024

# No compression: encoded images don't compress and compression makes random reads 10-100x slower.
_WRITE_OPTIONS = pa.ipc.IpcWriteOptions(compression=None)


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


def binary_array(values: Sequence[BytesLike], release: Callable[[], None] | None = None) -> pa.BinaryArray:
    """A binary array of bytes-like `values` (bytes, memoryviews, numpy uint8 views), copied once into one
    buffer from pyarrow's memory pool (memory it reuses: a new bytes object of a shard's size costs
    7x the copy in page faults); SeeUError past a binary column's 2 GB. `release` is called after every
    `_RELEASE_BYTES` or `_RELEASE_VALUES` copied (values that are views of `ReleasableIpcFile`s: their pages given back)."""
    views = [memoryview(v).cast("B") for v in values]  # type: ignore[arg-type]  # numpy's stubs lack the buffer protocol
    offsets = np.zeros(len(views) + 1, dtype=np.int64)
    np.cumsum([v.nbytes for v in views], out=offsets[1:])
    if offsets[-1] >= 2**31:
        raise SeeUError(
            f"{offsets[-1] / 1e9:.1f} GB of values in one binary column, over the 2 GB its 32-bit offsets allow"
        )
    data = pa.allocate_buffer(int(offsets[-1]))
    out = np.frombuffer(data, dtype=np.uint8)
    released = 0
    for i, (view, start, end) in enumerate(zip(views, offsets[:-1].tolist(), offsets[1:].tolist())):
        out[start:end] = view
        if release is not None and (end - released >= _RELEASE_BYTES or i % _RELEASE_VALUES == _RELEASE_VALUES - 1):
            release()
            released = end
    return pa.BinaryArray.from_buffers(pa.binary(), len(views), [None, pa.py_buffer(offsets.astype(np.int32)), data])


class AtomicIpcWriter:
    """An Arrow IPC *file* writer (pyarrow's, uncompressed) into a plain file on a temporary name.

    `write(table or batch)` as pyarrow's writer; `close()` finishes the file, fsyncs it when `fsync`,
    hashes it (`sha256_file`), renames it to `path` and returns its size in bytes (also `.size`; its
    sha256 is `.sha256`). `abort()` removes the partial file. As a context manager: the file is closed
    when the block succeeds and removed when it raises.
    """

    def __init__(self, path: str | Path, schema: pa.Schema, fsync: bool = False):
        self.path = Path(path)
        self.fsync = fsync
        self.tmp = tmp_path_for(self.path)
        self.size = 0
        self.sha256 = ""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file: BinaryIO | None = None
        try:
            with naming_os_errors(self.path):
                self._file = open(self.tmp, "wb")
                self._writer = pa.ipc.new_file(self._file, schema, options=_WRITE_OPTIONS)
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

    def close(self) -> int:
        """Finish the file and put it in place; return its size in bytes."""
        assert self._file is not None
        try:
            with naming_os_errors(self.path):
                self._writer.close()
                self._file.flush()
                if self.fsync:
                    os.fsync(self._file.fileno())
                self._file.close()
                self.size = self.tmp.stat().st_size
                self.sha256 = sha256_file(self.tmp)
                os.replace(self.tmp, self.path)
        except BaseException:
            self.abort()
            raise
        return self.size

    def abort(self) -> None:
        """Abandon the unfinished file: close it and remove it."""
        try:
            if self._file is not None:
                self._file.close()
        except OSError:
            pass  # the buffered tail could not be written either: the file goes anyway
        finally:
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
    return writer.size, writer.sha256


def open_ipc_file(
    path: str | Path, memory_map: bool = True, random_access: bool = False
) -> pa.ipc.RecordBatchFileReader:
    """Open an Arrow IPC file for random access (memory-mapped by default).

    `random_access`: mapped with the kernel's read-ahead off (`MADV_RANDOM`), for checks that read a
    few bytes here and there (image headers): each byte touched reads its page, not the read-ahead
    window around it (which would read most of a file of 50 kB images).
    """
    if random_access:
        return ReleasableIpcFile(path, random_access=True).reader
    return _open_ipc(path, lambda p: pa.memory_map(p, "r") if memory_map else pa.OSFile(p, "rb"))


class ReleasableIpcFile:
    """An IPC file read through a read-only memory map whose resident pages can be given back.

    A pass over a file of small record batches makes nearly all of it resident: on each page touched
    the kernel also maps the cached pages around it (fault-around, 64 kB), whatever the advice. So a
    reader that goes over a data set a scene at a time calls `release()` (MADV_DONTNEED) between
    scenes: its resident size stays about one scene. A buffer still held after a release reads its
    pages again from the page cache, unchanged (the map is shared and read-only). `random_access`: no
    read-ahead, for checks that read a few bytes here and there (`open_ipc_file`).
    """

    def __init__(self, path: str | Path, random_access: bool = False):
        import mmap

        self._mmap = mmap

        def source(p: str) -> pa.BufferReader:
            with open(p, "rb") as fh:
                self._map = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)  # ValueError on an empty file
            if random_access and hasattr(mmap, "MADV_RANDOM"):
                self._map.madvise(mmap.MADV_RANDOM)  # as `open_ipc_file(random_access=True)`
            return pa.BufferReader(pa.py_buffer(self._map))

        self.reader = _open_ipc(path, source)
        self.address = pa.py_buffer(self._map).address
        """The address of the map's first byte: a buffer of the reader starts at file position
        `buffer.address - address` (`loader/shard_reader.py` reads image bytes there with `os.pread`)."""

    def release(self) -> None:
        """Give back the resident pages of the map (nothing else changes)."""
        self._map.madvise(self._mmap.MADV_DONTNEED)

    def batches(self, release_every: int = 256) -> Iterator[pa.RecordBatch]:
        """The record batches in order, their buffers in place; the pages touched meanwhile (reading
        their metadata, and what the caller reads of them) are given back every `release_every` batches."""
        for i in range(self.reader.num_record_batches):
            yield self.reader.get_batch(i)
            if i % release_every == release_every - 1:
                self.release()
        self.release()

    def table(self) -> pa.Table:
        """The whole file as a table, its buffers in place (`batches`: nothing left resident)."""
        return pa.Table.from_batches(list(self.batches()), schema=self.reader.schema)


def _open_ipc(path: str | Path, source) -> pa.ipc.RecordBatchFileReader:
    path = Path(path)
    if not path.exists():
        raise SeeUError("file not found", path)
    try:
        reader = pa.ipc.open_file(source(str(path)))
        _ = reader.schema.names  # every name decodes (a flipped byte there is a UnicodeDecodeError later)
        return reader
    except (pa.ArrowInvalid, OSError, UnicodeDecodeError, ValueError) as exc:
        raise SeeUError(f"not a readable Arrow IPC file (truncated or corrupt?): {exc}".splitlines()[0], path) from None


def read_table(path: str | Path, memory_map: bool = True) -> pa.Table:
    return open_ipc_file(path, memory_map).read_all()


def sha256_file(path: str | Path) -> str:
    with open(path, "rb") as fh:
        return hashlib.file_digest(fh, "sha256").hexdigest()
