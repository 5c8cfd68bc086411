"""Same-size undistortion (`seeu_data.undistort`) against OpenCV's own lens model: SIMPLE_RADIAL with
focal f and k is OpenCV's camera matrix with distCoeffs (k, 0, 0, 0)."""

from __future__ import annotations

import cv2
import numpy as np
import pycolmap
import pytest

from seeu_data.undistort import same_size_pinhole, undistort_files, undistort_maps

W, H = 160, 90


@pytest.mark.parametrize("k", [-0.12, 0.08])
def test_same_size_pinhole_maps_follow_opencv_lens_model(k):
    f, cx, cy = 110.0, 81.0, 44.0
    camera = pycolmap.Camera(model="SIMPLE_RADIAL", width=W, height=H, params=[f, cx, cy, k])
    pin = same_size_pinhole(camera)
    assert (pin.width, pin.height, pin.cx, pin.cy) == (W, H, cx, cy) and pin.fx == pytest.approx(pin.fy)
    map_x, map_y = undistort_maps(camera, pin)
    assert map_x.shape == map_y.shape == (H, W)
    # Every output pixel's ray, distorted by OpenCV's projection, lands where the map reads from.
    u, v = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    rays = np.stack([(u - pin.cx) / pin.fx, (v - pin.cy) / pin.fy, np.ones_like(u)], -1).reshape(-1, 3)
    K = np.array([[f, 0, cx], [0, f, cy], [0, 0, 1.0]])
    px, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), K, np.array([k, 0, 0, 0.0]))
    px = px.reshape(H, W, 2) - 0.5  # pixel-corner origin -> OpenCV's pixel-centre indices
    assert np.abs(map_x - px[..., 0]).max() < 1e-3 and np.abs(map_y - px[..., 1]).max() < 1e-3
    # No blank pixel (every read inside the frame's extent) and no needless crop (one side touches the edge).
    lo_x, hi_x, lo_y, hi_y = map_x.min() + 0.5, map_x.max() + 0.5, map_y.min() + 0.5, map_y.max() + 0.5
    assert lo_x >= -1e-3 and lo_y >= -1e-3 and hi_x <= W + 1e-3 and hi_y <= H + 1e-3
    margin = min(lo_x, lo_y, W - hi_x, H - hi_y)
    assert margin < 1.0, margin  # within a pixel of the frame edge, on the binding side


def test_undistort_files_keeps_size_and_names(tmp_path):
    camera = pycolmap.Camera(model="SIMPLE_RADIAL", width=W, height=H, params=[110.0, 80.0, 45.0, -0.1])
    rng = np.random.default_rng(0)
    img = cv2.GaussianBlur(rng.integers(0, 255, (H, W, 3), dtype=np.uint8), (0, 0), 2)
    (tmp_path / "in").mkdir()
    cv2.imwrite(str(tmp_path / "in" / "000001.jpg"), img)
    pin = undistort_files(camera, tmp_path / "in", ["000001.jpg"], tmp_path / "out")
    out = cv2.imread(str(tmp_path / "out" / "000001.jpg"))
    assert out.shape == (H, W, 3) and pin.scale < 1  # barrel lens: the pinhole sees a bit more
