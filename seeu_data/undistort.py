"""Undistort frames to a pinhole camera of the SAME size (what the peers' loaders need).

COLMAP's own undistorter (`pycolmap.undistort_images`) picks a new image size, which is often a pixel
smaller than the input (640x360 -> 639x359), and the pixelSplat / MVSplat RE10K loaders skip every
example whose frames are not exactly 360x640. Here the output keeps the input's W x H and the
principal point of the camera's pinhole part; only the focal length changes, by the one factor `s`
(the same for x and y, so square pixels stay square) that makes every output pixel see a ray that
lands inside the distorted frame: no blank border, nothing more cropped than needed.

    pin = same_size_pinhole(camera)             # PinholeCamera(fx, fy, cx, cy, width, height, scale)
    map_x, map_y = undistort_maps(camera, pin)  # (H, W) float32 source pixel of each output pixel
    out = cv2.remap(img, map_x, map_y, ...)     # or undistort_files(...)

`camera` is anything with COLMAP's camera interface (`width`, `height`, `calibration_matrix()`,
`cam_from_img((N, 2) pixels) -> (N, 2)` normalised, `img_from_cam((N, 3)) -> (N, 2)` pixels), i.e. a
`pycolmap.Camera` of any model. Pixel coordinates are COLMAP's: the top-left corner of the image is
(0, 0), the centre of pixel (row i, column j) is (j + 0.5, i + 0.5), as in `seeu_data.cameras`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seeu_data.limits import MAX_PIXELS
from seeu_data.store.dataset_check import check_image
from seeu_data.store.image_header import check_pixels, decode_image

# Border samples per image side used to find the largest undistorted rectangle.
_BORDER_SAMPLES = 256


@dataclass(frozen=True)
class PinholeCamera:
    """A pinhole camera in pixels; `scale`: its focal length / the distorted camera's."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    scale: float

    def matrix(self) -> np.ndarray:
        """The calibration matrix K `(3, 3)` in pixels."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def as_dict(self) -> dict:
        return {
            "model": "PINHOLE",
            "width": self.width,
            "height": self.height,
            "params": [self.fx, self.fy, self.cx, self.cy],
            "fx": self.fx,
            "fy": self.fy,
            "cx": self.cx,
            "cy": self.cy,
        }


def same_size_pinhole(camera) -> PinholeCamera:
    """The pinhole camera of the same W x H and principal point as `camera`'s pinhole part, with its
    focal length scaled so that the whole output frame is covered by the distorted frame.

    The distorted frame's four edges are unprojected to normalised image coordinates; the output's
    normalised extent [-cx/fx', (W-cx)/fx'] x [-cy/fy', (H-cy)/fy'] must lie inside the innermost
    point of each edge, which bounds fx' = s fx and fy' = s fy from below; s is the smallest factor
    meeting all four bounds (s < 1 when the lens shows more than its pinhole part: pincushion).
    """
    w, h = int(camera.width), int(camera.height)
    K = np.asarray(camera.calibration_matrix(), np.float64)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    t = np.linspace(0.0, 1.0, _BORDER_SAMPLES)

    def edge(x, y) -> np.ndarray:  # (N, 2) normalised coordinates of border pixels
        return np.asarray(camera.cam_from_img(np.stack([x, y], 1).astype(np.float64)), np.float64)

    left = edge(np.zeros_like(t), t * h)[:, 0].max()
    right = edge(np.full_like(t, w), t * h)[:, 0].min()
    top = edge(t * w, np.zeros_like(t))[:, 1].max()
    bottom = edge(t * w, np.full_like(t, h))[:, 1].min()
    if not (left < 0 < right and top < 0 < bottom):
        raise ValueError(f"the principal point ({cx:.1f}, {cy:.1f}) is not inside the undistorted frame")
    s = max(cx / -left / fx, (w - cx) / right / fx, cy / -top / fy, (h - cy) / bottom / fy)
    return PinholeCamera(fx=s * fx, fy=s * fy, cx=cx, cy=cy, width=w, height=h, scale=float(s))


def undistort_maps(camera, pinhole: PinholeCamera) -> tuple[np.ndarray, np.ndarray]:
    """For every output pixel of `pinhole`: the (x, y) pixel index in the distorted frame that sees
    the same ray, as `cv2.remap` maps (two (H, W) float32 arrays, integer = pixel centre)."""
    w, h = pinhole.width, pinhole.height
    u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    rays = np.stack([(u - pinhole.cx) / pinhole.fx, (v - pinhole.cy) / pinhole.fy, np.ones_like(u)], -1)
    src = np.asarray(camera.img_from_cam(rays.reshape(-1, 3)), np.float64).reshape(h, w, 2) - 0.5
    return src[..., 0].astype(np.float32), src[..., 1].astype(np.float32)


def undistort_files(
    camera,
    image_dir: str | Path,
    names: list[str],
    out_dir: str | Path,
    jpeg_quality: int = 95,
    max_pixels: int = MAX_PIXELS,
) -> PinholeCamera:
    """Undistort the frames `image_dir/name` to `out_dir/name` (JPEG at `jpeg_quality`, bilinear
    resampling, same size); returns the pinhole camera of the output frames. The camera's size and
    every frame's header are checked against `max_pixels` (and each other) before anything is
    allocated or decoded: SeeUError."""
    import cv2

    check_pixels(camera.width, camera.height, max_pixels, "camera size", image_dir)
    pin = same_size_pinhole(camera)
    map_x, map_y = undistort_maps(camera, pin)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    for name in names:
        path = Path(image_dir) / name
        data = path.read_bytes()
        check_image(data, pin.width, pin.height, path, max_pixels)
        img = decode_image(data, path, max_pixels)
        if img.shape[:2] != (pin.height, pin.width):
            raise ValueError(f"frame {name} is {img.shape[1]}x{img.shape[0]}, the camera {pin.width}x{pin.height}")
        out = cv2.remap(img, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        (out_dir / name).parent.mkdir(parents=True, exist_ok=True)
        ok, buf = cv2.imencode(Path(name).suffix or ".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)])
        if not ok:
            raise ValueError(f"cannot encode frame {name}")
        (out_dir / name).write_bytes(buf.tobytes())
    return pin
