"""The synthetic scene's ground truth is self-consistent (closed-form projections against the renderer)."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from pipelines.cli import main as cli_main
from seeu_data import cameras as cam
from seeu_data.store.posed import PosedDataset, PosedDatasetWriter
from seeu_data.synthetic import (
    camera_path,
    default_intrinsics_norm,
    load_ground_truth,
    make_scene,
    path_length,
    render_view,
    surface_points,
    synthetic_posed_scene,
)

W, H = 160, 96


@pytest.fixture(scope="module")
def scene():
    return make_scene(seed=3)


def _on_surface(scene, pts: np.ndarray, tol: float) -> np.ndarray:
    """Brute force: is each world point `(N, 3)` on some rectangle of the scene?"""
    ok = np.zeros(len(pts), bool)
    for k in range(len(scene)):
        a = int(scene.axis[k])
        b0, b1 = [i for i in range(3) if i != a]
        ok |= (
            (np.abs(pts[:, a] - scene.coord[k]) < tol)
            & (pts[:, b0] >= scene.lo[k, 0] - tol)
            & (pts[:, b0] <= scene.hi[k, 0] + tol)
            & (pts[:, b1] >= scene.lo[k, 1] - tol)
            & (pts[:, b1] <= scene.hi[k, 1] + tol)
        )
    return ok


def test_depth_unprojects_onto_scene_surfaces(scene):
    poses = camera_path(9)
    intr = default_intrinsics_norm(W, H)
    _, depth = render_view(scene, poses[4], intr, W, H)
    assert np.isfinite(depth).all() and depth.min() > 0.3 and depth.max() / depth.min() > 5  # a real depth range
    ii, jj = np.mgrid[0:H:7, 0:W:7]
    uv = np.stack([jj.ravel() + 0.5, ii.ravel() + 0.5], -1)
    pts = cam.unproject_pixels(uv, depth[ii.ravel(), jj.ravel()], poses[4], intr, W, H)
    assert _on_surface(scene, pts, tol=1e-3).all()


def test_surface_points_lie_on_the_scene_and_project_to_the_grid_pixel_centres(scene):
    poses = camera_path(9)[[2, 6]]
    intr = np.tile(default_intrinsics_norm(W, H), (2, 1))
    pts = surface_points(scene, poses, intr, W, H, grid=(4, 5), margin=3)
    assert pts.shape == (40, 3) and _on_surface(scene, pts, tol=1e-3).all()
    uv, _ = cam.project_points(pts[:20], poses[0], intr[0], W, H)
    ys, xs = np.meshgrid(np.linspace(3, H - 3, 4), np.linspace(3, W - 3, 5), indexing="ij")
    assert np.allclose(uv, np.stack([np.floor(xs.ravel()) + 0.5, np.floor(ys.ravel()) + 0.5], -1), atol=1e-6)


def test_known_points_project_where_rendered_depth_says(scene):
    """Face centres of the scene: projecting with the GT camera lands on a pixel whose rendered depth equals
    the point's camera depth whenever the point is visible; and a visible point's colour is seen there from
    two different cameras (same surface point, Lambertian shading)."""
    poses = camera_path(30)
    intr = default_intrinsics_norm(W, H)
    pts = scene.face_centres()
    checked = 0
    for f in (3, 15):
        _, depth = render_view(scene, poses[f], intr, W, H)
        uv, z = cam.project_points(pts, poses[f], intr, W, H)
        inside = (z > 0.1) & (uv[:, 0] > 1) & (uv[:, 0] < W - 1) & (uv[:, 1] > 1) & (uv[:, 1] < H - 1)
        # faces seen head-on enough that a half-pixel offset stays on the face
        normals = np.zeros((len(scene), 3))
        normals[np.arange(len(scene)), scene.axis] = scene.facing
        view = pts - poses[f][:3, 3]
        cos = -(normals * view).sum(1) / np.linalg.norm(view, axis=1)
        for k in np.nonzero(inside & (cos > 0.3))[0]:
            j, i = int(uv[k, 0]), int(uv[k, 1])
            rendered = depth[i, j]
            # the ray through the pixel centre hits the same plane near the point: depth within the pixel footprint
            if abs(rendered - z[k]) < 0.02 * z[k]:
                checked += 1
            else:  # otherwise the point must be hidden behind something nearer
                assert rendered < z[k]
    assert checked >= 6


def test_cross_view_reprojection_consistency(scene):
    """Unproject pixels of view A with its depth, project into view B: where visible in B, B's rendered
    depth agrees (the two GT cameras and depth maps describe one geometry)."""
    poses = camera_path(20)
    intr = default_intrinsics_norm(W, H)
    rgb_a, da = render_view(scene, poses[5], intr, W, H)
    rgb_b, db = render_view(scene, poses[7], intr, W, H)
    ii, jj = np.mgrid[2 : H - 2 : 5, 2 : W - 2 : 5]
    uv = np.stack([jj.ravel() + 0.5, ii.ravel() + 0.5], -1)
    pts = cam.unproject_pixels(uv, da[ii.ravel(), jj.ravel()], poses[5], intr, W, H)
    uvb, zb = cam.project_points(pts, poses[7], intr, W, H)
    jb, ib = np.floor(uvb[:, 0]).astype(int), np.floor(uvb[:, 1]).astype(int)
    ok = (ib >= 0) & (ib < H) & (jb >= 0) & (jb < W)
    rel = np.abs(db[ib[ok], jb[ok]] - zb[ok]) / zb[ok]
    # most points are visible in B and agree to within a pixel's depth change; none is in front of B's surface
    assert (rel < 0.03).mean() > 0.8
    assert (db[ib[ok], jb[ok]] > zb[ok] * 1.03 + 0.01).mean() < 0.03  # only at silhouettes (pixel rounding)


def test_render_determinism_and_seed(scene):
    pose = camera_path(5)[2]
    intr = default_intrinsics_norm(W, H)
    a, da = render_view(scene, pose, intr, W, H)
    b, db = render_view(make_scene(seed=3), pose, intr, W, H)
    c, _ = render_view(make_scene(seed=4), pose, intr, W, H)
    assert np.array_equal(a, b) and np.array_equal(da, db)
    assert np.abs(a.astype(int) - c.astype(int)).mean() > 10
    big, _ = render_view(scene, pose, default_intrinsics_norm(320, 180), 320, 180)
    sift = cv2.SIFT_create()
    assert len(sift.detect(cv2.cvtColor(big, cv2.COLOR_RGB2GRAY))) > 300  # textures give SfM features


def test_camera_path_moves_and_turns():
    poses = camera_path(60)
    assert cam.rotation_orthonormality_error(poses).max() < 1e-12
    assert path_length(poses) > 6.5
    yaw = np.degrees(np.arctan2(poses[:, 0, 2], poses[:, 2, 2]))
    assert yaw.max() - yaw.min() > 30  # it turns


def test_clip_and_ground_truth(tmp_path, scene):
    assert cli_main(["synth", "--out", str(tmp_path), "--frames", "6", "--size", "64x96", "--seed", "3"]) == 0
    gt = load_ground_truth(tmp_path / "clip.mp4")
    assert gt["cam_to_world"].shape == (6, 4, 4) and gt["width"] == 96 and gt["height"] == 64
    assert np.allclose(gt["cam_to_world"], camera_path(6))
    cap = cv2.VideoCapture(str(tmp_path / "clip.mp4"))
    frames = []
    while True:
        ok, f = cap.read()
        if not ok:
            break
        frames.append(cv2.cvtColor(f, cv2.COLOR_BGR2RGB))
    assert len(frames) == 6 and frames[0].shape == (64, 96, 3)
    ref, _ = render_view(scene, gt["cam_to_world"][2], gt["intrinsics_norm"][2], 96, 64)
    assert cv2.PSNR(frames[2], ref) > 20  # the decoded video is the rendered view (lossy mp4v)
    doc = json.loads((tmp_path / "clip.json").read_text())
    assert [f["frame"] for f in doc["frames"]] == list(range(6))


def test_synthetic_posed_scene_round_trip(tmp_path):
    s = synthetic_posed_scene(5, 48, 80, seed=1)
    s2 = synthetic_posed_scene(5, 48, 80, seed=1)
    assert s.images == s2.images
    with PosedDatasetWriter(tmp_path / "ds", params={}, provenance={}) as w:
        w.add(s)
    got = PosedDataset(tmp_path / "ds", verify=True).load_scene("synthetic_s1")
    assert np.allclose(got.cam_to_world, camera_path(5)) and got.near < got.far
    img = cv2.imdecode(np.frombuffer(got.images[0], np.uint8), cv2.IMREAD_COLOR)
    assert img.shape == (48, 80, 3)


def test_movers_change_exactly_their_masked_pixels_and_lie_inside_their_projected_box(scene):
    """A mover's mask: the pixels it changes against the static render (nearer depth there, nothing changed
    elsewhere), all inside the convex hull of its box's projected corners (closed form)."""
    from seeu_data.synthetic import MOVER_PRESETS, mover_boxes, place_movers, render_view_faces

    poses = camera_path(12)
    intr = default_intrinsics_norm(W, H)
    movers = MOVER_PRESETS["several"]
    boxes = mover_boxes(movers, seed=3)
    seen = 0
    for i in (0, 5, 11):
        centres = np.array([m.centre(i, poses[i][2, 3]) for m in movers])
        rgb0, depth0 = render_view(scene, poses[i], intr, W, H)
        rgb, depth, face = render_view_faces(place_movers(scene, boxes, centres), poses[i], intr, W, H)
        mask = face >= len(scene)
        assert np.array_equal(rgb[~mask], rgb0[~mask]) and np.array_equal(depth[~mask], depth0[~mask])
        assert (depth[mask] < depth0[mask]).all()
        hulls = np.zeros((H, W), np.uint8)
        jj, ii = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
        for m, c in zip(movers, centres):
            corners = c + np.array(np.meshgrid(*[[-s / 2, s / 2] for s in m.size])).reshape(3, -1).T
            uv, z = cam.project_points(corners, poses[i], intr, W, H)
            if (z < 0).all():  # the crossing mover, passed by the camera
                continue
            assert (z > 0).all()
            hull = cv2.convexHull(uv.astype(np.float32))
            inside = [cv2.pointPolygonTest(hull, (float(x), float(y)), True) for x, y in zip(jj.ravel(), ii.ravel())]
            hulls |= (np.array(inside).reshape(H, W) >= -1e-3).astype(np.uint8)
        assert not (mask & (hulls == 0)).any()
        seen += int(mask.sum())
    assert seen > 0.02 * 3 * W * H


def test_synth_movers_write_masks_named_by_the_ground_truth(tmp_path):
    from seeu_data.synthetic import write_clip

    assert cli_main(["synth", "--out", str(tmp_path), "--frames", "4", "--size", "48x80", "--movers", "box"]) == 0
    gt = load_ground_truth(tmp_path / "clip.mp4")
    assert gt["masks"] == "clip.masks.npz" and gt["mask"].shape == (4, 48, 80) and gt["mask"].dtype == bool
    assert 0.02 < gt["mask"].mean() < 0.3
    (mover,) = gt["movers"]
    assert np.allclose(np.array(mover["centres"])[:, 2] - gt["cam_to_world"][:, 2, 3], mover["distance"])
    plain = write_clip(tmp_path / "plain" / "clip.mp4", n_frames=2, size=(32, 48))
    assert "masks" not in plain and not (tmp_path / "plain" / "clip.masks.npz").exists()
