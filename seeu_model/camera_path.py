"""Novel-view camera paths between (and beyond) two cameras.

Rotations follow the geodesic (slerp written with the rotation log/exp maps, which extrapolate
naturally: ``R(t) = R0 exp(t log(R0^T R1))``), camera centres move linearly
(``c(t) = (1 - t) c0 + t c1``), normalised intrinsics are interpolated linearly. ``t`` in [0, 1]
interpolates, ``t < 0`` or ``t > 1`` extrapolates. All poses are OpenCV camera-to-world 4x4.
"""

from __future__ import annotations

import numpy as np


def so3_log(rot: np.ndarray) -> np.ndarray:
    """Rotation (3, 3) -> rotation vector (3,) (axis * angle, angle in [0, pi])."""
    cos = np.clip((np.trace(rot) - 1.0) / 2.0, -1.0, 1.0)
    angle = float(np.arccos(cos))
    w = np.array([rot[2, 1] - rot[1, 2], rot[0, 2] - rot[2, 0], rot[1, 0] - rot[0, 1]])
    if angle < 1e-8:
        return 0.5 * w
    if np.pi - angle < 1e-5:  # near pi: axis from the symmetric part
        sym = (rot + np.eye(3)) / 2.0
        axis = np.sqrt(np.clip(np.diag(sym), 0.0, None))
        k = int(np.argmax(axis))
        axis = sym[k] / max(axis[k], 1e-12)
        axis /= np.linalg.norm(axis)
        return axis * angle
    return w * (angle / (2.0 * np.sin(angle)))


def so3_exp(vec: np.ndarray) -> np.ndarray:
    """Rotation vector (3,) -> rotation (3, 3) (Rodrigues)."""
    angle = float(np.linalg.norm(vec))
    k = np.array([[0.0, -vec[2], vec[1]], [vec[2], 0.0, -vec[0]], [-vec[1], vec[0], 0.0]])
    if angle < 1e-12:
        return np.eye(3) + k
    k /= angle
    return np.eye(3) + np.sin(angle) * k + (1.0 - np.cos(angle)) * (k @ k)


def interpolate_pose(c2w_a: np.ndarray, c2w_b: np.ndarray, t: float) -> np.ndarray:
    """(4, 4), (4, 4), t -> (4, 4): geodesic rotation, linear camera centre (any real t)."""
    ra, rb = c2w_a[:3, :3], c2w_b[:3, :3]
    out = np.eye(4)
    out[:3, :3] = ra @ so3_exp(t * so3_log(ra.T @ rb))
    out[:3, 3] = (1.0 - t) * c2w_a[:3, 3] + t * c2w_b[:3, 3]
    return out


def path_parameters(num_frames: int, extrapolate: float = 0.0) -> np.ndarray:
    """(num_frames,) values of t from ``-extrapolate`` to ``1 + extrapolate`` (inclusive)."""
    if num_frames < 2:
        raise ValueError("a camera path needs at least 2 frames")
    return np.linspace(-extrapolate, 1.0 + extrapolate, num_frames)


def camera_path(
    c2w_a: np.ndarray, c2w_b: np.ndarray, intr_a: np.ndarray, intr_b: np.ndarray, ts: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Poses (N, 4, 4) and normalised intrinsics (N, 3, 3) at the path parameters `ts` (N,)."""
    poses = np.stack([interpolate_pose(c2w_a, c2w_b, float(t)) for t in ts])
    intr = np.stack([(1.0 - t) * intr_a + t * intr_b for t in ts])
    intr[:, 2, :] = (0.0, 0.0, 1.0)
    return poses, intr
