"""The stored view-overlap table of a posed-frames dataset (`schemas/overlap.v1.json`).

Beside every posed file `posed-XXXXX.arrow` the writer puts `overlap-posed-XXXXX.arrow`: one row per
scene of that file, in its order, the scene's `seeu_data.overlap.OverlapTable` in list columns. The
manifest lists them in its `overlap` block (written last with the rest of the manifest)::

    "overlap": {"schema": "seeu.overlap", "schema_version": "1.0", "params": {floor, max_partners, grid, depths},
                "files": [{"path", "rows", "bytes", "sha256", "posed": the posed file it covers}]}

A dataset written before overlap tables existed has no block: `seeu overlap DIR` adds one, and the
stages that need overlap compute it from the cameras meanwhile (`scene_overlap`).

    reader = OverlapReader(root, manifest)
    table = reader.table(scene_id)          # OverlapTable, or None when the dataset stores none
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa

from seeu_data.errors import SeeUError
from seeu_data.overlap import DEPTHS, FLOOR, GRID, MAX_PARTNERS, METHODS, OverlapTable
from seeu_data.store.arrow_io import ReleasableIpcFile, write_table
from seeu_data.store.schema import arrow_schema, schema_version

SCHEMA = "seeu.overlap"
MANIFEST_KEY = "overlap"
OVERLAP_FILES = "overlap-*.arrow"
PARAMS = {"floor": FLOOR, "max_partners": MAX_PARTNERS, "grid": GRID, "depths": DEPTHS}


def overlap_file_name(posed_file: str) -> str:
    """The overlap file of a posed file: `overlap-<its name>`, in the same directory."""
    p = Path(posed_file)
    return str(p.with_name(f"overlap-{p.name}"))


def to_arrow(rows: list[tuple[str, OverlapTable]]) -> pa.Table:
    """One row per (scene id, table)."""

    def lists(values: list[np.ndarray], dtype, arrow_type) -> pa.ListArray:
        offsets = np.concatenate([[0], np.cumsum([len(v) for v in values])]).astype(np.int32)
        flat = np.concatenate(values).astype(dtype) if values else np.zeros(0, dtype)
        return pa.ListArray.from_arrays(pa.array(offsets), pa.array(flat, arrow_type))

    tables = [t for _, t in rows]
    cols = {
        "scene_id": pa.array([sid for sid, _ in rows], pa.string()),
        "num_frames": pa.array([t.num_frames for t in tables], pa.int32()),
        "method": pa.array([t.method for t in tables], pa.string()),
        "frame_a": lists([t.frame_a for t in tables], np.int32, pa.int32()),
        "frame_b": lists([t.frame_b for t in tables], np.int32, pa.int32()),
        "overlap_ab": lists([t.overlap_ab for t in tables], np.float32, pa.float32()),
        "overlap_ba": lists([t.overlap_ba for t in tables], np.float32, pa.float32()),
    }
    schema = arrow_schema(SCHEMA)
    return pa.Table.from_arrays([cols[f.name] for f in schema], schema=schema)


class _Rows:
    """An overlap file's table read a row at a time (the list columns' offsets and values as arrays:
    views of the file's map, nothing decoded ahead)."""

    LISTS = ("frame_a", "frame_b", "overlap_ab", "overlap_ba")

    def __init__(self, table: pa.Table):
        self.scene_ids = table.column("scene_id").to_pylist()
        self.num_frames = table.column("num_frames").to_pylist()
        self.method = table.column("method").to_pylist()
        combined = {name: table.column(name).combine_chunks() for name in self.LISTS}
        self.lists = {name: (col.offsets.to_numpy(), col.values.to_numpy()) for name, col in combined.items()}

    def table(self, i: int) -> OverlapTable:
        """Row `i` (copies)."""
        part = {name: np.array(values[offsets[i] : offsets[i + 1]]) for name, (offsets, values) in self.lists.items()}
        return OverlapTable(
            int(self.num_frames[i]),
            part["frame_a"].astype(np.int32),
            part["frame_b"].astype(np.int32),
            part["overlap_ab"].astype(np.float32),
            part["overlap_ba"].astype(np.float32),
            str(self.method[i]),
        )


def from_arrow(table: pa.Table) -> dict[str, OverlapTable]:
    """Scene id -> OverlapTable of every row."""
    rows = _Rows(table)
    return {sid: rows.table(i) for i, sid in enumerate(rows.scene_ids)}


def write_overlap_file(root: Path, posed_file: str, rows: list[tuple[str, OverlapTable]], fsync: bool = False) -> dict:
    """Write the overlap file of `posed_file` (relative to `root`) atomically; its manifest entry."""
    path = overlap_file_name(posed_file)
    nbytes, sha = write_table(Path(root) / path, to_arrow(rows), fsync=fsync)
    return {"path": path, "rows": len(rows), "bytes": int(nbytes), "sha256": sha, "posed": posed_file}


def manifest_block(files: list[dict]) -> dict:
    """The manifest's `overlap` block for these files."""
    return {"schema": SCHEMA, "schema_version": schema_version(SCHEMA), "params": dict(PARAMS), "files": files}


def check_overlap_table(table: pa.Table, frames: dict[str, int], where: str | Path) -> None:
    """An overlap file's rows against the scenes of its posed file (`frames`: scene id -> frame count,
    in the file's order): one row per scene in that order, frame indices 0 <= a < b < n, strictly
    increasing pairs, overlaps in [0, 1], a known method."""
    ids = table.column("scene_id").to_pylist()
    if ids != list(frames):
        raise SeeUError(f"overlap rows name scenes {ids[:3]}..., the posed file holds {list(frames)[:3]}...", where)
    for sid, t in from_arrow(table).items():
        n = frames[sid]
        what = f"scene {sid!r} overlap"
        if t.num_frames != n:
            raise SeeUError(f"{what}: num_frames {t.num_frames}, the scene has {n}", where)
        if t.method not in METHODS:
            raise SeeUError(f"{what}: unknown method {t.method!r}", where)
        lengths = {len(t.frame_a), len(t.frame_b), len(t.overlap_ab), len(t.overlap_ba)}
        if len(lengths) != 1:
            raise SeeUError(f"{what}: its lists have different lengths", where)
        a, b = t.frame_a.astype(np.int64), t.frame_b.astype(np.int64)
        if len(a) and not ((a >= 0).all() and (a < b).all() and (b < n).all()):
            raise SeeUError(f"{what}: a pair is not 0 <= frame_a < frame_b < {n}", where)
        if len(a) > 1 and not (np.diff(a * n + b) > 0).all():
            raise SeeUError(f"{what}: pairs repeat or are not in (frame_a, frame_b) order", where)
        values = np.concatenate([t.overlap_ab, t.overlap_ba])
        if not (np.isfinite(values).all() and (values >= 0).all() and (values <= 1).all()):
            raise SeeUError(f"{what}: an overlap is not in [0, 1]", where)


class OverlapReader:
    """The stored tables of one posed dataset, read a file at a time and a row at a time (the pages a row
    touched are given back before the next: `arrow_io.ReleasableIpcFile`)."""

    def __init__(self, root: str | Path, manifest: dict):
        self.root = Path(root)
        block = manifest.get(MANIFEST_KEY) or {}
        by_posed = {f["posed"]: f["path"] for f in block.get("files", [])}
        self._file_of = {s["scene_id"]: by_posed.get(s["file"]) for s in manifest.get("scenes", [])}
        self._open: tuple[str, ReleasableIpcFile, _Rows, dict[str, int]] | None = None

    @property
    def stored(self) -> bool:
        """True when every scene has a stored table."""
        return bool(self._file_of) and all(self._file_of.values())

    def table(self, scene_id: str) -> OverlapTable | None:
        """The stored table of `scene_id`, or None when the dataset stores none for it."""
        path = self._file_of.get(scene_id)
        if path is None:
            return None
        if self._open is None or self._open[0] != path:
            self._open = None
            file = ReleasableIpcFile(self.root / path)
            rows = _Rows(file.reader.read_all())
            self._open = (path, file, rows, {sid: i for i, sid in enumerate(rows.scene_ids)})
        _, file, rows, index = self._open
        file.release()
        i = index.get(scene_id)
        return None if i is None else rows.table(i)
