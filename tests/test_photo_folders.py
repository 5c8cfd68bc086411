"""A folder of unordered photos in portrait and landscape (EXIF-rotated or not) posed by `seeu ingest`:
exhaustive matching (`--matcher auto` on an image folder), one camera per frame size, per-frame
intrinsics in the posed chunks, centres against the synthetic ground truth."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from seeu_data.ingest.match_graph import EXHAUSTIVE_MAX_IMAGES, UNORDERED_OVERLAP, choose_matcher
from seeu_data.ingest.pose_eval import umeyama
from seeu_data.synthetic import camera_path, default_intrinsics_norm, make_scene, render_view

EXIF_ROTATE_CW = 6  # EXIF orientation 6: the stored pixels are shown turned 90 degrees clockwise
LONG, SHORT = 240, 180


def _jpeg_with_orientation(rgb: np.ndarray, orientation: int, path: Path) -> None:
    from PIL import Image

    image = Image.fromarray(rgb)
    exif = image.getexif()
    exif[0x0112] = orientation
    image.save(path, quality=95, exif=exif.tobytes())


def write_photo_folder(folder: Path, n: int = 21, seed: int = 0) -> dict[str, np.ndarray]:
    """`n` photos of the synthetic corridor along its walk-through path, under shuffled names: every
    third one rendered portrait, every third one rendered landscape but stored turned 90 degrees
    counter-clockwise with an EXIF orientation tag saying so, the rest landscape. Returns the
    ground-truth camera-to-world pose `(4, 4)` of each file name (as the photo is shown, upright)."""
    folder.mkdir(parents=True)
    scene = make_scene(seed)
    poses = camera_path(n)
    order = np.random.default_rng(seed).permutation(n)
    truth = {}
    for i, c2w in enumerate(poses):
        name = f"IMG_{order[i] * 7 % 1000:04d}.jpg"
        kind = i % 3
        w, h = (SHORT, LONG) if kind == 0 else (LONG, SHORT)
        rgb, _ = render_view(scene, c2w, default_intrinsics_norm(w, h), w, h)
        if kind == 1:  # shown upright only when the EXIF orientation is applied
            _jpeg_with_orientation(np.ascontiguousarray(np.rot90(rgb, 1)), EXIF_ROTATE_CW, folder / name)
        else:
            cv2.imwrite(str(folder / name), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 95])
        truth[name] = c2w
    return truth


def test_exif_orientation_is_applied_when_decoding(tmp_path):
    from seeu_data.ingest.video import discover_sources, iter_frames

    rgb = np.zeros((30, 40, 3), np.uint8)
    rgb[:5] = 255  # a white top band, shown at the top once turned upright
    (tmp_path / "p").mkdir()
    _jpeg_with_orientation(np.ascontiguousarray(np.rot90(rgb, 1)), EXIF_ROTATE_CW, tmp_path / "p" / "a.jpg")
    (frame,) = iter_frames(discover_sources([tmp_path / "p"])[0])
    assert frame.rgb.shape == (30, 40, 3)
    assert frame.rgb[:5].mean() > 200 and frame.rgb[10:].mean() < 50


def test_choose_matcher():
    assert choose_matcher("auto", True, 1000, 10)["used"] == "sequential"
    small = choose_matcher("auto", False, EXHAUSTIVE_MAX_IMAGES, 10)
    assert small["used"] == "exhaustive" and not small["quadratic"] and small["shortlist"]
    assert not choose_matcher("auto", False, 21, 10)["shortlist"]  # few enough: every pair
    large = choose_matcher("auto", False, EXHAUSTIVE_MAX_IMAGES + 1, 10)
    assert (large["used"], large["overlap"], large["quadratic"]) == ("sequential", UNORDERED_OVERLAP, False)
    assert choose_matcher("sequential", False, 20, 10)["overlap"] == 10
    assert choose_matcher("exhaustive", True, 5000, 10)["used"] == "exhaustive"


def test_unordered_mixed_orientation_photos(tmp_path):
    from pipelines.ingest import IngestConfig, ingest
    from seeu_data.ingest.chunks import ChunkConfig
    from seeu_data.store.posed import PosedDataset

    truth = write_photo_folder(tmp_path / "photos")
    cfg = IngestConfig(out=tmp_path / "out", inputs=(tmp_path / "photos",), chunks=ChunkConfig(min_chunk_frames=3))
    (result,) = ingest(cfg)
    report = result.report
    assert report["sfm"]["matcher"]["used"] == "exhaustive", report["sfm"]["matcher"]
    posed = PosedDataset(tmp_path / "out" / "photos")
    names, est = [], []
    sizes = set()
    gt_centres = np.stack([c[:3, 3] for c in truth.values()])
    extent = float(np.linalg.norm(gt_centres.max(0) - gt_centres.min(0)))
    worst = 0.0
    for sid in posed.scene_ids:
        scene = posed.load_scene(sid)
        names += list(scene.source_name)
        sizes |= {(int(w), int(h)) for w, h in zip(scene.width, scene.height)}
        for i, data in enumerate(scene.images):  # every frame upright, its size in the table
            img = cv2.imdecode(np.frombuffer(bytes(data), np.uint8), cv2.IMREAD_COLOR)
            assert img.shape[:2] == (scene.height[i], scene.width[i])
            truth_intr = default_intrinsics_norm(int(scene.width[i]), int(scene.height[i]))
            assert np.allclose(scene.intrinsics_norm[i], truth_intr, rtol=0.03), (scene.intrinsics_norm[i], truth_intr)
        gt = np.stack([truth[n][:3, 3] for n in scene.source_name])
        if len(gt) >= 3:
            sim = umeyama(scene.cam_to_world[:, :3, 3], gt)
            worst = max(worst, float(np.linalg.norm(sim.apply(scene.cam_to_world[:, :3, 3]) - gt, axis=1).max()))
        est += list(scene.cam_to_world)
    assert sizes == {(SHORT, LONG), (LONG, SHORT)}
    assert len(set(names)) >= 0.9 * len(truth), (len(names), report["summary"])
    assert worst <= 0.01 * extent, (worst, extent)


def test_unordered_photos_are_chunked_per_model_with_per_frame_cameras(tmp_path):
    """Matched out of order, a chunk is every photo a model registered (gaps in name order allowed),
    each with its own camera's intrinsics and size."""
    from seeu_data.ingest.chunks import ChunkConfig, plan_chunks

    names = [f"IMG_{i:04d}.jpg" for i in range(12)]
    reg = [i for i in range(12) if i % 4 != 1]  # 1, 5, 9 not registered: no run of 4 in name order
    np.save(tmp_path / "points_depth_0.npy", np.linspace(0.5, 1.5, 101))
    landscape = {"model": "PINHOLE", "width": 100, "height": 50, "params": [80, 80, 50, 25]}
    landscape.update(fx=80.0, fy=80.0, cx=50.0, cy=25.0)
    portrait = {**landscape, "width": 50, "height": 100, "fx": 40.0, "fy": 40.0, "cx": 25.0, "cy": 50.0}
    w2c = np.linalg.inv(camera_path(12)[reg])
    model = {
        "index": 0,
        "undistorted": False,
        "image_dir": str(tmp_path),
        "mean_reprojection_error": 0.5,
        "camera": landscape,
        "cameras": [landscape, portrait],
        "images": [{"name": names[i], "world_to_cam": w2c[k, :3].tolist(), "camera": k % 2} for k, i in enumerate(reg)],
    }
    unordered = {"models": [model], "matcher": {"used": "exhaustive", "quadratic": False}}
    (c,), dropped = plan_chunks("s", names, unordered, tmp_path, ChunkConfig(min_chunk_frames=4))
    assert c.frame_positions == reg and [d["position"] for d in dropped] == [1, 5, 9]
    assert list(c.width) == [(100, 50)[k % 2] for k in range(9)] and list(c.height) == [
        (50, 100)[k % 2] for k in range(9)
    ]
    assert np.allclose(c.intrinsics_norm[0], [0.8, 1.6, 0.5, 0.5]) and np.allclose(
        c.intrinsics_norm[1], [0.8, 0.4, 0.5, 0.5]
    )
    ordered = {"models": [model], "matcher": {"used": "sequential", "quadratic": True}}
    chunks, _ = plan_chunks("s", names, ordered, tmp_path, ChunkConfig(min_chunk_frames=4))
    assert chunks == []  # in name order the runs are 1 and 3 frames long
    # the default --min-chunk-frames 10: a photo set keeps a model of 80 % of its photos (9 of 12), as SfM does
    (c,), _ = plan_chunks("s", names, unordered, tmp_path, ChunkConfig())
    assert c.frame_positions == reg
    model["images"] = model["images"][:8]  # 8 of 12: a leftover
    chunks, dropped = plan_chunks("s", names, unordered, tmp_path, ChunkConfig())
    assert chunks == [] and dropped[0]["reason"] == "in an SfM model of 8 frames (< 9, 80% of the photos)"
