"""Plane-sweep matching against closed-form geometry: two ray-cast views of a textured fronto-parallel
plane at a known depth, matched with a fixed hand-made feature (normalised 5x5 image patches)."""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from seeu_data.cameras import intrinsics_norm_matrix
from seeu_model.cost_volume import (
    depth_candidates,
    depth_from_unit_disparity,
    depth_posterior,
    expected_depth,
    matching_entropy,
    pixel_centres,
    plane_sweep_cost,
    unit_disparity_from_depth,
)

H = W = 64
PLANE_Z = 3.3  # not on a candidate
NEAR, FAR = 1.0, 10.0
FLAT_HALF = 0.6  # the plane is textureless for |X| < FLAT_HALF (world units)
TEX_RES = 24  # random texels over [-4, 4]: 0.33 world units, about 6 pixels at the plane (smooth enough that bilinear warps do not pixel-lock)


def _texture(seed: int = 0) -> torch.Tensor:
    """A smooth random RGB texture (1, 3, 512, 512) covering plane coordinates [-4, 4]^2."""
    g = torch.Generator().manual_seed(seed)
    tex = torch.rand(1, 3, TEX_RES, TEX_RES, generator=g)
    return F.interpolate(tex, size=(512, 512), mode="bicubic", align_corners=False).clamp(0, 1)


def _raycast_plane(cam_to_world: torch.Tensor, intr_norm: torch.Tensor, tex: torch.Tensor) -> torch.Tensor:
    """Render (3, H, W) of the plane z = PLANE_Z seen by a camera (rays through pixel centres)."""
    K = intrinsics_norm_matrix(intr_norm) * torch.tensor([[W], [H], [1.0]])
    uv = pixel_centres(H, W)
    rays_cam = torch.cat([uv, torch.ones(H * W, 1)], -1) @ torch.linalg.inv(K).T
    rays = rays_cam @ cam_to_world[:3, :3].T
    origin = cam_to_world[:3, 3]
    s = (PLANE_Z - origin[2]) / rays[:, 2]
    pts = origin + s[:, None] * rays  # (HW, 3)
    grid = (pts[:, :2] / 4.0).reshape(1, H, W, 2)
    img = F.grid_sample(tex, grid, mode="bilinear", align_corners=False)[0]
    flat = (pts[:, 0].abs() < FLAT_HALF).reshape(1, H, W)
    return torch.where(flat, torch.full_like(img, 0.5), img)


def _patch_feature(img: torch.Tensor, scale: float) -> torch.Tensor:
    """(3, H, W) -> zero-mean, unit-norm 5x5 patches (75, H, W) times `scale` (a fixed, non-learned feature)."""
    patches = F.unfold(img[None], kernel_size=5, padding=2)[0]  # (75, HW)
    patches = patches - patches.mean(0, keepdim=True)
    patches = patches / (patches.norm(dim=0, keepdim=True) + 1e-6)
    return (patches * scale).reshape(75, H, W)


def _scene():
    intr = torch.tensor([1.0, 1.0, 0.5, 0.5])
    c2w_0 = torch.eye(4)
    c2w_1 = torch.eye(4)
    c2w_1[:3, 3] = torch.tensor([0.4, 0.05, 0.0])  # mostly horizontal baseline, slight vertical
    tex = _texture()
    imgs = torch.stack([_raycast_plane(c2w_0, intr, tex), _raycast_plane(c2w_1, intr, tex)])
    c2w = torch.stack([c2w_0, c2w_1])[None]
    K = intrinsics_norm_matrix(intr)[None, None].expand(1, 2, 3, 3)
    return imgs, c2w, K


def test_depth_candidates_uniform_in_inverse_depth():
    near = torch.tensor([[1.0, 2.0]])
    far = torch.tensor([[100.0, 4.0]])
    d = depth_candidates(near, far, 5)
    assert torch.allclose(d[..., 0], near) and torch.allclose(d[..., -1], far)
    inv = 1.0 / d
    assert torch.allclose(inv.diff(dim=-1), inv.diff(dim=-1)[..., :1].expand(-1, -1, 4), atol=1e-6)
    t = unit_disparity_from_depth(d, near, far)
    assert torch.allclose(t[..., 0], torch.ones(1, 2)) and torch.allclose(t[..., -1], torch.zeros(1, 2), atol=1e-6)
    assert torch.allclose(depth_from_unit_disparity(t, near, far), d, rtol=1e-5)


def test_plane_sweep_recovers_known_plane_depth_and_entropy_marks_textureless():
    imgs, c2w, K = _scene()
    num_d = 64
    c = 75
    # cost = 25 * NCC: dot product / sqrt(C) of features scaled by sqrt(25 * sqrt(C)).
    feats = torch.stack([_patch_feature(im, math.sqrt(25.0 * math.sqrt(c))) for im in imgs])[None]
    near = torch.full((1, 2), NEAR)
    far = torch.full((1, 2), FAR)
    depths = depth_candidates(near, far, num_d)
    cost = plane_sweep_cost(feats, c2w, K, depths)
    assert cost.shape == (1, 2, num_d, H, W)
    post = depth_posterior(cost)
    depth = expected_depth(post, depths)
    ent = matching_entropy(post)
    assert float(ent.min()) >= 0.0 and float(ent.max()) <= 1.0

    # Independent truth: both cameras are fronto-parallel to the plane, so every pixel's depth is PLANE_Z.
    # Visible-in-both pixels: disparity fx*b/Z = 64*0.4/3.3 = 7.8 px (view 0 sees the point at u,
    # view 1 at u - 7.8); keep a 6 px margin for the 5x5 patches and the shift.
    disp = W * 0.4 / PLANE_Z
    u = torch.arange(W) + 0.5
    world_x = (u - W / 2) / W * PLANE_Z  # view 0 (camera at origin)
    cols_ok = [(u > disp + 6) & (u < W - 6), (u > 6) & (u < W - disp - 6)]
    for view in range(2):
        x_view = world_x + (0.4 if view == 1 else 0.0)
        textured = cols_ok[view] & (x_view.abs() > FLAT_HALF + 3 * PLANE_Z / W)
        flat = cols_ok[view] & (x_view.abs() < FLAT_HALF - 3 * PLANE_Z / W)
        rows = slice(6, H - 6)
        d_tex = depth[0, view, rows][:, textured]
        rel_err = (d_tex - PLANE_Z).abs() / PLANE_Z
        assert float(rel_err.median()) < 0.02, float(rel_err.median())
        assert float((rel_err < 0.05).float().mean()) > 0.9
        e_tex = ent[0, view, rows][:, textured].mean()
        e_flat = ent[0, view, rows][:, flat].mean()
        assert float(e_flat) > 0.95  # textureless: uniform posterior
        assert float(e_flat) > float(e_tex) + 0.3, (float(e_flat), float(e_tex))


def test_plane_sweep_is_permutation_equivariant_over_views():
    torch.manual_seed(0)
    feats = torch.randn(1, 3, 8, 16, 16)
    c2w = torch.eye(4).repeat(1, 3, 1, 1)
    c2w[0, 1, :3, 3] = torch.tensor([0.3, 0.0, 0.0])
    c2w[0, 2, :3, 3] = torch.tensor([-0.2, 0.1, 0.05])
    K = intrinsics_norm_matrix(torch.tensor([0.9, 0.9, 0.5, 0.5]))[None, None].expand(1, 3, 3, 3)
    depths = depth_candidates(torch.ones(1, 3), torch.full((1, 3), 20.0), 8)
    cost = plane_sweep_cost(feats, c2w, K, depths)
    perm = torch.tensor([2, 0, 1])
    cost_p = plane_sweep_cost(feats[:, perm], c2w[:, perm], K[:, perm], depths[:, perm])
    assert torch.allclose(cost_p, cost[:, perm], atol=1e-5)
