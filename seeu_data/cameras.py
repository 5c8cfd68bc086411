"""Camera conventions: the one module that owns them. Everything else calls these functions.

Stored convention (posed frames, triples, loader batches, model inputs):

* Camera axes are OpenCV's: +x right, +y down, +z forward (looking direction).
* Poses are **camera-to-world** 4x4 matrices (`cam_to_world`), row-major when flattened to 16.
* Intrinsics are **normalised**: `intrinsics_norm = (fx/W, fy/H, cx/W, cy/H)`, or as a 3x3 matrix
  with the same entries (`intrinsics_norm_matrix`).
* Image coordinates are continuous with the top-left *corner* of the image at (0, 0); the centre of
  pixel (row i, column j) is at (j + 0.5, i + 0.5). This is COLMAP's and gsplat's convention and
  the one that makes normalised intrinsics independent of resolution.

Boundary conversions (each importer calls exactly one of these):

* RE10K text / pixelSplat chunks / COLMAP / DTU hold **world-to-camera**: `cam_to_world_from_world_to_cam`.
* COLMAP quaternions: `[x, y, z, w]` in pycolmap, `[w, x, y, z]` in text files.
* nerfstudio / NeRF `transforms.json`: OpenGL camera-to-world (+y up, +z backward): `opencv_from_opengl`.
* gsplat: world-to-camera `viewmats` and pixel `Ks`: `world_to_cam_from_cam_to_world`, `intrinsics_pixels`.

Functions accept numpy arrays or torch tensors with arbitrary leading batch dimensions and return
the same kind.
"""

from __future__ import annotations

import sys
from typing import Any

import numpy as np

Array = Any  # numpy.ndarray or torch.Tensor

# Mirror of the x axis; used for horizontal flips (pose E -> F E F) and OpenGL <-> OpenCV.
FLIP_X = np.diag([-1.0, 1.0, 1.0, 1.0])
OPENGL_TO_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])


def _torch():
    """The torch module if it is already imported (a tensor can only exist then); never imports it,
    so data-side processes that only use numpy do not pay torch's import time."""
    return sys.modules.get("torch")


def _is_torch(x: Array) -> bool:
    torch = _torch()
    return torch is not None and isinstance(x, torch.Tensor)


def _t(x: Array) -> Array:
    """Swap the last two axes."""
    return x.transpose(-1, -2) if _is_torch(x) else np.swapaxes(x, -1, -2)


def _like(const: np.ndarray, ref: Array) -> Array:
    if _is_torch(ref):
        return _torch().as_tensor(const, dtype=ref.dtype, device=ref.device)
    return const.astype(ref.dtype if np.issubdtype(ref.dtype, np.floating) else np.float64)


def _stack(xs: list, axis: int) -> Array:
    return _torch().stack(xs, dim=axis) if _is_torch(xs[0]) else np.stack(xs, axis=axis)


def _zeros_like_shape(ref: Array, shape: tuple) -> Array:
    if _is_torch(ref):
        return _torch().zeros(shape, dtype=ref.dtype, device=ref.device)
    return np.zeros(shape, dtype=ref.dtype if np.issubdtype(ref.dtype, np.floating) else np.float64)


# ---------------------------------------------------------------------------------------------
# Rigid transforms
# ---------------------------------------------------------------------------------------------


def invert_rigid(transform: Array) -> Array:
    """Inverse of rigid (or similarity-free) 4x4 transforms, `(..., 4, 4) -> (..., 4, 4)`.

    Uses R^T and -R^T t rather than a general inverse, so it is exact for rotations.
    """
    rot = transform[..., :3, :3]
    trans = transform[..., :3, 3:4]
    rot_t = _t(rot)
    out = _zeros_like_shape(transform, tuple(transform.shape))
    out[..., :3, :3] = rot_t
    out[..., :3, 3:4] = -(rot_t @ trans)
    out[..., 3, 3] = 1.0
    return out


def cam_to_world_from_world_to_cam(world_to_cam: Array) -> Array:
    """`(..., 4, 4)` world-to-camera (RE10K, pixelSplat, COLMAP, DTU) -> camera-to-world."""
    return invert_rigid(world_to_cam)


def world_to_cam_from_cam_to_world(cam_to_world: Array) -> Array:
    """`(..., 4, 4)` camera-to-world -> world-to-camera (gsplat `viewmats`, exporters)."""
    return invert_rigid(cam_to_world)


def homogeneous_from_3x4(mat34: Array) -> Array:
    """`(..., 3, 4)` -> `(..., 4, 4)` with a last row (0, 0, 0, 1)."""
    out = _zeros_like_shape(mat34, tuple(mat34.shape[:-2]) + (4, 4))
    out[..., :3, :] = mat34
    out[..., 3, 3] = 1.0
    return out


def opencv_from_opengl(cam_to_world_gl: Array) -> Array:
    """OpenGL/nerfstudio camera-to-world `(..., 4, 4)` (+y up, +z back) -> OpenCV camera-to-world."""
    return cam_to_world_gl @ _like(OPENGL_TO_OPENCV, cam_to_world_gl)


def opengl_from_opencv(cam_to_world_cv: Array) -> Array:
    """OpenCV camera-to-world `(..., 4, 4)` -> OpenGL/nerfstudio camera-to-world."""
    return cam_to_world_cv @ _like(OPENGL_TO_OPENCV, cam_to_world_cv)


def flip_horizontal(cam_to_world: Array, intrinsics_norm: Array) -> tuple[Array, Array]:
    """Pose and intrinsics for a horizontally mirrored image (the peers' training flip).

    The whole scene is mirrored in world x, so every view of a sample stays consistent:
    `cam_to_world -> F @ cam_to_world @ F` with `F = diag(-1, 1, 1, 1)`, and `cx -> 1 - cx`.
    Shapes: `(..., 4, 4)` and `(..., 4)` (fx, fy, cx, cy normalised).
    """
    flip = _like(FLIP_X, cam_to_world)
    pose = flip @ cam_to_world @ flip
    intr = intrinsics_norm.clone() if _is_torch(intrinsics_norm) else intrinsics_norm.copy()
    intr[..., 2] = 1.0 - intrinsics_norm[..., 2]
    return pose, intr


def rotation_orthonormality_error(cam_to_world: Array) -> Array:
    """Max |R^T R - I| and |det R - 1| per pose, `(..., 4, 4) -> (...)`. 0 for a proper rotation."""
    rot = np.asarray(cam_to_world, dtype=np.float64)[..., :3, :3]
    gram = np.swapaxes(rot, -1, -2) @ rot - np.eye(3)
    return np.maximum(np.abs(gram).max(axis=(-1, -2)), np.abs(np.linalg.det(rot) - 1.0))


# ---------------------------------------------------------------------------------------------
# Quaternions
# ---------------------------------------------------------------------------------------------


def rotmat_from_quat_wxyz(quat: Array) -> Array:
    """Unit quaternion `(..., 4)` as (w, x, y, z) -> rotation `(..., 3, 3)`. Normalises first."""
    norm = (quat * quat).sum(-1, keepdims=True) ** 0.5 if not _is_torch(quat) else quat.norm(dim=-1, keepdim=True)
    w, x, y, z = [(quat / norm)[..., i] for i in range(4)]
    rows = [
        _stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        _stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        _stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ]
    return _stack(rows, -2)


def rotmat_from_quat_xyzw(quat: Array) -> Array:
    """pycolmap's `[x, y, z, w]` quaternion `(..., 4)` -> rotation `(..., 3, 3)`."""
    return rotmat_from_quat_wxyz(quat[..., [3, 0, 1, 2]])


def quat_wxyz_from_rotmat(rot: np.ndarray) -> np.ndarray:
    """Rotation `(..., 3, 3)` -> unit quaternion `(..., 4)` (w, x, y, z) with w >= 0 (numpy)."""
    rot = np.asarray(rot, dtype=np.float64)
    flat = rot.reshape(-1, 3, 3)
    out = np.empty((flat.shape[0], 4))
    for i, m in enumerate(flat):
        trace = m[0, 0] + m[1, 1] + m[2, 2]
        if trace > 0:
            s = 2.0 * np.sqrt(trace + 1.0)
            q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
        elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
            s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
            q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
        elif m[1, 1] > m[2, 2]:
            s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
            q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
        else:
            s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
            q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
        qa = np.asarray(q)
        out[i] = qa * (1.0 if qa[0] >= 0 else -1.0) / np.linalg.norm(qa)
    return out.reshape(rot.shape[:-2] + (4,))


# ---------------------------------------------------------------------------------------------
# Intrinsics
# ---------------------------------------------------------------------------------------------


def intrinsics_norm_matrix(intrinsics_norm: Array) -> Array:
    """`(..., 4)` (fx/W, fy/H, cx/W, cy/H) -> normalised 3x3 matrix `(..., 3, 3)`."""
    fx, fy, cx, cy = [intrinsics_norm[..., i] for i in range(4)]
    zero = fx * 0
    one = zero + 1
    return _stack([_stack([fx, zero, cx], -1), _stack([zero, fy, cy], -1), _stack([zero, zero, one], -1)], -2)


def intrinsics_norm_vector(intrinsics_norm_mat: Array) -> Array:
    """Normalised 3x3 matrix `(..., 3, 3)` -> `(..., 4)` (fx, fy, cx, cy)."""
    m = intrinsics_norm_mat
    return _stack([m[..., 0, 0], m[..., 1, 1], m[..., 0, 2], m[..., 1, 2]], -1)


def intrinsics_pixels(intrinsics_norm: Array, width: int, height: int) -> Array:
    """Normalised intrinsics `(..., 4)` or `(..., 3, 3)` -> pixel K `(..., 3, 3)` for a W x H image."""
    mat = intrinsics_norm_matrix(intrinsics_norm) if intrinsics_norm.shape[-1] == 4 else intrinsics_norm
    scale = _like(np.array([[width, 0.0, 0.0], [0.0, height, 0.0], [0.0, 0.0, 1.0]]), mat)
    return scale @ mat


def intrinsics_norm_from_pixels(K: Array, width: int, height: int) -> Array:
    """Pixel K `(..., 3, 3)` for a W x H image -> normalised `(..., 4)` (fx/W, fy/H, cx/W, cy/H)."""
    vec = intrinsics_norm_vector(K)
    return vec / _like(np.array([width, height, width, height], dtype=np.float64), vec)


def cover_crop_geometry(in_hw: tuple[int, int], out_hw: tuple[int, int]) -> tuple[tuple[int, int], tuple[int, int]]:
    """The peers' resize-then-centre-crop: scale so the image covers `out_hw`, crop the middle.

    Returns `(scaled_hw, crop_offset_yx)`: resize the image to `scaled_hw`, then take rows
    `[oy, oy + out_h)` and columns `[ox, ox + out_w)`. (360x640 -> 256x256 gives 256x455, offset (0, 99).)
    """
    in_h, in_w = in_hw
    out_h, out_w = out_hw
    scale = max(out_h / in_h, out_w / in_w)
    scaled_h = max(out_h, int(round(in_h * scale)))
    scaled_w = max(out_w, int(round(in_w * scale)))
    return (scaled_h, scaled_w), ((scaled_h - out_h) // 2, (scaled_w - out_w) // 2)


def crop_intrinsics_norm(
    intrinsics_norm: Array, scaled_hw: tuple[int, int], crop_offset_yx: tuple[int, int], out_hw: tuple[int, int]
) -> Array:
    """Normalised intrinsics `(..., 4)` after resizing to `scaled_hw` and cropping `out_hw` at the offset.

    With the corner-at-origin convention a resize scales pixel coordinates exactly, so
    `fx' = fx_n * scaled_w / out_w` and `cx' = (cx_n * scaled_w - ox) / out_w` (likewise y).
    """
    sh, sw = scaled_hw
    oy, ox = crop_offset_yx
    oh, ow = out_hw
    out = intrinsics_norm.clone() if _is_torch(intrinsics_norm) else np.array(intrinsics_norm, dtype=np.float64)
    out[..., 0] = intrinsics_norm[..., 0] * sw / ow
    out[..., 1] = intrinsics_norm[..., 1] * sh / oh
    out[..., 2] = (intrinsics_norm[..., 2] * sw - ox) / ow
    out[..., 3] = (intrinsics_norm[..., 3] * sh - oy) / oh
    return out


def field_of_view_deg(intrinsics_norm: Array) -> tuple[Array, Array]:
    """Horizontal and vertical field of view in degrees from `(..., 4)` normalised intrinsics."""
    fx = np.asarray(intrinsics_norm)[..., 0]
    fy = np.asarray(intrinsics_norm)[..., 1]
    return np.degrees(2 * np.arctan(0.5 / fx)), np.degrees(2 * np.arctan(0.5 / fy))


# ---------------------------------------------------------------------------------------------
# Projection
# ---------------------------------------------------------------------------------------------


def project_points(
    points_world: Array, cam_to_world: Array, intrinsics_norm: Array, width: int, height: int
) -> tuple[Array, Array]:
    """Project world points into a camera.

    Shapes: points `(..., N, 3)`, cam_to_world `(..., 4, 4)`, intrinsics_norm `(..., 4)`.
    Returns pixel coordinates `(..., N, 2)` (corner-at-origin convention) and camera depth `(..., N)`.
    """
    w2c = world_to_cam_from_cam_to_world(cam_to_world)
    cam = points_world @ _t(w2c[..., :3, :3]) + w2c[..., None, :3, 3]
    depth = cam[..., 2]
    K = intrinsics_pixels(intrinsics_norm, width, height)
    uvw = cam @ _t(K)
    uv = uvw[..., :2] / uvw[..., 2:3]
    return uv, depth


def unproject_pixels(
    uv: Array, depth: Array, cam_to_world: Array, intrinsics_norm: Array, width: int, height: int
) -> Array:
    """Inverse of `project_points`: pixels `(..., N, 2)` at camera depth `(..., N)` -> world `(..., N, 3)`."""
    K = intrinsics_pixels(intrinsics_norm, width, height)
    fx, fy, cx, cy = K[..., 0, 0], K[..., 1, 1], K[..., 0, 2], K[..., 1, 2]
    x = (uv[..., 0] - cx[..., None]) / fx[..., None] * depth
    y = (uv[..., 1] - cy[..., None]) / fy[..., None] * depth
    cam = _stack([x, y, depth], -1)
    return cam @ _t(cam_to_world[..., :3, :3]) + cam_to_world[..., None, :3, 3]


def project_points_to_cameras(
    points_world: np.ndarray, cam_to_world: np.ndarray, intrinsics_norm: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """`project_points` of one point set into many cameras at once, on the normalised (1 x 1) image,
    numpy only, as one matrix product (fast for thousands of points and cameras).

    Shapes: points `(M, 3)`, cam_to_world `(B, 4, 4)`, intrinsics_norm `(B, 4)`. Returns image
    coordinates `(B, M, 2)` in [0, 1] inside the image (corner-at-origin) and camera depth `(B, M)`.
    """
    pts = np.asarray(points_world, np.float64)
    w2c = world_to_cam_from_cam_to_world(np.asarray(cam_to_world, np.float64))
    b = len(w2c)
    cam = (pts @ w2c[:, :3, :3].transpose(0, 2, 1).transpose(1, 0, 2).reshape(3, 3 * b)).reshape(len(pts), b, 3)
    cam = cam.transpose(1, 0, 2) + w2c[:, None, :3, 3]
    k = np.asarray(intrinsics_norm, np.float64)
    depth = cam[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = k[:, None, 0] * cam[..., 0] / depth + k[:, None, 2]
        v = k[:, None, 1] * cam[..., 1] / depth + k[:, None, 3]
    return np.stack([u, v], -1), depth
