"""nerfstudio / NeRF `transforms.json` -> one posed scene.

Keys read: `fl_x`, `fl_y`, `cx`, `cy`, `w`, `h` (top level, or per frame overriding it; NeRF-synthetic
files with only `camera_angle_x` get f = w / (2 tan(angle / 2)) and a centred principal point),
`camera_model` (OPENCV, the default, PINHOLE or SIMPLE_PINHOLE; distortion `k1..k4`, `p1`, `p2` must be
zero), `frames[].file_path` (relative to the JSON's folder; a missing extension tries .png/.jpg),
`frames[].transform_matrix` (4x4 or 3x4 OpenGL camera-to-world: +x right, +y up, +z backward) and
`applied_transform` (3x4).

World frame written: `ns-process-data` stores `applied_transform @ c2w` (it swaps the COLMAP world's
y and z axes and negates the new z). By default this importer undoes it, so the poses are in the
*original* world (the COLMAP model's, when the data came from COLMAP): importing a COLMAP model and
the nerfstudio folder made from it gives the same cameras. `keep_applied_transform` keeps
nerfstudio's world instead. Axes: `cameras.opencv_from_opengl`; intrinsics:
`cameras.intrinsics_norm_from_pixels` at (w, h). Frames are sorted by file path (as nerfstudio's
dataparser does); image bytes are kept as they are.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from ..cameras import homogeneous_from_3x4, intrinsics_norm_from_pixels, invert_rigid, opencv_from_opengl
from ..arrow_io import read_json
from ..errors import SeeUError
from ..posed import PosedScene
from .common import SkippedScene, probe_images

PINHOLE_MODELS = {"OPENCV", "PINHOLE", "SIMPLE_PINHOLE"}
DISTORTION_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")


@dataclass
class NerfstudioImportConfig:
    transforms: Path
    scene_id: str | None = None
    undo_applied_transform: bool = True
    near: float | None = None  # None: the `seeu` block's value (our exports), else DEFAULT_NEAR_FAR
    far: float | None = None
    verify_decode: bool = False


DEFAULT_NEAR_FAR = (0.1, 100.0)


class CameraModelError(SeeUError):
    """The camera model cannot be imported at all (raised, not a skipped scene)."""


def _matrix(value, rows_ok: tuple[int, ...], where: str, path: Path) -> np.ndarray:
    try:
        m = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise SeeUError(f"{where} is not a numeric matrix", path) from None
    if m.ndim != 2 or m.shape[1] != 4 or m.shape[0] not in rows_ok:
        raise SeeUError(f"{where} has shape {m.shape}, expected {' or '.join(f'{r}x4' for r in rows_ok)}", path)
    return homogeneous_from_3x4(m[:3]) if m.shape[0] == 3 else m


def _resolve_image(base: Path, file_path: str) -> Path:
    p = base / file_path
    if p.suffix == "" or not p.exists():
        for ext in (".png", ".jpg", ".jpeg", ".JPG", ".PNG"):
            if p.with_name(p.name + ext).exists():
                return p.with_name(p.name + ext)
    return p


def load_transforms(path: Path) -> dict:
    path = Path(path)
    if not path.is_file():
        raise SeeUError("transforms.json not found", path)
    doc = read_json(path)
    if not isinstance(doc, dict) or not isinstance(doc.get("frames"), list) or not doc["frames"]:
        raise SeeUError("no 'frames' list", path)
    return doc


def _camera(doc: dict, frame: dict, path: Path, image_size: tuple[int, int] | None) -> tuple[np.ndarray, int, int]:
    """Pixel K (3, 3), w, h of a frame (frame keys override the top level)."""

    def get(key):
        return frame.get(key, doc.get(key))

    model = get("camera_model") or "OPENCV"
    if model not in PINHOLE_MODELS:
        raise CameraModelError(f"unsupported camera_model {model!r} (OPENCV/PINHOLE without distortion only; "
                        f"undistort the images first)", path)
    dist = {k: get(k) for k in DISTORTION_KEYS if get(k)}
    if dist:
        raise CameraModelError(f"non-zero distortion {dist}: undistort the images first (e.g. COLMAP image_undistorter)", path)
    w, h = get("w"), get("h")
    if (w is None or h is None) and image_size is not None:
        w, h = image_size
    if w is None or h is None:
        raise SeeUError("no image size (w, h)", path)
    fx, fy = get("fl_x"), get("fl_y")
    if fx is None and get("camera_angle_x") is not None:
        fx = 0.5 * float(w) / math.tan(0.5 * float(get("camera_angle_x")))
    if fy is None:
        fy = 0.5 * float(h) / math.tan(0.5 * float(get("camera_angle_y"))) if get("camera_angle_y") is not None else fx
    if fx is None:
        raise SeeUError("no focal length (fl_x or camera_angle_x)", path)
    cx = get("cx") if get("cx") is not None else 0.5 * float(w)
    cy = get("cy") if get("cy") is not None else 0.5 * float(h)
    K = np.array([[float(fx), 0.0, float(cx)], [0.0, float(fy), float(cy)], [0.0, 0.0, 1.0]])
    return K, int(w), int(h)


def import_plan(cfg: NerfstudioImportConfig):
    """The import as one resumable unit (`importers.common.ImportPlan`) whose fingerprint covers
    transforms.json and the frame images it names."""
    from .common import ImportPlan, ImportUnit, files_fingerprint

    path = Path(cfg.transforms)
    doc = load_transforms(path)
    images = [_resolve_image(path.parent, str(f["file_path"])) for f in doc["frames"]
              if isinstance(f, dict) and "file_path" in f]
    return ImportPlan([ImportUnit(path.name, files_fingerprint([path, *sorted(images)]), lambda: iter_scenes(cfg))])


def iter_scenes(cfg: NerfstudioImportConfig) -> Iterator[PosedScene | SkippedScene]:
    path = Path(cfg.transforms)
    doc = load_transforms(path)
    base = path.parent
    extra = doc.get("seeu", {}) if isinstance(doc.get("seeu"), dict) else {}
    scene_id = cfg.scene_id or extra.get("scene_id") or base.resolve().name
    frames = sorted(doc["frames"], key=lambda f: str(f.get("file_path", "")))
    for f in frames:
        if not isinstance(f, dict) or "file_path" not in f or "transform_matrix" not in f:
            raise SeeUError("every frame needs file_path and transform_matrix", path)
    applied = None
    if doc.get("applied_transform") is not None:
        applied = _matrix(doc["applied_transform"], (3, 4), "applied_transform", path)
        if np.abs(applied[:3, :3].T @ applied[:3, :3] - np.eye(3)).max() > 1e-6:
            raise SeeUError("applied_transform is not a rigid transform (scaled poses are not supported)", path)
    try:
        paths = [_resolve_image(base, f["file_path"]) for f in frames]
        missing = [str(p) for p in paths if not p.is_file()]
        if missing:
            raise SeeUError(f"{len(missing)} of {len(paths)} frame images are missing (first: {missing[0]})", path)
        images = [p.read_bytes() for p in paths]
        fmt, width, height = probe_images(images, [str(p) for p in paths], cfg.verify_decode)
        intr, c2w_gl = [], []
        for k, f in enumerate(frames):
            K, w, h = _camera(doc, f, path, (int(width[k]), int(height[k])))
            if abs(width[k] / height[k] - w / h) > 1e-2 * w / h:
                raise SeeUError(f"image is {width[k]}x{height[k]}, transforms.json says {w}x{h}", paths[k])
            intr.append(intrinsics_norm_from_pixels(K, w, h))
            c2w_gl.append(_matrix(f["transform_matrix"], (3, 4), f"transform_matrix of {f['file_path']}", path))
    except CameraModelError:
        raise
    except SeeUError as exc:
        yield SkippedScene(scene_id, str(exc))
        return
    c2w_gl = np.stack(c2w_gl)
    if applied is not None and cfg.undo_applied_transform:
        c2w_gl = invert_rigid(applied) @ c2w_gl
    names = [str(f["file_path"]) for f in frames]
    if all("seeu_source_frame" in f for f in frames):
        source_frame = np.asarray([int(f["seeu_source_frame"]) for f in frames], dtype=np.int64)
    else:
        nums = [re.findall(r"\d+", Path(n).stem) for n in names]
        vals = [int(m[-1]) if m else None for m in nums]
        source_frame = (np.asarray(vals, dtype=np.int64) if None not in vals and len(set(vals)) == len(vals)
                        else np.arange(len(names), dtype=np.int64))
    timestamps = np.asarray([int(f.get("seeu_timestamp_us", 0)) for f in frames], dtype=np.int64)
    meta = {"dataset": "nerfstudio", "transforms": str(path.resolve()),
            "world": "nerfstudio (applied_transform kept)" if applied is not None and not cfg.undo_applied_transform
            else "original (applied_transform undone)" if applied is not None else "as stored"}
    meta.update(extra.get("meta", {}))
    near = float(cfg.near if cfg.near is not None else extra.get("near", DEFAULT_NEAR_FAR[0]))
    far = float(cfg.far if cfg.far is not None else extra.get("far", DEFAULT_NEAR_FAR[1]))
    yield PosedScene(scene_id=str(scene_id), images=images, image_format=fmt, width=width, height=height,
                     intrinsics_norm=np.stack(intr), cam_to_world=opencv_from_opengl(c2w_gl), near=near, far=far,
                     source_frame=source_frame, timestamp_us=timestamps,
                     source_name=[str(f.get("seeu_source_name", n)) for f, n in zip(frames, names)], meta=meta)
