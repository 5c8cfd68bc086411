"""Cheap checks of encoded images: format and size from the JPEG/PNG headers, truncation from the trailer.

Importers keep the source's encoded bytes untouched and need each frame's width and height. A full
decode of every 360x640 JPEG costs ~1-2 ms per image per core, which alone is slower than reading
the pixelSplat chunks; parsing the header costs microseconds. The cheap check here therefore is:

* JPEG: starts with SOI, a start-of-frame (SOF0..SOF15, not DHT/JPG/DAC) segment is reachable by
  walking the marker segments, and the stream ends with EOI (trailing NUL padding is allowed);
* PNG: signature, an IHDR chunk first, and the IEND chunk as the last 12 bytes.

A file that fails any of these counts as "failed to decode". It catches truncated downloads and
non-image files; it does not prove that the entropy-coded data is valid. `decode_check` does a full
decode (OpenCV) for the cases where that is wanted (`seeu import ... --verify-decode`).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from seeu_data.errors import SeeUError

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_IEND = b"\x00\x00\x00\x00IEND\xaeB`\x82"
# Start-of-frame markers carry the image size; C4 (DHT), C8 (JPG) and CC (DAC) share the range but do not.
_JPEG_SOF = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
# Markers without a length field.
_JPEG_STANDALONE = frozenset(range(0xD0, 0xD8)) | {0x01, 0xD8}


@dataclass(frozen=True)
class ImageInfo:
    """Format ('jpeg' | 'png') and size in pixels of an encoded image."""

    format: str
    width: int
    height: int


def _jpeg_size(data: memoryview) -> tuple[int, int]:
    n = len(data)
    i = 2
    while i + 4 <= n:
        if data[i] != 0xFF:
            raise ValueError(f"JPEG marker expected at byte {i}")
        marker = data[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if marker in _JPEG_STANDALONE:
            i += 2
            continue
        if marker == 0xD9:
            break
        (length,) = struct.unpack_from(">H", data, i + 2)
        if length < 2:
            raise ValueError(f"JPEG segment with length {length} at byte {i}")
        if marker in _JPEG_SOF:
            if i + 9 > n:
                break
            height, width = struct.unpack_from(">HH", data, i + 5)
            return width, height
        if marker == 0xDA:  # start of scan before any frame header
            raise ValueError("JPEG scan data before a frame header")
        i += 2 + length
    raise ValueError("no JPEG frame header (truncated?)")


def _jpeg_complete(data: memoryview) -> bool:
    if data[-2:] == b"\xff\xd9":
        return True
    tail = bytes(data[-64:]).rstrip(b"\x00")  # some writers pad with NULs
    return tail.endswith(b"\xff\xd9")


def image_info(data, where: str | None = None, trailer: bool = True) -> ImageInfo:
    """Format and size of an encoded JPEG or PNG image from its header; checks the trailer too.

    `data`: any bytes-like object (bytes, memoryview, uint8 numpy array); nothing is copied, and only
    the bytes parsed are touched (a JPEG's markers are walked by their lengths), so over a memory map
    the header reads the first page of the image, the trailer check its last one. `trailer=False`:
    the header alone (a stored file whose sha256 vouches for the bytes).
    Raises SeeUError("image failed to decode: ...", where) for anything else, a truncated file,
    or a zero size.
    """
    data = memoryview(data).cast("B") if not isinstance(data, bytes) else memoryview(data)
    try:
        if data[:2] == b"\xff\xd8":
            width, height = _jpeg_size(data)
            if trailer and not _jpeg_complete(data):
                raise ValueError("JPEG has no end-of-image marker (truncated)")
            fmt = "jpeg"
        elif data[:8] == _PNG_SIGNATURE:
            if len(data) < 33 or data[12:16] != b"IHDR":
                raise ValueError("PNG without an IHDR chunk")
            width, height = struct.unpack_from(">II", data, 16)
            if trailer and data[-12:] != _PNG_IEND:
                raise ValueError("PNG does not end with IEND (truncated)")
            fmt = "png"
        else:
            raise ValueError("neither a JPEG nor a PNG")
        if width <= 0 or height <= 0:
            raise ValueError(f"size {width}x{height}")
    except (ValueError, struct.error) as exc:
        raise SeeUError(f"image failed to decode: {exc}", where) from None
    return ImageInfo(fmt, int(width), int(height))


def decode_check(data, where: str | None = None) -> ImageInfo:
    """Full decode with OpenCV (slow path): header checks, then pixels, then size agreement."""
    import cv2
    import numpy as np

    info = image_info(data, where)
    img = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise SeeUError("image failed to decode (OpenCV)", where)
    if img.shape[:2] != (info.height, info.width):
        raise SeeUError(
            f"decoded size {img.shape[1]}x{img.shape[0]} differs from the header's {info.width}x{info.height}", where
        )
    return info


def extension_for(fmt: str) -> str:
    """File extension for an image format: 'jpeg' -> '.jpg', 'png' -> '.png'."""
    return {"jpeg": ".jpg", "png": ".png"}[fmt]


def file_image_size(path, prefix_bytes: int = 1 << 16) -> tuple[int, int]:
    """(width, height) of a JPEG or PNG file from its header alone: reads the first `prefix_bytes`
    (the whole file when a JPEG's frame header lies further in), decodes no pixels, checks no trailer
    (`image_info` does that when the frame is read). Raises SeeUError naming the file otherwise."""
    from pathlib import Path

    path = Path(path)
    try:
        with open(path, "rb") as f:
            data = memoryview(f.read(prefix_bytes))
            if data[:2] == b"\xff\xd8":
                try:
                    return _jpeg_size(data)
                except (ValueError, struct.error):
                    data = memoryview(data.tobytes() + f.read())
                    return _jpeg_size(data)
    except OSError as exc:
        raise SeeUError(f"image unreadable ({exc.strerror})", path) from None
    except (ValueError, struct.error) as exc:
        raise SeeUError(f"image failed to decode: {exc}", path) from None
    if data[:8] == _PNG_SIGNATURE and len(data) >= 24 and data[12:16] == b"IHDR":
        width, height = struct.unpack_from(">II", data, 16)
        if width > 0 and height > 0:
            return int(width), int(height)
    raise SeeUError("image failed to decode: neither a JPEG nor a PNG header", path)
