"""Per-sample transforms: OpenCV decode, cover resize + centre crop (intrinsics updated), flip.

Geometry comes from `seeu_data.cameras` (`cover_crop_geometry`, `crop_intrinsics_norm`,
`flip_horizontal`): the image is resized so it covers the training size, then the middle is cut out
(360x640 -> 256x455 -> 256x256, as the peers do). Filters (`interpolation`):

* `"linear"` (default): bilinear `cv2.INTER_LINEAR`, ~0.2 ms per 360x640 view, so the loader runs
  near the JPEG-decode limit. Not anti-aliased: at the usual 1.4x reduction every source pixel still
  contributes, but fine texture can alias slightly.
* `"area"`: exact pixel-area averaging (`cv2.INTER_AREA`, anti-aliased); ~1 ms per view at 1.4x
  (OpenCV's non-integer area path is not vectorised), i.e. about 1.6x the cost of the JPEG decode.
* `"lanczos"` / `"cubic"`: Lanczos is the peers' (PIL) filter, ~2 ms per view.

Pixels are moved by `seeu_data.image_ops.resize_cover_crop` (shared with `seeu build`).
Images are decoded to BGR and written as planar RGB (V, 3, H, W) uint8 with one `cv2.mixChannels`.
A flip mirrors every view of a sample (the whole scene is mirrored in world x).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .. import cameras
from ..image_ops import INTERPOLATIONS, resize_cover_crop
from ..errors import SeeUError
from .shard_reader import RawSample



@dataclass
class ViewsSample:
    """A transformed sample, V views at H x W.

    images: (V, 3, H, W) uint8 RGB (planar); cam_to_world: (V, 4, 4) float32; intrinsics: (V, 3, 3)
    float32 normalised; near, far: (V,) float32; frame_index: (V,) int64.
    """

    sample_id: str
    scene_id: str
    num_context: int
    images: np.ndarray
    cam_to_world: np.ndarray
    intrinsics: np.ndarray
    near: np.ndarray
    far: np.ndarray
    frame_index: np.ndarray
    gap: int


def decode_bgr(buf: np.ndarray, where: str) -> np.ndarray:
    """Encoded JPEG/PNG bytes (1-D uint8) -> (H, W, 3) uint8 BGR; SeeUError naming `where` if undecodable."""
    img = cv2.imdecode(buf, cv2.IMREAD_COLOR) if len(buf) else None
    if img is None:
        raise SeeUError("image does not decode (corrupt or truncated)", where)
    return img


_BGR_TO_PLANAR_RGB = [2, 0, 1, 1, 0, 2]


def transform_sample(raw: RawSample, out_hw: tuple[int, int], flip: bool = False, interpolation: str = "linear",
                     where: str = "") -> ViewsSample:
    """Decode, resize/crop (and optionally mirror) every view of a stored sample.

    Cameras: intrinsics via `cameras.crop_intrinsics_norm`, mirrored with `cameras.flip_horizontal`.
    """
    if interpolation not in INTERPOLATIONS:
        raise ValueError(f"interpolation must be one of {sorted(INTERPOLATIONS)}")
    num_views = len(raw.images)
    oh, ow = out_hw
    images = np.empty((num_views, 3, oh, ow), dtype=np.uint8)
    intrinsics = np.empty((num_views, 4), dtype=np.float64)
    name = f"{where} sample {raw.sample_id}"
    for v in range(num_views):
        bgr = decode_bgr(raw.images[v], f"{name} view {v}")
        h, w = bgr.shape[:2]
        if (h, w) != (int(raw.height[v]), int(raw.width[v])):
            raise SeeUError(f"view {v} decodes to {w}x{h}, the row says {raw.width[v]}x{raw.height[v]}", name)
        scaled, offset = cameras.cover_crop_geometry((h, w), out_hw)
        intrinsics[v] = cameras.crop_intrinsics_norm(raw.intrinsics_norm[v], scaled, offset, out_hw)
        crop = resize_cover_crop(bgr, out_hw, interpolation)
        if flip:
            crop = cv2.flip(crop, 1)
        cv2.mixChannels([crop], [images[v, 0], images[v, 1], images[v, 2]], _BGR_TO_PLANAR_RGB)
    cam_to_world = np.asarray(raw.cam_to_world, dtype=np.float64)
    if flip:
        cam_to_world, intrinsics = cameras.flip_horizontal(cam_to_world, intrinsics)
    return ViewsSample(
        sample_id=raw.sample_id, scene_id=raw.scene_id, num_context=raw.num_context, images=images,
        cam_to_world=cam_to_world.astype(np.float32),
        intrinsics=cameras.intrinsics_norm_matrix(intrinsics).astype(np.float32),
        near=np.asarray(raw.near, np.float32), far=np.asarray(raw.far, np.float32),
        frame_index=np.asarray(raw.frame_index, np.int64), gap=raw.gap,
    )
