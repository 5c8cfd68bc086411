"""A fast, restricted reader of `torch.save` files holding plain data (pixelSplat chunks).

A `torch.save` file (zip format, torch >= 1.6) is an uncompressed zip archive: `<name>/data.pkl`
(the pickled object, tensors pickled as `torch._utils._rebuild_tensor_v2(storage, offset, size,
stride, ...)` with storages as persistent ids `('storage', torch.<Type>Storage, key, location,
numel)`) and one entry `<name>/data/<key>` per storage holding its raw little-endian bytes.

`load_plain` memory-maps the file and unpickles `data.pkl` with the C unpickler restricted to an
allowlist (the tensor rebuild function, the storage types, OrderedDict): any other global is
refused, as `torch.load(weights_only=True)` refuses it. Tensors come back as read-only numpy views
into the mapped file, so nothing is copied and the chunk's bytes stay in the page cache instead of
the process's memory. Anything unusual (the legacy non-zip format, compressed entries, big-endian
data, another global) raises `UnsupportedChunk` and the caller falls back to `torch.load`.
Kept over `torch.load(weights_only=True, mmap=True)`, which is as safe, because it reads the peers'
100 MB chunks about 5x faster (benchmarks/RESULTS.md, pixelSplat chunk import).
"""

from __future__ import annotations

import mmap
import pickle
import struct
import zipfile
from collections import OrderedDict
from pathlib import Path

import numpy as np

_STORAGE_DTYPES = {
    "ByteStorage": np.uint8,
    "CharStorage": np.int8,
    "ShortStorage": np.int16,
    "IntStorage": np.int32,
    "LongStorage": np.int64,
    "FloatStorage": np.float32,
    "DoubleStorage": np.float64,
    "HalfStorage": np.float16,
    "BoolStorage": np.bool_,
}


class UnsupportedChunk(Exception):
    """The file is not a plain-data zip-format torch.save file this reader handles."""


class _StorageType:
    def __init__(self, dtype):
        self.dtype = np.dtype(dtype)


def _rebuild_tensor(storage: np.ndarray, offset: int, size, stride, *_ignored) -> np.ndarray:
    size, stride = tuple(size), tuple(stride)
    if len(size) != len(stride):
        raise UnsupportedChunk("tensor size and stride disagree")
    if any(n == 0 for n in size):
        return np.zeros(size, dtype=storage.dtype)
    end = offset + 1 + sum((n - 1) * s for n, s in zip(size, stride))
    if offset < 0 or end > storage.size or any(s < 0 for s in stride):
        raise UnsupportedChunk("tensor outside its storage")
    if stride == (1,):  # the common case (1-D contiguous: encoded images, timestamps): a plain slice
        return storage[offset:end]
    base = storage[offset:]
    return np.lib.stride_tricks.as_strided(
        base, shape=size, strides=[s * storage.itemsize for s in stride], writeable=False
    )


class _RestrictedUnpickler(pickle.Unpickler):
    def __init__(self, file, storage_loader):
        super().__init__(file)
        self._storage_loader = storage_loader

    def find_class(self, module: str, name: str):
        if module == "torch._utils" and name == "_rebuild_tensor_v2":
            return _rebuild_tensor
        if module == "torch" and name in _STORAGE_DTYPES:
            return _StorageType(_STORAGE_DTYPES[name])
        if module == "collections" and name == "OrderedDict":
            return OrderedDict
        raise UnsupportedChunk(f"global {module}.{name} is not allowed")

    def persistent_load(self, pid):
        if not (isinstance(pid, tuple) and len(pid) == 5 and pid[0] == "storage" and isinstance(pid[1], _StorageType)):
            raise UnsupportedChunk(f"unexpected persistent id {pid!r:.80}")
        return self._storage_loader(str(pid[2]), pid[1].dtype, int(pid[4]))


def load_plain(path: str | Path):
    """Load a plain-data torch.save file (lists, dicts, str, numbers, tensors as numpy views).

    Raises UnsupportedChunk when the file needs `torch.load` instead; OSError/zipfile.BadZipFile
    /pickle errors for damaged files.
    """
    path = Path(path)
    if not zipfile.is_zipfile(path):
        raise UnsupportedChunk("not the zip serialization format")
    with zipfile.ZipFile(path) as zf:
        infos = {i.filename: i for i in zf.infolist()}
        pkl = [n for n in infos if n.endswith("/data.pkl") and n.count("/") == 1]
        if len(pkl) != 1:
            raise UnsupportedChunk("no single <name>/data.pkl entry")
        prefix = pkl[0][: -len("data.pkl")]
        order = infos.get(prefix + "byteorder")
        if order is not None and zf.read(order).strip() != b"little":
            raise UnsupportedChunk("big-endian storages")
        data_pkl = zf.read(pkl[0])
    with open(path, "rb") as fh:
        mm = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)
    cache: dict[str, np.ndarray] = {}

    def storage(key: str, dtype: np.dtype, numel: int) -> np.ndarray:
        if key in cache:
            return cache[key]
        info = infos.get(f"{prefix}data/{key}")
        if info is None or info.compress_type != zipfile.ZIP_STORED:
            raise UnsupportedChunk(f"storage {key} missing or compressed")
        name_len, extra_len = struct.unpack_from("<HH", mm, info.header_offset + 26)
        start = info.header_offset + 30 + name_len + extra_len
        if info.file_size != numel * dtype.itemsize or start + info.file_size > len(mm):
            raise UnsupportedChunk(f"storage {key} has {info.file_size} bytes for {numel} x {dtype}")
        cache[key] = np.frombuffer(mm, dtype=dtype, count=numel, offset=start)
        return cache[key]

    import io

    return _RestrictedUnpickler(io.BytesIO(data_pkl), storage).load()
