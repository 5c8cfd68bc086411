"""The checks of a dataset (posed frames or triple shards) that every stage applies to what it reads.

One validator, used by `seeu validate` (`check_dataset`: everything), `seeu build` / `seeu index` on
their posed inputs (`build.scan_inputs` calls `check_dataset` before anything is written),
`seeu export`, the importers on what they write (`check_image`), and the streaming loader on the
shards it opens (`check_file_schema`, `check_table_cameras`, `check_recorded_sizes` per file;
`check_image` on every image before it is decoded).

What is checked:

* the manifest (`manifest.read_manifest`: JSON shape, known schema and major version, entries inside
  the directory, no file listed twice, no scene listed twice, `total_rows`);
* every listed file: present, byte size, sha256 (unless skipped), row count equal to the manifest's;
* each file's own Arrow schema metadata (`seeu.schema`, `seeu.schema_version`): the same schema as
  the manifest, a major version this seeu reads. Every writer has put it there since the first
  release (`schema.arrow_schema`), so a file without it is refused;
* column names and types against `schemas/`, and Arrow's full validation of the data (offsets
  inside their buffers, strings valid UTF-8: a damaged file is caught without its sha256);
* cameras: finite, cam_to_world's last row (0, 0, 0, 1), orthonormal rotations, positive focal
  lengths, finite 0 < near < far;
* posed frames: each scene's rows lie inside its file, hold that scene id, and number their frames
  0, 1, ..., n - 1 (unique and in order: `seeu build` samples by that position);
* posed frames' overlap tables (`store.overlap_table`, when the manifest has an overlap block): each
  file present with its size, sha256 and rows, its schema, one row per scene of the posed file it
  covers with valid pairs and overlaps in [0, 1], every posed file covered once;
* images: the size in the JPEG/PNG header (`image_header.image_info`, no decode) equals the
  recorded width/height and is at most `max_pixels` (`MAX_PIXELS`, 64 MP, raised with `--max-pixels`),
  so a tiny file whose header declares 60000x60000 is refused before anything allocates for it;
* masks (the optional `mask` column, posed and triples): each non-null one a PNG, 8-bit greyscale,
  of its frame's width/height (`check_mask`, header only).

What is read: each file is mapped without read-ahead (`ReleasableIpcFile(random_access=True)`) and
read where the checks look, a part at a time, its pages given back after each part: the columns of cameras and ids, the image
column's offsets, and the header bytes of each image (read from the column's buffers in place, no copy;
the trailers are not read: the sha256 vouches for a stored file's bytes, and the loader checks each
image whole before it decodes it). So a check of a posed data set reads a few pages per image, not its
images, and holds one file's columns at a time.

Every problem is a `SeeUError` naming the file: one line at the CLI, exit 2.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa

from seeu_data.cameras import rotation_orthonormality_error
from seeu_data.errors import SeeUError
from seeu_data.limits import MAX_PIXELS
from seeu_data.store.arrow_io import ReleasableIpcFile
from seeu_data.store.image_header import ImageInfo, check_pixels, image_info
from seeu_data.store.manifest import read_manifest, verify_file
from seeu_data.store.overlap_table import MANIFEST_KEY as OVERLAP_KEY
from seeu_data.store.overlap_table import SCHEMA as OVERLAP_SCHEMA
from seeu_data.store.overlap_table import check_overlap_table
from seeu_data.store.schema import arrow_schema, check_version

_ORTHONORMAL_TOL = 1e-4
_ROWS_PER_PART = 4096  # rows checked between two releases of a file's pages (a few MB resident)
_SCENES_PER_PART = 256  # scenes' rows checked between two releases


# ------------------------------------------------------------------------------------------------
# Images
# ------------------------------------------------------------------------------------------------


def check_image(
    data,
    width: int | None,
    height: int | None,
    where: str | Path | None,
    max_pixels: int = MAX_PIXELS,
    trailer: bool = True,
) -> ImageInfo:
    """Header check of one encoded image (microseconds, no decode): a JPEG/PNG (`image_info`; its
    trailer too unless `trailer=False`), at most `max_pixels`, and of the recorded `width` x `height`
    (None: not recorded yet, as in importers)."""
    info = image_info(data, None if where is None else str(where), trailer)
    check_pixels(info.width, info.height, max_pixels, "image header declares", where)
    if width is not None and height is not None and (info.width, info.height) != (int(width), int(height)):
        raise SeeUError(
            f"image header declares {info.width}x{info.height}, the row records {int(width)}x{int(height)}", where
        )
    return info


def check_recorded_sizes(width: np.ndarray, height: np.ndarray, max_pixels: int, where: str | Path) -> None:
    """Refuse recorded sizes `(M,)` that are not positive or are over `max_pixels`."""
    w = np.asarray(width, np.int64)
    h = np.asarray(height, np.int64)
    if len(w) == 0:
        return
    if (w <= 0).any() or (h <= 0).any():
        raise SeeUError("a recorded image width/height is not positive", where)
    i = int(np.argmax(w * h))
    check_pixels(int(w[i]), int(h[i]), max_pixels, "recorded image size", where)


def _sizes_and_values(table: pa.Table | pa.RecordBatch, name: str, per: str, where: Path) -> tuple:
    """(width (M,) int64, height (M,) int64, the binary column `name`'s chunks as flat values, in place):
    one value per recorded size, else SeeUError ("N <name>s for M <per>")."""
    width = _flat_values(table.column("width"), 1).reshape(-1).astype(np.int64)
    height = _flat_values(table.column("height"), 1).reshape(-1).astype(np.int64)
    col = table.column(name)
    chunks = [_binary_values(c) for c in (col.chunks if isinstance(col, pa.ChunkedArray) else [col])]
    count = sum(len(c) for c in chunks)
    if count != len(width):
        raise SeeUError(f"{count} {name}s for {len(width)} {per}", where)
    return width, height, chunks


def check_table_images(table: pa.Table | pa.RecordBatch, max_pixels: int, where: Path) -> None:
    """`check_image` (header only) on every image of a table (posed or triples) against its recorded
    size, read from the image column's buffers in place: its offsets and each image's first bytes."""
    width, height, chunks = _sizes_and_values(table, "image", "recorded sizes", where)
    check_recorded_sizes(width, height, max_pixels, where)
    i = 0
    for images in chunks:
        bufs = images.buffers()
        offsets = np.frombuffer(bufs[1], np.int32)[images.offset : images.offset + len(images) + 1]
        data = memoryview(bufs[2]) if bufs[2] is not None else memoryview(b"")
        for j in range(len(images)):
            try:
                check_image(data[offsets[j] : offsets[j + 1]], width[i], height[i], None, max_pixels, trailer=False)
            except SeeUError as exc:
                raise SeeUError(f"{_image_label(table, i)}: {exc}", where) from None
            i += 1


def _binary_values(arr: pa.Array) -> pa.Array:
    """The values of one chunk of a binary or list<binary> column as one binary array (a slice: no copy)."""
    while pa.types.is_list(arr.type):
        arr = arr.flatten()
    return arr


def check_mask(data, width: int, height: int, where: str | Path | None, max_pixels: int = MAX_PIXELS) -> None:
    """Header check of one frame's mask (no decode): a PNG, 8-bit single channel (IHDR bit depth 8,
    colour type 0), at most `max_pixels`, of the frame's `width` x `height`."""
    info = image_info(data, None if where is None else str(where))
    if info.format != "png":
        raise SeeUError(f"mask is a {info.format.upper()}, not a PNG", where)
    ihdr = memoryview(data).cast("B")[24:26]  # bit depth, colour type
    if tuple(ihdr) != (8, 0):
        raise SeeUError(f"mask PNG has bit depth {ihdr[0]}, colour type {ihdr[1]}: 8-bit greyscale expected", where)
    check_pixels(info.width, info.height, max_pixels, "mask header declares", where)
    if (info.width, info.height) != (int(width), int(height)):
        raise SeeUError(f"mask is {info.width}x{info.height}, its frame {int(width)}x{int(height)}", where)


def check_table_masks(table: pa.Table | pa.RecordBatch, max_pixels: int, where: Path) -> None:
    """`check_mask` on every non-null mask of a table (posed: `mask`; triples: per view), chunk by chunk."""
    width, height, chunks = _sizes_and_values(table, "mask", "images", where)
    i = 0
    for masks in chunks:
        for data in masks:
            if data.is_valid:
                try:
                    check_mask(data.as_buffer(), width[i], height[i], None, max_pixels)
                except SeeUError as exc:
                    raise SeeUError(f"{_image_label(table, i)}: {exc}", where) from None
            i += 1


def _image_label(table: pa.Table, i: int) -> str:
    """What to call image `i` of a table: its posed scene and frame, or its row and view in a shard."""
    if pa.types.is_list(table.schema.field("image").type):
        offsets = table.column("image").combine_chunks().offsets.to_numpy()
        row = int(np.searchsorted(offsets, i, side="right") - 1)
        return f"sample {table.column('sample_id')[row].as_py()!r} view {i - int(offsets[row])}"
    return f"scene {table.column('scene_id')[i].as_py()!r} frame {table.column('frame_index')[i].as_py()}"


# ------------------------------------------------------------------------------------------------
# Cameras and tables
# ------------------------------------------------------------------------------------------------


def _flat_values(col: pa.ChunkedArray | pa.Array, width: int) -> np.ndarray:
    """Flatten (list of) fixed-size-list columns to `(M, width)` float64."""
    arr = col.combine_chunks() if isinstance(col, pa.ChunkedArray) else col
    while pa.types.is_list(arr.type) or pa.types.is_fixed_size_list(arr.type):
        arr = arr.flatten()
    return arr.to_numpy(zero_copy_only=False).reshape(-1, width).astype(np.float64)


def check_cameras(
    cam_to_world: np.ndarray, intrinsics_norm: np.ndarray, near: np.ndarray, far: np.ndarray, where: str | Path
) -> None:
    """Cameras `(M, 4, 4)` cam_to_world, `(M, 4)` intrinsics_norm, `(M,)` near/far: finite rigid poses,
    positive focal lengths, finite 0 < near < far."""
    c2w = np.asarray(cam_to_world, np.float64).reshape(-1, 4, 4)
    intr = np.asarray(intrinsics_norm, np.float64).reshape(-1, 4)
    if not (np.isfinite(c2w).all() and np.isfinite(intr).all()):
        raise SeeUError("non-finite camera values", where)
    if len(c2w) == 0:
        return
    if not np.allclose(c2w[:, 3], [0, 0, 0, 1]):
        raise SeeUError("cam_to_world last row is not (0, 0, 0, 1)", where)
    err = float(rotation_orthonormality_error(c2w).max())
    if err > _ORTHONORMAL_TOL:
        raise SeeUError(f"a camera rotation is not orthonormal (max error {err:.2e})", where)
    if (intr[:, :2] <= 0).any():
        raise SeeUError("non-positive focal length in intrinsics_norm", where)
    near = np.asarray(near, np.float64)
    far = np.asarray(far, np.float64)
    if not (np.isfinite(near).all() and np.isfinite(far).all() and (near > 0).all() and (far > near).all()):
        raise SeeUError("near/far must be finite with 0 < near < far", where)


def check_table_cameras(table: pa.Table | pa.RecordBatch, where: str | Path) -> None:
    """`check_cameras` on a table's (posed or triples) camera columns."""
    check_cameras(
        _flat_values(table.column("cam_to_world"), 16),
        _flat_values(table.column("intrinsics_norm"), 4),
        _flat_values(table.column("near"), 1).reshape(-1),
        _flat_values(table.column("far"), 1).reshape(-1),
        where,
    )


def check_file_schema(schema: pa.Schema, expect: str, where: str | Path) -> None:
    """A file's own Arrow schema metadata names schema `expect` at a major version this seeu reads."""
    meta = schema.metadata or {}
    name = meta.get(b"seeu.schema", b"").decode("utf-8", "replace")
    if name != expect:
        raise SeeUError(f"the file's metadata names schema {name or 'none'!r}, the dataset is {expect}", where)
    check_version(name, meta.get(b"seeu.schema_version", b"").decode("utf-8", "replace"), where)


def check_columns(schema: pa.Schema, expected: pa.Schema, where: str | Path) -> None:
    """Column names and types against the schema file's; an optional (nullable) column may be missing
    (a file of an earlier minor version: `schema` module docstring)."""
    got = {f.name: f.type for f in schema}
    for f in expected:
        if f.name not in got and f.nullable:
            continue
        if f.name not in got:
            raise SeeUError(f"column {f.name!r} is missing", where)
        if got[f.name] != f.type:
            raise SeeUError(f"column {f.name!r} has type {got[f.name]}, the schema says {f.type}", where)


def check_table(table: pa.Table, expected: pa.Schema, where: Path, max_pixels: int = MAX_PIXELS) -> None:
    """One file's table: schema metadata, columns, Arrow's full validation (offsets, UTF-8), cameras,
    images (headers against recorded sizes)."""
    check_file_schema(table.schema, expected.metadata[b"seeu.schema"].decode(), where)
    check_columns(table.schema, expected, where)
    table.validate(full=True)  # offsets in range, strings valid UTF-8 (a damaged file: pa.ArrowInvalid)
    if table.num_rows:
        check_table_cameras(table, where)
        check_table_images(table, max_pixels, where)
        if "mask" in table.schema.names:
            check_table_masks(table, max_pixels, where)


def check_frame_order(frame_index: np.ndarray, scene_id: str, where: str | Path) -> None:
    """A posed scene numbers its frames 0, 1, ..., n - 1: unique, in order (build samples by position)."""
    idx = np.asarray(frame_index, np.int64)
    if not np.array_equal(idx, np.arange(len(idx))):
        dup = len(np.unique(idx)) < len(idx)
        why = "repeats indices" if dup else "is not in order"
        raise SeeUError(f"scene {scene_id!r}: frame_index {why} (must be 0..{len(idx) - 1})", where)


# ------------------------------------------------------------------------------------------------
# A whole dataset
# ------------------------------------------------------------------------------------------------


def _unreadable(exc: Exception, where: Path) -> SeeUError:
    return SeeUError(f"unreadable (corrupt?): {type(exc).__name__}: {str(exc).splitlines()[0][:160]}", where)


def check_scene_rows(table: pa.Table, scenes: list[dict], where: Path) -> None:
    """The manifest's scenes in one posed file: rows inside the file, holding that scene's id, frames
    numbered 0..n-1."""
    for scene in scenes:
        sid = scene["scene_id"]
        end = scene["row_start"] + scene["num_frames"]
        if end > table.num_rows:
            raise SeeUError(
                f"scene {sid!r}: the manifest claims rows {scene['row_start']}..{end}, the file holds {table.num_rows}",
                where,
            )
        rows = table.slice(scene["row_start"], scene["num_frames"])
        ids = set(rows.column("scene_id").to_pylist())
        if ids != {sid}:
            raise SeeUError(f"rows of scene {sid!r} hold scene ids {sorted(ids)[:3]}", where)
        check_frame_order(rows.column("frame_index").to_numpy(), sid, where)


def check_dataset(
    root: str | Path, check_sha: bool = True, max_pixels: int = MAX_PIXELS, expect_schema: str | None = None
) -> dict:
    """Every check above on a dataset directory; SeeUError on the first problem; returns a summary
    (path, schema, schema_version, files, rows, scenes, bytes, sha256_checked, unlisted_files)."""
    root = Path(root)
    manifest = read_manifest(root, expect_schema=expect_schema)
    expected = arrow_schema(manifest["schema"], int(manifest["schema_version"].split(".")[0]))
    listed = {e["path"] for e in manifest["files"]}
    scenes_in: dict[str, list[dict]] = {}
    for scene in manifest.get("scenes", []):
        if scene["file"] not in listed:
            raise SeeUError(
                f"scene {scene['scene_id']!r} points at a file the manifest does not list", root / scene["file"]
            )
        scenes_in.setdefault(scene["file"], []).append(scene)
    for entry in manifest["files"]:
        where = root / entry["path"]
        try:
            verify_file(root, entry, check_sha=check_sha, count_rows=False)
            file = ReleasableIpcFile(where, random_access=True)
            table = file.table()
            if table.num_rows != entry["rows"]:
                raise SeeUError(f"{table.num_rows} rows, the manifest says {entry['rows']}", where)
            # a part at a time, its pages given back after it: one file of small scenes is not all resident
            for start in range(0, max(table.num_rows, 1), _ROWS_PER_PART):
                check_table(table.slice(start, _ROWS_PER_PART), expected, where, max_pixels)
                file.release()
            scenes = scenes_in.get(entry["path"], [])
            for start in range(0, len(scenes), _SCENES_PER_PART):
                check_scene_rows(table, scenes[start : start + _SCENES_PER_PART], where)
                file.release()
        except (pa.ArrowException, UnicodeDecodeError, ValueError, IndexError, TypeError, OverflowError) as exc:
            raise _unreadable(exc, where) from None  # corrupt bytes (seen with --no-sha)
        del table  # one file's columns mapped at a time
    overlap = check_overlap_files(root, manifest, listed, check_sha)
    listed |= {e["path"] for e in (manifest.get("overlap") or {}).get("files", [])}
    stray = sorted(p.name for p in root.glob("*.arrow") if p.name not in listed)
    return {
        "path": str(root),
        "schema": manifest["schema"],
        "schema_version": manifest["schema_version"],
        "files": len(manifest["files"]),
        "rows": manifest["total_rows"],
        "scenes": len(manifest.get("scenes", [])) or None,
        "bytes": int(sum(e["bytes"] for e in manifest["files"])),
        "sha256_checked": check_sha,
        "unlisted_files": stray,
        "overlap": overlap,
        "manifest": manifest,
    }


def check_overlap_files(root: Path, manifest: dict, posed_files: set[str], check_sha: bool) -> dict | None:
    """The overlap files a posed dataset's manifest lists (`store.overlap_table`): each present with its
    size, sha256 and rows, its schema, one row per scene of its posed file (`check_overlap_table`),
    and every posed file covered once. Returns {"files", "scenes_by_method"}, or None without a block."""
    block = manifest.get(OVERLAP_KEY)
    if block is None:
        return None
    check_version(OVERLAP_SCHEMA, block["schema_version"], root / "manifest.json")
    covered: dict[str, str] = {}
    methods: dict[str, int] = {}
    scenes_in: dict[str, list[dict]] = {}
    for scene in manifest.get("scenes", []):
        scenes_in.setdefault(scene["file"], []).append(scene)
    for entry in block["files"]:
        where = root / entry["path"]
        if entry["posed"] not in posed_files:
            raise SeeUError(f"covers {entry['posed']!r}, a file the manifest does not list", where)
        if entry["posed"] in covered:
            raise SeeUError(f"{entry['posed']!r} is covered twice (also by {covered[entry['posed']]})", where)
        covered[entry["posed"]] = entry["path"]
        try:
            verify_file(root, entry, check_sha=check_sha)
            table = ReleasableIpcFile(where, random_access=True).table()
            check_file_schema(table.schema, OVERLAP_SCHEMA, where)
            check_columns(table.schema, arrow_schema(OVERLAP_SCHEMA), where)
            table.validate(full=True)
        except (pa.ArrowException, UnicodeDecodeError, ValueError, IndexError, TypeError, OverflowError) as exc:
            raise _unreadable(exc, where) from None
        frames = {s["scene_id"]: int(s["num_frames"]) for s in scenes_in.get(entry["posed"], [])}
        check_overlap_table(table, frames, where)
        for m in table.column("method").to_pylist():
            methods[m] = methods.get(m, 0) + 1
    missing = sorted(posed_files - set(covered))
    if missing:
        raise SeeUError(f"the overlap block covers no table for {missing[0]}", root / "manifest.json")
    return {"files": len(block["files"]), "scenes_by_method": methods}
