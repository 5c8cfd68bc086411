"""Check a dataset directory (posed frames or triple shards) against its schema and manifest.

Checks: the manifest (JSON shape, known schema and major version), every listed file (present,
byte size, sha256, row count), column names and types against `schemas/`, finite cameras,
orthonormal rotations, positive focal lengths, 0 < near < far, and for posed frames that each
scene's rows are where the manifest says.

Example:
    from pathlib import Path
    from pipelines.validate import validate_dataset

    summary = validate_dataset(Path("data/posed/clip"))   # SeeUError on the first problem
    print(summary["rows"], summary["files"])
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa

from seeu_data.arrow_io import open_ipc_file
from seeu_data.cameras import rotation_orthonormality_error
from seeu_data.errors import SeeUError
from seeu_data.manifest import read_manifest, verify_file
from seeu_data.schema import arrow_schema


def _flat_values(col: pa.ChunkedArray | pa.Array, width: int) -> np.ndarray:
    """Flatten (list of) fixed-size-list columns to `(M, width)` float64."""
    arr = col.combine_chunks() if isinstance(col, pa.ChunkedArray) else col
    while pa.types.is_list(arr.type) or pa.types.is_fixed_size_list(arr.type):
        arr = arr.flatten()
    return arr.to_numpy(zero_copy_only=False).reshape(-1, width).astype(np.float64)


def check_table(table: pa.Table, expected: pa.Schema, where: Path) -> None:
    """Column names/types and camera sanity of one file's table."""
    got = {f.name: f.type for f in table.schema}
    for f in expected:
        if f.name not in got:
            raise SeeUError(f"column {f.name!r} is missing", where)
        if got[f.name] != f.type:
            raise SeeUError(f"column {f.name!r} has type {got[f.name]}, the schema says {f.type}", where)
    if table.num_rows == 0:
        return
    c2w = _flat_values(table.column("cam_to_world"), 16).reshape(-1, 4, 4)
    intr = _flat_values(table.column("intrinsics_norm"), 4)
    if not (np.isfinite(c2w).all() and np.isfinite(intr).all()):
        raise SeeUError("non-finite camera values", where)
    if not np.allclose(c2w[:, 3], [0, 0, 0, 1]):
        raise SeeUError("cam_to_world last row is not (0, 0, 0, 1)", where)
    err = float(rotation_orthonormality_error(c2w).max())
    if err > 1e-4:
        raise SeeUError(f"a camera rotation is not orthonormal (max error {err:.2e})", where)
    if (intr[:, :2] <= 0).any():
        raise SeeUError("non-positive focal length in intrinsics_norm", where)
    near = _flat_values(table.column("near"), 1)
    far = _flat_values(table.column("far"), 1)
    if not (np.isfinite(near).all() and np.isfinite(far).all() and (near > 0).all() and (far > near).all()):
        raise SeeUError("near/far must be finite with 0 < near < far", where)


def validate_dataset(root: Path, check_sha: bool = True) -> dict:
    """Validate a dataset directory; raise SeeUError on the first problem; return a summary."""
    manifest = read_manifest(root)
    expected = arrow_schema(manifest["schema"], int(manifest["schema_version"].split(".")[0]))
    rows_by_file: dict[str, int] = {}
    for entry in manifest["files"]:
        try:
            verify_file(root, entry, check_sha=check_sha)
            table = open_ipc_file(root / entry["path"]).read_all()
            check_table(table, expected, root / entry["path"])
        except (pa.ArrowException, UnicodeDecodeError, ValueError) as exc:  # corrupt bytes (seen with --no-sha)
            raise SeeUError(
                f"unreadable (corrupt?): {type(exc).__name__}: {str(exc).splitlines()[0][:160]}", root / entry["path"]
            ) from None
        rows_by_file[entry["path"]] = table.num_rows
    for scene in manifest.get("scenes", []):
        where = root / scene["file"]
        if scene["file"] not in rows_by_file:
            raise SeeUError(f"scene {scene['scene_id']!r} points at a file the manifest does not list", where)
        end = scene["row_start"] + scene["num_frames"]
        if end > rows_by_file[scene["file"]]:
            raise SeeUError(f"scene {scene['scene_id']!r} rows {scene['row_start']}..{end} exceed the file", where)
        rows = open_ipc_file(where).read_all().slice(scene["row_start"], scene["num_frames"])
        ids = set(rows.column("scene_id").to_pylist())
        if ids != {scene["scene_id"]}:
            raise SeeUError(f"rows of scene {scene['scene_id']!r} hold scene ids {sorted(ids)[:3]}", where)
        if rows.column("frame_index").to_pylist() != list(range(scene["num_frames"])):
            raise SeeUError(f"scene {scene['scene_id']!r}: frame_index is not 0..{scene['num_frames'] - 1}", where)
    listed = {e["path"] for e in manifest["files"]}
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
    }
