"""Random access to the rows of one triple shard (Arrow IPC file), safe against the file changing
under the reader.

A shard holds record batches of `seeu.triples` rows (`schemas/triples.v1.json`). The reader keeps
a row -> (batch, row in batch) table and, per record batch, its columns as views into the memory
map (made when the shard is opened). A row comes back as a `triple_row.TripleRow`: its small values
copied out of the map, its encoded images (and masks, where the shard has them) read with
`os.pread` at their offsets in the file. The map's pages are given back every `RELEASE_EVERY` rows.
What a reader holds is about 115 bytes a row at build's default 64 rows a batch (the views of each
batch); its small columns decoded into copies at the opening took 1.35 kB a row.

A shard truncated or rewritten in place while a run reads it (a rebuild into the same directory, a
sync tool, a full disk) must not kill the reader with SIGBUS, the signal a memory map raises when a
page beyond the file's new end is touched, nor feed it changed rows. So: the file is memory-mapped
only for its layout and small columns (the footer, each record batch's small columns, copied out
when a row is read, and the place of its image bytes); image bytes, nearly all of a shard, are
never read through the map. The file's size and modification time are taken when the reader opens
it and compared on every read (`fstat`, before the map is touched and after the image bytes are
read): a difference, or a short read, is `ShardChanged`, one line naming the shard; the loader
never skips it (`on_error="skip"` skips unreadable samples, not a dataset that changes under the
run).
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

import numpy as np
import pyarrow as pa

from seeu_data.errors import SeeUError
from seeu_data.limits import MAX_PIXELS
from seeu_data.store.arrow_io import ReleasableIpcFile
from seeu_data.store.dataset_check import check_file_schema, check_recorded_sizes, check_table_cameras
from seeu_data.store.triple_row import PER_VIEW_COLUMNS, TripleRow

# Rows read between two releases of the map's pages (`ReleasableIpcFile.release`): a row's values are
# read through the map when the row is read, and each page touched maps the 64 kB around it. Every 256
# rows, a loader epoch over 20,000 tiny scenes (16 shards open a worker) held 84 MB more of the maps than
# over 5,000; every 16 rows, as little as the copies at the opening did (at 5,000), for the same time.
RELEASE_EVERY = 16

_REQUIRED = ("sample_id", "scene_id", "mode", "num_context", "image_format", "gap", "target_offset") + PER_VIEW_COLUMNS


class ShardChanged(SeeUError):
    """A shard's size or modification time differs from when the reader opened it (truncated or
    rewritten under the run), or its image bytes are no longer there."""


def _binary_parts(arr: pa.Array, map_address: int) -> tuple[np.ndarray, int]:
    """(offsets (n + 1,) (a view), the file position of the values) of a binary array of a
    memory-mapped file whose first byte is at `map_address`; reads the offsets only."""
    bufs = arr.buffers()
    dtype = np.int64 if pa.types.is_large_binary(arr.type) else np.int32
    offsets = np.frombuffer(bufs[1], dtype=dtype)[arr.offset : arr.offset + len(arr) + 1]
    return offsets, (bufs[2].address - map_address if bufs[2] is not None else 0)


def _pread(fd: int, offsets: np.ndarray, start: int, k: int, what: str) -> memoryview:
    """Value `k` of a binary column whose values begin at file position `start` (EOFError if short)."""
    size = int(offsets[k + 1] - offsets[k])
    data = os.pread(fd, size, start + int(offsets[k]))
    if len(data) != size:
        raise EOFError(f"{what}: {len(data)} of {size} bytes")
    return memoryview(data)


class _BatchColumns:
    """The columns of one record batch as views into the shard's map (per-view columns flattened over all
    views): no copy, so nothing a row. `sample` copies one row's values out."""

    def __init__(self, batch: pa.RecordBatch, where: str, map_address: int):
        col = batch.column
        self.sample_id, self.scene_id, self.mode, self.image_format = (
            col(name) for name in ("sample_id", "scene_id", "mode", "image_format")
        )
        self.num_context = col("num_context").to_numpy()
        self.gap = col("gap").to_numpy()
        self.target_offsets = np.asarray(col("target_offset").offsets)
        self.target_offset = col("target_offset").values.to_numpy()
        self.view_offsets = np.asarray(col("frame_index").offsets)
        for name in PER_VIEW_COLUMNS[1:]:
            if not np.array_equal(np.asarray(col(name).offsets), self.view_offsets):
                raise SeeUError(f"column {name} has a different number of views than frame_index", where)
        self.frame_index, self.source_frame, self.width, self.height, self.near, self.far = (
            col(name).values.to_numpy() for name in ("frame_index", "source_frame", "width", "height", "near", "far")
        )
        self.intrinsics = col("intrinsics_norm").values.flatten().to_numpy().reshape(-1, 4)
        self.cam_to_world = col("cam_to_world").values.flatten().to_numpy().reshape(-1, 4, 4)
        self.image_offsets, self.image_start = _binary_parts(col("image").values, map_address)
        self.has_mask = None  # (views,) bool, or None: no view of the batch has a mask
        if "mask" in batch.schema.names and col("mask").values.null_count < len(col("mask").values):
            if not np.array_equal(np.asarray(col("mask").offsets), self.view_offsets):
                raise SeeUError("column mask has a different number of views than frame_index", where)
            masks = col("mask").values
            self.has_mask = masks.is_valid().to_numpy(zero_copy_only=False)
            self.mask_offsets, self.mask_start = _binary_parts(masks, map_address)

    def sample(self, j: int, fd: int) -> TripleRow:
        """Row `j` of the batch (its values copied: the map's pages may be given back), its images read
        from the open file `fd` (a short read: ShardChanged by the caller, which knows the shard's name)."""
        lo, hi = int(self.view_offsets[j]), int(self.view_offsets[j + 1])
        images = [_pread(fd, self.image_offsets, self.image_start, k, f"image {k - lo}") for k in range(lo, hi)]
        masks = None
        if self.has_mask is not None and self.has_mask[lo:hi].any():
            mo, ms = self.mask_offsets, self.mask_start
            masks = [_pread(fd, mo, ms, k, f"mask {k - lo}") if self.has_mask[k] else None for k in range(lo, hi)]
        return TripleRow(
            sample_id=self.sample_id[j].as_py(),
            scene_id=self.scene_id[j].as_py(),
            mode=self.mode[j].as_py(),
            num_context=int(self.num_context[j]),
            frame_index=self.frame_index[lo:hi].astype(np.int64),
            source_frame=self.source_frame[lo:hi].astype(np.int64),
            images=images,
            image_format=self.image_format[j].as_py(),
            width=self.width[lo:hi].copy(),
            height=self.height[lo:hi].copy(),
            intrinsics_norm=self.intrinsics[lo:hi].copy(),
            cam_to_world=self.cam_to_world[lo:hi].copy(),
            near=self.near[lo:hi].astype(np.float32),
            far=self.far[lo:hi].astype(np.float32),
            gap=int(self.gap[j]),
            target_offset=self.target_offset[self.target_offsets[j] : self.target_offsets[j + 1]].astype(np.int64),
            masks=masks,
        )


class ShardReader:
    """Rows of one shard by index. `name` is what errors call the shard (its URL or path).

    Opening a shard runs the cheap per-file checks of `seeu_data.store.dataset_check`: the file's schema
    metadata (`seeu.triples`, a major version this seeu reads), its row count against the manifest's,
    finite rigid cameras with 0 < near < far, recorded image sizes under `max_pixels` (each image's
    header is checked against them when it is decoded: `transforms.transform_sample`). From then on
    every read compares the file's size and modification time with those at the opening
    (`ShardChanged`, see the module docstring)."""

    def __init__(self, path: str | Path, name: str, expected_rows: int | None = None, max_pixels: int = MAX_PIXELS):
        self.path = Path(path)
        self.name = name
        try:
            self._file = open(self.path, "rb", buffering=0)  # held while the reader lives: image bytes are read from it
            self._stamp = self._stat()
            self._ipc = ReleasableIpcFile(self.path)
            self._reader, self._map_address = self._ipc.reader, self._ipc.address
        except OSError as exc:
            raise SeeUError(f"cannot be opened ({exc.strerror})", name) from None
        except SeeUError as exc:
            raise SeeUError(str(exc).split(": ", 1)[-1], name) from None
        self.check_unchanged()
        check_file_schema(self._reader.schema, "seeu.triples", name)
        missing = [c for c in _REQUIRED if c not in self._reader.schema.names]
        if missing:
            raise SeeUError(f"missing columns: {', '.join(missing)}", name)
        try:
            counts = [self._reader.get_batch(i).num_rows for i in range(self._reader.num_record_batches)]
        except (pa.ArrowInvalid, OSError) as exc:
            raise SeeUError(f"unreadable record batch (corrupt?): {exc}".splitlines()[0], name) from None
        self.batch_starts = np.concatenate([[0], np.cumsum(counts, dtype=np.int64)]).astype(np.int64)
        self.num_rows = int(self.batch_starts[-1])
        if expected_rows is not None and self.num_rows != expected_rows:
            raise SeeUError(f"{self.num_rows} rows, the manifest says {expected_rows}", name)
        try:  # the per-view camera and size columns only (memory-mapped): a few ms per shard
            for i in range(self._reader.num_record_batches):
                batch = self._reader.get_batch(i)
                check_table_cameras(batch, name)
                w = batch.column("width").values.to_numpy(zero_copy_only=False)
                h = batch.column("height").values.to_numpy(zero_copy_only=False)
                check_recorded_sizes(w, h, max_pixels, name)
        except (pa.ArrowInvalid, pa.ArrowTypeError, OSError, ValueError) as exc:
            raise SeeUError(f"unreadable record batch (corrupt?): {exc}".splitlines()[0], name) from None
        self.check_unchanged()
        self._batches: dict[int, _BatchColumns] = {}
        self._decode_all()
        self._reads = 0
        self._ipc.release()

    def _decode_all(self) -> None:
        """Every batch's columns (`_BatchColumns`: views) made at the opening, as one burst: made as their
        rows were first read and kept, they were allocated between the batches' image tensors, pinning the
        heap holes those leave when freed (an epoch over 20,000 tiny scenes grew to 1.7 GB resident). A
        batch that fails here fails again, with its one line, when a row of it is read."""
        for b in range(len(self.batch_starts) - 1):
            with contextlib.suppress(SeeUError):
                self._columns(b)

    def _stat(self) -> tuple[int, int]:
        st = os.fstat(self._file.fileno())
        return st.st_size, st.st_mtime_ns

    def check_unchanged(self) -> None:
        """ShardChanged when the file's size or modification time is not what it was at the opening."""
        (size, _), now = self._stamp, self._stat()
        if now != self._stamp:
            what = f"size {size} -> {now[0]} bytes" if now[0] != size else "modified in place"
            raise ShardChanged(
                f"shard changed while this run reads it ({what}); a shard must not be rewritten under a "
                "running job: restore it (or rebuild into another directory) and resume",
                self.name,
            )

    def _columns(self, b: int) -> _BatchColumns:
        cols = self._batches.get(b)
        if cols is None:
            self.check_unchanged()  # before the map is touched: a shrunk file must not be read through it
            try:
                batch = self._reader.get_batch(b)
                cols = _BatchColumns(batch, self.name, self._map_address)
            except (pa.ArrowInvalid, pa.ArrowTypeError, OSError, ValueError, KeyError) as exc:
                raise SeeUError(f"unreadable record batch {b} (corrupt?): {exc}".splitlines()[0], self.name) from None
            self._batches[b] = cols
        return cols

    def sample(self, row: int) -> TripleRow:
        """Row `row` of the shard (0-based)."""
        if not 0 <= row < self.num_rows:
            raise IndexError(f"row {row} outside [0, {self.num_rows}) in {self.name}")
        b = int(np.searchsorted(self.batch_starts, row, side="right") - 1)
        cols = self._columns(b)
        self.check_unchanged()
        try:
            out = cols.sample(row - int(self.batch_starts[b]), self._file.fileno())
        except (EOFError, OSError) as exc:
            raise ShardChanged(
                f"row {row}: image bytes cannot be read ({exc}): truncated under the run?", self.name
            ) from None
        self.check_unchanged()  # a write while the bytes were read
        self._reads += 1
        if self._reads % RELEASE_EVERY == 0:
            self._ipc.release()
        return out

    def gaps(self) -> np.ndarray:
        """`(rows,) int64` context gap of every row."""
        out = [self._columns(b).gap for b in range(len(self.batch_starts) - 1)]
        return np.concatenate(out).astype(np.int64) if out else np.zeros(0, np.int64)
