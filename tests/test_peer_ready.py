"""A user's video made ready for the peers' RE10K loaders by default: `seeu synth` ->
`seeu ingest` (default options) -> `seeu export pixelsplat` gives 360x640 frames whose 18-number
cameras put ground-truth 3-D points where the ground-truth camera puts them: within 0.05 px for the
layout itself (exact cameras), and within 0.05 px median end to end (0.044 px on this clip, p95 0.123
px, since ingest's last bundle adjustment uses a robust loss; 0.066 px without it, see the first test)."""

from __future__ import annotations

import io
import json

import cv2
import numpy as np
import pytest
import torch
from PIL import Image

from pipelines.cli import main as cli_main
from seeu_data import cameras as cam
from seeu_data.exporters.pixelsplat import peer_fov_deg
from seeu_data.ingest.pose_eval import fit_projection_similarity, similarity_from_cameras, umeyama
from seeu_data.store.posed import PosedDataset
from seeu_data.synthetic import load_ground_truth, make_scene, render_view, surface_points, write_clip

W, H, N = 640, 360, 24


def _gt_points(gt: dict, rows: list[int]) -> np.ndarray:
    """World points on the synthetic room's surfaces: a 6 x 10 pixel grid of the ground-truth views
    `rows`, lifted by the exact rendered depth. (60 len(rows), 3)."""
    return surface_points(make_scene(gt["config"]["seed"]), gt["cam_to_world"][rows], gt["intrinsics_norm"][rows], W, H)


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    root = tmp_path_factory.mktemp("peer")
    write_clip(root / "clip.mp4", n_frames=N, size=(H, W), seed=0)
    assert cli_main(["ingest", str(root / "clip.mp4"), "--out", str(root / "posed")]) == 0
    assert (
        cli_main(
            ["export", "pixelsplat", str(root / "posed" / "clip"), "--out", str(root / "ps"), "--size-check", "refuse"]
        )
        == 0
    )
    return root


def _peer_cameras(ex: dict) -> tuple[np.ndarray, np.ndarray]:
    """The 18 numbers read the way the peers' RE10K loader reads them (float32 tensor: normalised
    fx fy cx cy, two zeros, the 3x4 world-to-camera, inverted to camera-to-world): (N, 4, 4), (N, 4)."""
    cams = ex["cameras"]
    w2c = torch.eye(4, dtype=torch.float32).repeat(len(cams), 1, 1)
    w2c[:, :3] = cams[:, 6:].reshape(-1, 3, 4)
    return w2c.inverse().double().numpy(), cams[:, :4].double().numpy()


def _gt_pixels(pts_gt: np.ndarray, gt: dict, rows: list[int], intr: np.ndarray, meta: dict):
    """Where the ground-truth cameras put `pts_gt (P, 3)` in the exported frames: `(N, P, 2)` pixels and
    `(N, P)` in front and inside. An undistorted chunk's frames were resampled through the lens SfM
    fitted (SIMPLE_RADIAL f, cx, cy, k = OpenCV's model with distCoeffs (k, 0, 0, 0)): the ground-truth
    pixel in the clip is mapped through it into the undistorted frame."""
    uv, depth = cam.project_points(pts_gt, gt["cam_to_world"][rows], gt["intrinsics_norm"][rows], W, H)
    inside = (depth > 0) & (uv[..., 0] > 0) & (uv[..., 0] < W) & (uv[..., 1] > 0) & (uv[..., 1] < H)
    if meta["undistorted"]:
        f, cx, cy, k = meta["camera_as_mapped"]["params"]
        K = np.array([[f, 0, cx], [0, f, cy], [0, 0, 1.0]])
        for i in range(len(rows)):
            xy = cv2.undistortPoints(uv[i].reshape(-1, 1, 2), K, np.array([k, 0, 0, 0.0])).reshape(-1, 2)
            Kn = cam.intrinsics_pixels(intr[i], W, H)
            uv[i] = xy * [Kn[0, 0], Kn[1, 1]] + [Kn[0, 2], Kn[1, 2]]
    return uv, inside


def _projection_errors(pts_gt, uv_gt, inside, sim, project) -> np.ndarray:
    """Pixel distances between the exported cameras' projections of `pts_gt` (mapped into their world by
    the similarity `gt = s R est + t`) and the ground-truth pixels, over the points inside: `(M,)`."""
    return np.linalg.norm(project(sim.inverse_apply(pts_gt)) - uv_gt, axis=-1)[inside]


def test_default_ingest_export_passes_peer_rule_and_projects_ground_truth(exported):
    """Default options end to end. The frames are exactly what the loaders accept; ground-truth points
    through the exported 18 numbers land within 0.05 px (median) of where the ground-truth camera puts them.

    The world frame SfM leaves free (a similarity) is fitted on every other ground-truth point by pixel
    error (`fit_projection_similarity`) and the error is measured on the others: this clip 0.044 px
    median, p95 0.123 px (the frame fitted to the camera centres and orientations, the earlier measure,
    adds its own error; printed, not asserted). What gets it under 0.05 px is ingest's last bundle
    adjustment with a soft-L1 loss at 0.5 px (`SfmConfig.final_ba_loss`): COLMAP's own adjustments
    use a squared loss, and the 9 % of SIFT's observations above 1 px from the truth carry 62 % of
    its squared error. Without it: 0.066 px median, p95 0.167 px. Scene seeds 1-3 of the same clip go
    from 0.330 / 0.071 / 0.070 px to 0.228 / 0.059 / 0.051 px, so 0.05 px is not reached on every clip:
    the rest is SIFT's noise (COLMAP fed the exact projections of the same tracks is exact, 0.0003 px;
    with Gaussian noise of SIFT's residual size, 0.50 px per coordinate, it gives 0.044-0.148 px
    median over 8 draws). `benchmarks/projection_floor.py`, RESULTS.md. The figure does not hang on this
    machine: with OpenBLAS forced to other CPU kernels (OPENBLAS_CORETYPE Haswell, Sandybridge, Prescott)
    it is the same to 1e-12 px, and with the frames left distorted (the fitted lens moves the border by
    0.108 px, just over the 0.1 px undistortion threshold) it is 0.047 px. The focal length scaled by
    1.002 after SfM fails the bounds (0.25 px median), as does any layout error (next test)."""
    root = exported
    index = json.loads((root / "ps" / "test" / "index.json").read_text())
    sidecar = json.loads((root / "ps" / "test" / "seeu_posed.json").read_text())
    report = json.loads((root / "posed" / "clip" / "report.json").read_text())
    assert report["registered"] / N >= 0.95
    gt = load_ground_truth(root / "clip.mp4")
    checked = 0
    for key, chunk_name in index.items():
        (ex,) = [e for e in torch.load(root / "ps" / "test" / chunk_name, weights_only=True) if e["key"] == key]
        # The peers' loader: PIL decode, (3, 360, 640) or skipped; FOV <= 100 deg or skipped.
        for img in ex["images"]:
            assert Image.open(io.BytesIO(img.numpy().tobytes())).size == (640, 360)
        c2w, intr = _peer_cameras(ex)
        assert (peer_fov_deg(intr) <= 100).all()
        rows = [int(np.nonzero(gt["frame"] == f)[0][0]) for f in sidecar[key]["source_frame"]]
        pts_gt = _gt_points(gt, rows[:: max(1, len(rows) // 3)])
        uv_gt, inside = _gt_pixels(pts_gt, gt, rows, intr, sidecar[key]["meta"])

        def project(pts, c2w=c2w, intr=intr):  # exported-world points (P, 3) -> pixels (N, P, 2)
            return cam.project_points(pts, c2w, intr, W, H)[0]

        first_guess = similarity_from_cameras(c2w, gt["cam_to_world"][rows])
        fit = np.arange(len(pts_gt)) % 2 == 0  # every other grid point fits the world frame, the rest measure
        sim = fit_projection_similarity(pts_gt[fit], uv_gt[:, fit], inside[:, fit], project, first_guess)
        errs = _projection_errors(pts_gt[~fit], uv_gt[:, ~fit], inside[:, ~fit], sim, project)
        by_centres = _projection_errors(pts_gt, uv_gt, inside, first_guess, project)
        checked += len(errs)
        print(
            f"{key}: undistorted {sidecar[key]['meta']['undistorted']}, projection error vs ground truth "
            f"(held-out points): median {np.median(errs):.3f} px, p95 {np.percentile(errs, 95):.3f} px, max "
            f"{errs.max():.3f} px; world frame from the camera centres instead: median {np.median(by_centres):.3f} px"
        )
        assert np.median(errs) < 0.05 and np.percentile(errs, 95) < 0.2, (np.median(errs), np.percentile(errs, 95))
    assert checked > 500


def test_fit_projection_similarity_recovers_the_world_frame():
    """Exact cameras in a world scaled, rotated and moved by a known similarity: from the camera-fitted
    first guess, disturbed, the pixel fit finds the similarity again and the projections agree to 1e-6 px."""
    from seeu_data.ingest.pose_eval import Similarity
    from seeu_data.synthetic import camera_path, default_intrinsics_norm

    gt_c2w = camera_path(8)
    intr = np.tile(default_intrinsics_norm(W, H), (8, 1))
    pts = surface_points(make_scene(0), gt_c2w[[1, 5]], intr[:2], W, H)
    axis = np.array([0.3, -0.8, 0.5]) / np.linalg.norm([0.3, -0.8, 0.5])
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    rot = np.eye(3) + np.sin(0.7) * k + (1 - np.cos(0.7)) * k @ k
    truth = Similarity(2.5, rot, np.array([1.0, -2.0, 0.5]))  # gt = s R est + t
    est_c2w = np.tile(np.eye(4), (8, 1, 1))
    est_c2w[:, :3, :3] = rot.T @ gt_c2w[:, :3, :3]
    est_c2w[:, :3, 3] = truth.inverse_apply(gt_c2w[:, :3, 3])
    uv_gt, depth = cam.project_points(pts, gt_c2w, intr, W, H)

    def project(p):
        return cam.project_points(p, est_c2w, intr, W, H)[0]

    guess = similarity_from_cameras(est_c2w, gt_c2w)
    off = Similarity(guess.scale * 1.01, _rot_z(0.01) @ guess.rotation, guess.translation + 0.05)
    inside = (depth > 0) & (uv_gt[..., 0] > 0) & (uv_gt[..., 0] < W) & (uv_gt[..., 1] > 0) & (uv_gt[..., 1] < H)
    assert np.abs(project(off.inverse_apply(pts)) - uv_gt)[inside].max() > 10  # a poor first guess
    sim = fit_projection_similarity(pts, uv_gt, inside, project, off)
    assert abs(sim.scale / truth.scale - 1) < 1e-7 and np.abs(sim.rotation - rot).max() < 1e-7
    assert np.abs(project(sim.inverse_apply(pts)) - uv_gt)[inside].max() < 1e-6


def _rot_z(a: float) -> np.ndarray:
    return np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])


def test_pixelsplat_layout_projects_ground_truth_within_005_px(tmp_path):
    """The exact ground-truth cameras of a 640x360 synthetic scene through `seeu export pixelsplat` and
    back the way the peers read the 18 numbers (float32): ground-truth surface points land within
    0.05 px of where the ground-truth camera puts them."""
    from seeu_data.store.posed import PosedDatasetWriter
    from seeu_data.synthetic import synthetic_posed_scene

    scene = synthetic_posed_scene(n_frames=3, height=H, width=W, seed=0, scene_id="gt")
    with PosedDatasetWriter(tmp_path / "posed", params={}, provenance={}) as w:
        w.add(scene)
    assert (
        cli_main(
            ["export", "pixelsplat", str(tmp_path / "posed"), "--out", str(tmp_path / "ps"), "--size-check", "refuse"]
        )
        == 0
    )
    (ex,) = torch.load(tmp_path / "ps" / "test" / "000000.torch", weights_only=True)
    c2w, intr = _peer_cameras(ex)
    gt = {"config": {"seed": 0}, "cam_to_world": scene.cam_to_world, "intrinsics_norm": scene.intrinsics_norm}
    pts = _gt_points(gt, [0, 2])
    for i in range(3):
        uv, _ = cam.project_points(pts, c2w[i], intr[i], W, H)
        uv_gt, d_gt = cam.project_points(pts, scene.cam_to_world[i], scene.intrinsics_norm[i], W, H)
        front = d_gt > 0.1
        assert front.sum() > 50 and np.abs(uv - uv_gt)[front].max() < 0.05


def test_colmap_keypoints_use_the_pixel_convention_of_the_cameras_module():
    """Ingest keeps COLMAP's principal point (W/2, H/2, not refined) for a camera rendered with the
    principal point at the image centre in seeu_data.cameras' convention (top-left corner at (0, 0),
    pixel centres at +0.5). That is right only if COLMAP's SIFT keypoints use the same convention; a
    half-pixel mismatch would be absorbed by the focal length and poses. Gaussian blobs drawn at known
    sub-pixel positions in that convention: COLMAP's keypoints land on them (measured 0.004 px)."""
    import pycolmap

    rng = np.random.default_rng(0)
    centres = np.stack([rng.uniform(30, W - 30, 40), rng.uniform(30, H - 30, 40)], 1)
    apart = np.linalg.norm(centres[:, None] - centres[None], axis=-1) + 1e3 * np.eye(len(centres)) > 25
    centres = centres[apart.all(1)]
    x, y = np.arange(W) + 0.5, np.arange(H) + 0.5  # pixel centres
    img = 40.0 + sum(180 * np.exp(-((x[None] - cx) ** 2 + (y[:, None] - cy) ** 2) / (2 * 2.5**2)) for cx, cy in centres)
    options = pycolmap.FeatureExtractionOptions()
    options.num_threads = 1
    keypoints, _ = pycolmap.FeatureExtractor.create(options).extract_from_uint8_array(
        np.clip(img, 0, 255).round().astype(np.uint8)
    )
    kp = np.array([[k.x, k.y] for k in keypoints])
    offset = kp - centres[np.linalg.norm(kp[:, None] - centres[None], axis=-1).argmin(1)]
    near = np.linalg.norm(offset, axis=1) < 1.0
    assert near.sum() >= len(centres)
    assert np.abs(offset[near].mean(0)).max() < 0.02, offset[near].mean(0)


def test_peer_fov_rule_closed_form():
    from seeu_data.exporters.pixelsplat import peer_skip_reason

    fx = np.array([0.4, 0.45, 0.6])
    intr = np.stack([fx, fx * 16 / 9, np.full(3, 0.5), np.full(3, 0.5)], 1)
    assert np.allclose(peer_fov_deg(intr)[:, 0], np.degrees(2 * np.arctan(0.5 / fx)))
    off = np.array([[0.5, 0.9, 0.3, 0.5]])  # principal point off-centre in x
    assert peer_fov_deg(off)[0, 0] == pytest.approx(np.degrees(np.arctan(0.3 / 0.5) + np.arctan(0.7 / 0.5)))
    w, h = np.full(2, 640), np.full(2, 360)
    assert "field of view 102.7" in peer_skip_reason(w, h, intr[[1, 0]])  # any frame too wide: skipped
    assert peer_skip_reason(w, h, intr[[1, 2]]) is None
    assert "639x359" in peer_skip_reason(np.array([640, 639]), np.array([360, 359]), intr[[1, 2]])


def test_export_resize_makes_frames_peer_size_with_ground_truth_intrinsics(tmp_path, capsys):
    from seeu_data.store.posed import PosedDatasetWriter
    from seeu_data.synthetic import synthetic_posed_scene

    scene = synthetic_posed_scene(n_frames=1, height=600, width=800, seed=1, scene_id="four_three")
    with PosedDatasetWriter(tmp_path / "posed", params={}, provenance={}) as w:
        w.add(scene)
    base = ["export", "pixelsplat", str(tmp_path / "posed")]
    # as stored (600x800, --resize none) the loaders would skip it: refused in one line, no index.json
    assert cli_main(base + ["--out", str(tmp_path / "bad"), "--resize", "none", "--size-check", "refuse"]) == 2
    err = capsys.readouterr().err.strip()
    assert "800x600" in err and "--resize none" in err and "\n" not in err
    assert not (tmp_path / "bad" / "test" / "index.json").exists()
    assert cli_main(base + ["--out", str(tmp_path / "ps"), "--resize", "360x640", "--size-check", "refuse"]) == 0
    (ex,) = torch.load(tmp_path / "ps" / "test" / "000000.torch", weights_only=True)
    cams = ex["cameras"].double().numpy()
    for i, data in enumerate(ex["images"]):
        got = np.asarray(Image.open(io.BytesIO(data.numpy().tobytes())).convert("RGB"))
        assert got.shape == (360, 640, 3)
        # Ground truth: the synthetic room rendered directly at 360x640 with the exported intrinsics.
        truth, _ = render_view(make_scene(1), scene.cam_to_world[i], cams[i, :4], 640, 360)
        blur = lambda a: cv2.GaussianBlur(a, (0, 0), 1.0)  # geometry, not JPEG/filter noise
        assert cv2.PSNR(blur(got), blur(truth)) > 30
    # 600x800 covers 360x640 at 0.8 (480x640), then 60 rows are cropped top and bottom
    assert np.allclose(
        cams[:, :4], [[scene.intrinsics_norm[0, 0], scene.intrinsics_norm[0, 1] * 480 / 360, 0.5, 0.5]], atol=1e-6
    )


def test_ingested_sfm_points_lie_on_ground_truth_surfaces_and_reach_nerfstudio(exported, tmp_path):
    from seeu_data.ingest.points import read_points_ply

    root = exported
    ds = PosedDataset(root / "posed" / "clip")
    scene = ds.load_scene(ds.scene_ids[0])
    assert scene.meta["scale_convention"] == "re10k" and (scene.near, scene.far) == (1.0, 100.0)
    xyz, rgb = read_points_ply(root / "posed" / "clip" / scene.meta["points3d"])
    assert len(xyz) == scene.meta["points3d_count"] > 500
    # Into the ground truth's world with the Sim(3) of the camera centres; compare each point's depth
    # in a ground-truth camera with the exact rendered depth of the pixel it falls in.
    gt = load_ground_truth(root / "clip.mp4")
    rows = [int(np.nonzero(gt["frame"] == f)[0][0]) for f in scene.source_frame]
    sim = umeyama(scene.cam_to_world[:, :3, 3], gt["cam_to_world"][rows, :3, 3])
    world = sim.apply(xyz)
    r = rows[len(rows) // 2]
    uv, d = cam.project_points(world, gt["cam_to_world"][r], gt["intrinsics_norm"][r], W, H)
    ok = (d > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H)
    _, depth = render_view(make_scene(0), gt["cam_to_world"][r], gt["intrinsics_norm"][r], W, H)
    true_d = depth[uv[ok, 1].astype(int), uv[ok, 0].astype(int)]
    rel = np.abs(d[ok] - true_d) / true_d
    assert ok.sum() > 200 and np.median(rel) < 0.01, (ok.sum(), np.median(rel))
    # nerfstudio export: ply_file_path names a copy of the points beside transforms.json
    assert cli_main(["export", "nerfstudio", str(root / "posed" / "clip"), "--out", str(tmp_path / "ns")]) == 0
    doc = json.loads((tmp_path / "ns" / scene.scene_id / "transforms.json").read_text())
    assert doc["ply_file_path"] == "sparse_pc.ply"
    xyz2, rgb2 = read_points_ply(tmp_path / "ns" / scene.scene_id / doc["ply_file_path"])
    assert np.array_equal(xyz2, xyz) and np.array_equal(rgb2, rgb)


def test_check_cameras_on_exported_chunks(exported, tmp_path, capsys):
    """`seeu check-cameras` passes the exported pixelSplat chunks of an ingested clip (median Sampson
    error stated) and finds the RE10K near/far 1 / 100 they carry clipping none of the points."""
    capsys.readouterr()
    assert cli_main(["check-cameras", str(exported / "ps"), "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    rep = json.loads((tmp_path / "check.json").read_text())
    assert rep["kind"] == "pixelsplat" and rep["verdict"] == "consistent" and rep["median_error_px"] < 1.0, out
    nf = rep["scenes"][0]["near_far"]
    assert nf["source"] == "triangulated_matches" and nf["stored"] == [1.0, 100.0] and not rep["near_far_clipped"]
