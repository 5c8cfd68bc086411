"""Image decode / resize + centre-crop / encode: pure functions on uint8 RGB arrays (OpenCV).

The crop geometry and the intrinsics update come from `seeu_data.cameras` (`cover_crop_geometry`,
`crop_intrinsics_norm`); this module only moves pixels. Shapes: images are (H, W, 3) uint8 RGB.
"""

from __future__ import annotations

from contextlib import contextmanager
from typing import Iterator

import cv2
import numpy as np

from .cameras import cover_crop_geometry, crop_intrinsics_norm

INTERPOLATIONS = {"area": cv2.INTER_AREA, "lanczos": cv2.INTER_LANCZOS4, "linear": cv2.INTER_LINEAR,
                  "cubic": cv2.INTER_CUBIC}


def decode_rgb(data: bytes) -> np.ndarray:
    """Encoded JPEG/PNG bytes -> (H, W, 3) uint8 RGB. Raises ValueError when undecodable."""
    arr = np.frombuffer(data, dtype=np.uint8)
    img = cv2.imdecode(arr, cv2.IMREAD_COLOR) if arr.size else None
    if img is None:
        raise ValueError("image bytes cannot be decoded")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def resize_cover_crop(img: np.ndarray, out_hw: tuple[int, int], interpolation: str = "area") -> np.ndarray:
    """(H, W, 3) -> (out_h, out_w, 3): scale to cover `out_hw`, then crop the centre (the peers' crop).

    `interpolation` 'area' (default) uses INTER_AREA when shrinking and INTER_CUBIC when enlarging;
    'lanczos', 'linear', 'cubic' force that filter.
    """
    (sh, sw), (oy, ox) = cover_crop_geometry(img.shape[:2], out_hw)
    if (sh, sw) != img.shape[:2]:
        flag = INTERPOLATIONS[interpolation]
        if interpolation == "area" and (sh > img.shape[0] or sw > img.shape[1]):
            flag = cv2.INTER_CUBIC
        img = cv2.resize(img, (sw, sh), interpolation=flag)
    return np.ascontiguousarray(img[oy:oy + out_hw[0], ox:ox + out_hw[1]])


def resized_intrinsics(intrinsics_norm: np.ndarray, in_hw: tuple[int, int], out_hw: tuple[int, int]) -> np.ndarray:
    """Normalised intrinsics `(..., 4)` after `resize_cover_crop(img of in_hw, out_hw)`."""
    scaled_hw, offset = cover_crop_geometry(in_hw, out_hw)
    return crop_intrinsics_norm(np.asarray(intrinsics_norm, dtype=np.float64), scaled_hw, offset, out_hw)


def encode_jpeg(img: np.ndarray, quality: int = 95) -> bytes:
    """(H, W, 3) uint8 RGB -> baseline JPEG bytes (deterministic for a given OpenCV build)."""
    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(img, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError("JPEG encoding failed")
    return buf.tobytes()


def encode_png(img: np.ndarray, compression: int = 3) -> bytes:
    """(H, W, 3) uint8 RGB -> PNG bytes (lossless)."""
    ok, buf = cv2.imencode(".png", cv2.cvtColor(img, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_PNG_COMPRESSION, int(compression)])
    if not ok:
        raise ValueError("PNG encoding failed")
    return buf.tobytes()


@contextmanager
def single_threaded_cv2() -> Iterator[None]:
    """Make OpenCV single-threaded while worker processes are forked, then restore the caller's setting.

    A forked child inherits OpenCV's thread-pool state without its threads: calling
    `cv2.setNumThreads` (or a parallel OpenCV function) there deadlocks once the parent has used the
    pool. Shrinking the pool in the parent before the fork gives the workers a clean single-threaded
    OpenCV (one decode per worker process is the right parallelism anyway).
    """
    previous = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        yield
    finally:
        cv2.setNumThreads(previous)
