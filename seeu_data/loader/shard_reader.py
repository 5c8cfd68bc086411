"""Random access to the rows of one triple shard (Arrow IPC file, memory-mapped, zero-copy).

A shard holds record batches of `seeu.triples` rows (`schemas/triples.v1.json`). The reader keeps
a row -> (batch, row in batch) table and, per record batch it has touched, the per-view columns as
flat numpy arrays. A row comes back as a `triple_row.TripleRow`, its encoded images (and masks, where
the shard has them) memoryviews straight into the memory map (no copy).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa

from seeu_data.errors import SeeUError
from seeu_data.limits import MAX_PIXELS
from seeu_data.store.arrow_io import open_ipc_file
from seeu_data.store.dataset_check import check_file_schema, check_recorded_sizes, check_table_cameras
from seeu_data.store.triple_row import PER_VIEW_COLUMNS, TripleRow

_REQUIRED = ("sample_id", "scene_id", "mode", "num_context", "image_format", "gap", "target_offset") + PER_VIEW_COLUMNS


def _binary_parts(arr: pa.Array) -> tuple[np.ndarray, np.ndarray]:
    """(offsets (n + 1,) int64, data uint8) of a binary array, zero-copy."""
    bufs = arr.buffers()
    dtype = np.int64 if pa.types.is_large_binary(arr.type) else np.int32
    offsets = np.frombuffer(bufs[1], dtype=dtype)[arr.offset : arr.offset + len(arr) + 1].astype(np.int64)
    data = np.frombuffer(bufs[2], dtype=np.uint8) if bufs[2] is not None else np.zeros(0, np.uint8)
    return offsets, data


class _BatchColumns:
    """The columns of one record batch as numpy (per-view columns flattened over all views)."""

    def __init__(self, batch: pa.RecordBatch, where: str):
        col = batch.column
        self.sample_id = col("sample_id").to_pylist()
        self.scene_id = col("scene_id").to_pylist()
        self.mode = col("mode").to_pylist()
        self.image_format = col("image_format").to_pylist()
        self.num_context = col("num_context").to_numpy()
        self.gap = col("gap").to_numpy()
        self.target_offsets = np.asarray(col("target_offset").offsets).astype(np.int64)
        self.target_offset = col("target_offset").values.to_numpy(zero_copy_only=False).astype(np.int64)
        self.view_offsets = np.asarray(col("frame_index").offsets).astype(np.int64)
        for name in PER_VIEW_COLUMNS[1:]:
            if not np.array_equal(np.asarray(col(name).offsets), self.view_offsets):
                raise SeeUError(f"column {name} has a different number of views than frame_index", where)

        def flat(name: str) -> np.ndarray:
            return col(name).values.to_numpy(zero_copy_only=False)

        self.frame_index = flat("frame_index").astype(np.int64)
        self.source_frame = flat("source_frame").astype(np.int64)
        self.width = flat("width")
        self.height = flat("height")
        self.near = flat("near").astype(np.float32)
        self.far = flat("far").astype(np.float32)
        self.intrinsics = col("intrinsics_norm").values.flatten().to_numpy().reshape(-1, 4)
        self.cam_to_world = col("cam_to_world").values.flatten().to_numpy().reshape(-1, 4, 4)
        self.image_offsets, self.image_data = _binary_parts(col("image").values)
        self.has_mask = None  # (views,) bool, or None: no view of the batch has a mask
        if "mask" in batch.schema.names and col("mask").values.null_count < len(col("mask").values):
            if not np.array_equal(np.asarray(col("mask").offsets), self.view_offsets):
                raise SeeUError("column mask has a different number of views than frame_index", where)
            masks = col("mask").values
            self.has_mask = masks.is_valid().to_numpy(zero_copy_only=False)
            self.mask_offsets, self.mask_data = _binary_parts(masks)

    def sample(self, j: int) -> TripleRow:
        lo, hi = int(self.view_offsets[j]), int(self.view_offsets[j + 1])
        io, data = self.image_offsets, self.image_data
        masks = None
        if self.has_mask is not None and self.has_mask[lo:hi].any():
            mo, md = self.mask_offsets, self.mask_data
            masks = [md[mo[k] : mo[k + 1]].data if self.has_mask[k] else None for k in range(lo, hi)]
        return TripleRow(
            sample_id=self.sample_id[j],
            scene_id=self.scene_id[j],
            mode=self.mode[j],
            num_context=int(self.num_context[j]),
            frame_index=self.frame_index[lo:hi],
            source_frame=self.source_frame[lo:hi],
            images=[data[io[k] : io[k + 1]].data for k in range(lo, hi)],
            image_format=self.image_format[j],
            width=self.width[lo:hi],
            height=self.height[lo:hi],
            intrinsics_norm=self.intrinsics[lo:hi],
            cam_to_world=self.cam_to_world[lo:hi],
            near=self.near[lo:hi],
            far=self.far[lo:hi],
            gap=int(self.gap[j]),
            target_offset=self.target_offset[self.target_offsets[j] : self.target_offsets[j + 1]],
            masks=masks,
        )


class ShardReader:
    """Rows of one shard by index. `name` is what errors call the shard (its URL or path).

    Opening a shard runs the cheap per-file checks of `seeu_data.store.dataset_check`: the file's schema
    metadata (`seeu.triples`, a major version this seeu reads), its row count against the manifest's,
    finite rigid cameras with 0 < near < far, recorded image sizes under `max_pixels` (each image's
    header is checked against them when it is decoded: `transforms.transform_sample`)."""

    def __init__(self, path: str | Path, name: str, expected_rows: int | None = None, max_pixels: int = MAX_PIXELS):
        self.path = Path(path)
        self.name = name
        try:
            self._reader = open_ipc_file(self.path)
        except SeeUError as exc:
            raise SeeUError(str(exc).split(": ", 1)[-1], name) from None
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
        self._batches: dict[int, _BatchColumns] = {}

    def _columns(self, b: int) -> _BatchColumns:
        cols = self._batches.get(b)
        if cols is None:
            try:
                batch = self._reader.get_batch(b)
                cols = _BatchColumns(batch, self.name)
            except (pa.ArrowInvalid, pa.ArrowTypeError, OSError, ValueError, KeyError) as exc:
                raise SeeUError(f"unreadable record batch {b} (corrupt?): {exc}".splitlines()[0], self.name) from None
            self._batches[b] = cols
        return cols

    def sample(self, row: int) -> TripleRow:
        """Row `row` of the shard (0-based)."""
        if not 0 <= row < self.num_rows:
            raise IndexError(f"row {row} outside [0, {self.num_rows}) in {self.name}")
        b = int(np.searchsorted(self.batch_starts, row, side="right") - 1)
        return self._columns(b).sample(row - int(self.batch_starts[b]))

    def gaps(self) -> np.ndarray:
        """`(rows,) int64` context gap of every row (reads only the gap column's buffers)."""
        out = [
            np.asarray(self._reader.get_batch(b).column("gap").to_numpy(), dtype=np.int64)
            for b in range(len(self.batch_starts) - 1)
        ]
        return np.concatenate(out) if out else np.zeros(0, np.int64)
