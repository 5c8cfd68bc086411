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

The image-size gate: `decode_image` is the one place an encoded image becomes pixels. It reads the
size the header declares (`header_size`: JPEG, PNG and the other formats an image folder may hold,
BMP, TIFF, WebP), refuses more than `max_pixels` (`check_pixels`, the `--max-pixels` limit) before
OpenCV allocates anything, then decodes. Every reader decodes through it (the loader, ingest's video
and folder readers, render's cameras file, the importers' full decode, build's resize, the viewers),
so no command decodes past `--max-pixels`: a 300 KB PNG declaring 20000x20000 is one line, not 6 GB.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

from seeu_data.errors import SeeUError
from seeu_data.limits import MAX_PIXELS

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


def _tiff_size(data: memoryview) -> tuple[int, int]:
    order = "<" if data[:2] == b"II" else ">"
    (ifd,) = struct.unpack_from(order + "I", data, 4)
    (count,) = struct.unpack_from(order + "H", data, ifd)
    sides: dict[int, int] = {}
    for k in range(count):
        tag, kind = struct.unpack_from(order + "HH", data, ifd + 2 + 12 * k)
        if tag in (256, 257):  # ImageWidth, ImageLength: SHORT (3) or LONG (4)
            sides[tag] = struct.unpack_from(order + ("H" if kind == 3 else "I"), data, ifd + 10 + 12 * k)[0]
    if len(sides) < 2:
        raise ValueError("TIFF without ImageWidth/ImageLength")
    return sides[256], sides[257]


def _webp_size(data: memoryview) -> tuple[int, int]:
    chunk = bytes(data[12:16])
    if chunk == b"VP8 " and data[23:26] == b"\x9d\x01\x2a":
        width, height = struct.unpack_from("<HH", data, 26)
        return width & 0x3FFF, height & 0x3FFF
    if chunk == b"VP8L" and data[20] == 0x2F:
        (bits,) = struct.unpack_from("<I", data, 21)
        return (bits & 0x3FFF) + 1, ((bits >> 14) & 0x3FFF) + 1
    if chunk == b"VP8X":
        return 1 + int.from_bytes(data[24:27], "little"), 1 + int.from_bytes(data[27:30], "little")
    raise ValueError("WebP without a VP8/VP8L/VP8X header")


def header_size(data, where: str | Path | None = None) -> tuple[int, int]:
    """(width, height) that an encoded image's header declares, for every format an image folder may
    hold (JPEG, PNG, BMP, TIFF, WebP); reads no pixels and checks no trailer. SeeUError("image failed to
    decode: ...", where) for another format, a cut header or a zero size."""
    data = memoryview(data).cast("B") if not isinstance(data, bytes) else memoryview(data)
    try:
        if data[:2] == b"\xff\xd8":
            width, height = _jpeg_size(data)
        elif data[:8] == _PNG_SIGNATURE and data[12:16] == b"IHDR":
            width, height = struct.unpack_from(">II", data, 16)
        elif data[:2] == b"BM":
            (dib,) = struct.unpack_from("<I", data, 14)
            width, height = struct.unpack_from("<HH" if dib == 12 else "<ii", data, 18)
            height = abs(height)  # negative: stored top-down
        elif data[:4] in (b"II*\x00", b"MM\x00*"):
            width, height = _tiff_size(data)
        elif data[:4] == b"RIFF" and data[8:12] == b"WEBP":
            width, height = _webp_size(data)
        else:
            raise ValueError("neither a JPEG, PNG, BMP, TIFF nor WebP")
        if width <= 0 or height <= 0:
            raise ValueError(f"size {width}x{height}")
    except (ValueError, struct.error, IndexError) as exc:
        raise SeeUError(f"image failed to decode: {exc}", where) from None
    return int(width), int(height)


def check_pixels(width: int, height: int, max_pixels: int, what: str, where: str | Path | None) -> None:
    """Refuse an image of `width` x `height` over `max_pixels`."""
    if int(width) * int(height) > max_pixels:
        raise SeeUError(
            f"{what} {int(width)}x{int(height)} ({int(width) * int(height) / 1e6:.1f} MP) is over the "
            f"{max_pixels / 1e6:g} MP limit (--max-pixels)",
            where,
        )


def decode_image(data, where: str | Path | None, max_pixels: int = MAX_PIXELS, unchanged: bool = False):
    """The image-size gate: encoded bytes -> `(H, W, 3)` uint8 BGR pixels (`unchanged`: as stored,
    e.g. `(H, W)` grey or with alpha), decoded only after the header's size is checked against
    `max_pixels`. EXIF orientation is applied (a portrait photo stored landscape comes out upright).
    SeeUError naming `where`: over the limit, an unknown format, or bytes that do not decode."""
    import cv2
    import numpy as np

    width, height = header_size(data, where)
    check_pixels(width, height, max_pixels, "image header declares", where)
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED if unchanged else cv2.IMREAD_COLOR)
    if img is None:
        raise SeeUError("image failed to decode (corrupt or truncated)", where)
    if img.shape[0] * img.shape[1] != width * height:  # another size than the header's (turned by EXIF: same count)
        raise SeeUError(f"image decodes to {img.shape[1]}x{img.shape[0]}, its header declares {width}x{height}", where)
    return img


def read_image_file(path: str | Path, max_pixels: int = MAX_PIXELS):
    """`decode_image` of a file: `(H, W, 3)` uint8 BGR, upright by its EXIF orientation."""
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise SeeUError(f"image unreadable ({exc.strerror})", path) from None
    return decode_image(data, path, max_pixels)


def decode_check(data, where: str | None = None, max_pixels: int = MAX_PIXELS) -> ImageInfo:
    """Full decode with OpenCV (slow path): header checks, then pixels (`decode_image`), then size agreement."""
    info = image_info(data, where)
    img = decode_image(data, where, max_pixels, unchanged=True)
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
