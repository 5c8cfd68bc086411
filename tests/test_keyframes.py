"""Keyframe mapping (seeu_data.ingest.keyframes): the stride rule, the motion measurement on a database of
known keypoints, and a dense clip mapped on keyframes with every frame registered after, accurate
against the ground truth and identical run after run."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from seeu_data.errors import SeeUError
from seeu_data.ingest.keyframes import consecutive_motion_px, keyframe_names, keyframe_stride
from seeu_data.ingest.pose_eval import pose_accuracy
from seeu_data.ingest.sfm import SfmConfig, run_sfm
from seeu_data.synthetic import camera_path, default_intrinsics_norm, make_scene, render_view


def test_keyframe_stride_keeps_the_motion_between_keyframes_under_the_target():
    # the synthetic walk at 50 / 100 / 200 / 400 frames moves about 18 / 9 / 4.5 / 2.3 px per frame
    assert [keyframe_stride(50 * 2**i, 18.3 / 2**i, 20.0, 30, 128) for i in range(4)] == [1, 2, 4, 8]
    assert keyframe_stride(400, 2.5, 20.0, 30, 128) == 8  # 8 x 2.5 = 20: at the target is allowed
    assert keyframe_stride(400, 2.6, 20.0, 30, 128) == 4
    assert keyframe_stride(100, 0.5, 20.0, 30, 128) == 2  # stride 4 would leave 25 < 30 keyframes
    assert keyframe_stride(10_000, 0.01, 20.0, 30, 128) == 128  # never beyond the matched offsets
    assert keyframe_stride(400, None, 20.0, 30, 128) == 1  # not a video
    assert keyframe_stride(400, 2.0, 0.0, 30, 128) == 1  # switched off
    assert keyframe_stride(400, 0.0, 20.0, 30, 128) == 1


def test_keyframe_names_cover_the_whole_video():
    names = [f"{i:06d}.jpg" for i in range(10)]
    assert keyframe_names(names, 1) == names
    assert keyframe_names(names, 4) == [names[0], names[4], names[8], names[9]]
    assert keyframe_names(names[:9], 4) == [names[0], names[4], names[8]]


def _database(path, shifts: list[float | None], n_points: int = 40):
    """A COLMAP database of len(shifts)+1 frames whose consecutive pairs i, i+1 match all `n_points`
    keypoints, every one moved by exactly shifts[i] pixels (None: the pair is not matched). Each
    frame stores its keypoints in another order, so matches must be followed by index."""
    import pycolmap

    rng = np.random.default_rng(0)
    db = pycolmap.Database.open(path)
    camera_id = db.write_camera(pycolmap.Camera.create_from_model_name(1, "PINHOLE", 100.0, 320, 180))
    xy = rng.uniform(50, 130, (n_points, 2))
    ids, rows = [], []  # rows[i][p]: the keypoint row of point p in frame i
    for i in range(len(shifts) + 1):
        if i:
            xy = xy + [shifts[i - 1] or 0.0, 0.0]
        perm = rng.permutation(n_points)  # row j holds point perm[j]
        ids.append(db.write_image(pycolmap.Image(name=f"{i:06d}.jpg", camera_id=camera_id)))
        db.write_keypoints(ids[-1], xy[perm].astype(np.float32))
        rows.append(np.argsort(perm))
    for i, shift in enumerate(shifts):
        if shift is not None:
            geometry = pycolmap.TwoViewGeometry()
            geometry.config = pycolmap.TwoViewGeometryConfiguration.CALIBRATED
            geometry.inlier_matches = np.stack([rows[i], rows[i + 1]], 1).astype(np.uint32)
            db.write_two_view_geometry(ids[i], ids[i + 1], geometry)
    return db


def test_consecutive_motion_is_the_median_of_each_pairs_median_displacement(tmp_path):
    names = [f"{i:06d}.jpg" for i in range(5)]
    db = _database(tmp_path / "a.db", [1.0, 2.0, 3.0, 10.0])
    assert consecutive_motion_px(db, names) == pytest.approx(2.5, rel=1e-6)  # median of 1, 2, 3, 10
    db.close()
    # fewer than 90 % of consecutive pairs matched: not a video, no measurement
    db = _database(tmp_path / "b.db", [1.0, None, 3.0, 10.0])
    assert consecutive_motion_px(db, names) is None
    db.close()


def test_keyframe_motion_is_checked():
    with pytest.raises(SeeUError, match="keyframe-motion"):
        SfmConfig(keyframe_motion=-1).check()
    with pytest.raises(SeeUError, match="keyframe-motion"):
        SfmConfig(keyframe_motion=float("nan")).check()


@pytest.mark.slow
def test_video_is_mapped_on_keyframes_and_every_frame_registered_identically(tmp_path):
    """The synthetic walk in 48 frames at 320x180 (about 9 px of image motion per frame): stride 2
    (min_keyframes lowered to 8 for so short a clip, --keyframe-motion 20), 25 keyframes mapped, the other 23 frames
    registered after; every frame posed within 0.5 % of the path of the ground truth (mapping all 48
    gave 0.069 %, keyframes 0.077 %), and a second run gives bit-identical poses."""
    n, w, h = 48, 320, 180
    frames = tmp_path / "frames"
    frames.mkdir()
    poses = camera_path(n)
    scene, intr = make_scene(0), default_intrinsics_norm(w, h)
    for i in range(n):
        rgb, _ = render_view(scene, poses[i], intr, w, h)
        cv2.imwrite(str(frames / f"{i:06d}.jpg"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    names = [f"{i:06d}.jpg" for i in range(n)]
    cfg = SfmConfig(min_keyframes=8, keyframe_motion=20.0, min_model_size=5, sfm_check=False, sfm_attempts=1)
    results = [run_sfm(frames, names, tmp_path / f"sfm{r}", cfg, frames) for r in range(2)]
    kf = results[0]["keyframes"]
    assert kf["stride"] == 2 and kf["count"] == 25 and 5.0 < kf["motion_px"] < 15.0
    assert results[0]["mapping_attempts"][0]["registered"] == 25  # the mapper saw the keyframes only
    assert kf["registered_after"] == n - 25
    assert "register_s" in results[0]["timings"]
    posed = [{im["name"]: im["world_to_cam"] for m in res["models"] for im in m["images"]} for res in results]
    assert posed[0] == posed[1] and sorted(posed[0]) == names
    w2c = np.stack([np.vstack([np.asarray(posed[0][nm]), [0, 0, 0, 1.0]]) for nm in names])
    assert pose_accuracy(np.linalg.inv(w2c), poses).centre_rmse_pct_path <= 0.5
