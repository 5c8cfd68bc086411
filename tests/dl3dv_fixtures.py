"""Tiny DL3DV-10K scenes in the release and benchmark layouts (see seeu_data/importers/dl3dv.py).

Like the real ones: transforms.json names `images/frame_0000K.png` with the intrinsics for the
full-resolution size (w, h) (here 384x216, DL3DV's 3840x2160 / 10), k1/k2/p1/p2 present, Blender
camera-to-world matrices; the frames sit in `images_8/` (w/8 x h/8 = 48x27) and `images_4/` (96x54).
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

from tests.helpers import look_at_cam_to_world

W, H = 384, 216  # transforms.json's w, h
FL = (300.0, 298.0, 190.0, 110.0)  # fl_x, fl_y, cx, cy at W x H
BLENDER = np.diag([1.0, -1.0, -1.0, 1.0])  # OpenCV <-> OpenGL camera axes


def c2w_opencv(n: int) -> np.ndarray:
    """(n, 4, 4) OpenCV camera-to-world poses on an arc looking at the origin."""
    eyes = [np.array([np.sin(t), 0.2 * t, -3.0 * np.cos(t)]) for t in np.linspace(-0.4, 0.4, n)]
    return np.stack([look_at_cam_to_world(e, np.zeros(3)) for e in eyes])


def make_scene(folder: Path, n: int = 4, seed: int = 0, sizes: dict[str, tuple[int, int]] | None = None) -> np.ndarray:
    """A DL3DV scene folder (transforms.json + images_8/ + images_4/); returns its OpenCV c2w (n, 4, 4).
    `sizes` overrides a folder's frame size (w, h), e.g. {"images_8": (48, 36)} for a wrong-size scene."""
    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True)
    c2w = c2w_opencv(n)
    doc = {
        "w": W,
        "h": H,
        "fl_x": FL[0],
        "fl_y": FL[1],
        "cx": FL[2],
        "cy": FL[3],
        "k1": 0.01,
        "k2": -0.002,
        "p1": 0.0,
        "p2": 0.0,
        "camera_model": "OPENCV",
        "frames": [
            {"file_path": f"images/frame_{k + 1:05d}.png", "transform_matrix": (c2w[k] @ BLENDER).tolist()}
            for k in range(n)
        ],
    }
    (folder / "transforms.json").write_text(json.dumps(doc))
    for sub, size in {"images_8": (W // 8, H // 8), "images_4": (W // 4, H // 4), **(sizes or {})}.items():
        (folder / sub).mkdir()
        for k in range(n):
            img = rng.integers(0, 255, (size[1], size[0], 3), dtype=np.uint8)
            cv2.imwrite(str(folder / sub / f"frame_{k + 1:05d}.png"), img)
    return c2w


HASHES = [f"{c:x}" * 64 for c in (10, 11, 12, 13)]  # aaaa..., bbbb..., cccc..., dddd...


def make_release(root: Path) -> dict[str, np.ndarray]:
    """`root/1K/<hash>/` (two good scenes, one whose images_8 frames are 48x36) and `root/2K/<hash>/`."""
    poses = {
        HASHES[0]: make_scene(root / "1K" / HASHES[0], seed=1),
        HASHES[1]: make_scene(root / "1K" / HASHES[1], seed=2, sizes={"images_8": (48, 36)}),
        HASHES[2]: make_scene(root / "2K" / HASHES[2], n=3, seed=3),
    }
    return poses


def make_benchmark(root: Path) -> dict[str, np.ndarray]:
    """`root/<hash>/nerfstudio/` for two scenes, one whose images_4 frames are 96x60."""
    return {
        HASHES[0]: make_scene(root / HASHES[0] / "nerfstudio", seed=4),
        HASHES[3]: make_scene(root / HASHES[3] / "nerfstudio", seed=5, sizes={"images_4": (96, 60)}),
    }
