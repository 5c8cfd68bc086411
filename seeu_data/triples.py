"""Triple shards (`schemas/triples.v1.json`): build the rows of one shard, and read shards back.

A triples directory::

    manifest.json        written last (schema seeu.triples, files with rows/bytes/sha256, params, report)
    shard-00000.arrow    Arrow IPC files, uncompressed; schema metadata holds `seeu.shard_plan_sha256`
    shard-00001.arrow ...

Each row is self-contained: V context views then T target views, every per-view column a list of
V + T entries (frame_index, source_frame, image, width, height, intrinsics_norm, cam_to_world,
near, far), plus `gap` and per-target `target_offset`.

`build_shard_table(spec)` is a pure function of its `ShardSpec` (samples, where their posed rows
are, image options): the local process pool and the Ray engine both call it, which is why their
shards are byte-identical.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import numpy as np
import pyarrow as pa

from .arrow_io import deferred_binary, map_readonly, open_ipc_file, populate
from .errors import SeeUError
from .manifest import read_manifest
from .sampling import Sample, make_sample
from .schema import arrow_schema
from .triple_row import TripleRow

SCHEMA = "seeu.triples"
PLAN_KEY = b"seeu.shard_plan_sha256"
_POSED_COLUMNS = [
    "source_frame",
    "image",
    "image_format",
    "width",
    "height",
    "intrinsics_norm",
    "cam_to_world",
    "near",
    "far",
]
_PER_VIEW = (
    "frame_index",
    "source_frame",
    "image",
    "width",
    "height",
    "intrinsics_norm",
    "cam_to_world",
    "near",
    "far",
)


@dataclass(frozen=True)
class ImageOptions:
    """Build-time image handling. resize None: copy the encoded bytes as they are (no re-encode)."""

    resize: tuple[int, int] | None = None  # (H, W)
    interpolation: str = "area"
    jpeg_quality: int = 95

    def as_dict(self) -> dict:
        return {
            "resize": list(self.resize) if self.resize else None,
            "interpolation": self.interpolation,
            "jpeg_quality": self.jpeg_quality,
        }


def shard_schema(plan_sha256: str) -> pa.Schema:
    """The triples schema with this shard's plan hash in the metadata (identical in every engine)."""
    schema = arrow_schema(SCHEMA)
    meta = dict(schema.metadata)
    meta[PLAN_KEY] = plan_sha256.encode()
    return schema.with_metadata(meta)


@dataclass(frozen=True)
class SceneRows:
    """Where one scene's posed frames are: `num_frames` rows from `row_start` of the posed Arrow file
    `path` (absolute), whose sha256 is `file_sha256`."""

    path: str
    row_start: int
    num_frames: int
    file_sha256: str


@dataclass(frozen=True)
class ShardSpec:
    """One shard's plan, made on the build driver: its `samples` in row order, where their scenes'
    rows are (`sources`, by scene id), the image options, rows per record batch and the user's
    near/far override (None: the data's).

    `plan_sha256` (computed) hashes everything the shard's bytes depend on, the posed files by content
    (sha256 and rows), not by path: moving the posed data does not invalidate shards. `as_dict` /
    `from_dict`: its JSON form, for the Ray engine's rows.
    """

    index: int
    file: str
    samples: tuple[Sample, ...]
    sources: dict[str, SceneRows]
    image: ImageOptions
    rows_per_batch: int
    near_far: tuple[float, float] | None = None
    plan_sha256: str = field(init=False)

    def __post_init__(self) -> None:
        content: dict = {
            "samples": [s.as_dict() for s in self.samples],
            "image": self.image.as_dict(),
            "rows_per_batch": self.rows_per_batch,
            "sources": {
                sid: {"row_start": r.row_start, "num_frames": r.num_frames, "file_sha256": r.file_sha256}
                for sid, r in self.sources.items()
            },
        }
        if self.near_far is not None:  # absent unless overridden: older plans keep their hashes
            content["near_far"] = list(self.near_far)
        text = json.dumps(content, sort_keys=True, separators=(",", ":"))
        object.__setattr__(self, "plan_sha256", hashlib.sha256(text.encode()).hexdigest())

    def as_dict(self) -> dict:
        return {
            "index": self.index,
            "file": self.file,
            "samples": [s.as_dict() for s in self.samples],
            "sources": {sid: vars(r) for sid, r in self.sources.items()},
            "image": self.image.as_dict(),
            "rows_per_batch": self.rows_per_batch,
            "near_far": list(self.near_far) if self.near_far is not None else None,
        }

    @classmethod
    def from_dict(cls, d: dict) -> ShardSpec:
        image = d["image"]
        return cls(
            index=int(d["index"]),
            file=d["file"],
            samples=tuple(
                make_sample(s["scene_id"], s["mode"], s["k"], s["context"], s["target"]) for s in d["samples"]
            ),
            sources={sid: SceneRows(**r) for sid, r in d["sources"].items()},
            image=ImageOptions(
                tuple(image["resize"]) if image["resize"] else None, image["interpolation"], image["jpeg_quality"]
            ),
            rows_per_batch=int(d["rows_per_batch"]),
            near_far=tuple(d["near_far"]) if d.get("near_far") is not None else None,
        )


# ---------------------------------------------------------------------------------------------
# Building
# ---------------------------------------------------------------------------------------------


class _MappedFile:
    """A posed Arrow file mapped once per process: the table (zero-copy over the mapping) and which
    scenes' image pages are already populated."""

    def __init__(self, path: str):
        if not Path(path).exists():
            raise SeeUError("file not found", path)
        self.key = _file_key(path)
        self.mapping = map_readonly(path)
        buf = pa.py_buffer(self.mapping)
        self.base = buf.address
        try:
            self.table = pa.ipc.open_file(pa.BufferReader(buf)).read_all()
        except (pa.ArrowInvalid, OSError) as exc:
            raise SeeUError(
                f"not a readable Arrow IPC file (truncated or corrupt?): {exc}".splitlines()[0], path
            ) from None
        self.populated: set[str] = set()


_MAPPED: dict[str, _MappedFile] = {}  # path -> mapping, kept across shards: no map/unmap per shard
_MAX_MAPPED = 64


def _file_key(path: str) -> tuple[int, ...]:
    """Identity of a file's content for the mapping cache: a rewrite (a new inode: our writes rename
    a new file into place), a size or a modification time change maps it again."""
    st = os.stat(path)
    return (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)


def _mapped(path: str) -> _MappedFile:
    entry = _MAPPED.get(path)
    try:
        fresh = entry is not None and entry.key == _file_key(path)
    except OSError:
        fresh = False
    if not fresh:
        _MAPPED.pop(path, None)
        entry = _MappedFile(path)
        if len(_MAPPED) >= _MAX_MAPPED:
            _MAPPED.pop(next(iter(_MAPPED)))
        _MAPPED[path] = entry
    assert entry is not None
    return entry


class _SceneTables:
    """Posed rows per scene for one shard, from the process's mapped posed files (zero-copy reads)."""

    def __init__(self, sources: dict[str, SceneRows]):
        self.sources = sources
        self._files: dict[str, _MappedFile] = {}  # the same mapping for every scene of the shard

    def _file(self, scene_id: str) -> _MappedFile:
        path = self.sources[scene_id].path
        if path not in self._files:
            self._files[path] = _mapped(path)
        return self._files[path]

    def table(self, scene_id: str) -> pa.Table:
        src = self.sources[scene_id]
        path = src.path
        full = self._file(scene_id).table
        if src.row_start + src.num_frames > full.num_rows:
            raise SeeUError(
                f"scene {scene_id!r} rows {src.row_start}..{src.row_start + src.num_frames} "
                f"exceed the file's {full.num_rows} rows",
                path,
            )
        rows = full.slice(src.row_start, src.num_frames)
        first = rows.column("scene_id")[0].as_py()
        if first != scene_id:
            raise SeeUError(f"rows of scene {scene_id!r} hold scene {first!r} (manifest out of date?)", path)
        return rows.select(_POSED_COLUMNS)

    def image_views(self, scene_id: str, rows: pa.Table) -> list[memoryview]:
        """The scene's encoded images as views into the mapped file (no copy), their pages mapped at once."""
        mapped = self._file(scene_id)
        views: list[memoryview] = []
        for chunk in rows.column("image").chunks:
            _, offsets_buf, data_buf = chunk.buffers()
            offsets = np.frombuffer(offsets_buf, dtype=np.int32)[chunk.offset : chunk.offset + len(chunk) + 1]
            if len(chunk) and scene_id not in mapped.populated:
                populate(
                    mapped.mapping, data_buf.address - mapped.base + int(offsets[0]), int(offsets[-1] - offsets[0])
                )
            data = memoryview(data_buf)
            views.extend(data[a:b] for a, b in zip(offsets[:-1].tolist(), offsets[1:].tolist()))
        mapped.populated.add(scene_id)
        return views


def _list_column(offsets: pa.Array, values: pa.Array | pa.ChunkedArray, typ: pa.DataType) -> pa.Array:
    if isinstance(values, pa.ChunkedArray):
        values = values.combine_chunks()
    return pa.ListArray.from_arrays(offsets, values, type=typ)


def _resize_views(
    taken: pa.Table, view_scene: list[str], view_frame: np.ndarray, opts: ImageOptions, sources: dict[str, SceneRows]
) -> tuple[list[bytes], np.ndarray, np.ndarray, np.ndarray]:
    """Decode, resize + centre-crop and re-encode every view (cached per scene frame within the shard)."""
    from .image_ops import decode_rgb, encode_jpeg, encode_png, resize_cover_crop, resized_intrinsics

    assert opts.resize is not None
    out_h, out_w = opts.resize
    images = taken.column("image").to_pylist()
    fmts = taken.column("image_format").to_pylist()
    heights = taken.column("height").to_numpy()
    widths = taken.column("width").to_numpy()
    intr = taken.column("intrinsics_norm").combine_chunks().flatten().to_numpy().reshape(-1, 4)
    cache: dict[tuple[str, int], bytes] = {}
    out = []
    for i, (sid, f) in enumerate(zip(view_scene, view_frame)):
        key = (sid, int(f))
        if key not in cache:
            try:
                img = decode_rgb(images[i])
            except ValueError:
                raise SeeUError(
                    f"scene {sid!r} frame {int(f)}: image bytes cannot be decoded", sources[sid].path
                ) from None
            if img.shape[:2] != (heights[i], widths[i]):
                raise SeeUError(
                    f"scene {sid!r} frame {int(f)}: image is {img.shape[1]}x{img.shape[0]}, "
                    f"the table says {widths[i]}x{heights[i]}",
                    sources[sid].path,
                )
            img = resize_cover_crop(img, (out_h, out_w), opts.interpolation)
            cache[key] = encode_png(img) if fmts[i] == "png" else encode_jpeg(img, opts.jpeg_quality)
        out.append(cache[key])
    new_intr = (
        np.stack(
            [resized_intrinsics(intr[i], (int(heights[i]), int(widths[i])), (out_h, out_w)) for i in range(len(out))]
        )
        if out
        else np.zeros((0, 4))
    )
    n = len(out)
    return out, np.full(n, out_w, np.int32), np.full(n, out_h, np.int32), new_intr


def build_shard_table(spec: ShardSpec, deferred_images: bool = False) -> pa.Table:
    """Rows of one shard from its spec (one row per sample, in order; schema `shard_schema`).

    `deferred_images=True` (copy path only, i.e. no resize): the image column is an
    `arrow_io.deferred_binary` over views into the mapped posed files, for a table that is only
    written with `arrow_io.write_table*` (the bytes go from the posed files to the shard in one copy).
    """
    samples = spec.samples
    opts = spec.image
    tables = _SceneTables(spec.sources)
    scene_order: list[str] = []
    base: dict[str, int] = {}
    parts: list[pa.Table] = []
    for s in samples:
        if s.scene_id not in base:
            t = tables.table(s.scene_id)
            base[s.scene_id] = sum(p.num_rows for p in parts)
            parts.append(t)
            scene_order.append(s.scene_id)
        n = spec.sources[s.scene_id].num_frames
        if any(not 0 <= v < n for v in s.views):
            raise SeeUError(f"sample {s.sample_id}: frame index out of range 0..{n - 1}", spec.sources[s.scene_id].path)
    schema = shard_schema(spec.plan_sha256)
    if not samples:
        return schema.empty_table()
    posed = pa.concat_tables(parts) if len(parts) > 1 else parts[0]
    view_scene = [s.scene_id for s in samples for _ in s.views]
    view_frame = np.array([v for s in samples for v in s.views], dtype=np.int64)
    flat = np.array([base[s.scene_id] + v for s in samples for v in s.views], dtype=np.int64)
    deferred = deferred_images and opts.resize is None
    taken = posed.drop_columns(["image"]).take(pa.array(flat)) if deferred else posed.take(pa.array(flat))
    counts = np.array([len(s.views) for s in samples], dtype=np.int32)
    offsets = pa.array(np.concatenate([[0], np.cumsum(counts)]).astype(np.int32))

    if opts.resize is None:
        if deferred:
            scene_views = {sid: tables.image_views(sid, part) for sid, part in zip(scene_order, parts)}
            images = deferred_binary([scene_views[sid][int(f)] for sid, f in zip(view_scene, view_frame)])
        else:
            images = taken.column("image")
        width, height = taken.column("width"), taken.column("height")
        intr = taken.column("intrinsics_norm")
    else:
        imgs, w, h, intr_np = _resize_views(taken, view_scene, view_frame, opts, spec.sources)
        images = pa.array(imgs, pa.binary())
        width, height = pa.array(w), pa.array(h)
        intr = pa.FixedSizeListArray.from_arrays(pa.array(intr_np.reshape(-1)), 4)
    per_view = {
        "frame_index": pa.array(view_frame.astype(np.int32)),
        "source_frame": taken.column("source_frame"),
        "image": images,
        "width": width,
        "height": height,
        "intrinsics_norm": intr,
        "cam_to_world": taken.column("cam_to_world"),
        "near": taken.column("near"),
        "far": taken.column("far"),
    }
    if spec.near_far is not None:  # `seeu build --near/--far`: the user's bounds instead of the data's
        for key, value in zip(("near", "far"), spec.near_far):
            per_view[key] = pa.array(np.full(len(flat), value), per_view[key].type)
    fmt_col = taken.column("image_format")
    first_view = np.concatenate([[0], np.cumsum(counts)[:-1]])
    row_fmt = [fmt_col[int(i)].as_py() for i in first_view]
    tgt_counts = np.array([len(s.target) for s in samples], dtype=np.int32)
    cols = {
        "sample_id": pa.array([s.sample_id for s in samples], pa.string()),
        "scene_id": pa.array([s.scene_id for s in samples], pa.string()),
        "mode": pa.array([s.mode for s in samples], pa.string()),
        "num_context": pa.array(np.array([len(s.context) for s in samples], dtype=np.int32)),
        "image_format": pa.array(row_fmt, pa.string()),
        "gap": pa.array(np.array([s.gap for s in samples], dtype=np.int32)),
        "target_offset": pa.ListArray.from_arrays(
            pa.array(np.concatenate([[0], np.cumsum(tgt_counts)]).astype(np.int32)),
            pa.array(np.array([o for s in samples for o in s.target_offset], dtype=np.int32)),
        ),
    }
    for name in _PER_VIEW:
        cols[name] = _list_column(offsets, per_view[name], schema.field(name).type)
    arrays = []
    for f in schema:
        col = cols[f.name]
        if col.type != f.type:  # e.g. list field nullability: cast to the schema's exact type
            col = col.cast(f.type)
        arrays.append(col)
    return pa.Table.from_arrays(arrays, schema=schema)


# ---------------------------------------------------------------------------------------------
# Reading
# ---------------------------------------------------------------------------------------------


class TripleShards:
    """Read a triples directory: manifest checked (sha256 optional), shards memory-mapped, in order."""

    def __init__(self, root: str | Path, verify: bool = False):
        self.root = Path(root)
        self.manifest = read_manifest(self.root, expect_schema=SCHEMA, verify=verify)

    @property
    def files(self) -> list[str]:
        return [e["path"] for e in self.manifest["files"]]

    def __len__(self) -> int:
        return int(self.manifest["total_rows"])

    def read_shard(self, i: int, columns: list[str] | None = None) -> pa.Table:
        table = open_ipc_file(self.root / self.files[i]).read_all()
        return table.select(columns) if columns else table

    def read_columns(self, columns: list[str]) -> pa.Table:
        """Selected columns of every shard, concatenated in manifest order (images untouched if unselected)."""
        parts = [self.read_shard(i, columns) for i in range(len(self.files))]
        return pa.concat_tables(parts) if parts else arrow_schema(SCHEMA).empty_table().select(columns)

    def iter_rows(self) -> Iterator[TripleRow]:
        for i in range(len(self.files)):
            table = self.read_shard(i)
            for batch in table.to_batches():
                for d in batch.to_pylist():
                    yield TripleRow.from_pydict(d)

    def rows(self) -> list[TripleRow]:
        return list(self.iter_rows())
