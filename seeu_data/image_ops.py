"""Image decode / resize + centre-crop / encode: pure functions on uint8 RGB arrays (OpenCV).

The crop geometry and the intrinsics update come from `seeu_data.cameras` (`cover_crop_geometry`,
`crop_intrinsics_norm`); this module only moves pixels. Shapes: images are (H, W, 3) uint8 RGB.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import cv2
import numpy as np

from seeu_data.cameras import cover_crop_geometry, crop_intrinsics_norm
from seeu_data.limits import MAX_PIXELS
from seeu_data.store.image_header import decode_image

INTERPOLATIONS = {
    "area": cv2.INTER_AREA,
    "lanczos": cv2.INTER_LANCZOS4,
    "linear": cv2.INTER_LINEAR,
    "cubic": cv2.INTER_CUBIC,
}


def decode_rgb(data: bytes | memoryview, where: str | Path | None, max_pixels: int = MAX_PIXELS) -> np.ndarray:
    """Encoded image bytes -> (H, W, 3) uint8 RGB through the image-size gate
    (`image_header.decode_image`: at most `max_pixels`). SeeUError naming `where` when it is refused."""
    return cv2.cvtColor(decode_image(data, where, max_pixels), cv2.COLOR_BGR2RGB)


# Source-pixel radius of each filter's footprint (INTER_AREA when shrinking: at most one pixel past the box).
_TAP_RADIUS = {cv2.INTER_AREA: 1, cv2.INTER_LINEAR: 1, cv2.INTER_CUBIC: 2, cv2.INTER_LANCZOS4: 4}


def aligned_span(size_in: int, size_scaled: int, start: int, length: int, radius: int = 1) -> tuple[int, int, int, int]:
    """Source span `[s0, s1)` and scaled span `[d0, d1)` to resize instead of the whole axis.

    `cv2.resize` maps output pixel centres by the ratio `size_in / size_scaled` = p / q (reduced): a
    run of q output pixels starting at a multiple of q reads exactly p input pixels starting at the
    same multiple of p, with the same interpolation weights as in the full resize (the ratio of the
    spans is the same double). The span covers the kept `[start, start + length)` plus a margin wider
    than the filter's footprint (`radius` source pixels), so the span's edge clamping never reaches a
    kept pixel.
    """
    g = math.gcd(size_in, size_scaled)
    p, q = size_in // g, size_scaled // g
    margin = 2 + -(-radius * q // p)  # output pixels whose taps can fall outside the span
    a = max(0, (start - margin) // q)
    b = min(size_scaled // q, -(-(start + length + margin) // q))
    return a * p, b * p, a * q, b * q


def resize_cover_crop(
    img: np.ndarray, out_hw: tuple[int, int], interpolation: str = "area", copy: bool = True
) -> np.ndarray:
    """(H, W, 3) -> (out_h, out_w, 3): scale to cover `out_hw`, then crop the centre (the peers' crop).

    `interpolation` 'area' (default) uses INTER_AREA when shrinking and INTER_CUBIC when enlarging;
    'lanczos', 'linear', 'cubic' force that filter. Only the block-aligned span of the source that
    holds the crop is resized (`aligned_span`; 360x640 -> 256x256 resizes 384 of 640 columns): the
    same pixels as resizing the whole frame and cropping (bit-identical for 'area', up to the last
    bit of OpenCV's fixed-point weights for the others; tested). `copy=False` may return a view.
    """
    h, w = img.shape[:2]
    (sh, sw), (oy, ox) = cover_crop_geometry((h, w), out_hw)
    oh, ow = out_hw
    if (sh, sw) != (h, w):
        flag = INTERPOLATIONS[interpolation]
        if interpolation == "area" and (sh > h or sw > w):
            flag = cv2.INTER_CUBIC
        r = _TAP_RADIUS[flag]
        y0, y1, dy0, dy1 = aligned_span(h, sh, oy, oh, r)
        x0, x1, dx0, dx1 = aligned_span(w, sw, ox, ow, r)
        img = cv2.resize(img[y0:y1, x0:x1], (dx1 - dx0, dy1 - dy0), interpolation=flag)
        oy, ox = oy - dy0, ox - dx0
    crop = img[oy : oy + oh, ox : ox + ow]
    return np.ascontiguousarray(crop) if copy else crop


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
    ok, buf = cv2.imencode(
        ".png", cv2.cvtColor(img, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_PNG_COMPRESSION, int(compression)]
    )
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
