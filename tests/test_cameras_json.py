"""`.ply` bundle of `seeu render`: cameras.json in the 3DGS viewers' layout (checked by projecting
points the way that layout is read: w2c = [R^T | -R^T position], principal point at the centre),
and the SH-degree sidecar."""

from __future__ import annotations

import json

import numpy as np
import torch

from seeu_data import cameras as cam
from seeu_model.gaussians import Gaussians
from seeu_model.ply import cameras_json, load_ply, save_ply_bundle


def _poses(n: int, rng) -> np.ndarray:
    c2w = np.tile(np.eye(4), (n, 1, 1))
    for i in range(n):
        q = rng.normal(size=4)
        c2w[i, :3, :3] = cam.rotmat_from_quat_wxyz(q / np.linalg.norm(q))
        c2w[i, :3, 3] = rng.normal(size=3)
    return c2w


def test_cameras_json_layout_projects_like_our_cameras():
    rng = np.random.default_rng(0)
    c2w = _poses(3, rng)
    intr = np.array([[0.9, 1.6, 0.5, 0.5]] * 3)
    W, H = 96, 54
    entries = cameras_json(c2w, intr, W, H, ["a", "b", "c"])
    assert [e["img_name"] for e in entries] == ["a", "b", "c"] and [e["id"] for e in entries] == [0, 1, 2]
    assert set(entries[0]) == {"id", "img_name", "width", "height", "position", "rotation", "fx", "fy"}
    pts = rng.normal(size=(20, 3)) * 0.3
    for i, e in enumerate(entries):
        rot, pos = np.array(e["rotation"]), np.array(e["position"])
        # the 3DGS reader: rotation = camera-to-world rows, position = camera centre
        pts_world = pos + 3.0 * rot[:, 2] + pts @ rot.T  # in front of the camera
        x = (pts_world - pos) @ rot
        uv = np.stack([e["fx"] * x[:, 0] / x[:, 2] + e["width"] / 2, e["fy"] * x[:, 1] / x[:, 2] + e["height"] / 2], 1)
        ours, _ = cam.project_points(pts_world, c2w[i], intr[i], W, H)
        assert np.allclose(uv, ours, atol=1e-9)
    # (N, 3, 3) normalised K gives the same entries
    K = cam.intrinsics_norm_matrix(intr)
    assert cameras_json(c2w, K, W, H, ["a", "b", "c"]) == entries


def test_ply_bundle_names_sh_degree(tmp_path):
    n, k = 5, 9  # SH degree 2
    g = Gaussians(
        means=torch.randn(1, n, 3),
        scales=torch.rand(1, n, 3) + 0.1,
        rotations=torch.nn.functional.normalize(torch.randn(1, n, 4), dim=-1),
        opacities=torch.rand(1, n) * 0.8 + 0.1,
        sh=torch.randn(1, n, k, 3),
    )
    side = save_ply_bundle(
        g,
        tmp_path,
        _poses(2, np.random.default_rng(1)),
        np.array([[1.0, 1.0, 0.5, 0.5]] * 2),
        32,
        32,
        ["context_0", "context_1"],
    )
    assert side["sh_degree"] == 2 and side["num_gaussians"] == n
    assert json.loads((tmp_path / "gaussians.json").read_text()) == side
    assert len(json.loads((tmp_path / "cameras.json").read_text())) == 2
    assert load_ply(tmp_path / "gaussians.ply").sh.shape == (1, n, k, 3)
