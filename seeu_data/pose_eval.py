"""Accuracy of estimated camera poses against ground truth (tests, benchmarks, the demo).

    sim = umeyama(src (N, 3), dst (N, 3))            # dst ~ s * R @ src + t
    acc = pose_accuracy(est_c2w (N, 4, 4), gt_c2w (N, 4, 4), est_intr (N, 4), gt_intr (N, 4))

Metrics (the issue's "Must show"): camera-centre RMSE after a similarity alignment (absolute and as
a percentage of the ground-truth path length), mean and max frame-to-frame relative rotation error
in degrees (invariant to the world frame), and the relative focal-length error.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from .errors import SeeUError


@dataclass(frozen=True)
class Similarity:
    """x -> scale * rotation @ x + translation."""

    scale: float
    rotation: np.ndarray
    translation: np.ndarray

    def apply(self, points: np.ndarray) -> np.ndarray:
        """`(N, 3) -> (N, 3)`."""
        return self.scale * points @ self.rotation.T + self.translation


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool = True) -> Similarity:
    """Least-squares similarity (Umeyama 1991) mapping `src (N, 3)` onto `dst (N, 3)`, N >= 3."""
    src = np.asarray(src, np.float64)
    dst = np.asarray(dst, np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3 or len(src) < 3:
        raise SeeUError(f"umeyama needs two (N>=3, 3) point sets, got {src.shape} and {dst.shape}")
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    cov = xd.T @ xs / len(src)
    u, d, vt = np.linalg.svd(cov)
    sign = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        sign[2, 2] = -1
    rot = u @ sign @ vt
    var_s = (xs**2).sum() / len(src)
    scale = float(np.trace(np.diag(d) @ sign) / var_s) if with_scale else 1.0
    return Similarity(scale, rot, mu_d - scale * rot @ mu_s)


def rotation_angle_deg(rot: np.ndarray) -> np.ndarray:
    """Angle of rotation matrices `(..., 3, 3) -> (...)` in degrees."""
    cos = (np.trace(rot, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


@dataclass(frozen=True)
class PoseAccuracy:
    num_frames: int
    path_length: float
    centre_rmse: float
    centre_rmse_pct_path: float
    rel_rot_err_mean_deg: float
    rel_rot_err_max_deg: float
    focal_err_pct: float
    alignment_scale: float

    def as_dict(self) -> dict:
        return asdict(self)


def pose_accuracy(
    est_c2w: np.ndarray, gt_c2w: np.ndarray, est_intr: np.ndarray | None = None, gt_intr: np.ndarray | None = None
) -> PoseAccuracy:
    """Compare `(N, 4, 4)` camera-to-world poses of the same frames (same order).

    Frame-to-frame relative rotations `R_i^T R_{i+1}` do not depend on the world frame or scale,
    so they need no alignment. Focal error: max over x/y of |mean(f_est)/mean(f_gt) - 1| in % of
    the normalised focal lengths `(N, 4)`.
    """
    est = np.asarray(est_c2w, np.float64)
    gt = np.asarray(gt_c2w, np.float64)
    if est.shape != gt.shape or est.shape[1:] != (4, 4):
        raise SeeUError(f"pose arrays differ: {est.shape} vs {gt.shape}")
    sim = umeyama(est[:, :3, 3], gt[:, :3, 3])
    err = np.linalg.norm(sim.apply(est[:, :3, 3]) - gt[:, :3, 3], axis=1)
    rmse = float(np.sqrt((err**2).mean()))
    length = float(np.linalg.norm(np.diff(gt[:, :3, 3], axis=0), axis=1).sum())
    rel_est = np.swapaxes(est[:-1, :3, :3], -1, -2) @ est[1:, :3, :3]
    rel_gt = np.swapaxes(gt[:-1, :3, :3], -1, -2) @ gt[1:, :3, :3]
    rot_err = rotation_angle_deg(np.swapaxes(rel_gt, -1, -2) @ rel_est) if len(est) > 1 else np.zeros(1)
    focal = float("nan")
    if est_intr is not None and gt_intr is not None:
        e, g = np.asarray(est_intr, np.float64), np.asarray(gt_intr, np.float64)
        focal = float(100 * max(abs(e[:, 0].mean() / g[:, 0].mean() - 1), abs(e[:, 1].mean() / g[:, 1].mean() - 1)))
    return PoseAccuracy(
        len(est),
        length,
        rmse,
        100 * rmse / length if length > 0 else float("nan"),
        float(rot_err.mean()),
        float(rot_err.max()),
        focal,
        sim.scale,
    )
