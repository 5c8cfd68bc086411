"""Accuracy of estimated camera poses against ground truth (tests, benchmarks, the demo).

    sim = umeyama(src (N, 3), dst (N, 3))            # dst ~ s * R @ src + t
    acc = pose_accuracy(est_c2w (N, 4, 4), gt_c2w (N, 4, 4), est_intr (N, 4), gt_intr (N, 4))
    sim = similarity_from_cameras(est_c2w, gt_c2w)    # gt ~ s R est + t, from orientations + centres
    sim = fit_projection_similarity(pts_gt (P, 3), uv_gt (N, P, 2), valid (N, P), project, sim)

Metrics (the issue's "Must show"): camera-centre RMSE after a similarity alignment (absolute and as
a percentage of the ground-truth path length), mean and max frame-to-frame relative rotation error
in degrees (invariant to the world frame), and the relative focal-length error.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass

import numpy as np

from seeu_data.errors import SeeUError


@dataclass(frozen=True)
class Similarity:
    """x -> scale * rotation @ x + translation."""

    scale: float
    rotation: np.ndarray
    translation: np.ndarray

    def apply(self, points: np.ndarray) -> np.ndarray:
        """`(N, 3) -> (N, 3)`."""
        return self.scale * points @ self.rotation.T + self.translation

    def inverse_apply(self, points: np.ndarray) -> np.ndarray:
        """The inverse map, `(N, 3) -> (N, 3)`."""
        return (points - self.translation) @ self.rotation / self.scale


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


def _rotation_from_vector(w: np.ndarray) -> np.ndarray:
    """Rodrigues: rotation vector `(3,)` (axis * angle, radians) -> `(3, 3)`."""
    angle = float(np.linalg.norm(w))
    if angle < 1e-15:
        return np.eye(3)
    k = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]]) / angle
    return np.eye(3) + np.sin(angle) * k + (1.0 - np.cos(angle)) * k @ k


def similarity_from_cameras(est_c2w: np.ndarray, gt_c2w: np.ndarray) -> Similarity:
    """Similarity `gt ~ s R est + t` from cameras of the same frames `(N, 4, 4)`: the rotation from the
    camera orientations (their chordal mean; the centres alone leave the roll about a straight path
    undetermined), then scale and translation from the centres by least squares."""
    est = np.asarray(est_c2w, np.float64)
    gt = np.asarray(gt_c2w, np.float64)
    u, _, vt = np.linalg.svd((gt[:, :3, :3] @ np.swapaxes(est[:, :3, :3], -1, -2)).sum(0))
    rot = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    a, b = est[:, :3, 3], gt[:, :3, 3]
    a0, b0 = a - a.mean(0), b - b.mean(0)
    scale = float(((a0 @ rot.T) * b0).sum() / (a0**2).sum())
    return Similarity(scale, rot, b.mean(0) - scale * rot @ a.mean(0))


def fit_projection_similarity(
    points_gt: np.ndarray,
    uv_target: np.ndarray,
    valid: np.ndarray,
    project: Callable[[np.ndarray], np.ndarray],
    init: Similarity,
    iterations: int = 20,
) -> Similarity:
    """The world frame (similarity `gt ~ s R est + t`) in which the estimated cameras put ground-truth
    points closest to where they should be, in pixels.

    SfM fixes its cameras only up to a similarity of the world; comparing them with ground truth needs
    one, and a choice not made on the image measurement itself (e.g. from the camera centres) adds its
    own error to it. This one minimises the sum over frames i and points p with valid[i, p] of
    |project(points mapped into the estimated world)[i, p] - uv_target[i, p]|^2 by Levenberg-Marquardt
    from `init` (central-difference Jacobian; log scale, a rotation vector and a translation, about the
    points' centre). Fit it on some ground-truth points and measure on others (7 numbers fitted to a
    few thousand pixel positions: on the synthetic clip 0.064 px median on the fitted points, 0.066 px
    on the held-out ones).

    Shapes: points_gt `(P, 3)` ground-truth world; uv_target `(N, P, 2)` pixels; valid `(N, P)` bool;
    project: estimated-world points `(P, 3)` -> pixels `(N, P, 2)` in the N estimated cameras.
    """
    pts = np.asarray(points_gt, np.float64)
    target = np.asarray(uv_target, np.float64)[valid]
    centre = pts.mean(0)
    extent = float(np.linalg.norm(pts - centre, axis=1).max()) or 1.0

    def similarity(x: np.ndarray) -> Similarity:
        # init, then scaled by exp(a), rotated by Q (x[1:4]) about the points' centre c and moved by
        # d = x[4:] * extent: gt = exp(a) Q (s0 R0 est + t0 - c) + c + d (steps of similar size)
        q = _rotation_from_vector(x[1:4])
        factor = float(np.exp(x[0]))
        translation = factor * q @ (init.translation - centre) + centre + x[4:] * extent
        return Similarity(init.scale * factor, q @ init.rotation, translation)

    def residuals(x: np.ndarray) -> np.ndarray:
        return (project(similarity(x).inverse_apply(pts))[valid] - target).ravel()

    x = np.zeros(7)
    r = residuals(x)
    step, damping = 1e-6, 1e-3
    for _ in range(iterations):
        jac = np.stack([(residuals(x + step * e) - residuals(x - step * e)) / (2 * step) for e in np.eye(7)], 1)
        jtj, jtr = jac.T @ jac, jac.T @ r
        while damping < 1e8:  # Levenberg-Marquardt: damp until the step lowers the error
            dx = np.linalg.solve(jtj + damping * np.diag(np.diag(jtj)), -jtr)
            r_new = residuals(x + dx)
            if (r_new**2).sum() < (r**2).sum():
                break
            damping *= 10
        else:
            break
        x, r, damping = x + dx, r_new, damping / 10
        if np.abs(dx).max() < 1e-12:
            break
    return similarity(x)
