"""Image header probing (the importers' cheap decode check) against OpenCV's full decode."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from seeu_data.errors import SeeUError
from seeu_data.store.image_header import decode_check, image_info


@pytest.mark.parametrize(
    "ext,params,fmt",
    [
        (".jpg", [], "jpeg"),
        (".jpg", [cv2.IMWRITE_JPEG_PROGRESSIVE, 1], "jpeg"),  # SOF2
        (".png", [], "png"),
    ],
)
@pytest.mark.parametrize("h,w,c", [(360, 640, 3), (1, 7, 3), (33, 17, 1)])
def test_size_matches_opencv(ext, params, fmt, h, w, c):
    img = (np.random.default_rng(h * w).random((h, w, c)) * 255).astype(np.uint8)
    ok, buf = cv2.imencode(ext, img, params)
    assert ok
    data = buf.tobytes()
    info = image_info(data)
    decoded = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
    assert (info.format, info.width, info.height) == (fmt, decoded.shape[1], decoded.shape[0])
    assert image_info(memoryview(data)) == info == image_info(np.frombuffer(data, dtype=np.uint8))
    assert decode_check(data) == info


def test_broken_images_fail():
    img = (np.random.default_rng(0).random((20, 30, 3)) * 255).astype(np.uint8)
    jpg = cv2.imencode(".jpg", img)[1].tobytes()
    png = cv2.imencode(".png", img)[1].tobytes()
    for bad in (jpg[:-100], jpg[:300], png[:-5], b"", b"GIF89a....", b"\xff\xd8\xff\xd9"):
        with pytest.raises(SeeUError, match="failed to decode"):
            image_info(bad, "x.jpg")
    assert image_info(jpg + b"\x00" * 16).width == 30  # NUL padding after EOI is accepted
    # Headers and trailer intact but no scan data: only the full decode (--verify-decode) notices.
    no_scan = jpg[: jpg.index(b"\xff\xda")] + b"\xff\xd9"
    assert image_info(no_scan).width == 30
    with pytest.raises(SeeUError, match="failed to decode"):
        decode_check(no_scan)
