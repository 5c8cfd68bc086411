"""Arrow IPC file IO: uncompressed, written to a temporary name and renamed when complete."""

from __future__ import annotations

import hashlib
import os
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

import pyarrow as pa

from .errors import SeeUError

# No compression: encoded images don't compress and compression makes random reads 10-100x slower.
_WRITE_OPTIONS = pa.ipc.IpcWriteOptions(compression=None)


def tmp_path_for(path: Path) -> Path:
    return path.with_name(f".{path.name}.{os.getpid()}.tmp")


@contextmanager
def atomic_ipc_writer(path: str | Path, schema: pa.Schema) -> Iterator[pa.ipc.RecordBatchFileWriter]:
    """Yield an IPC *file* writer on a temporary name; rename to `path` only if the block succeeds."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = tmp_path_for(path)
    try:
        with pa.OSFile(str(tmp), "wb") as sink:
            with pa.ipc.new_file(sink, schema, options=_WRITE_OPTIONS) as writer:
                yield writer
        with open(tmp, "rb") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_table(path: str | Path, table: pa.Table, max_chunksize: int | None = None) -> None:
    """Write a whole table atomically as an Arrow IPC file."""
    with atomic_ipc_writer(path, table.schema) as writer:
        writer.write_table(table, max_chunksize=max_chunksize)


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
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = tmp_path_for(path)
    try:
        with open(tmp, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def atomic_write_text(path: str | Path, text: str) -> None:
    atomic_write_bytes(path, text.encode("utf-8"))
