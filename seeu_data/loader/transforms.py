"""Per-sample transforms: OpenCV decode, cover resize + centre crop (intrinsics updated), flip.

Geometry comes from `seeu_data.cameras` (`cover_crop_geometry`, `crop_intrinsics_norm`,
`flip_horizontal`): the image is resized so it covers the training size, then the middle is cut out
(360x640 -> 256x455 -> 256x256, as the peers do). Filters (`interpolation`):

* `"linear"` (default): bilinear `cv2.INTER_LINEAR`, ~0.1 ms per 360x640 view (~0.6 ms to decode
  it), so the loader runs near the JPEG-decode limit. Not anti-aliased: at the usual 1.4x reduction
  every source pixel still contributes, but fine texture can alias slightly.
* `"area"`: exact pixel-area averaging (`cv2.INTER_AREA`, anti-aliased); ~0.8 ms per view at 1.4x
  (OpenCV's non-integer area path is not vectorised), i.e. about 1.3x the cost of the JPEG decode.
* `"lanczos"` / `"cubic"`: Lanczos is the peers' (PIL) filter, ~1.2 ms per view.

Pixels are moved by `seeu_data.image_ops.resize_cover_crop` (shared with `seeu build`), which
resizes only the block-aligned source span that holds the crop (384 of 640 columns here).
Images are decoded to BGR and written as planar RGB (V, 3, H, W) uint8 with one `cv2.mixChannels`.
A flip mirrors every view of a sample (the whole scene is mirrored in world x). Masks (where a
view has one) follow the image: header checked (`dataset_check.check_mask`), decoded, resized and
cropped (`masks.resize_mask`: conservative, an output pixel any excluded source pixel reaches is
excluded), mirrored.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from seeu_data import cameras
from seeu_data.errors import SeeUError
from seeu_data.image_ops import INTERPOLATIONS, resize_cover_crop
from seeu_data.limits import MAX_PIXELS
from seeu_data.masks import decode_mask, resize_mask
from seeu_data.store.dataset_check import check_image, check_mask
from seeu_data.store.triple_row import TripleRow


@dataclass
class ViewsSample:
    """A transformed sample, V views at H x W.

    images: (V, 3, H, W) uint8 RGB (planar); cam_to_world: (V, 4, 4) float64; intrinsics_norm: (V, 4)
    float64 (fx/W, fy/H, cx/W, cy/H of the output image; `collate_views` makes the 3x3 matrices of a whole
    batch at once); near, far: (V,) float32; frame_index: (V,) int64; masks: (V, H, W) bool, True =
    excluded pixel (all False for a view without a mask), or None when no view has one.
    """

    sample_id: str
    scene_id: str
    num_context: int
    images: np.ndarray
    cam_to_world: np.ndarray
    intrinsics_norm: np.ndarray
    near: np.ndarray
    far: np.ndarray
    frame_index: np.ndarray
    gap: int
    masks: np.ndarray | None = None


def decode_bgr(buf, where: str) -> np.ndarray:
    """Encoded JPEG/PNG bytes (bytes-like) -> (H, W, 3) uint8 BGR; SeeUError naming `where` if undecodable."""
    arr = np.frombuffer(buf, np.uint8)
    img = cv2.imdecode(arr, cv2.IMREAD_COLOR) if len(arr) else None
    if img is None:
        raise SeeUError("image does not decode (corrupt or truncated)", where)
    return img


_BGR_TO_PLANAR_RGB = [2, 0, 1, 1, 0, 2]


def transform_sample(
    raw: TripleRow,
    out_hw: tuple[int, int],
    flip: bool = False,
    interpolation: str = "linear",
    where: str = "",
    out: np.ndarray | None = None,
    max_pixels: int = MAX_PIXELS,
) -> ViewsSample:
    """Decode, resize/crop (and optionally mirror) every view of a stored sample.

    `out`, if given, is a (V, 3, H, W) uint8 array the images are written into (a batch buffer row).
    Each image's header is checked before it is decoded (`dataset_check.check_image`: the recorded
    size, at most `max_pixels`).
    Cameras: intrinsics via `cameras.crop_intrinsics_norm`, mirrored with `cameras.flip_horizontal`.
    """
    if interpolation not in INTERPOLATIONS:
        raise ValueError(f"interpolation must be one of {sorted(INTERPOLATIONS)}")
    num_views = len(raw.images)
    oh, ow = out_hw
    name = f"{where} sample {raw.sample_id}"
    if out is not None and out.shape != (num_views, 3, oh, ow):
        raise SeeUError(f"sample has {num_views} views, the batch {out.shape[0]}: batches need equal view counts", name)
    images = out if out is not None else np.empty((num_views, 3, oh, ow), dtype=np.uint8)
    sizes = []
    for v in range(num_views):
        # the header first (microseconds): a tiny file declaring 60000x60000 must not reach the decoder
        check_image(raw.images[v], raw.width[v], raw.height[v], f"{name} view {v}", max_pixels)
        bgr = decode_bgr(raw.images[v], f"{name} view {v}")
        h, w = bgr.shape[:2]
        if h != raw.height[v] or w != raw.width[v]:
            raise SeeUError(f"view {v} decodes to {w}x{h}, the row says {raw.width[v]}x{raw.height[v]}", name)
        sizes.append((h, w))
        crop = resize_cover_crop(bgr, out_hw, interpolation, copy=False)  # resizes only the span that is kept
        if flip:
            crop = cv2.flip(crop, 1)
        cv2.mixChannels([crop], [images[v, 0], images[v, 1], images[v, 2]], _BGR_TO_PLANAR_RGB)
    if len(set(sizes)) == 1:  # the usual case: one size for all views
        scaled, offset = cameras.cover_crop_geometry(sizes[0], out_hw)
        intrinsics = cameras.crop_intrinsics_norm(raw.intrinsics_norm, scaled, offset, out_hw)
    else:
        intrinsics = np.empty((num_views, 4), dtype=np.float64)
        for size in set(sizes):
            scaled, offset = cameras.cover_crop_geometry(size, out_hw)
            idx = [v for v in range(num_views) if sizes[v] == size]
            intrinsics[idx] = cameras.crop_intrinsics_norm(raw.intrinsics_norm[idx], scaled, offset, out_hw)
    masks = None
    if raw.masks is not None:
        masks = np.zeros((num_views, oh, ow), dtype=bool)
        for v, data in enumerate(raw.masks):
            if data is not None:
                check_mask(data, raw.width[v], raw.height[v], f"{name} view {v}", max_pixels)
                m = resize_mask(decode_mask(data, f"{name} view {v}"), out_hw)
                masks[v] = m[:, ::-1] if flip else m
    cam_to_world = np.asarray(raw.cam_to_world, dtype=np.float64)
    if flip:
        cam_to_world, intrinsics = cameras.flip_horizontal(cam_to_world, intrinsics)
    return ViewsSample(
        sample_id=raw.sample_id,
        scene_id=raw.scene_id,
        num_context=raw.num_context,
        images=images,
        cam_to_world=cam_to_world,
        intrinsics_norm=intrinsics,
        near=np.asarray(raw.near, np.float32),
        far=np.asarray(raw.far, np.float32),
        frame_index=np.asarray(raw.frame_index, np.int64),
        gap=raw.gap,
        masks=masks,
    )
