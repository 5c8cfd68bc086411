"""Posed-frames datasets: the output of `seeu ingest` and `seeu import`, the input of `seeu build`.

Layout of a posed-frames directory::

    manifest.json          written last (schema seeu.posed_frames, files, scenes, params, provenance)
    posed-00000.arrow      Arrow IPC files; each holds whole scenes, one record batch per scene
    posed-00001.arrow ...

    overlap-posed-00000.arrow ...   the view-overlap table of each posed file's scenes (`overlap_table`)

Rows follow `schemas/posed_frames.v1.json`; cameras follow `seeu_data.cameras`.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa

from seeu_data.errors import SeeUError
from seeu_data.overlap import OverlapTable, overlap_from_cameras, overlap_from_observations
from seeu_data.store.arrow_io import AtomicIpcWriter, BytesLike, ReleasableIpcFile, binary_array
from seeu_data.store.manifest import FileEntry, read_manifest, write_manifest
from seeu_data.store.overlap_table import OverlapReader, manifest_block, write_overlap_file
from seeu_data.store.schema import arrow_schema, schema_version

SCHEMA = "seeu.posed_frames"
POSED_FILES = "posed-*.arrow"  # glob of the files `PosedDatasetWriter` writes (default prefix)


@dataclass
class PosedScene:
    """All frames of one scene (posed chunk), in frame_index order. N = number of frames.

    images: N encoded images (bytes, or read-only bytes-like views such as numpy uint8 arrays into a
    memory-mapped input file); width/height: (N,) int; intrinsics_norm: (N, 4);
    cam_to_world: (N, 4, 4) OpenCV camera-to-world; source_frame/timestamp_us: (N,) int64;
    source_name: N strings; meta: scene-level metadata kept in the manifest (url, near/far method ...);
    masks: None (the scene has none) or N entries, each a frame's mask as PNG bytes (8-bit single
    channel, the frame's size, nonzero = excluded pixel: `seeu_data.masks.encode_mask`) or None (no
    mask for that frame).
    """

    scene_id: str
    images: Sequence[BytesLike]
    image_format: str
    width: np.ndarray
    height: np.ndarray
    intrinsics_norm: np.ndarray
    cam_to_world: np.ndarray
    near: float
    far: float
    source_frame: np.ndarray
    timestamp_us: np.ndarray
    source_name: list[str] = field(default_factory=list)
    meta: dict = field(default_factory=dict)
    masks: Sequence[BytesLike | None] | None = None
    overlap: OverlapTable | None = None  # its view overlap, once measured (an import's readers measure it)

    def __len__(self) -> int:
        return len(self.images)

    def check(self) -> None:
        """Raise SeeUError when the scene is inconsistent, its cameras are not finite rigid poses
        (`dataset_check.check_cameras`) or a mask is not a greyscale PNG of its frame's size (`check_mask`)."""
        from seeu_data.store.dataset_check import check_cameras, check_mask

        n = len(self.images)
        where = f"scene {self.scene_id}"
        if n == 0:
            raise SeeUError(f"{where}: no frames")
        for name in ("width", "height", "source_frame", "timestamp_us"):
            if len(getattr(self, name)) != n:
                raise SeeUError(f"{where}: {name} has {len(getattr(self, name))} entries for {n} frames")
        if self.source_name and len(self.source_name) != n:
            raise SeeUError(f"{where}: source_name has {len(self.source_name)} entries for {n} frames")
        if np.shape(self.intrinsics_norm) != (n, 4) or np.shape(self.cam_to_world) != (n, 4, 4):
            raise SeeUError(
                f"{where}: cameras have shapes {np.shape(self.intrinsics_norm)} / {np.shape(self.cam_to_world)}, expected ({n}, 4) / ({n}, 4, 4)"
            )
        if not (0 < self.near < self.far and np.isfinite(self.far)):
            raise SeeUError(f"{where}: invalid near/far {self.near}/{self.far}")
        check_cameras(self.cam_to_world, self.intrinsics_norm, np.array([self.near]), np.array([self.far]), where)
        if self.image_format not in ("jpeg", "png"):
            raise SeeUError(f"{where}: image_format must be 'jpeg' or 'png', got {self.image_format!r}")
        if self.masks is not None:
            if len(self.masks) != n:
                raise SeeUError(f"{where}: masks has {len(self.masks)} entries for {n} frames")
            for i, mask in enumerate(self.masks):
                if mask is not None:
                    check_mask(mask, self.width[i], self.height[i], f"{where} frame {i}")

    def to_record_batch(self) -> pa.RecordBatch:
        """The scene's rows (its images copied into one column)."""
        n = len(self)
        schema = arrow_schema(SCHEMA)
        names = self.source_name or [""] * n
        cols = {
            "scene_id": pa.array([self.scene_id] * n, pa.string()),
            "frame_index": pa.array(np.arange(n, dtype=np.int32)),
            "source_frame": pa.array(np.asarray(self.source_frame, dtype=np.int64)),
            "source_name": pa.array(names, pa.string()),
            "timestamp_us": pa.array(np.asarray(self.timestamp_us, dtype=np.int64)),
            "image": binary_array(self.images),
            "image_format": pa.array([self.image_format] * n, pa.string()),
            "width": pa.array(np.asarray(self.width, dtype=np.int32)),
            "height": pa.array(np.asarray(self.height, dtype=np.int32)),
            "intrinsics_norm": pa.FixedSizeListArray.from_arrays(
                pa.array(np.asarray(self.intrinsics_norm, dtype=np.float64).reshape(-1)), 4
            ),
            "cam_to_world": pa.FixedSizeListArray.from_arrays(
                pa.array(np.asarray(self.cam_to_world, dtype=np.float64).reshape(-1)), 16
            ),
            "near": pa.array(np.full(n, self.near, dtype=np.float32)),
            "far": pa.array(np.full(n, self.far, dtype=np.float32)),
            "mask": pa.array(
                [None if m is None else memoryview(m).cast("B").tobytes() for m in self.masks or [None] * n],  # type: ignore[arg-type]
                pa.binary(),
            ),
        }
        return pa.RecordBatch.from_arrays([cols[f.name] for f in schema], schema=schema)

    @classmethod
    def from_record_batch(cls, batch: pa.RecordBatch | pa.Table, meta: dict | None = None) -> PosedScene:
        def fixed(name: str, k: int) -> np.ndarray:
            col = batch.column(name)
            if isinstance(col, pa.ChunkedArray):
                col = col.combine_chunks()
            return col.values.to_numpy(zero_copy_only=False).reshape(-1, k)

        scene_ids = batch.column("scene_id")
        fmt = batch.column("image_format")
        has_masks = "mask" in batch.schema.names and batch.column("mask").null_count < batch.num_rows
        return cls(
            scene_id=str(scene_ids[0]),
            images=batch.column("image").to_pylist(),
            image_format=str(fmt[0]),
            width=batch.column("width").to_numpy(),
            height=batch.column("height").to_numpy(),
            intrinsics_norm=fixed("intrinsics_norm", 4),
            cam_to_world=fixed("cam_to_world", 16).reshape(-1, 4, 4),
            near=float(batch.column("near")[0].as_py()),
            far=float(batch.column("far")[0].as_py()),
            source_frame=batch.column("source_frame").to_numpy(),
            timestamp_us=batch.column("timestamp_us").to_numpy(),
            source_name=batch.column("source_name").to_pylist(),
            meta=dict(meta or {}),
            masks=batch.column("mask").to_pylist() if has_masks else None,
        )


class PosedDatasetWriter:
    """Stream scenes into a posed-frames directory with bounded memory.

    Scenes are appended to the current file until it exceeds `target_file_bytes`; each file is
    written under a temporary name, hashed and renamed when closed (`arrow_io.AtomicIpcWriter`),
    followed by its overlap file (each scene's `scene_overlap`, `store.overlap_table`);
    `close()` writes the manifest last.
    Use as a context manager: an exception leaves no manifest, so the output never looks complete.
    """

    def __init__(
        self,
        out_dir: str | Path,
        params: dict,
        provenance: dict,
        target_file_bytes: int = 256 << 20,
        prefix: str = "posed",
        fsync: bool = False,
    ):
        self.out_dir = Path(out_dir)
        self.fsync = fsync
        self.params = params
        self.provenance = provenance
        self.target_file_bytes = target_file_bytes
        self.prefix = prefix
        self.files: list[FileEntry] = []  # closed files
        self.overlap_files: list[dict] = []  # their overlap files' manifest entries
        self._overlap_rows: list[tuple[str, OverlapTable]] = []  # the open file's scenes
        self.scenes: list[dict] = []
        self._seen: set[str] = set()
        self._writer: AtomicIpcWriter | None = None
        self._path: Path | None = None
        self._rows = 0
        self._bytes = 0
        self.report: dict = {}
        self.out_dir.mkdir(parents=True, exist_ok=True)
        (self.out_dir / "manifest.json").unlink(missing_ok=True)  # being rewritten: not complete

    def __enter__(self) -> PosedDatasetWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        elif self._writer is not None:
            self._writer.abort()  # removes the temporary file
            self._writer = None

    def add(self, scene: PosedScene, may_close: bool = True) -> None:
        """Check the scene (`PosedScene.check`) and append it to the open file. `may_close=False` keeps
        the file open past the target size (importers close files only at unit ends)."""
        scene.check()
        self.add_checked(scene, may_close)

    def add_checked(self, scene: PosedScene, may_close: bool = True) -> None:
        """`add` for a scene already `check()`ed."""
        if scene.scene_id in self._seen:
            raise SeeUError(f"duplicate scene id {scene.scene_id!r}")
        self._seen.add(scene.scene_id)
        if self._writer is None:
            self._open()
        assert self._path is not None and self._writer is not None
        batch = scene.to_record_batch()
        self._writer.write(batch)
        self._overlap_rows.append((scene.scene_id, scene_overlap(scene)))
        entry = {
            "scene_id": scene.scene_id,
            "file": self._path.name,
            "row_start": self._rows,
            "num_frames": len(scene),
            "near": float(scene.near),
            "far": float(scene.far),
        }
        if scene.meta:
            entry["meta"] = scene.meta
        self.scenes.append(entry)
        self._rows += batch.num_rows
        self._bytes += batch.nbytes
        if may_close and self._bytes >= self.target_file_bytes:
            self._finish_file()

    def _open(self) -> None:
        self._path = self.out_dir / f"{self.prefix}-{len(self.files):05d}.arrow"
        self._writer = AtomicIpcWriter(self._path, arrow_schema(SCHEMA), fsync=self.fsync)
        self._rows = 0
        self._bytes = 0

    def _finish_file(self) -> None:
        if self._writer is None:
            return
        writer, self._writer = self._writer, None
        size = writer.close()
        assert self._path is not None
        name = str(self._path.relative_to(self.out_dir))
        self.files.append(FileEntry(name, int(self._rows), size, writer.sha256))
        self.overlap_files.append(write_overlap_file(self.out_dir, name, self._overlap_rows, self.fsync))
        self._overlap_rows = []

    def close(self) -> dict:
        self._finish_file()
        if not self.scenes:
            raise SeeUError("no usable scene to write", self.out_dir)
        return write_manifest(
            self.out_dir,
            SCHEMA,
            schema_version(SCHEMA),
            self.files,
            self.params,
            self.provenance,
            scenes=self.scenes,
            report=self.report or None,
            fsync=self.fsync,
            overlap=manifest_block(self.overlap_files),
        )


class _PosedFile:
    """The posed file a `PosedDataset` reads now: its map, and record batch by first row."""

    def __init__(self, root: Path, name: str):
        self.name = name
        self.file = ReleasableIpcFile(root / name)
        self.table = self.file.table()
        self.batches = self.table.to_batches()
        starts = np.cumsum([0] + [b.num_rows for b in self.batches])
        self.batch_at_row = {int(row): i for i, row in enumerate(starts[:-1])}

    def rows(self, row_start: int, num_rows: int) -> pa.RecordBatch | pa.Table:
        """Rows `[row_start, row_start + num_rows)`: their record batch, or a slice of the table when a
        scene was written as several batches. The pages read for the previous call are given back first."""
        self.file.release()
        i = self.batch_at_row.get(row_start)
        if i is not None and self.batches[i].num_rows == num_rows:
            return self.batches[i]
        return self.table.slice(row_start, num_rows)


class PosedDataset:
    """Read a posed-frames directory: manifest checked, scenes by id.

    One file is open at a time, and the pages each read touched are given back before the next
    (`arrow_io.ReleasableIpcFile`): a pass over the scenes in manifest order (build, index) keeps a
    resident size of about one scene, whatever the size of the data set."""

    def __init__(self, root: str | Path, verify: bool = False):
        self.root = Path(root)
        self.manifest = read_manifest(self.root, expect_schema=SCHEMA, verify=verify)
        self._scenes = {s["scene_id"]: s for s in self.manifest.get("scenes", [])}
        self._file: _PosedFile | None = None
        self._overlaps = OverlapReader(self.root, self.manifest)

    @property
    def scene_ids(self) -> list[str]:
        return list(self._scenes)

    def scene_info(self, scene_id: str) -> dict:
        if scene_id not in self._scenes:
            raise SeeUError(f"no scene {scene_id!r} in this dataset", self.root)
        return self._scenes[scene_id]

    def __len__(self) -> int:
        return len(self._scenes)

    def _rows(self, info: dict) -> pa.RecordBatch | pa.Table:
        if self._file is None or self._file.name != info["file"]:
            self._file = None  # the previous file's map goes (with the last buffer of it still held)
            self._file = _PosedFile(self.root, info["file"])
        return self._file.rows(info["row_start"], info["num_frames"])

    def load_scene(self, scene_id: str) -> PosedScene:
        info = self.scene_info(scene_id)
        scene = PosedScene.from_record_batch(self._rows(info), info.get("meta"))
        if scene.scene_id != scene_id:
            raise SeeUError(
                f"manifest points scene {scene_id!r} at rows holding {scene.scene_id!r}", self.root / info["file"]
            )
        return scene

    def iter_scenes(self, scene_ids: Iterable[str] | None = None) -> Iterator[PosedScene]:
        for sid in scene_ids if scene_ids is not None else self.scene_ids:
            yield self.load_scene(sid)

    def load_cameras(self, scene_id: str) -> tuple[np.ndarray, np.ndarray, float, float]:
        """A scene's cameras without its images: cam_to_world (N, 4, 4), intrinsics_norm (N, 4), near, far
        (copies: nothing of the map is held)."""
        rows = self._rows(self.scene_info(scene_id)).select(["cam_to_world", "intrinsics_norm", "near", "far"])

        def flat(name: str, k: int) -> np.ndarray:
            col = rows.column(name)
            col = col.combine_chunks() if isinstance(col, pa.ChunkedArray) else col
            return np.array(col.values.to_numpy(zero_copy_only=False)).reshape(-1, k)

        near, far = rows.column("near")[0].as_py(), rows.column("far")[0].as_py()
        return flat("cam_to_world", 16).reshape(-1, 4, 4), flat("intrinsics_norm", 4), float(near), float(far)

    def stored_overlap(self, scene_id: str) -> OverlapTable | None:
        """The scene's stored overlap table (`store.overlap_table`), None when the dataset has none."""
        return self._overlaps.table(scene_id)

    def overlap(self, scene_id: str) -> OverlapTable:
        """The scene's stored overlap table; measured from its cameras when the dataset was written
        without one (`seeu overlap` stores it)."""
        table = self._overlaps.table(scene_id)
        if table is not None:
            return table
        c2w, intr, near, far = self.load_cameras(scene_id)
        return overlap_from_cameras(c2w, intr, near, far)


@dataclass
class TrackedScene(PosedScene):
    """A `PosedScene` with its structure-from-motion observations (an ingest's or a COLMAP model's), from
    which its view overlap is measured: `observations` = (frame index (M,), 3D point id (M,)) of every
    observation of a 3D point."""

    observations: tuple[np.ndarray, np.ndarray] | None = None


def scene_overlap(scene: PosedScene) -> OverlapTable:
    """The view overlap of a scene (`seeu_data.overlap`): from its SfM observations when it is a
    `TrackedScene` with some, else from its cameras and near/far (`scene.overlap` when measured already)."""
    if scene.overlap is not None:
        return scene.overlap
    if isinstance(scene, TrackedScene) and scene.observations is not None and len(scene.observations[0]):
        return overlap_from_observations(len(scene), *scene.observations)
    # near/far as stored (float32), so the table measured again from the written scene is the same
    near, far = float(np.float32(scene.near)), float(np.float32(scene.far))
    return overlap_from_cameras(scene.cam_to_world, scene.intrinsics_norm, near, far)
