"""Geometry metrics for datasets with ground truth (DTU): depth RMSE and the DTUeval Chamfer distance.

* `depth_rmse`: per image, sqrt(mean((d_pred - d_gt)^2)) over pixels with valid ground truth
  (gt > 0 and finite, optionally within a mask).
* `chamfer_dtueval`: the DTU MVS evaluation protocol (DTUeval, as the MVS papers run it):
  1. the predicted cloud is thinned to a minimum point spacing `density` (0.2 mm) by the same greedy
     radius filter (points visited in a seeded random order; a point removes its neighbours within
     `density`),
  2. *accuracy*: distance from each predicted point inside the observation mask to the nearest
     ground-truth point, averaged over distances < `max_dist` (20 mm),
  3. *completeness*: distance from each ground-truth point (above the ground plane) to the nearest
     predicted point, averaged over distances < `max_dist`,
  4. *overall* = (accuracy + completeness) / 2. Units are those of the points (DTU: mm).
  The observation mask and ground plane come from DTU's ObsMask/Plane .mat files
  (`dtu_observation_filter`) or any boolean per-point arrays.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch


def depth_rmse(pred: torch.Tensor, gt: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """pred, gt: (..., H, W) -> (...) RMSE over valid pixels (NaN where an image has none)."""
    valid = torch.isfinite(gt) & (gt > 0)
    if mask is not None:
        valid &= mask.bool()
    diff = torch.where(valid, pred.float() - torch.nan_to_num(gt.float()), torch.zeros((), dtype=torch.float32))
    n = valid.flatten(-2).sum(-1)
    mse = diff.pow(2).flatten(-2).sum(-1) / n.clamp_min(1)
    return torch.where(n > 0, mse.sqrt(), torch.full_like(mse, float("nan")))


def nearest_distances(query: np.ndarray, ref: np.ndarray, chunk: int = 4096) -> np.ndarray:
    """(N, 3), (M, 3) -> (N,) Euclidean distance from each query point to its nearest ref point."""
    if len(ref) == 0:
        return np.full(len(query), np.inf)
    try:
        from scipy.spatial import cKDTree

        return cKDTree(ref).query(query, k=1)[0]
    except ImportError:  # exact brute force in chunks (slower, no extra dependency)
        r = torch.from_numpy(np.ascontiguousarray(ref, dtype=np.float64))
        out = []
        for s in range(0, len(query), chunk):
            q = torch.from_numpy(np.ascontiguousarray(query[s : s + chunk], dtype=np.float64))
            out.append(torch.cdist(q, r).min(dim=1).values.numpy())
        return np.concatenate(out) if out else np.zeros(0)


def downsample_density(points: np.ndarray, density: float, seed: int = 0) -> np.ndarray:
    """DTUeval's thinning: visit points in a seeded random order; each kept point removes all
    not-yet-visited points within `density`. Returns the kept points (K, 3)."""
    if len(points) == 0 or density <= 0:
        return points
    order = np.random.default_rng(seed).permutation(len(points))
    pts = points[order]
    keep = np.ones(len(pts), dtype=bool)
    try:
        from scipy.spatial import cKDTree

        tree = cKDTree(pts)
        neighbours = tree.query_ball_point(pts, r=density)
        for i in range(len(pts)):
            if keep[i]:
                for j in neighbours[i]:
                    if j > i:
                        keep[j] = False
    except ImportError:
        t = torch.from_numpy(np.ascontiguousarray(pts, dtype=np.float64))
        for i in range(len(pts)):
            if keep[i]:
                d = (t[i + 1 :] - t[i]).norm(dim=1).numpy()
                keep[i + 1 :][d <= density] = False
    return pts[keep]


@dataclass
class ChamferResult:
    accuracy: float
    completeness: float
    overall: float
    num_pred: int  # after thinning
    num_pred_in_mask: int
    num_gt: int


def chamfer_dtueval(
    pred: np.ndarray,
    gt: np.ndarray,
    pred_in_mask=None,
    gt_above_plane=None,
    density: float = 0.2,
    max_dist: float = 20.0,
    seed: int = 0,
) -> ChamferResult:
    """DTUeval accuracy / completeness / overall between point clouds (N, 3) and (M, 3).

    pred_in_mask: callable (K, 3) -> (K,) bool (observation mask test of the thinned points), or None.
    gt_above_plane: (M,) bool, or None (all ground-truth points count).
    """
    pred = np.asarray(pred, dtype=np.float64).reshape(-1, 3)
    gt = np.asarray(gt, dtype=np.float64).reshape(-1, 3)
    down = downsample_density(pred, density, seed)
    inside = down if pred_in_mask is None else down[np.asarray(pred_in_mask(down), dtype=bool)]
    d_acc = nearest_distances(inside, gt)
    gt_used = gt if gt_above_plane is None else gt[np.asarray(gt_above_plane, dtype=bool)]
    d_comp = nearest_distances(gt_used, down)
    acc = float(d_acc[d_acc < max_dist].mean()) if np.any(d_acc < max_dist) else float("nan")
    comp = float(d_comp[d_comp < max_dist].mean()) if np.any(d_comp < max_dist) else float("nan")
    return ChamferResult(acc, comp, (acc + comp) / 2.0, len(down), len(inside), len(gt_used))


def dtu_observation_filter(obs_mask: np.ndarray, bbox: np.ndarray, res: float, plane: np.ndarray | None = None):
    """DTU's ObsMask{scan}_10.mat (ObsMask volume, BB (2, 3), Res) and Plane{scan}.mat (4,) ->
    (points -> in-mask bool function, gt points -> above-plane bool function)."""
    obs_mask = np.asarray(obs_mask, dtype=bool)
    bb_min = np.asarray(bbox, dtype=np.float64).reshape(2, 3)[0]

    def in_mask(points: np.ndarray) -> np.ndarray:
        idx = np.round((points - bb_min) / res).astype(np.int64)
        ok = np.all((idx >= 0) & (idx < np.array(obs_mask.shape)), axis=1)
        out = np.zeros(len(points), dtype=bool)
        out[ok] = obs_mask[idx[ok, 0], idx[ok, 1], idx[ok, 2]]
        return out

    def above_plane(points: np.ndarray) -> np.ndarray:
        if plane is None:
            return np.ones(len(points), dtype=bool)
        p = np.asarray(plane, dtype=np.float64).reshape(4)
        return np.concatenate([points, np.ones((len(points), 1))], axis=1) @ p > 0

    return in_mask, above_plane
