"""Coarse matching by plane sweep (paper §3.1.2) and the matching entropy used by CEA (§3.2.1).

For each view i, D depth candidates uniform in inverse depth between the view's near and far; the
features of every other view j are warped to view i through each candidate plane (fronto-parallel
in camera i), correlated with F^i by a dot product / sqrt(C), and averaged over j != i:

    C^i(p, d) = mean_{j != i}  <F^i(p), F^j(pi_j(d * K_i^-1 p))> / sqrt(C)

P^i(d | p) = softmax_d C^i(p, d);  depth Z^i(p) = sum_d P d;  entropy w^i(p) = H(P) / log D in [0, 1].

Geometry goes through `seeu_data.cameras` (OpenCV axes, camera-to-world, normalised intrinsics,
pixel centres at (j + 0.5, i + 0.5)); sampling uses ``grid_sample(align_corners=False)``, whose
coordinate -1 is the image's left edge, i.e. the same corner-at-origin convention.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from seeu_data.cameras import project_points, unproject_pixels

from .multiview_transformer import other_view_index


def depth_candidates(near: torch.Tensor, far: torch.Tensor, num: int) -> torch.Tensor:
    """near, far (B, V) -> depths (B, V, D), uniform in inverse depth, from near to far."""
    t = torch.linspace(0.0, 1.0, num, device=near.device, dtype=near.dtype)
    inv = 1.0 / near[..., None] + t * (1.0 / far[..., None] - 1.0 / near[..., None])
    return 1.0 / inv


def unit_disparity_from_depth(depth: torch.Tensor, near: torch.Tensor, far: torch.Tensor) -> torch.Tensor:
    """depth (B, V, ...) -> t in [0, 1] (0 at far, 1 at near), linear in inverse depth. near/far (B, V)."""
    extra = (None,) * (depth.dim() - near.dim())
    n, f = near[(...,) + extra], far[(...,) + extra]
    return (1.0 / depth - 1.0 / f) / (1.0 / n - 1.0 / f)


def depth_from_unit_disparity(t: torch.Tensor, near: torch.Tensor, far: torch.Tensor) -> torch.Tensor:
    """Inverse of `unit_disparity_from_depth`: t (B, V, ...) -> depth (B, V, ...)."""
    extra = (None,) * (t.dim() - near.dim())
    n, f = near[(...,) + extra], far[(...,) + extra]
    return 1.0 / (t * (1.0 / n - 1.0 / f) + 1.0 / f)


def pixel_centres(h: int, w: int, device=None, dtype=torch.float32) -> torch.Tensor:
    """(h*w, 2) pixel centres (x, y) = (j + 0.5, i + 0.5), row-major."""
    ys, xs = torch.meshgrid(
        torch.arange(h, device=device, dtype=dtype) + 0.5,
        torch.arange(w, device=device, dtype=dtype) + 0.5,
        indexing="ij",
    )
    return torch.stack([xs, ys], -1).reshape(h * w, 2)


def plane_sweep_cost(
    features: torch.Tensor, cam_to_world: torch.Tensor, intrinsics: torch.Tensor, depths: torch.Tensor
) -> torch.Tensor:
    """Plane-sweep correlation volume averaged over the other views.

    features (B, V, C, h, w), cam_to_world (B, V, 4, 4), intrinsics (B, V, 3, 3) normalised,
    depths (B, V, D)  ->  cost (B, V, D, h, w).  Needs V >= 2. Samples falling outside view j
    (or behind it) contribute a zero correlation (zero padding), as in MVSplat.
    """
    b, v, c, h, w = features.shape
    d = depths.shape[-1]
    if v < 2:
        raise ValueError("plane sweep needs at least two views")
    dtype = features.dtype
    cam_to_world = cam_to_world.float()
    intrinsics = intrinsics.float()
    uv = pixel_centres(h, w, features.device)  # (hw, 2)
    uv = uv[None, None, None].expand(b, v, d, h * w, 2).reshape(b, v, d * h * w, 2)
    z = depths.float()[..., None].expand(b, v, d, h * w).reshape(b, v, d * h * w)
    points = unproject_pixels(uv, z, cam_to_world, intrinsics, w, h)  # (B, V, D*h*w, 3)

    others = other_view_index(v, features.device)  # (V, V-1)
    c2w_j = cam_to_world[:, others]  # (B, V, V-1, 4, 4)
    k_j = intrinsics[:, others]  # (B, V, V-1, 3, 3)
    uv_j, z_j = project_points(points[:, :, None], c2w_j, k_j, w, h)  # (B, V, V-1, D*h*w, 2), (...)
    grid = torch.stack([uv_j[..., 0] / w * 2 - 1, uv_j[..., 1] / h * 2 - 1], -1)
    grid = torch.where((z_j > 1e-6)[..., None], grid, torch.full_like(grid, -3.0))  # behind: outside
    grid = grid.reshape(b * v * (v - 1), d * h, w, 2).to(dtype)

    feat_j = features[:, others].reshape(b * v * (v - 1), c, h, w)
    warped = F.grid_sample(feat_j, grid, mode="bilinear", padding_mode="zeros", align_corners=False)
    warped = warped.reshape(b, v, v - 1, c, d, h, w)
    corr = (features[:, :, None, :, None] * warped).sum(3) / math.sqrt(c)  # (B, V, V-1, D, h, w)
    return corr.mean(2)


def depth_posterior(cost: torch.Tensor) -> torch.Tensor:
    """cost (B, V, D, h, w) -> P(d | p) (B, V, D, h, w), softmax over D."""
    return torch.softmax(cost.float(), dim=2)


def expected_depth(posterior: torch.Tensor, depths: torch.Tensor) -> torch.Tensor:
    """P (B, V, D, h, w), depths (B, V, D) -> Z = sum_d P d, (B, V, h, w)."""
    return (posterior * depths[..., None, None]).sum(2)


def matching_entropy(posterior: torch.Tensor) -> torch.Tensor:
    """Normalised entropy H(P) / log D of the depth posterior, (B, V, D, h, w) -> (B, V, h, w) in [0, 1]."""
    d = posterior.shape[2]
    ent = -(posterior * torch.log(posterior.clamp_min(1e-12))).sum(2)
    return (ent / math.log(d)).clamp(0.0, 1.0)
