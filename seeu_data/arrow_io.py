"""File IO: Arrow IPC files (uncompressed) and other outputs written to a temporary name and renamed
when complete; JSON inputs read with a one-line error.

Durability policy (decided here, in one place): every write is atomic (temporary name, rename when
complete, manifests written last with bytes + sha256 per file), so a crash, Ctrl-C or kill never
leaves a half-written file under its final name. fsync is opt-in: with it off (the default) data
reaches the page cache and a file torn by a power loss is caught by its manifest sha256
(`read_manifest(verify=True)`, `seeu validate`, the size/sha256 checks before a resume keeps a file);
with it on (`set_fsync(True)`, set by the `--fsync` flag of `seeu import/build/ingest`, or the
environment variable `SEEU_FSYNC=1`) every file is fsynced before its rename.

Every IPC file written here is hashed while it is written: `AtomicIpcWriter` hands each 8 MB the
file grows by to a sha256 on a helper thread, which maps that range of the file (the page-cache
pages just written) and hashes it in one call, overlapping the writes (hashlib and file writes both
release the GIL), so the manifest's (bytes, sha256) come without a second pass over the file.

Encoded images are written without being copied into Arrow buffers first: `deferred_binary(pieces)`
makes a binary column whose data buffer is a placeholder (untouched anonymous memory) standing for
the concatenation of `pieces` (bytes, or read-only views into memory-mapped input files). When
pyarrow's IPC writer hands that buffer, or a slice of it, to `AtomicIpcWriter`'s sink, the sink
writes the pieces themselves (`os.writev`, one system call for up to 1024 images).
The file's bytes are exactly those pyarrow writes for the same column with its data copied into
one buffer (tested), in one copy of the image bytes instead of two.
"""

from __future__ import annotations

import bisect
import hashlib
import json
import mmap
import os
import threading
import weakref
from concurrent.futures import Future
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator, Sequence

import numpy as np

import pyarrow as pa

from .errors import SeeUError

# No compression: encoded images don't compress and compression makes random reads 10-100x slower.
_WRITE_OPTIONS = pa.ipc.IpcWriteOptions(compression=None)
_BIG_WRITE = 1 << 20  # smaller writes are staged and written together
_HASH_BLOCK = 8 << 20  # the hasher takes the written bytes in ranges of about this size


_FSYNC = os.environ.get("SEEU_FSYNC", "").strip().lower() in ("1", "true", "yes", "on")


def set_fsync(enabled: bool) -> None:
    """Turn fsync-before-rename on or off for every write of this process (and of workers forked later)."""
    global _FSYNC
    _FSYNC = bool(enabled)


@contextmanager
def fsync_policy(enabled: bool | None) -> Iterator[None]:
    """Within the block, fsync on/off as `enabled` (None: unchanged); the previous policy is restored after.

    What the `--fsync` flags use: `with fsync_policy(True if args.fsync else None): ...`. The
    environment variable is set too, so worker processes started in the block (spawned or forked)
    follow the same policy.
    """
    previous, previous_env = _FSYNC, os.environ.get("SEEU_FSYNC")
    if enabled is not None:
        set_fsync(enabled)
        os.environ["SEEU_FSYNC"] = "1" if enabled else "0"
    try:
        yield
    finally:
        set_fsync(previous)
        if previous_env is None:
            os.environ.pop("SEEU_FSYNC", None)
        else:
            os.environ["SEEU_FSYNC"] = previous_env


def fsync_enabled() -> bool:
    """Whether files are fsynced before their rename (`--fsync` / `SEEU_FSYNC=1`; default off)."""
    return _FSYNC


def tmp_path_for(path: Path) -> Path:
    return path.with_name(f".{path.name}.{os.getpid()}.tmp")


def pending_path(path: Path) -> Path:
    """Where a file written with `commit=False` waits, complete but not yet in place, until `commit_pending`."""
    return path.with_name(f".{path.name}.pending")


def _fsync_replace(src: Path, dst: Path) -> None:
    """Make the written file `src` durable when the fsync policy is on, then rename it to `dst` (the atomic step)."""
    if _FSYNC:
        with open(src, "rb") as fh:
            os.fsync(fh.fileno())
    os.replace(src, dst)


def commit_pending(path: Path) -> None:
    """Rename the pending file of `path` into place (fsynced first when the fsync policy is on)."""
    _fsync_replace(pending_path(path), path)


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
def atomic_path(path: str | Path) -> Iterator[Path]:
    """A temporary name beside `path` for a writer that takes a file name (torch.save, ...).

    When the block succeeds the file is renamed to `path` (fsynced first with the fsync policy on);
    when it raises, it is removed.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = tmp_path_for(path)
    try:
        with naming_os_errors(path):
            yield tmp
            _fsync_replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


class _Placeholder(mmap.mmap):
    """Anonymous memory without access rights, never read or written, standing for the
    concatenation of `pieces` (`offsets[i]`: where piece i starts; `offsets[-1]`: total bytes)."""

    pieces: list[memoryview]
    offsets: list[int]


_PLACEHOLDERS: dict[int, weakref.ref] = {}  # base address -> placeholder, while an array still uses it
_PLACEHOLDERS_LOCK = threading.Lock()


def deferred_binary(pieces: Sequence) -> pa.BinaryArray:
    """A binary array of `len(pieces)` values whose bytes are not copied: they are written straight
    from `pieces` when the array is written by `AtomicIpcWriter` (or `write_table`).

    `pieces`: bytes-like objects (bytes, numpy uint8 views into a memory-mapped file, pyarrow
    buffers) that must not change until the file is closed. The array is for writing only: reading
    its values anywhere else faults (`deferred` arrays never leave the write paths that make them).
    """
    views = [memoryview(p).cast("B") for p in pieces]
    offsets = np.zeros(len(views) + 1, dtype=np.int64)
    np.cumsum([v.nbytes for v in views], out=offsets[1:])
    total = int(offsets[-1])
    if total >= 2**31:
        raise SeeUError(f"{total / 1e9:.1f} GB of values in one binary column, over the 2 GB its 32-bit offsets allow")
    # Private and without access rights (where the platform has them): never backed by memory nor
    # charged to the commit limit, and a read by anything but the writer's sink faults loudly.
    placeholder = (
        _Placeholder(-1, max(total, 1), flags=mmap.MAP_PRIVATE | getattr(mmap, "MAP_NORESERVE", 0), prot=0)
        if hasattr(mmap, "MAP_PRIVATE")
        else _Placeholder(-1, max(total, 1))
    )
    placeholder.pieces, placeholder.offsets = views, offsets.tolist()
    data = pa.py_buffer(placeholder)[:total]
    base = data.address
    with _PLACEHOLDERS_LOCK:
        _PLACEHOLDERS[base] = weakref.ref(placeholder)
    weakref.finalize(placeholder, _forget_placeholder, base)
    return pa.BinaryArray.from_buffers(pa.binary(), len(views), [None, pa.py_buffer(offsets.astype(np.int32)), data])


def _forget_placeholder(base: int) -> None:
    # Only a dead entry: the memory is unmapped before this runs, and a placeholder made meanwhile on
    # another thread may already be registered at the same address.
    with _PLACEHOLDERS_LOCK:
        ref = _PLACEHOLDERS.get(base)
        if ref is not None and ref() is None:
            del _PLACEHOLDERS[base]


def _deferred_pieces(address: int, size: int) -> list[memoryview] | None:
    """The pieces (sliced at the ends) a buffer at `address` of `size` bytes stands for, or None
    when it is not (a slice of) a `deferred_binary` placeholder."""
    with _PLACEHOLDERS_LOCK:
        if not _PLACEHOLDERS:
            return None
        found = None
        for base, ref in _PLACEHOLDERS.items():
            ph = ref()
            if ph is not None and base <= address < base + len(ph):
                found = (base, ph)
                break
    if found is None:
        return None
    base, ph = found
    start, end = address - base, address - base + size
    if end > ph.offsets[-1]:
        raise AssertionError("a write reaches past the end of a deferred binary column")
    out = []
    i = bisect.bisect_right(ph.offsets, start) - 1
    while start < end:
        piece, lo = ph.pieces[i], ph.offsets[i]
        a, b = start - lo, min(end - lo, piece.nbytes)
        if b > a:
            out.append(piece[a:b] if (a, b) != (0, piece.nbytes) else piece)
        start = lo + b
        i += 1
    return out


def _writev_all(fd: int, views: list[memoryview]) -> None:
    """Write every view in order (os.writev in groups of 1024, retrying short writes)."""
    if not hasattr(os, "writev"):  # not POSIX
        for v in views:
            written = 0
            while written < v.nbytes:
                written += os.write(fd, v[written:])
        return
    i = 0
    while i < len(views):
        group = views[i : i + 1024]
        written = os.writev(fd, group)
        for v in group:
            if written < v.nbytes:  # a short write: go on from inside this view
                views = [v[written:]] + views[i + 1 :]
                i = 0
                break
            written -= v.nbytes
            i += 1


class _HashingFile:
    """Raw write-only file object that hashes (sha256) every byte it writes (used through pa.PythonFile).

    The hash is computed on one helper thread, from the file itself: once every `_HASH_BLOCK` bytes
    written, that range is memory-mapped (from the page cache the writes just filled) and hashed in
    one `update`, so hashing overlaps the writes and building the next batch without holding on to
    any written buffer. One `update` per block matters: hashlib releases the GIL only inside each
    call, and hashing the written buffers one image at a time (~50 KB) made the hasher wait for the
    GIL once per image while the writer's thread held it (measured: up to 5 ms, the switch interval,
    per call under a busy thread). Small writes (IPC metadata, padding, small columns) are staged
    and written in one piece when they grow large, before the next large write and at the end: far
    fewer system calls. (Starting write-back early with sync_file_range was measured and made the
    import slower: it moves the kernel's write-back work into this thread.)
    """

    def __init__(self, path: Path):
        from concurrent.futures import ThreadPoolExecutor

        self._fh = open(path, "wb", buffering=0)
        self._reader = open(path, "rb", buffering=0)  # the hasher's: stays valid across the rename
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="seeu-sha256")
        self._sha256 = hashlib.sha256()
        self._small = bytearray()
        self._hash_submitted = 0  # bytes handed to the hasher so far
        self._hash_error: BaseException | None = None
        self._digest_requested = False
        self.size = 0
        self.closed = False

    def _hash_range(self, start: int, length: int) -> None:
        """Hash file bytes [start, start + length) (runs on the hasher's thread, in order)."""
        if self._hash_error is not None:
            return
        aligned = start - start % mmap.ALLOCATIONGRANULARITY
        try:
            try:
                m = mmap.mmap(self._reader.fileno(), start + length - aligned, access=mmap.ACCESS_READ, offset=aligned)
            except (OSError, ValueError):  # a file system that can't map files: read the range back
                self._reader.seek(start)
                left = length
                while left:
                    block = self._reader.read(min(_HASH_BLOCK, left))
                    if not block:
                        raise OSError(f"the file ends {left} bytes before what was written") from None
                    self._sha256.update(block)
                    left -= len(block)
                return
            with m, memoryview(m) as view:
                self._sha256.update(view[start - aligned :])
        except BaseException as exc:  # reported by the digest, never a digest of part of the file
            self._hash_error = exc

    def _digest(self) -> str:
        try:
            if self._hash_error is not None:
                raise SeeUError(f"could not hash {self._fh.name} as it was written: {self._hash_error}")
            return self._sha256.hexdigest()
        finally:
            self._reader.close()

    def _submit_written(self, final: bool = False) -> None:
        """Queue the written bytes not yet hashed, once they fill a block (or all of them, `final`)."""
        pending = self.size - self._hash_submitted
        if pending >= _HASH_BLOCK or (final and pending):
            self._pool.submit(self._hash_range, self._hash_submitted, pending)
            self._hash_submitted = self.size

    def _write_all(self, view: memoryview) -> None:
        written = 0
        while written < view.nbytes:
            written += self._fh.write(view[written:])

    def _flush_small(self) -> None:
        if self._small:
            self._write_all(memoryview(self._small))
            self.size += len(self._small)
            self._small = bytearray()

    def write(self, data) -> int:
        if isinstance(data, pa.Buffer) and (pieces := _deferred_pieces(data.address, data.size)) is not None:
            self._flush_small()  # a deferred_binary column: write the pieces it stands for
            _writev_all(self._fh.fileno(), pieces)
            nbytes = data.size
        else:
            view = memoryview(data).cast("B")
            nbytes = view.nbytes
            if nbytes < _BIG_WRITE:  # staged: one system call for many small buffers
                self._small += view
                if len(self._small) >= _BIG_WRITE:
                    self._flush_small()
                    self._submit_written()
                return nbytes
            self._flush_small()
            self._write_all(view)
        self.size += nbytes
        self._submit_written()
        return nbytes

    def tell(self) -> int:
        return self.size + len(self._small)

    def digest_future(self) -> Future:
        """The sha256 (hex) of every byte written, as a future: queued after the pending ranges, so
        the caller can go on (the next shard) while the hasher finishes. No writes after this."""
        self._flush_small()
        self._submit_written(final=True)
        future = self._pool.submit(self._digest)
        self._pool.shutdown(wait=False)
        self._digest_requested = True
        return future

    def flush(self) -> None:
        pass

    def writable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return False

    def fsync(self) -> None:
        os.fsync(self._fh.fileno())

    def close(self) -> None:
        if not self.closed:
            try:
                self._fh.close()
            finally:
                if not self._digest_requested:  # abandoned: stop hashing
                    self._pool.shutdown(wait=True, cancel_futures=True)
                    self._reader.close()
                self.closed = True


class AtomicIpcWriter:
    """An Arrow IPC *file* writer (uncompressed) on a temporary name, hashing the bytes as it writes.

    `write_batch` / `write_table` as pyarrow's writer; `close()` finishes the file, fsyncs it when the
    fsync policy is on (`set_fsync`), renames it to `path` and returns `(bytes, sha256)` (also kept as `.size` / `.sha256`). With
    `commit=False` the finished file is left at `pending_path(path)` and the caller calls
    `commit_pending(path)` later (`seeu build` does that on a background thread, so a disk flush
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
            with naming_os_errors(self.path):
                self._sink = pa.PythonFile(self._raw, mode="w")
                self._writer = pa.ipc.new_file(self._sink, schema, options=_WRITE_OPTIONS)
        except BaseException:
            self.abort()
            raise

    def write_batch(self, batch: pa.RecordBatch) -> None:
        with naming_os_errors(self.path):
            self._writer.write_batch(batch)

    def write_table(self, table: pa.Table, max_chunksize: int | None = None) -> None:
        with naming_os_errors(self.path):
            self._writer.write_table(table, max_chunksize=max_chunksize)

    def close(self) -> tuple[int, str]:
        """Finish the file and put it in place (or leave it pending); return (bytes, sha256)."""
        size, digest = self.close_async()
        try:
            self.sha256 = digest.result()
        except BaseException:
            (self.path if self.commit else self.tmp).unlink(missing_ok=True)  # never a file without its hash
            raise
        return size, self.sha256

    def close_async(self) -> tuple[int, Future]:
        """`close` without waiting for the hasher: (bytes, future of the sha256). The file is complete
        (and in place unless `commit=False`) when this returns; the digest follows."""
        try:
            with naming_os_errors(self.path):
                self._writer.close()
                digest = self._raw.digest_future()
                if self.commit and _FSYNC:
                    self._raw.fsync()
                self._sink.close()  # closes self._raw too (pa.PythonFile closes its file object)
                if self.commit:
                    os.replace(self.tmp, self.path)
        except BaseException:
            self.abort()
            raise
        self.size = self._raw.size
        return self.size, digest

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


def write_table(
    path: str | Path, table: pa.Table, max_chunksize: int | None = None, commit: bool = True
) -> tuple[int, str]:
    """Write a whole table atomically as an Arrow IPC file; return (bytes, sha256) of the file."""
    with AtomicIpcWriter(path, table.schema, commit=commit) as writer:
        writer.write_table(table, max_chunksize=max_chunksize)
    assert writer.sha256 is not None
    return writer.size, writer.sha256


def write_table_async(
    path: str | Path, table: pa.Table, max_chunksize: int | None = None, commit: bool = True
) -> tuple[int, Future]:
    """`write_table` returning (bytes, future of the sha256) as soon as the file is written: the
    hashing of its last buffers overlaps whatever the caller does next."""
    writer = AtomicIpcWriter(path, table.schema, commit=commit)
    try:
        writer.write_table(table, max_chunksize=max_chunksize)
    except BaseException:
        writer.abort()
        raise
    return writer.close_async()


_MADV_POPULATE_READ = 22  # Linux >= 5.14 (not yet a constant in Python 3.11's mmap module)


def map_readonly(path: str | Path, populate: bool = False) -> mmap.mmap:
    """A read-only shared memory map of the whole file. `populate=True` fills its page tables at once
    (MAP_POPULATE on Linux): for a file that will be read whole, one call instead of a page fault
    per 64 KB, several times faster on a VM (writing 100 MB from a mapped file: 0.03 s vs 0.08 s)."""
    with open(path, "rb") as fh:
        if populate and hasattr(mmap, "MAP_POPULATE"):
            return mmap.mmap(fh.fileno(), 0, flags=mmap.MAP_SHARED | mmap.MAP_POPULATE, prot=mmap.PROT_READ)
        return mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)


def populate(mapping: mmap.mmap, start: int, length: int) -> None:
    """Fill the page tables of `mapping[start:start + length]` now (MADV_POPULATE_READ), for a part of
    a mapped file about to be read whole. Best effort: a no-op where the kernel lacks it."""
    page = mmap.PAGESIZE
    lo = start // page * page
    hi = min(len(mapping), start + length)
    if hi > lo and hasattr(mapping, "madvise"):
        try:
            mapping.madvise(_MADV_POPULATE_READ, lo, hi - lo)
        except OSError:
            pass


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
