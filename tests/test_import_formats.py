"""RE10K text, DTU (MVSNet), COLMAP and nerfstudio importers: exact parsing of the published
layouts, and a known 3D point projected with each format's own convention (as its peer code does
it) landing on the same pixel after import."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import cv2  # before pycolmap: the other import order breaks OpenCV's PNG encoder
import numpy as np
import pycolmap
import pytest

from pipelines.cli import main as cli_main
from pipelines.validate import validate_dataset
from seeu_data import cameras as cam
from seeu_data.errors import SeeUError
from seeu_data.importers import ImportReport, write_import
from seeu_data.importers import colmap as colmap_imp
from seeu_data.importers import dtu as dtu_imp
from seeu_data.importers import nerfstudio as ns_imp
from seeu_data.importers import re10k_text as re10k_imp
from seeu_data.store.posed import PosedDataset
from tests.helpers import look_at_cam_to_world


def _img(rng, h, w, ext=".png") -> bytes:
    ok, buf = cv2.imencode(ext, (rng.random((h, w, 3)) * 255).astype(np.uint8))
    assert ok
    return buf.tobytes()


def _run(items, out, fmt="x") -> ImportReport:
    return write_import(items, out, ImportReport(fmt), params={}, provenance={})


# ------------------------------------------------------------------------------------------ RE10K text

# Two lines in the exact published layout (the first frames of a RealEstate10K test file).
RE10K_LINES = [
    "50250000 0.474455 0.843477 0.500000 0.500000 0.000000 0.000000 0.998855 0.002043 -0.047815 "
    "-0.039135 -0.002060 0.999998 -0.000300 -0.025227 0.047814 0.000398 0.998856 -0.204567",
    "50283367 0.474455 0.843477 0.500000 0.500000 0.000000 0.000000 0.998848 0.002040 -0.047942 "
    "-0.039552 -0.002056 0.999998 -0.000284 -0.025169 0.047941 0.000382 0.998850 -0.210931",
]


def _re10k_fixture(root: Path, rng, n_extra: int = 3) -> tuple[Path, Path, list[str]]:
    cams, frames = root / "RealEstate10K" / "test", root / "dataset" / "test"
    cams.mkdir(parents=True)
    lines = list(RE10K_LINES)
    for k in range(n_extra):  # more frames moving along z, rotations exactly orthonormal
        t = 50316733 + 33367 * k
        c2w = look_at_cam_to_world(np.array([0.1 * k, 0.0, -0.3 * k]), np.array([0.1 * k + 0.2, 0.1, 5.0]))
        w2c = np.linalg.inv(c2w)[:3]
        lines.append(
            f"{t} 0.474455 0.843477 0.500000 0.500000 0.000000 0.000000 "
            + " ".join(f"{v:.9f}" for v in w2c.reshape(-1))
        )
    (cams / "0000cf2ea3c0f0c1.txt").write_text(
        "https://www.youtube.com/watch?v=-aldZQifF2U\n" + "\n".join(lines) + "\n"
    )
    for ln in lines:
        (frames / "0000cf2ea3c0f0c1").mkdir(parents=True, exist_ok=True)
        (frames / "0000cf2ea3c0f0c1" / f"{ln.split()[0]}.png").write_bytes(_img(rng, 45, 80))
    return cams, frames, lines


def test_re10k_text_parsed_exactly_and_projects_like_the_peers(tmp_path):
    rng = np.random.default_rng(0)
    cams, frames, lines = _re10k_fixture(tmp_path, rng)
    parsed = re10k_imp.parse_camera_file(cams / "0000cf2ea3c0f0c1.txt")
    assert parsed.url == "https://www.youtube.com/watch?v=-aldZQifF2U"
    assert parsed.timestamps_us.tolist()[:2] == [50250000, 50283367]
    assert np.allclose(parsed.intrinsics_norm[0], [0.474455, 0.843477, 0.5, 0.5])
    assert np.allclose(parsed.world_to_cam[0, 0], [0.998855, 0.002043, -0.047815, -0.039135])
    assert np.allclose(parsed.world_to_cam[0, 2], [0.047814, 0.000398, 0.998856, -0.204567])
    cfg = re10k_imp.Re10kTextImportConfig(cameras_dir=cams, frames_dir=frames)
    _run(re10k_imp.iter_scenes(cfg), tmp_path / "out")
    scene = PosedDataset(tmp_path / "out").load_scene("0000cf2ea3c0f0c1")
    assert len(scene) == len(lines) and scene.image_format == "png" and (scene.width == 80).all()
    assert scene.meta["url"].endswith("-aldZQifF2U") and scene.source_name[0] == "50250000.png"
    point = np.array([0.4, -0.3, 3.0])
    W, H = 640, 360
    for i, ln in enumerate(lines):  # the peers: w2c from tokens 7..18, K normalised times (W, H)
        tok = [float(t) for t in ln.split()]
        w2c = np.array(tok[7:19]).reshape(3, 4)
        x = w2c[:, :3] @ point + w2c[:, 3]
        expected = [tok[1] * x[0] / x[2] + tok[3], tok[2] * x[1] / x[2] + tok[4]]
        uv, _ = cam.project_points(point[None], scene.cam_to_world[i], scene.intrinsics_norm[i], W, H)
        assert np.allclose(uv[0], np.array(expected) * [W, H], atol=1e-6)


def test_re10k_text_bad_files_skip_their_scene(tmp_path):
    rng = np.random.default_rng(1)
    cams, frames, lines = _re10k_fixture(tmp_path, rng)
    # A file with an 18-token line, a scene with a missing frame, a scene with an undecodable frame.
    (cams / "short.txt").write_text("https://youtu.be/x\n" + " ".join(lines[0].split()[:18]) + "\n")
    (frames / "short").mkdir()
    (cams / "missing.txt").write_text("https://youtu.be/y\n" + "\n".join(lines[:3]) + "\n")
    shutil.copytree(frames / "0000cf2ea3c0f0c1", frames / "missing")
    (frames / "missing" / "50283367.png").unlink()
    (cams / "broken.txt").write_text("https://youtu.be/z\n" + "\n".join(lines[:2]) + "\n")
    (frames / "broken").mkdir()
    (frames / "broken" / "50250000.png").write_bytes(_img(rng, 45, 80))
    (frames / "broken" / "50283367.png").write_bytes(_img(rng, 45, 80)[:-40])
    cfg = re10k_imp.Re10kTextImportConfig(cameras_dir=cams, frames_dir=frames)
    report = _run(re10k_imp.iter_scenes(cfg), tmp_path / "out")
    reasons = {s.scene_id: s.reason for s in report.skipped}
    assert report.scenes == 1 and set(reasons) == {"short", "missing", "broken"}
    assert "18 tokens, expected 19" in reasons["short"] and "line 2" in reasons["short"]
    assert "1 of 3 frames" in reasons["missing"] and "failed to decode" in reasons["broken"]
    # --allow-missing-frames keeps the scene without the missing frame.
    cfg2 = re10k_imp.Re10kTextImportConfig(
        cameras_dir=cams, frames_dir=frames, scenes=frozenset({"missing", "nope"}), allow_missing_frames=True
    )
    report = _run(re10k_imp.iter_scenes(cfg2), tmp_path / "out2")
    assert [s.scene_id for s in report.skipped] == ["nope"]
    scene = PosedDataset(tmp_path / "out2").load_scene("missing")
    assert scene.timestamp_us.tolist() == [50250000, 50316733] and scene.source_frame.tolist() == [0, 2]


# ------------------------------------------------------------------------------------------ DTU


def _write_cam_txt(path: Path, w2c_mm: np.ndarray, K: np.ndarray, dmin=425.0, dint=2.5) -> None:
    rows = "\n".join(" ".join(f"{v:.6f}" for v in r) + " " for r in w2c_mm)
    krows = "\n".join(" ".join(f"{v:.6f}" for v in r) + " " for r in K)
    path.write_text(f"extrinsic\n{rows}\n\nintrinsic\n{krows}\n\n{dmin} {dint}\n")


def _dtu_fixture(root: Path, rng, views=3, scans=(1, 8)) -> list[np.ndarray]:
    (root / "Cameras" / "train").mkdir(parents=True)
    w2cs = []
    for v in range(views):
        c2w = look_at_cam_to_world(np.array([-150.0 + 150 * v, -50.0, -600.0]), np.array([0.0, 0.0, 0.0]))
        w2c = np.linalg.inv(c2w)
        w2c[:3, :3] = np.round(w2c[:3, :3], 6)
        # re-orthonormalise the rounded rotation so the file is exactly what we compare with
        u, _, vt = np.linalg.svd(w2c[:3, :3])
        w2c[:3, :3] = u @ vt
        K = np.array([[361.54125, 0.0, 82.900625], [0.0, 360.3975, 66.383875], [0.0, 0.0, 1.0]])
        _write_cam_txt(root / "Cameras" / "train" / f"{v:08d}_cam.txt", w2c, K)
        w2cs.append(dtu_imp.parse_cam_file(root / "Cameras" / "train" / f"{v:08d}_cam.txt").world_to_cam)
    for s in scans:
        d = root / "Rectified" / f"scan{s}_train"
        d.mkdir(parents=True)
        for v in range(views):
            for light in (3, 6):
                (d / f"rect_{v + 1:03d}_{light}_r5000.png").write_bytes(_img(rng, 32, 40))
    return w2cs


def test_dtu_cam_file_parsed_exactly():
    text = (
        "extrinsic\n0.970263 0.00747983 0.241939 -191.02 \n-0.0147429 0.999493 0.0282234 3.28832 \n"
        "-0.241605 -0.030951 0.969881 22.5401 \n0.0 0.0 0.0 1.0 \n\nintrinsic\n361.54125 0.0 82.900625 \n"
        "0.0 360.3975 66.383875 \n0.0 0.0 1.0 \n\n425.0 2.5\n"
    )
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        p = Path(tmp) / "00000000_cam.txt"
        p.write_text(text)
        c = dtu_imp.parse_cam_file(p)
    assert c.world_to_cam[0].tolist() == [0.970263, 0.00747983, 0.241939, -191.02]
    assert (
        c.world_to_cam[2, 3] == 22.5401 and c.K[1, 2] == 66.383875 and (c.depth_min, c.depth_interval) == (425.0, 2.5)
    )


def test_dtu_import_matches_the_mvsnet_projection_and_keeps_ground_truth(tmp_path):
    rng = np.random.default_rng(2)
    w2cs = _dtu_fixture(tmp_path / "dtu", rng)
    (tmp_path / "dtu" / "Depths" / "scan1_train").mkdir(parents=True)
    (tmp_path / "dtu" / "Depths" / "scan1_train" / "depth_map_0000.pfm").write_bytes(b"Pf\n")
    (tmp_path / "dtu" / "Points" / "stl").mkdir(parents=True)
    (tmp_path / "dtu" / "Points" / "stl" / "stl001_total.ply").write_bytes(b"ply\n")
    rc = cli_main(["import", "dtu", str(tmp_path / "dtu"), "--out", str(tmp_path / "out")])
    assert rc == 0
    ds = PosedDataset(tmp_path / "out", verify=True)
    assert ds.scene_ids == ["scan1", "scan8"]
    scene = ds.load_scene("scan1")
    assert (scene.near, scene.far) == pytest.approx((2.125, 4.525)) and scene.source_name[0] == "rect_001_3_r5000.png"
    assert scene.meta["gt_points"].endswith("stl001_total.ply") and scene.meta["gt_depth_dir"].endswith("scan1_train")
    assert "gt_points" not in ds.load_scene("scan8").meta
    K160 = np.array([[361.54125, 0.0, 82.900625], [0.0, 360.3975, 66.383875], [0.0, 0.0, 1.0]])
    point_mm = np.array([20.0, -35.0, 40.0])
    for v, w2c in enumerate(w2cs):  # MVSNet: P = K @ E (mm, 160x128); the 640x512 pixel is 4x that
        x = K160 @ (w2c[:3, :3] @ point_mm + w2c[:3, 3])
        expected = 4 * x[:2] / x[2]
        uv, depth = cam.project_points(point_mm[None] / 200, scene.cam_to_world[v], scene.intrinsics_norm[v], 640, 512)
        assert np.allclose(uv[0], expected, atol=1e-6)
        assert np.isclose(depth[0], (w2c[2, :3] @ point_mm + w2c[2, 3]) / 200)


def test_dtu_bad_scan_is_skipped(tmp_path):
    rng = np.random.default_rng(3)
    _dtu_fixture(tmp_path / "dtu", rng)
    (tmp_path / "dtu" / "Rectified" / "scan8_train" / "rect_002_3_r5000.png").unlink()
    cfg = dtu_imp.DtuImportConfig(root=tmp_path / "dtu", scans=[1, 8, 9])
    report = _run(dtu_imp.iter_scenes(cfg), tmp_path / "out")
    reasons = {s.scene_id: s.reason for s in report.skipped}
    assert report.scenes == 1 and set(reasons) == {"scan8", "scan9"}
    assert "1 of 3 images missing" in reasons["scan8"] and "no Rectified/scan9_train" in reasons["scan9"]
    with pytest.raises(SeeUError, match="no Rectified/ directory"):
        dtu_imp.scan_list(dtu_imp.DtuImportConfig(root=tmp_path / "dtu" / "Rectified"))
    shutil.rmtree(tmp_path / "dtu" / "Cameras")
    with pytest.raises(SeeUError, match="no Cameras/train/"):
        dtu_imp.scan_list(dtu_imp.DtuImportConfig(root=tmp_path / "dtu"))


# ------------------------------------------------------------------------------------------ COLMAP


def colmap_fixture(root: Path, model_id, params, w=96, h=64, frames=5, ext=".png"):
    o = pycolmap.SyntheticDatasetOptions()
    o.num_rigs, o.num_cameras_per_rig, o.num_frames_per_rig, o.num_points3D = 1, 1, frames, 60
    o.camera_width, o.camera_height = w, h
    o.camera_model_id = model_id
    o.camera_params = params
    pycolmap.set_random_seed(0)
    rec = pycolmap.synthesize_dataset(o)
    (root / "sparse" / "0").mkdir(parents=True)
    (root / "images").mkdir()
    rec.write(str(root / "sparse" / "0"))
    rng = np.random.default_rng(4)
    for im in rec.images.values():
        (root / "images" / im.name).write_bytes(_img(rng, h, w, ext))
    return rec


def test_colmap_pinhole_projects_like_pycolmap(tmp_path):
    rec = colmap_fixture(tmp_path / "scene", pycolmap.CameraModelId.PINHOLE, [90.0, 85.0, 47.0, 33.0])
    rc = cli_main(
        [
            "import",
            "colmap",
            str(tmp_path / "scene" / "sparse" / "0"),
            "--images",
            str(tmp_path / "scene" / "images"),
            "--out",
            str(tmp_path / "out"),
        ]
    )
    assert rc == 0
    scene = PosedDataset(tmp_path / "out").load_scene("scene")
    names = sorted(im.name for im in rec.images.values())
    assert scene.source_name == names and scene.meta["near_far_method"].startswith("SfM point depths")
    assert 0 < scene.near < scene.far
    checked = 0
    for k, name in enumerate(names):
        image = rec.find_image_with_name(name)
        for p in list(rec.points3D.values())[:10]:
            expected = image.project_point(p.xyz)  # COLMAP's own projection (pixel centres at +0.5)
            if expected is None:
                continue
            uv, _ = cam.project_points(np.asarray(p.xyz)[None], scene.cam_to_world[k], scene.intrinsics_norm[k], 96, 64)
            assert np.allclose(uv[0], expected, atol=1e-6)
            checked += 1
    assert checked >= 10


def test_colmap_distorted_model_is_undistorted(tmp_path):
    rec = colmap_fixture(tmp_path / "s", pycolmap.CameraModelId.SIMPLE_RADIAL, [80.0, 48.0, 32.0, 0.08])
    cfg = colmap_imp.ColmapImportConfig(model_dir=tmp_path / "s" / "sparse" / "0", images_dir=tmp_path / "s" / "images")
    _run(colmap_imp.iter_scenes(cfg), tmp_path / "out")
    scene = PosedDataset(tmp_path / "out").load_scene("s")
    assert scene.meta["undistorted"].startswith("same-size pinhole")
    assert (scene.width == 96).all() and (scene.height == 64).all()  # the frame size kept (peer loaders)
    names = sorted(im.name for im in rec.images.values())
    checked = 0
    for k, name in enumerate(names):
        image = rec.find_image_with_name(name)
        distorted = rec.camera(image.camera_id)
        w, h = int(scene.width[k]), int(scene.height[k])
        for p in list(rec.points3D.values())[:10]:
            expected = image.project_point(p.xyz)  # pixel in the original, distorted image
            if expected is None:
                continue
            uv, depth = cam.project_points(
                np.asarray(p.xyz)[None], scene.cam_to_world[k], scene.intrinsics_norm[k], w, h
            )
            if depth[0] <= 0:
                continue
            # Back through the imported pinhole camera to a ray, then through COLMAP's distorted model.
            K = cam.intrinsics_pixels(scene.intrinsics_norm[k], w, h)
            ray = np.array([(uv[0, 0] - K[0, 2]) / K[0, 0], (uv[0, 1] - K[1, 2]) / K[1, 1], 1.0])
            assert np.allclose(distorted.img_from_cam(ray), expected, atol=1e-4)
            checked += 1
    assert checked >= 10 and not np.allclose(scene.intrinsics_norm[0], [80 / 96, 80 / 64, 0.5, 0.5])
    # Refusing instead of undistorting, and an unknown model, are one-line errors.
    args = [
        "import",
        "colmap",
        str(tmp_path / "s" / "sparse" / "0"),
        "--images",
        str(tmp_path / "s" / "images"),
        "--out",
        str(tmp_path / "o2"),
    ]
    assert cli_main(args + ["--no-undistort"]) == 2
    text_model = tmp_path / "txt"
    text_model.mkdir()
    rec.write_text(str(text_model))
    lines = [
        ln if ln.startswith("#") else "1 EQUIRECTANGULAR 96 64 96 64"
        for ln in (text_model / "cameras.txt").read_text().splitlines()
    ]
    (text_model / "cameras.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(SeeUError, match="unsupported camera model EQUIRECTANGULAR"):
        list(
            colmap_imp.iter_scenes(
                colmap_imp.ColmapImportConfig(model_dir=text_model, images_dir=tmp_path / "s" / "images")
            )
        )


# ------------------------------------------------------------------------------------------ nerfstudio


def nerfstudio_from_colmap(rec, root: Path, images: Path) -> Path:
    """transforms.json exactly as nerfstudio's colmap_to_json writes it (keep_original_world_coordinate=False)."""
    frames = []
    for im in rec.images.values():
        w2c = np.eye(4)
        w2c[:3] = im.cam_from_world().matrix()
        c2w = np.linalg.inv(w2c)
        c2w[0:3, 1:3] *= -1
        c2w = c2w[np.array([0, 2, 1, 3]), :]
        c2w[2, :] *= -1
        frames.append(
            {"file_path": f"./images/{im.name}", "transform_matrix": c2w.tolist(), "colmap_im_id": im.image_id}
        )
    c = next(iter(rec.cameras.values()))
    applied = np.eye(4)[:3, :][np.array([0, 2, 1]), :]
    applied[2, :] *= -1
    doc = {
        "w": c.width,
        "h": c.height,
        "fl_x": c.params[0],
        "fl_y": c.params[1],
        "cx": c.params[2],
        "cy": c.params[3],
        "k1": 0.0,
        "k2": 0.0,
        "p1": 0.0,
        "p2": 0.0,
        "camera_model": "OPENCV",
        "frames": frames,
        "applied_transform": applied.tolist(),
    }
    root.mkdir(parents=True, exist_ok=True)
    shutil.copytree(images, root / "images")
    (root / "transforms.json").write_text(json.dumps(doc, indent=4))
    return root / "transforms.json"


def test_nerfstudio_projects_like_nerfstudio_and_matches_colmap(tmp_path):
    rec = colmap_fixture(tmp_path / "scene", pycolmap.CameraModelId.PINHOLE, [90.0, 85.0, 47.0, 33.0], ext=".jpg")
    tj = nerfstudio_from_colmap(rec, tmp_path / "ns", tmp_path / "scene" / "images")
    _run(ns_imp.iter_scenes(ns_imp.NerfstudioImportConfig(transforms=tj)), tmp_path / "a")
    _run(ns_imp.iter_scenes(ns_imp.NerfstudioImportConfig(transforms=tj, undo_applied_transform=False)), tmp_path / "b")
    _run(
        colmap_imp.iter_scenes(
            colmap_imp.ColmapImportConfig(
                model_dir=tmp_path / "scene" / "sparse" / "0", images_dir=tmp_path / "scene" / "images"
            )
        ),
        tmp_path / "c",
    )
    undone = PosedDataset(tmp_path / "a").load_scene("ns")
    kept = PosedDataset(tmp_path / "b").load_scene("ns")
    via_colmap = PosedDataset(tmp_path / "c").load_scene("scene")
    assert undone.image_format == "jpeg" and undone.images == via_colmap.images
    assert np.allclose(undone.cam_to_world, via_colmap.cam_to_world, atol=1e-9)
    assert np.allclose(undone.intrinsics_norm, via_colmap.intrinsics_norm, atol=1e-12)
    doc = json.loads(tj.read_text())
    A = cam.homogeneous_from_3x4(np.array(doc["applied_transform"]))
    point = np.array([0.3, 0.2, 0.1])  # a point in the COLMAP world
    point_ns = (A @ np.append(point, 1.0))[:3]
    for k, f in enumerate(sorted(doc["frames"], key=lambda f: f["file_path"])):
        # nerfstudio's pinhole: camera looks down -z, image y down = -camera y.
        x = np.linalg.inv(np.array(f["transform_matrix"])) @ np.append(point_ns, 1.0)
        expected = [doc["cx"] + doc["fl_x"] * x[0] / -x[2], doc["cy"] - doc["fl_y"] * x[1] / -x[2]]
        uv, _ = cam.project_points(point[None], undone.cam_to_world[k], undone.intrinsics_norm[k], 96, 64)
        uv_kept, _ = cam.project_points(point_ns[None], kept.cam_to_world[k], kept.intrinsics_norm[k], 96, 64)
        assert np.allclose(uv[0], expected, atol=1e-6) and np.allclose(uv_kept[0], expected, atol=1e-6)


def test_nerfstudio_refuses_unknown_models_and_names_missing_frames(tmp_path, capsys):
    rec = colmap_fixture(tmp_path / "scene", pycolmap.CameraModelId.PINHOLE, [90.0, 85.0, 47.0, 33.0])
    tj = nerfstudio_from_colmap(rec, tmp_path / "ns", tmp_path / "scene" / "images")
    doc = json.loads(tj.read_text())
    for change, extra, message in (
        ({"k1": 0.1}, ["--no-undistort"], "distortion"),
        ({"k4": 0.01}, [], "k4"),
        ({"camera_model": "EQUIRECTANGULAR"}, [], "camera_model"),
    ):
        (tmp_path / "ns" / "transforms.json").write_text(json.dumps({**doc, **change}))
        rc = cli_main(["import", "nerfstudio", str(tj), "--out", str(tmp_path / "o")] + extra)
        err = capsys.readouterr().err
        assert rc == 2 and message in err and len(err.strip().splitlines()) == 1
    # A missing frame file skips the (only) scene: nothing usable -> exit 2, no manifest; the error
    # names the file and the flag. With --skip-missing the frame is dropped and counted.
    (tmp_path / "ns" / "transforms.json").write_text(json.dumps(doc))
    gone = sorted((tmp_path / "ns" / "images").iterdir())[1]
    gone.unlink()
    assert cli_main(["import", "nerfstudio", str(tj), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert gone.name in err and "--skip-missing" in err and not (tmp_path / "o" / "manifest.json").exists()
    assert cli_main(["import", "nerfstudio", str(tj), "--skip-missing", "--out", str(tmp_path / "o")]) == 0
    out = capsys.readouterr().out
    assert "dropped 1 frames" in out
    manifest = json.loads((tmp_path / "o" / "manifest.json").read_text())
    assert manifest["report"]["skipped_frames"] == 1
    scene = PosedDataset(tmp_path / "o").load_scene("ns")
    assert len(scene) == len(doc["frames"]) - 1 and f"./images/{gone.name}" not in scene.source_name
    assert [d["frame"] for d in scene.meta["skipped_frames"]] == [f"./images/{gone.name}"]


def _blob_image(h: int, w: int, centres: list[np.ndarray], sigma: float = 1.2) -> np.ndarray:
    """Grey image with a bright Gaussian blob centred on each continuous pixel position (pixel
    (i, j) covers [i, i + 1) x [j, j + 1), the COLMAP / nerfstudio convention)."""
    ys, xs = np.mgrid[0:h, 0:w] + 0.5
    img = np.zeros((h, w))
    for u, v in centres:
        img += np.exp(-((xs - u) ** 2 + (ys - v) ** 2) / (2 * sigma**2))
    return np.clip(20 + 235 * img, 0, 255).astype(np.uint8)


def _blob_centre(img: np.ndarray, near: np.ndarray, radius: int = 5) -> np.ndarray:
    """Intensity-weighted centre (continuous pixel coordinates) of the blob around `near`."""
    x0, y0 = int(near[0]), int(near[1])
    patch = img[max(y0 - radius, 0) : y0 + radius + 1, max(x0 - radius, 0) : x0 + radius + 1].astype(np.float64) - 20
    patch = np.clip(patch, 0, None)
    ys, xs = (
        np.mgrid[
            max(y0 - radius, 0) : max(y0 - radius, 0) + patch.shape[0],
            max(x0 - radius, 0) : max(x0 - radius, 0) + patch.shape[1],
        ]
        + 0.5
    )
    return np.array([(xs * patch).sum(), (ys * patch).sum()]) / patch.sum()


@pytest.mark.parametrize(
    "model,dist",
    [
        ("OPENCV", {"k1": -0.3, "k2": 0.08, "p1": 0.003, "p2": -0.002}),
        ("OPENCV", {"k1": -0.25, "k2": 0.05, "k3": 0.02, "p1": 0.0, "p2": 0.001}),
        ("OPENCV_FISHEYE", {"k1": 0.05, "k2": -0.01, "k3": 0.004, "k4": -0.001}),
    ],
)
def test_nerfstudio_distorted_frames_are_undistorted_like_opencv_projects(tmp_path, model, dist):
    """A 3-D point projected with OpenCV's distortion model (cv2.projectPoints / cv2.fisheye) marks
    the distorted frame; after import, the same point through the imported pinhole camera lands on
    that mark in the undistorted frame."""
    w, h, fx, fy, cx, cy = 160, 120, 110.0, 108.0, 81.3, 58.6
    K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    rng = np.random.default_rng(5)
    points = np.array([[1.2, 0.8, 3.0], [-1.1, -0.75, 3.0], [0.05, -0.02, 2.5]])
    (tmp_path / "ns" / "images").mkdir(parents=True)
    frames, expected_shift = [], 0.0
    for k in range(3):
        c2w = look_at_cam_to_world(np.array([0.05 * k, 0.02 * k, 0.0]), np.array([0.05 * k, 0.0, 3.0]))
        w2c = np.linalg.inv(c2w)
        rvec, _ = cv2.Rodrigues(w2c[:3, :3])
        if model == "OPENCV_FISHEYE":
            d = np.array([dist["k1"], dist["k2"], dist["k3"], dist["k4"]])
            uv, _ = cv2.fisheye.projectPoints(points[None], rvec, w2c[:3, 3], K, d)
        else:
            d = np.array([dist["k1"], dist["k2"], dist["p1"], dist["p2"], dist.get("k3", 0.0)])
            uv, _ = cv2.projectPoints(points, rvec, w2c[:3, 3], K, d)
        uv = uv.reshape(-1, 2)
        pinhole, _ = cv2.projectPoints(points, rvec, w2c[:3, 3], K, None)
        expected_shift = max(expected_shift, float(np.abs(uv - pinhole.reshape(-1, 2)).max()))
        img = _blob_image(h, w, list(uv)) + rng.integers(0, 3, (h, w), dtype=np.uint8)
        ok, buf = cv2.imencode(".png", img)
        (tmp_path / "ns" / "images" / f"f{k}.png").write_bytes(buf.tobytes())
        frames.append({"file_path": f"images/f{k}.png", "transform_matrix": cam.opengl_from_opencv(c2w).tolist()})
    assert expected_shift > 2.0  # the distortion matters: without undistortion the test fails
    doc = {"camera_model": model, "w": w, "h": h, "fl_x": fx, "fl_y": fy, "cx": cx, "cy": cy, **dist, "frames": frames}
    (tmp_path / "ns" / "transforms.json").write_text(json.dumps(doc))
    assert (
        cli_main(["import", "nerfstudio", str(tmp_path / "ns" / "transforms.json"), "--out", str(tmp_path / "out")])
        == 0
    )
    scene = PosedDataset(tmp_path / "out").load_scene("ns")
    assert scene.meta["undistorted"].startswith("same-size pinhole")
    for k in range(3):
        img = cv2.imdecode(np.frombuffer(scene.images[k], np.uint8), cv2.IMREAD_GRAYSCALE)
        sw, sh = int(scene.width[k]), int(scene.height[k])
        assert img.shape == (sh, sw) == (h, w)  # the frame size kept
        uv, depth = cam.project_points(points, scene.cam_to_world[k], scene.intrinsics_norm[k], sw, sh)
        for p in range(len(points)):
            assert depth[p] > 0 and 6 <= uv[p, 0] < sw - 6 and 6 <= uv[p, 1] < sh - 6
            assert np.allclose(_blob_centre(img, uv[p]), uv[p], atol=0.25), (k, p)


# ------------------------------------------------------------------------------------------ resume


def _files(out: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(out.glob("posed-*.arrow"))}


def _mtimes(out: Path) -> dict[str, int]:
    return {p.name: p.stat().st_mtime_ns for p in sorted(out.glob("posed-*.arrow"))}


def _touch(path: Path) -> None:
    st = path.stat()
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))


def _counting(monkeypatch, module, name: str, key) -> list:
    """Replace `module.name` with a wrapper that records `key(*args)` of every call."""
    calls: list = []
    real = getattr(module, name)

    def wrapper(*args, **kw):
        calls.append(key(*args))
        return real(*args, **kw)

    monkeypatch.setattr(module, name, wrapper)
    return calls


def _re10k_plan_import(cams, frames, out, near=1.0, **kw) -> ImportReport:
    """Every camera file closes its own output file (target size 1 byte), as the pixelsplat resume test does."""
    cfg = re10k_imp.Re10kTextImportConfig(cameras_dir=cams, frames_dir=frames, near=near, **kw)
    return write_import(
        re10k_imp.import_plan(cfg),
        out,
        ImportReport("re10k"),
        params={"near": near},
        provenance={},
        target_file_bytes=1,
    )


def test_re10k_rerun_resumes_scene_by_scene(tmp_path, monkeypatch):
    rng = np.random.default_rng(20)
    cams, frames, lines = _re10k_fixture(tmp_path, rng, n_extra=1)
    src = cams / "0000cf2ea3c0f0c1.txt"
    for sid in ("s0", "s1", "s2"):
        shutil.copy(src, cams / f"{sid}.txt")
        shutil.copytree(frames / src.stem, frames / sid)
    src.unlink()
    (cams / "broken.txt").write_text("https://youtu.be/z\n" + " ".join(lines[0].split()[:18]) + "\n")
    scenes = frozenset({"s0", "s1", "s2", "broken", "nope"})
    out = tmp_path / "out"
    first = _re10k_plan_import(cams, frames, out, scenes=scenes)
    expected, mtimes = _files(out), _mtimes(out)
    assert len(expected) == 3 and {s.scene_id for s in first.skipped} == {"broken", "nope"}
    read = _counting(monkeypatch, re10k_imp, "scene_from_files", lambda f, cfg: f.stem)

    # a complete output: nothing read, nothing rewritten, the same skips reported
    report = _re10k_plan_import(cams, frames, out, scenes=scenes)
    assert read == [] and report.notes["resumed_files"] == 3 and report.scenes == 3
    assert _files(out) == expected and _mtimes(out) == mtimes
    assert sorted(s.scene_id for s in report.skipped) == ["broken", "nope"]
    assert {s.reason for s in report.skipped} == {s.reason for s in first.skipped}
    assert "(3 scenes in 3 files kept from a previous run)" in report.summary_line(out)
    assert validate_dataset(out)["unlisted_files"] == []

    # one frame of s1 touched: s1 and the scenes after it are read again, with the same bytes
    _touch(frames / "s1" / f"{lines[0].split()[0]}.png")
    report = _re10k_plan_import(cams, frames, out, scenes=scenes)
    assert read == ["s1", "s2"] and report.notes["resumed_files"] == 1 and _files(out) == expected
    # the last scene's camera file replaced: only it is read
    read.clear()
    (cams / "s2.txt").write_text((cams / "s2.txt").read_text())
    _touch(cams / "s2.txt")
    _re10k_plan_import(cams, frames, out, scenes=scenes)
    assert read == ["s2"] and _files(out) == expected
    # a frame added to s0 (the scene now has a frame without a camera line): s0 redone, and skipped
    # (broken, a scene skipped before s0, is recorded with s0's file and so is read again too)
    read.clear()
    (frames / "s0" / "99999999.png").write_bytes(_img(rng, 45, 80))
    report = _re10k_plan_import(cams, frames, out, scenes=scenes)
    assert read == ["broken", "s0", "s1", "s2"] and "s0" in {s.scene_id for s in report.skipped}
    (frames / "s0" / "99999999.png").unlink()
    # other options: everything read again
    _re10k_plan_import(cams, frames, out, scenes=scenes)
    read.clear()
    report = _re10k_plan_import(cams, frames, out, near=0.5, scenes=scenes)
    assert read == ["broken", "s0", "s1", "s2"] and "resumed_files" not in report.notes
    assert validate_dataset(out)["unlisted_files"] == []


def test_dtu_rerun_resumes_scan_by_scan(tmp_path, monkeypatch):
    rng = np.random.default_rng(21)
    root = tmp_path / "dtu"
    _dtu_fixture(root, rng, scans=(1, 8, 21))

    def run(out, **kw):
        cfg = dtu_imp.DtuImportConfig(root=root, scans=[1, 8, 9, 21], **kw)
        return write_import(
            dtu_imp.import_plan(cfg),
            out,
            ImportReport("dtu"),
            params={"lighting": cfg.lighting},
            provenance={},
            target_file_bytes=1,
        )

    out = tmp_path / "out"
    first = run(out)
    expected, mtimes = _files(out), _mtimes(out)
    assert len(expected) == 3 and [s.scene_id for s in first.skipped] == ["scan9"]
    read = _counting(monkeypatch, dtu_imp, "scene_for_scan", lambda scan, cams, cfg: scan)
    cams_read = _counting(monkeypatch, dtu_imp, "read_cameras", lambda r: 1)
    report = run(out)
    assert read == [] and cams_read == [] and report.notes["resumed_files"] == 3
    assert _files(out) == expected and _mtimes(out) == mtimes and report.scenes == 3
    assert [(s.scene_id, s.reason) for s in report.skipped] == [(s.scene_id, s.reason) for s in first.skipped]
    assert validate_dataset(out)["unlisted_files"] == []

    _touch(root / "Rectified" / "scan8_train" / "rect_002_3_r5000.png")  # an image of scan8
    run(out)
    assert read == [8, 9, 21] and cams_read == [1] and _files(out) == expected
    read.clear()
    _touch(root / "Rectified" / "scan1_train" / "rect_002_6_r5000.png")  # another lighting: not read, kept
    run(out)
    assert read == []
    (root / "Points" / "stl").mkdir(parents=True)  # ground truth for scan21 (skipped scan9 shares its file)
    (root / "Points" / "stl" / "stl021_total.ply").write_bytes(b"ply\n")
    run(out)
    assert read == [9, 21] and PosedDataset(out).load_scene("scan21").meta["gt_points"].endswith("stl021_total.ply")
    read.clear()
    _touch(root / "Cameras" / "train" / "00000001_cam.txt")  # shared by every scan
    run(out)
    assert read == [1, 8, 9, 21]
    read.clear()
    report = run(out, lighting=6)  # other options
    assert read == [1, 8, 9, 21] and "resumed_files" not in report.notes
    assert validate_dataset(out)["unlisted_files"] == []


def test_cli_rerun_of_dtu_and_re10k_keeps_everything(tmp_path, capsys):
    rng = np.random.default_rng(22)
    _dtu_fixture(tmp_path / "dtu", rng)
    cams, frames, _ = _re10k_fixture(tmp_path, rng, n_extra=1)
    for cmd in (
        ["import", "dtu", str(tmp_path / "dtu"), "--scans", "1,8,9"],
        ["import", "re10k", "--cameras", str(cams), "--frames", str(frames), "--scenes", "0000cf2ea3c0f0c1,nope"],
    ):
        out = tmp_path / f"out-{cmd[1]}"
        assert cli_main([*cmd, "--out", str(out)]) == 0
        first = capsys.readouterr().out
        doc1, files1 = json.loads((out / "manifest.json").read_text()), _files(out)
        assert cli_main([*cmd, "--out", str(out)]) == 0
        second = capsys.readouterr().out
        doc2 = json.loads((out / "manifest.json").read_text())
        assert "kept from a previous run" not in first and "kept from a previous run" in second
        assert "skipped 1 scenes" in first and "skipped 1 scenes" in second
        assert doc2["report"]["resumed_files"] == 1 and _files(out) == files1
        assert doc1["files"] == doc2["files"] and doc1["scenes"] == doc2["scenes"]
        assert doc1["report"]["skipped"] == doc2["report"]["skipped"]
        assert validate_dataset(out)["unlisted_files"] == []


@pytest.mark.parametrize("fmt", ["colmap", "nerfstudio"])
def test_single_scene_formats_resume_until_an_input_changes(tmp_path, capsys, fmt):
    rec = colmap_fixture(tmp_path / "scene", pycolmap.CameraModelId.PINHOLE, [90.0, 85.0, 47.0, 33.0])
    if fmt == "colmap":
        cmd = [
            "import",
            "colmap",
            str(tmp_path / "scene" / "sparse" / "0"),
            "--images",
            str(tmp_path / "scene" / "images"),
        ]
        images, model_file = tmp_path / "scene" / "images", tmp_path / "scene" / "sparse" / "0" / "images.bin"
    else:
        tj = nerfstudio_from_colmap(rec, tmp_path / "ns", tmp_path / "scene" / "images")
        cmd = ["import", "nerfstudio", str(tj)]
        images, model_file = tmp_path / "ns" / "images", tj
    out = tmp_path / "out"
    cmd += ["--out", str(out)]

    def run(*extra) -> tuple[str, dict]:
        assert cli_main([*cmd, *extra]) == 0
        return capsys.readouterr().out, json.loads((out / "manifest.json").read_text())

    line, doc = run()
    files, mtimes = _files(out), _mtimes(out)
    assert "kept" not in line and len(files) == 1
    line, doc2 = run()
    assert "(1 scenes in 1 files kept from a previous run)" in line and doc2["report"]["resumed_files"] == 1
    assert _files(out) == files and _mtimes(out) == mtimes and doc2["scenes"] == doc["scenes"]
    assert validate_dataset(out)["unlisted_files"] == []
    for changed in (sorted(images.iterdir())[1], model_file):  # a referenced image, the model / transforms.json
        _touch(changed)
        line, doc3 = run()
        assert "kept" not in line and "resumed_files" not in doc3["report"] and _files(out) == files
        assert "kept" in run()[0]
    line, doc4 = run("--near", "0.01")  # other options
    assert "kept" not in line and doc4["scenes"][0]["near"] == 0.01
    assert validate_dataset(out)["unlisted_files"] == []
