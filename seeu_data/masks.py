"""Per-frame masks of excluded pixels (moving or transient content): encode, decode, resize, read.

A mask is stored beside its frame (posed frames' and triples' `mask` column) as a PNG, 8-bit single
channel, of the frame's size: nonzero = excluded pixel, 0 = kept; null = no mask. In memory it is an
(H, W) bool array, True = excluded. Whoever makes masks stores them with `encode_mask` (`seeu
ingest`, the importers: a data set's own convention converted, `read_mask_file`; a user's folder,
`masks_from_folder`). Wherever a frame is resized and cropped (`build --resize`, the loader, `ingest
--size`) its mask follows with `resize_mask`, and through an undistortion with `undistort_mask`.

Example:
    >>> import numpy as np
    >>> m = np.zeros((4, 6), bool); m[1:3, 2:5] = True
    >>> bool((decode_mask(encode_mask(m)) == m).all())
    True
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from pathlib import Path

import cv2
import numpy as np

from seeu_data.cameras import cover_crop_geometry
from seeu_data.errors import SeeUError
from seeu_data.image_ops import resize_cover_crop
from seeu_data.limits import MAX_PIXELS
from seeu_data.store.dataset_check import check_pixels
from seeu_data.store.image_header import file_image_size
from seeu_data.undistort import same_size_pinhole, undistort_maps


def encode_mask(mask: np.ndarray) -> bytes:
    """(H, W) bool (True = excluded; any nonzero counts as True) -> PNG bytes, 8-bit greyscale, 255 / 0."""
    m = np.asarray(mask)
    if m.ndim != 2 or 0 in m.shape:
        raise ValueError(f"a mask is (H, W), got shape {m.shape}")
    ok, buf = cv2.imencode(".png", np.where(m != 0, 255, 0).astype(np.uint8), [cv2.IMWRITE_PNG_COMPRESSION, 3])
    if not ok:
        raise ValueError("PNG encoding failed")
    return buf.tobytes()


def decode_mask(data, where: str | None = None) -> np.ndarray:
    """PNG bytes of an 8-bit single-channel mask -> (H, W) bool, True = excluded (nonzero).
    SeeUError (naming `where`) when the bytes are no such image."""
    arr = np.frombuffer(data, dtype=np.uint8)
    img = cv2.imdecode(arr, cv2.IMREAD_UNCHANGED) if arr.size else None
    if img is None or img.ndim != 2 or img.dtype != np.uint8:
        raise SeeUError("mask is not an 8-bit single-channel image", where)
    return img != 0


def resize_mask(mask: np.ndarray, out_hw: tuple[int, int]) -> np.ndarray:
    """(H, W) bool -> (out_h, out_w) bool, with the image's cover resize + centre crop
    (`image_ops.resize_cover_crop`, the same geometry). Conservative: an output pixel is excluded when
    any excluded source pixel reaches it (pixel-area averaging when shrinking, bilinear when enlarging,
    then nonzero), so the mask covers what the image's area or bilinear filter mixes in."""
    h, w = mask.shape
    (sh, sw), _ = cover_crop_geometry((h, w), out_hw)
    filt = "area" if sh <= h and sw <= w else "linear"
    return resize_cover_crop(np.where(mask, 255, 0).astype(np.uint8), out_hw, filt) > 0


# ---- mask files: a data set's own, or a user's folder ----------------------------------------------

MASK_CONVENTIONS = ("exclude", "keep")  # nonzero marks excluded pixels (ours, motion masks) / kept ones (nerfstudio)
MASK_SUFFIXES = (".png", ".jpg", ".jpeg")


def read_mask_file(path: str | Path, convention: str = "exclude", max_pixels: int = MAX_PIXELS) -> np.ndarray:
    """A mask image file -> (H, W) bool, True = excluded. `convention` "exclude": nonzero pixels are
    excluded (motion masks, this toolkit's own); "keep": nonzero pixels are kept, 0 excluded
    (nerfstudio's `mask_path`: 0 = ignore). Colour files are read as greyscale. SeeUError naming the file."""
    w, h = file_image_size(path)
    check_pixels(w, h, max_pixels, "mask header declares", path)
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise SeeUError("mask image cannot be decoded", path)
    return (img != 0) if convention == "exclude" else (img == 0)


def match_mask_files(folder: str | Path, names: Sequence[str], numbers: Sequence[int]) -> list[Path | None]:
    """The mask file of each frame in `folder` (None: none): the file whose stem is the frame's name
    (`names[k]`, its stem or the whole name, as COLMAP's `image.jpg.png`), else the one whose stem's last
    number is the frame's number (`numbers[k]`, e.g. its video frame: `frame_000123.png`, `123.png`).
    A number two files claim matches neither."""
    files = sorted(p for p in Path(folder).iterdir() if p.suffix.lower() in MASK_SUFFIXES and p.is_file())
    by_stem = {p.stem: p for p in files}
    by_number: dict[int, Path | None] = {}
    for p in files:
        digits = re.findall(r"\d+", p.stem)
        if digits:
            n = int(digits[-1])
            by_number[n] = None if n in by_number else p
    out: list[Path | None] = []
    for name, number in zip(names, numbers):
        stem = Path(name).stem if name else None
        hit = (by_stem.get(stem) or by_stem.get(Path(name).name)) if stem else None
        out.append(hit or by_number.get(int(number)))
    return out


def undistort_mask(mask: np.ndarray, camera) -> np.ndarray:
    """(H, W) bool of a distorted frame -> the same frame undistorted as its image is
    (`seeu_data.undistort`: same-size pinhole of `camera`, a COLMAP camera); conservative like `resize_mask`."""
    pin = same_size_pinhole(camera)
    map_x, map_y = undistort_maps(camera, pin)
    img = np.where(mask, 255, 0).astype(np.uint8)
    return cv2.remap(img, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE) > 0


def masks_from_folder(
    folder: str | Path,
    names: Sequence[str],
    numbers: Sequence[int],
    sizes: Sequence[tuple[int, int]],
    convention: str = "exclude",
    max_pixels: int = MAX_PIXELS,
    fit: Callable[[int, np.ndarray], np.ndarray] | None = None,
) -> list[bytes | None]:
    """Each frame's mask from a user's `folder` (`match_mask_files` by frame name, else number) as PNG
    bytes, None where no file matches. `sizes[k]`: frame k's (width, height), which its mask must have
    after `fit(k, mask)` (e.g. ingest's downscale and undistortion). SeeUError (one line, naming the
    folder or the file) when no file matches any frame or a mask's size is not its frame's."""
    paths = match_mask_files(folder, names, numbers)
    if not any(p is not None for p in paths):
        example = next((n for n in names if n), None)
        like = f"named like {Path(example).stem!r} or " if example else ""
        raise SeeUError(f"no mask file matches a frame (frames are {like}numbered like {int(numbers[0])})", folder)
    out: list[bytes | None] = []
    for k, path in enumerate(paths):
        if path is None:
            out.append(None)
            continue
        mask = read_mask_file(path, convention, max_pixels)
        if fit is not None:
            mask = fit(k, mask)
        w, h = sizes[k]
        if mask.shape != (h, w):
            raise SeeUError(f"mask is {mask.shape[1]}x{mask.shape[0]}, its frame {w}x{h}", path)
        out.append(encode_mask(mask))
    return out


def tint_masked(rgb: np.ndarray, mask_png, colour: tuple[int, int, int] = (255, 0, 255)) -> np.ndarray:
    """(H, W, 3) uint8 RGB with its masked pixels (`mask_png`: the frame's stored mask, or None)
    blended half-way towards `colour`: how `seeu view` and `seeu inspect --sheet` show masks."""
    if mask_png is None:
        return rgb
    mask = decode_mask(mask_png)
    out = rgb.copy()
    out[mask] = (out[mask].astype(np.uint16) + np.asarray(colour, np.uint16)) // 2
    return out
