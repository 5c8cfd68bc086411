"""Ground-truth geometry readers for evaluation (DTU, and any dataset laid out the same way).

Depth maps: PFM (MVSNet / DTU `Depths`) or .npy, `ROOT/<scene_id>/<frame_index:06d>.npy|.pfm`.
Points: `points.npy` (M, 3) or `points.ply` with DTU's observation mask (`obs_mask.npz`: ObsMask, BB,
Res[, Plane]) beside them; or, for DTU imported with `seeu import dtu`, the paths the importer records
in each scene's meta (Depths/*.pfm in mm, Points/stl .ply, ObsMask/Plane .mat), found from triple
shards through their manifest (`posed_ground_truth`). Only reading here: the metrics (depth RMSE,
DTUeval Chamfer, the observation filter) are in `seeu_model.geometry_metrics`.

Example:
    from seeu_data.dtu_gt import posed_ground_truth, read_pfm

    depth = read_pfm("Depths/scan1_train/depth_map_0005.pfm")      # (H, W) float32, mm
    found = posed_ground_truth("data/shards/dtu_eval")             # None without recorded ground truth
    if found is not None:
        depth_loader, points_loader, geometry_scale = found
        gt = points_loader("scan1")                                 # GroundTruthPoints | None
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seeu_data.errors import SeeUError
from seeu_data.store.json_file import read_json


@dataclass
class ObservationMask:
    """DTU's observation mask: `obs_mask` (X, Y, Z) bool voxels of `res` mm from `bbox` (2, 3)'s
    corner; `plane` (4,) the table plane, or None."""

    obs_mask: np.ndarray
    bbox: np.ndarray
    res: float
    plane: np.ndarray | None = None


@dataclass
class GroundTruthPoints:
    """Ground-truth surface points (M, 3) and, when known, which part of space was observed."""

    points: np.ndarray
    observation: ObservationMask | None = None


def read_pfm(path: str | Path) -> np.ndarray:
    """A PFM depth map (MVSNet / DTU 'Depths') -> (H, W) float32, rows top to bottom."""
    with open(path, "rb") as fh:
        header = fh.readline().decode("latin-1").strip()
        if header not in ("Pf", "PF"):
            raise ValueError("not a PFM file")
        w, h = (int(v) for v in fh.readline().decode("latin-1").split())
        scale = float(fh.readline().decode("latin-1").strip())
        data = np.frombuffer(fh.read(), dtype="<f4" if scale < 0 else ">f4")
    ch = 3 if header == "PF" else 1
    return np.flipud(data[: h * w * ch].reshape(h, w, ch)[..., 0]).astype(np.float32)


def load_depth_map(root: Path, scene_id: str, frame_index: int) -> np.ndarray | None:
    """Ground-truth depth of a frame: ROOT/<scene_id>/<frame_index:06d>.npy|.pfm (or without zero padding)."""
    for name in (f"{frame_index:06d}", f"{frame_index}", f"depth_map_{frame_index:04d}"):
        for ext in (".npy", ".pfm"):
            p = Path(root) / scene_id / f"{name}{ext}"
            if p.is_file():
                return np.load(p).astype(np.float32) if ext == ".npy" else read_pfm(p)
    return None


def read_ply_points(path: str | Path) -> np.ndarray:
    """The vertices of a .ply point cloud -> (M, 3) float64."""
    from plyfile import PlyData

    v = PlyData.read(str(path))["vertex"]
    return np.stack([v["x"], v["y"], v["z"]], -1).astype(np.float64)


def read_points_dir(directory: str | Path) -> GroundTruthPoints | None:
    """DIR/points.npy (M, 3) or DIR/points.ply, with DIR/obs_mask.npz (ObsMask, BB, Res[, Plane]) when
    present; None without points."""
    d = Path(directory)
    if (d / "points.npy").is_file():
        pts = np.load(d / "points.npy").reshape(-1, 3)
    elif (d / "points.ply").is_file():
        pts = read_ply_points(d / "points.ply")
    else:
        return None
    obs = None
    if (d / "obs_mask.npz").is_file():
        z = np.load(d / "obs_mask.npz")
        obs = ObservationMask(z["ObsMask"], z["BB"], float(z["Res"]), z["Plane"] if "Plane" in z else None)
    return GroundTruthPoints(pts, obs)


def _read_mat_observation(meta: dict) -> ObservationMask | None:
    """DTU's ObsMask*.mat (and Plane*.mat) named in a scene's meta; None without scipy or the files."""
    if "obs_mask" not in meta:
        return None
    try:
        from scipy.io import loadmat
    except ImportError:
        return None
    om = loadmat(meta["obs_mask"])
    plane = loadmat(meta["obs_plane"])["P"] if "obs_plane" in meta else None
    return ObservationMask(om["ObsMask"], om["BB"], float(np.ravel(om["Res"])[0]), plane)


def posed_ground_truth(
    data: str,
) -> tuple[Callable[[str, int], np.ndarray | None], Callable[[str], GroundTruthPoints | None], float] | None:
    """Ground truth recorded by an importer (DTU) in the scene meta of the posed frames the triple
    shards `data` were built from (found through the shards' manifest). Returns (depth_loader,
    points_loader, geometry_scale) or None when no scene has any.

    depth_loader(scene_id, frame_index) -> (H, W) depth in scene units (maps in mm are multiplied by the
    scene's `scale`) or None; points_loader(scene_id) -> GroundTruthPoints (mm) or None;
    geometry_scale: 1 / scale, what predicted centres are multiplied by to compare in mm."""
    from seeu_data.store.posed import PosedDataset

    manifest = Path(str(data)) / "manifest.json"
    if not manifest.is_file():
        return None
    try:
        inputs = read_json(manifest, "manifest").get("params", {}).get("inputs", []) or []
    except (SeeUError, AttributeError):
        return None
    scenes: dict[str, tuple] = {}
    for inp in inputs:
        try:
            ds = PosedDataset(inp)
        except Exception:  # noqa: BLE001 - inputs moved or unreadable: no ground truth
            continue
        for sid in ds.scene_ids:
            meta = (ds.scene_info(sid) or {}).get("meta") or {}
            if any(k in meta for k in ("gt_depth_dir", "gt_points")):
                scenes[sid] = (ds, meta)
    if not scenes:
        return None
    frames_cache: dict[str, np.ndarray] = {}

    def depth_loader(scene: str, frame_index: int) -> np.ndarray | None:
        if scene not in scenes or "gt_depth_dir" not in scenes[scene][1]:
            return None
        ds, meta = scenes[scene]
        if scene not in frames_cache:
            frames_cache[scene] = np.asarray(ds.load_scene(scene).source_frame)
        src = frames_cache[scene]
        view = int(src[frame_index]) if frame_index < len(src) else frame_index
        p = Path(meta["gt_depth_dir"]) / meta.get("gt_depth_pattern", "depth_map_{view:04d}.pfm").format(view=view)
        if not p.is_file():
            return None
        depth = read_pfm(p)
        return depth * float(meta.get("scale", 1.0)) if meta.get("gt_depth_units") == "mm" else depth

    def points_loader(scene: str) -> GroundTruthPoints | None:
        if scene not in scenes or "gt_points" not in scenes[scene][1]:
            return None
        meta = scenes[scene][1]
        return GroundTruthPoints(read_ply_points(Path(meta["gt_points"])), _read_mat_observation(meta))

    scale = next((float(m.get("scale", 1.0)) for _, m in scenes.values()), 1.0)
    return depth_loader, points_loader, 1.0 / scale
