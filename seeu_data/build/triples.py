"""Triple shards (`schemas/triples.v1.json`): build the rows of one shard, and read shards back.

A triples directory::

    manifest.json        written last (schema seeu.triples, files with rows/bytes/sha256, params, report)
    shard-00000.arrow    Arrow IPC files, uncompressed; schema metadata holds `seeu.shard_plan_sha256`
    shard-00001.arrow ...

Each row is self-contained: V context views then T target views, every per-view column a list of
V + T entries (frame_index, source_frame, image, width, height, intrinsics_norm, cam_to_world,
near, far, mask: null for a view without one), plus `gap` and per-target `target_offset`.

`write_shard(spec, path)` writes the shard of a `ShardSpec` (samples, where their posed rows are,
image options), a pure function of it: the local process pool and the Ray engine both call it,
which is why their shards are byte-identical.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa

from seeu_data.build.sampling import Sample, make_sample
from seeu_data.errors import SeeUError
from seeu_data.settings import parse_dims, setting
from seeu_data.store.arrow_io import ReleasableIpcFile, binary_array, open_ipc_file, write_table
from seeu_data.store.manifest import read_manifest
from seeu_data.store.schema import arrow_schema
from seeu_data.store.triple_row import TripleRow

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


@dataclass(frozen=True)
class ImageOptions:
    """Build-time image handling. resize None: copy the encoded bytes as they are (no re-encode)."""

    resize: tuple[int, int] | None = setting(
        None,
        "resize + centre-crop at build time (intrinsics updated), e.g. 256x256; "
        "default: copy the encoded images as they are",
        parse=parse_dims,
        metavar="HxW",
    )  # (H, W)
    interpolation: str = setting(
        "area", "resize filter (INTER_AREA when shrinking)", choices=("area", "lanczos", "linear", "cubic")
    )
    jpeg_quality: int = setting(95, "JPEG quality of resized images")

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


def _posed_rows(spec: ShardSpec, scene_id: str, files: dict[str, tuple[ReleasableIpcFile, pa.Table]]) -> pa.Table:
    """The posed rows of one scene (`_POSED_COLUMNS`), zero-copy over its memory-mapped file (opened
    once per shard: `files`, path -> the file and its table)."""
    src = spec.sources[scene_id]
    if src.path not in files:
        file = ReleasableIpcFile(src.path)
        files[src.path] = (file, file.table())
    full = files[src.path][1]
    if src.row_start + src.num_frames > full.num_rows:
        raise SeeUError(
            f"scene {scene_id!r} rows {src.row_start}..{src.row_start + src.num_frames} "
            f"exceed the file's {full.num_rows} rows",
            src.path,
        )
    rows = full.slice(src.row_start, src.num_frames)
    first = rows.column("scene_id")[0].as_py()
    if first != scene_id:
        raise SeeUError(f"rows of scene {scene_id!r} hold scene {first!r} (manifest out of date?)", src.path)
    rows = rows.select(_POSED_COLUMNS + [c for c in ("mask",) if c in rows.schema.names])
    if "mask" not in rows.schema.names:  # posed frames of schema 1.0: no masks
        rows = rows.append_column("mask", pa.nulls(rows.num_rows, pa.binary()))
    return rows


def _value_views(column: pa.ChunkedArray) -> list[memoryview]:
    """The values of a binary column as views into its buffers (no copy)."""
    views: list[memoryview] = []
    for chunk in column.chunks:
        _, offsets_buf, data_buf = chunk.buffers()
        offsets = np.frombuffer(offsets_buf, dtype=np.int32)[chunk.offset : chunk.offset + len(chunk) + 1].tolist()
        data = memoryview(data_buf)
        views.extend(data[a:b] for a, b in zip(offsets[:-1], offsets[1:]))
    return views


def _list_column(offsets: pa.Array, values: pa.Array | pa.ChunkedArray, typ: pa.DataType) -> pa.Array:
    if isinstance(values, pa.ChunkedArray):
        values = values.combine_chunks()
    return pa.ListArray.from_arrays(offsets, values, type=typ)


def _resize_views(
    taken: pa.Table,
    images: list[memoryview],
    view_scene: list[str],
    view_frame: np.ndarray,
    opts: ImageOptions,
    sources: dict[str, SceneRows],
) -> tuple[list[bytes], np.ndarray, np.ndarray, np.ndarray, list[bytes | None]]:
    """Decode, resize + centre-crop and re-encode every view and its mask (`masks.resize_mask`; cached
    per scene frame within the shard)."""
    from seeu_data.image_ops import decode_rgb, encode_jpeg, encode_png, resize_cover_crop, resized_intrinsics
    from seeu_data.masks import decode_mask, encode_mask, resize_mask

    assert opts.resize is not None
    out_h, out_w = opts.resize
    fmts = taken.column("image_format").to_pylist()
    heights = taken.column("height").to_numpy()
    widths = taken.column("width").to_numpy()
    intr = taken.column("intrinsics_norm").combine_chunks().flatten().to_numpy().reshape(-1, 4)
    masks_in = taken.column("mask").to_pylist()
    cache: dict[tuple[str, int], bytes] = {}
    mask_cache: dict[tuple[str, int], bytes | None] = {}
    out, masks = [], []
    for i, (sid, f) in enumerate(zip(view_scene, view_frame)):
        key = (sid, int(f))
        if key not in cache:
            where = f"{sources[sid].path} scene {sid!r} frame {int(f)}"
            img = decode_rgb(images[i], where, int(heights[i]) * int(widths[i]))  # the recorded size, checked
            if img.shape[:2] != (heights[i], widths[i]):
                raise SeeUError(
                    f"scene {sid!r} frame {int(f)}: image is {img.shape[1]}x{img.shape[0]}, "
                    f"the table says {widths[i]}x{heights[i]}",
                    sources[sid].path,
                )
            img = resize_cover_crop(img, (out_h, out_w), opts.interpolation)
            cache[key] = encode_png(img) if fmts[i] == "png" else encode_jpeg(img, opts.jpeg_quality)
            mask = masks_in[i]
            where = f"scene {sid!r} frame {int(f)}"
            mask_cache[key] = (
                None if mask is None else encode_mask(resize_mask(decode_mask(mask, where), (out_h, out_w)))
            )
        out.append(cache[key])
        masks.append(mask_cache[key])
    new_intr = (
        np.stack(
            [resized_intrinsics(intr[i], (int(heights[i]), int(widths[i])), (out_h, out_w)) for i in range(len(out))]
        )
        if out
        else np.zeros((0, 4))
    )
    n = len(out)
    return out, np.full(n, out_w, np.int32), np.full(n, out_h, np.int32), new_intr, masks


def _take_releasing(table: pa.Table, rows: np.ndarray, release: Callable[[], None], block: int = 1 << 14) -> pa.Table:
    """`table.take(rows)` (rows `(K,) int64`), `block` rows of the table at a time with `release()` after
    each: a take over a whole shard's posed rows at once made every page of them resident."""
    order = np.argsort(rows, kind="stable")
    ascending = rows[order]
    pieces = []
    for lo in range(0, table.num_rows, block):
        a, b = np.searchsorted(ascending, [lo, lo + block])
        if b > a:
            pieces.append(table.slice(lo, block).take(pa.array(ascending[a:b] - lo)))
            release()
    return pa.concat_tables(pieces).take(pa.array(np.argsort(order)))


def build_shard_table(spec: ShardSpec) -> pa.Table:
    """The table of one shard from its spec (one row per sample, in order; schema `shard_schema`), its
    images (views into the memory-mapped posed files, or re-encoded bytes when resizing) copied into one column."""
    samples = spec.samples
    opts = spec.image
    files: dict[str, tuple[ReleasableIpcFile, pa.Table]] = {}

    def release() -> None:  # the posed pages read so far given back: a shard's sources are not all resident
        for file, _ in files.values():
            file.release()

    base: dict[str, int] = {}
    parts: list[pa.Table] = []
    rows = 0
    for s in samples:
        if s.scene_id not in base:
            base[s.scene_id] = rows
            parts.append(_posed_rows(spec, s.scene_id, files))
            rows += parts[-1].num_rows
            if len(parts) % 256 == 0:
                release()
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
    taken = _take_releasing(posed.drop_columns(["image"]), flat, release)
    posed_images = _value_views(posed.column("image"))
    release()
    images: list = [posed_images[i] for i in flat.tolist()]
    counts = np.array([len(s.views) for s in samples], dtype=np.int32)
    offsets = pa.array(np.concatenate([[0], np.cumsum(counts)]).astype(np.int32))

    if opts.resize is None:
        width, height = taken.column("width"), taken.column("height")
        intr = taken.column("intrinsics_norm")
        masks = taken.column("mask")
    else:
        images, w, h, intr_np, mask_list = _resize_views(taken, images, view_scene, view_frame, opts, spec.sources)
        release()
        width, height = pa.array(w), pa.array(h)
        intr = pa.FixedSizeListArray.from_arrays(pa.array(intr_np.reshape(-1)), 4)
        masks = pa.array(mask_list, pa.binary())
    per_view = {
        "frame_index": pa.array(view_frame.astype(np.int32)),
        "source_frame": taken.column("source_frame"),
        "width": width,
        "height": height,
        "intrinsics_norm": intr,
        "cam_to_world": taken.column("cam_to_world"),
        "near": taken.column("near"),
        "far": taken.column("far"),
        "mask": masks,
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
    for name, values in per_view.items():
        cols[name] = _list_column(offsets, values, schema.field(name).type)
    cols["image"] = _list_column(offsets, binary_array(images, release), schema.field("image").type)
    arrays = []
    for f in schema:
        col = cols[f.name]
        if col.type != f.type:  # e.g. list field nullability: cast to the schema's exact type
            col = col.cast(f.type)
        arrays.append(col)
    return pa.Table.from_arrays(arrays, schema=schema)


def write_shard(spec: ShardSpec, path: str | Path, fsync: bool = False) -> tuple[int, int, str]:
    """Write the shard of `spec` atomically to `path` (`build_shard_table`); return (rows, bytes, sha256)."""
    size, sha256 = write_table(path, build_shard_table(spec), max_chunksize=spec.rows_per_batch, fsync=fsync)
    return len(spec.samples), size, sha256


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
