"""Sparse SfM points as a coloured point-cloud `.ply` (x y z float32, red green blue uint8): what
nerfstudio's `ply_file_path` (the splatfacto initial point cloud) and 3DGS tools read.

`seeu ingest` keeps each chunk's SfM points, in the chunk's own frame and scale, as
`OUT/<scene>/points3d/<scene_id>.ply` and names that file in the chunk's meta (`points3d`, relative
to the dataset root); `seeu export nerfstudio` copies it beside transforms.json.

    write_points_ply(path, xyz (P, 3), rgb (P, 3) uint8);  xyz, rgb = read_points_ply(path)
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from seeu_data.errors import SeeUError

POINTS_DIR = "points3d"


def write_points_ply(path: str | Path, xyz: np.ndarray, rgb: np.ndarray, fsync: bool = False) -> Path:
    """Write (P, 3) points with (P, 3) 0-255 colours as a binary little-endian .ply (atomic; fsynced
    before its rename when `fsync`)."""
    from plyfile import PlyData, PlyElement

    from seeu_data.store.arrow_io import atomic_path

    xyz = np.asarray(xyz, np.float64).reshape(-1, 3)
    rgb = np.clip(np.round(np.asarray(rgb, np.float64).reshape(-1, 3)), 0, 255).astype(np.uint8)
    vertex = np.empty(
        len(xyz), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")]
    )
    for i, k in enumerate("xyz"):
        vertex[k] = xyz[:, i]
    for i, k in enumerate(("red", "green", "blue")):
        vertex[k] = rgb[:, i]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path, fsync) as tmp:
        PlyData([PlyElement.describe(vertex, "vertex")], byte_order="<").write(str(tmp))
    return path


def read_points_ply(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """(P, 3) float64 points and (P, 3) uint8 colours of a point-cloud .ply."""
    from plyfile import PlyData, PlyParseError

    try:
        v = PlyData.read(str(path))["vertex"]
        xyz = np.stack([np.asarray(v[k], np.float64) for k in "xyz"], 1)
        rgb = np.stack([np.asarray(v[k], np.uint8) for k in ("red", "green", "blue")], 1)
    except (OSError, KeyError, ValueError, IndexError, PlyParseError) as exc:
        raise SeeUError(f"not a readable point-cloud .ply ({exc})", path) from exc
    return xyz, rgb


def write_chunk_points(
    sfm_dir: str | Path,
    model_index: int,
    sfm_to_chunk: np.ndarray,
    dataset_dir: str | Path,
    scene_id: str,
    fsync: bool = False,
) -> dict:
    """Write the SfM points of model `model_index` (`points3d_<k>.npy` in `sfm_dir`), moved into a
    chunk's frame by the (4, 4) similarity `sfm_to_chunk`, to `dataset_dir/points3d/<scene_id>.ply`.
    Returns the meta entries to record ({} when the model has no point file)."""
    src = Path(sfm_dir) / f"points3d_{model_index}.npy"
    if not src.exists():
        return {}
    pts = np.load(src)
    m = np.asarray(sfm_to_chunk, np.float64)
    xyz = pts[:, :3] @ m[:3, :3].T + m[:3, 3]
    rel = f"{POINTS_DIR}/{scene_id}.ply"
    write_points_ply(Path(dataset_dir) / rel, xyz, pts[:, 3:6], fsync)
    return {"points3d": rel, "points3d_count": len(pts)}


def chunk_observations(
    sfm_dir: str | Path, model_index: int, frame_names: list[str]
) -> tuple[np.ndarray, np.ndarray] | None:
    """The SfM observations of a chunk's frames (`frame_names`, in chunk order) in model `model_index`
    (`observations_<k>.npz` in `sfm_dir`): (chunk frame index (M,), 3D point id (M,)), what
    `seeu_data.overlap.overlap_from_observations` counts; None when the model has no such file (an SfM
    stage run before it was written)."""
    src = Path(sfm_dir) / f"observations_{model_index}.npz"
    if not src.exists():
        return None
    with np.load(src) as data:
        names, obs = [str(n) for n in data["names"]], data["obs"]
    frame_of = {n: j for j, n in enumerate(frame_names)}
    image_to_frame = np.array([frame_of.get(n, -1) for n in names], np.int64)
    frame = image_to_frame[obs[:, 0]] if len(obs) else np.zeros(0, np.int64)
    keep = frame >= 0
    return frame[keep], obs[keep, 1]
