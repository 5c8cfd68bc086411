"""Exporters: nerfstudio folders and pixelSplat chunks round-trip through the importers
(cameras to 1e-6, image bytes identical), and read the way the peer tools read them."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import torch

from pipelines.cli import main as cli_main
from seeu_data import cameras as cam
from seeu_data.store.posed import PosedDataset, PosedDatasetWriter
from tests.helpers import make_posed_scene


def _dataset(path: Path) -> list:
    scenes = [
        make_posed_scene("alpha", n=5, seed=3),
        make_posed_scene("beta", n=3, seed=4, image_format="png", height=40, width=50),
    ]
    scenes[0].cam_to_world[:, :3, 3] += [3.0, -2.0, 7.5]  # not near the origin
    scenes[0].intrinsics_norm[:, 2] = 0.47
    scenes[1].meta = {"url": "https://example.org/beta", "dataset": "mine"}
    with PosedDatasetWriter(path, params={}, provenance={}) as w:
        for s in scenes:
            w.add(s)
    return scenes


def _assert_same(got, orig, timestamps=True):
    assert got.images == orig.images and got.image_format == orig.image_format
    assert np.allclose(got.cam_to_world, orig.cam_to_world, atol=1e-6)
    assert np.allclose(got.intrinsics_norm, orig.intrinsics_norm, atol=1e-6)
    assert np.array_equal(got.width, orig.width) and np.array_equal(got.height, orig.height)
    assert np.array_equal(got.source_frame, orig.source_frame) and got.source_name == orig.source_name
    assert got.near == orig.near and got.far == orig.far
    if timestamps:
        assert np.array_equal(got.timestamp_us, orig.timestamp_us)


def test_nerfstudio_round_trip_and_layout(tmp_path):
    scenes = _dataset(tmp_path / "posed")
    assert cli_main(["export", "nerfstudio", str(tmp_path / "posed"), "--out", str(tmp_path / "ns")]) == 0
    doc = json.loads((tmp_path / "ns" / "alpha" / "transforms.json").read_text())
    f0 = doc["frames"][0]
    assert doc["camera_model"] == "OPENCV" and f0["file_path"] == "images/frame_00000.jpg"
    assert (tmp_path / "ns" / "alpha" / f0["file_path"]).read_bytes() == scenes[0].images[0]
    # nerfstudio reads an OpenGL camera-to-world and pixel intrinsics: project a point its way.
    point = np.array([3.2, -1.9, 9.0])
    x = np.linalg.inv(np.array(f0["transform_matrix"])) @ np.append(point, 1.0)
    uv_ns = [f0["cx"] + f0["fl_x"] * x[0] / -x[2], f0["cy"] - f0["fl_y"] * x[1] / -x[2]]
    uv, _ = cam.project_points(point[None], scenes[0].cam_to_world[0], scenes[0].intrinsics_norm[0], 64, 48)
    assert np.allclose(uv[0], uv_ns, atol=1e-9)
    for s in scenes:
        out = tmp_path / f"back_{s.scene_id}"
        assert (
            cli_main(["import", "nerfstudio", str(tmp_path / "ns" / s.scene_id / "transforms.json"), "--out", str(out)])
            == 0
        )
        back = PosedDataset(out)
        assert back.scene_ids == [s.scene_id]
        got = back.load_scene(s.scene_id)
        _assert_same(got, s)
    assert PosedDataset(tmp_path / "back_beta").load_scene("beta").meta["url"] == "https://example.org/beta"


def test_pixelsplat_export_cli_and_reimport(tmp_path, capsys):
    scenes = _dataset(tmp_path / "posed")
    assert (
        cli_main(
            [
                "export",
                "pixelsplat",
                str(tmp_path / "posed"),
                "--out",
                str(tmp_path / "ps"),
                "--stage",
                "train",
                "--scenes",
                "beta",
                "--resize",
                "none",
            ]
        )
        == 0
    )
    err = capsys.readouterr().err.strip()
    assert "would skip 1 of 1 scenes" in err and "50x40" in err and "\n" not in err
    index = json.loads((tmp_path / "ps" / "train" / "index.json").read_text())
    assert index == {"beta": "000000.torch"}
    # The peer loader's view: intrinsics and the 3x4 world-to-camera from the 18 numbers.
    ex = torch.load(tmp_path / "ps" / "train" / "000000.torch", weights_only=True)[0]
    w2c = torch.eye(4, dtype=torch.float64)
    w2c[:3] = ex["cameras"][0, 6:].double().view(3, 4)
    assert torch.allclose(w2c.inverse(), torch.from_numpy(scenes[1].cam_to_world[0]), atol=1e-6)
    assert ex["cameras"][0, 4:6].abs().sum() == 0
    assert cli_main(["import", "pixelsplat", str(tmp_path / "ps"), "--out", str(tmp_path / "back")]) == 0
    _assert_same(PosedDataset(tmp_path / "back").load_scene("beta"), scenes[1])
    # Unknown scene: one-line error.
    assert (
        cli_main(["export", "pixelsplat", str(tmp_path / "posed"), "--out", str(tmp_path / "x"), "--scenes", "gamma"])
        == 2
    )
    assert "gamma" in capsys.readouterr().err


def _blob_scene(scene_id: str, height: int, width: int, point: np.ndarray) -> tuple:
    """Two frames of `height x width` (H x W): a dark image with a bright Gaussian blob (sigma 4 px)
    where the frame's camera puts `point` (3,), pixel centres at +0.5. Returns (scene, (N, 2) pixels)."""
    scene = make_posed_scene(scene_id, n=2, height=height, width=width)
    uv, _ = cam.project_points(point[None], scene.cam_to_world, scene.intrinsics_norm, width, height)
    x, y = np.arange(width) + 0.5, np.arange(height) + 0.5
    images = []
    for u, v in uv[:, 0]:
        blob = 20.0 + 200.0 * np.exp(-((x[None] - u) ** 2 + (y[:, None] - v) ** 2) / (2 * 4.0**2))
        ok, buf = cv2.imencode(".png", np.repeat(blob[..., None], 3, 2).round().astype(np.uint8))
        images.append(buf.tobytes())
    scene.images, scene.image_format = images, "png"
    return scene, uv[:, 0]


def test_pixelsplat_export_default_resizes_any_size_to_the_peers_frame(tmp_path, capsys):
    """Default export: every frame 360x640 (H x W) whatever its source size, and the exported cameras
    put a known 3-D point where the source camera put it after the peers' resize + centre crop
    (scale s = max(360 / H, 640 / W) to cover, crop the middle: the peers' `rescale_and_crop`), and where
    the frame's pixels show it (a blob drawn at its projection). `--resize none` keeps the source size."""
    point = np.array([0.07, 0.04, 0.0])
    sizes = {"landscape": (720, 1280), "portrait": (1280, 720), "four_three": (480, 640)}
    made = {k: _blob_scene(k, h, w, point) for k, (h, w) in sizes.items()}
    with PosedDatasetWriter(tmp_path / "posed", params={}, provenance={}) as w:
        for scene, _ in made.values():
            w.add(scene)
    argv = ["export", "pixelsplat", str(tmp_path / "posed"), "--size-check", "refuse"]
    assert cli_main([*argv, "--out", str(tmp_path / "ps")]) == 0
    index = json.loads((tmp_path / "ps" / "test" / "index.json").read_text())
    examples = {ex["key"]: ex for ex in torch.load(tmp_path / "ps" / "test" / "000000.torch", weights_only=True)}
    assert sorted(index) == sorted(examples) == sorted(sizes)
    for key, (h, w) in sizes.items():
        ex, (scene, uv_src) = examples[key], made[key]
        s = max(360 / h, 640 / w)
        oy, ox = (round(h * s) - 360) // 2, (round(w * s) - 640) // 2
        expected = uv_src * [round(w * s) / w, round(h * s) / h] - [ox, oy]  # source pixels after resize + crop
        w2c = torch.eye(4, dtype=torch.float64).repeat(2, 1, 1)
        w2c[:, :3] = ex["cameras"][:, 6:].double().view(2, 3, 4)
        uv, _ = cam.project_points(point[None], w2c.inverse().numpy(), ex["cameras"][:, :4].double().numpy(), 640, 360)
        assert np.abs(uv[:, 0] - expected).max() < 1e-3, (key, uv[:, 0], expected)
        for i, data in enumerate(ex["images"]):
            img = cv2.imdecode(data.numpy(), cv2.IMREAD_GRAYSCALE).astype(np.float64)
            assert img.shape == (360, 640)
            u0, v0 = np.round(expected[i]).astype(int)
            win = np.clip(img[v0 - 12 : v0 + 13, u0 - 12 : u0 + 13] - 20.0, 0, None)
            yy, xx = np.mgrid[v0 - 12 : v0 + 13, u0 - 12 : u0 + 13] + 0.5
            centroid = np.array([(win * xx).sum(), (win * yy).sum()]) / win.sum()
            assert np.abs(centroid - expected[i]).max() < 0.1, (key, centroid, expected[i])
    # --resize none: frames as stored (the loaders would skip them: one warning line)
    assert cli_main([*argv[:-2], "--out", str(tmp_path / "native"), "--resize", "none", "--scenes", "landscape"]) == 0
    assert "would skip 1 of 1 scenes" in capsys.readouterr().err
    (ex,) = torch.load(tmp_path / "native" / "test" / "000000.torch", weights_only=True)
    assert bytes(ex["images"][0].numpy()) == made["landscape"][0].images[0]
