"""Test data for the loader tests: small `seeu.triples` datasets written directly with pyarrow.

Every image is a real encoded JPEG/PNG whose pixels are known (`view_image`), and every camera is a
valid look-at pose, so tests can compare what the loader returns against an independent truth.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pyarrow as pa

from seeu_data.store.arrow_io import write_table
from seeu_data.store.manifest import FileEntry, provenance, write_manifest
from seeu_data.store.schema import arrow_schema, schema_version
from seeu_data.store.triple_row import TripleRow
from tests.helpers import look_at_cam_to_world

SCHEMA = "seeu.triples"


def view_image(shard: int, row: int, view: int, hw: tuple[int, int]) -> np.ndarray:
    """(H, W, 3) uint8 BGR: a flat colour that encodes (shard, row, view), plus a little texture."""
    h, w = hw
    img = np.empty((h, w, 3), dtype=np.uint8)
    img[..., 0] = 20 + 40 * (shard % 6)
    img[..., 1] = 10 + 12 * (row % 20)
    img[..., 2] = 30 + 40 * view
    return img


def row_dict(
    shard: int,
    row: int,
    num_context: int,
    num_target: int,
    hw: tuple[int, int],
    gap: int,
    image_fn: Callable[[int, int, int], bytes] | None = None,
    ext: str = ".jpg",
) -> dict:
    """One triples row (`TripleRow.to_pydict`) with V = num_context + num_target views of size hw."""
    v = num_context + num_target
    h, w = hw
    frames = [row + i for i in range(v)]
    images = []
    for k in range(v):
        if image_fn is not None:
            images.append(image_fn(shard, row, k))
        else:
            ok, buf = cv2.imencode(ext, view_image(shard, row, k, hw), [cv2.IMWRITE_JPEG_QUALITY, 95])
            assert ok
            images.append(buf.tobytes())
    poses = [
        look_at_cam_to_world(np.array([0.1 * f, 0.02 * shard, -2.0]), np.array([0.1 * f, 0.0, 0.0])) for f in frames
    ]
    return TripleRow(
        sample_id=f"s{shard}/interp/{row}",
        scene_id=f"s{shard}",
        mode="interp",
        num_context=num_context,
        frame_index=np.array(frames),
        source_frame=3 * np.array(frames),
        images=[memoryview(b) for b in images],
        image_format="jpeg" if ext == ".jpg" else "png",
        width=np.full(v, w),
        height=np.full(v, h),
        intrinsics_norm=np.array([[0.9 + 0.01 * k, 1.2, 0.5 + 0.01 * k, 0.48] for k in range(v)]),
        cam_to_world=np.stack(poses),
        near=np.full(v, 0.5),
        far=np.full(v, 10.0 + shard),
        gap=gap,
        target_offset=np.zeros(num_target, np.int64),
    ).to_pydict()


def write_triples(
    root: str | Path,
    shard_rows: list[int],
    num_context: int = 2,
    num_target: int = 3,
    hw: tuple[int, int] = (24, 40),
    gaps: Callable[[int, int], int] | None = None,
    rows_fn: Callable[[int, int], dict] | None = None,
    record_batch_rows: int = 4,
) -> Path:
    """A triples dataset: shard k holds `shard_rows[k]` rows; manifest written last."""
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    schema = arrow_schema(SCHEMA)
    entries = []
    for k, n in enumerate(shard_rows):
        rows = [
            rows_fn(k, j)
            if rows_fn
            else row_dict(k, j, num_context, num_target, hw, gaps(k, j) if gaps else 5 + (j % 3))
            for j in range(n)
        ]
        table = pa.Table.from_pylist(rows, schema=schema)
        path = root / f"shard-{k:05d}.arrow"
        write_table(path, table, max_chunksize=record_batch_rows)
        entries.append(FileEntry.for_file(root, path, n))
    write_manifest(
        root,
        SCHEMA,
        schema_version(SCHEMA),
        entries,
        params={"test": True},
        provenance=provenance("tests.loader_fixtures"),
    )
    return root


def all_sample_ids(shard_rows: list[int]) -> list[str]:
    return [f"s{k}/interp/{j}" for k, n in enumerate(shard_rows) for j in range(n)]
