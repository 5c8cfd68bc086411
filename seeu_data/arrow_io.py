"""File IO: Arrow IPC files (uncompressed) and other outputs written to a temporary name and renamed
when complete; JSON inputs read with a one-line error.

Durability policy (decided here, in one place): every write is atomic (temporary name, rename when
complete, manifests written last with bytes + sha256 per file), so a crash, Ctrl-C or kill never
leaves a half-written file under its final name. fsync is opt-in: with it off (the default) data
reaches the page cache and a file torn by a power loss is caught by its manifest sha256
(`read_manifest(verify=True)`, `seeu validate`, the size/sha256 checks before a resume keeps a file);
with it on (`set_fsync(True)`, set by the `--fsync` flag of `seeu import/build/ingest`, or the
environment variable `SEEU_FSYNC=1`) every file is fsynced before its rename.

IPC files are written by pyarrow's own writer through a sink that hashes every buffer as it writes
it (`AtomicIpcWriter`), so the manifest's (bytes, sha256) need no second pass over the file.
"""

from __future__ import annotations

import hashlib
import json
import os
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator, Sequence

import numpy as np

import pyarrow as pa

from .errors import SeeUError

# No compression: encoded images don't compress and compression makes random reads 10-100x slower.
_WRITE_OPTIONS = pa.ipc.IpcWriteOptions(compression=None)


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


def _fsync_replace(src: Path, dst: Path) -> None:
    """Make the written file `src` durable when the fsync policy is on, then rename it to `dst` (the atomic step)."""
    if _FSYNC:
        with open(src, "rb") as fh:
            os.fsync(fh.fileno())
    os.replace(src, dst)


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


def binary_array(values: Sequence) -> pa.BinaryArray:
    """A binary array of bytes-like `values` (bytes, memoryviews or numpy views into mapped files),
    with their bytes copied once into one buffer."""
    views = [memoryview(v).cast("B") for v in values]
    offsets = np.zeros(len(views) + 1, dtype=np.int64)
    np.cumsum([v.nbytes for v in views], out=offsets[1:])
    if offsets[-1] >= 2**31:
        raise SeeUError(f"{offsets[-1] / 1e9:.1f} GB of values in one binary column, over the 2 GB its 32-bit offsets allow")
    data = pa.py_buffer(b"".join(views))
    return pa.BinaryArray.from_buffers(pa.binary(), len(views), [None, pa.py_buffer(offsets.astype(np.int32)), data])


class _HashingSink:
    """Write-only file object (for `pa.PythonFile`) that hashes each buffer as it writes it: the
    manifest's (bytes, sha256) come in the same pass as the write, with no read-back."""

    def __init__(self, path: Path):
        self._fh = open(path, "wb")
        self._sha256 = hashlib.sha256()
        self.size = 0
        self.closed = False

    def write(self, data) -> int:
        view = memoryview(data).cast("B")
        self._sha256.update(view)
        self._fh.write(view)
        self.size += view.nbytes
        return view.nbytes

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
            self._fh.close()
            self.closed = True


class AtomicIpcWriter:
    """An Arrow IPC *file* writer (uncompressed) on a temporary name, hashing the bytes as it writes.

    `write_batch` / `write_table` as pyarrow's writer; `close()` finishes the file, fsyncs it when the
    fsync policy is on (`set_fsync`), renames it to `path` and returns `(bytes, sha256)` (also kept as
    `.size` / `.sha256`). `abort()` removes the partial file. As a context manager: the file is closed
    when the block succeeds and removed when it raises. The bytes are pyarrow's own IPC file writer's.
    """

    def __init__(self, path: str | Path, schema: pa.Schema):
        self.path = Path(path)
        self.tmp = tmp_path_for(self.path)
        self.size = 0
        self.sha256: str | None = None
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._raw = _HashingSink(self.tmp)
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
        """Finish the file and put it in place; return (bytes, sha256)."""
        try:
            with naming_os_errors(self.path):
                self._writer.close()
                if _FSYNC:
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
        finally:
            self.tmp.unlink(missing_ok=True)

    def __enter__(self) -> AtomicIpcWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


def write_table(path: str | Path, table: pa.Table, max_chunksize: int | None = None) -> tuple[int, str]:
    """Write a whole table atomically as an Arrow IPC file; return (bytes, sha256) of the file."""
    with AtomicIpcWriter(path, table.schema) as writer:
        writer.write_table(table, max_chunksize=max_chunksize)
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


def sha256_file(path: str | Path) -> str:
    with open(path, "rb") as fh:
        return hashlib.file_digest(fh, "sha256").hexdigest()


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
