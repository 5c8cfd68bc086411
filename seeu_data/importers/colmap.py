"""A COLMAP model (binary or text, read with pycolmap) and its image folder -> one posed scene.

Cameras: PINHOLE and SIMPLE_PINHOLE are used directly, as are distortion models whose distortion
parameters are all zero. The frames of cameras with distortion (SIMPLE_RADIAL, RADIAL, OPENCV,
FULL_OPENCV, the fisheye models, ...) are undistorted first, as `seeu ingest` does it
(`seeu_data.undistort`): into a temporary folder, to a pinhole camera of the SAME width x height and
principal point, only the focal length scaled (what the peers' RE10K loaders need; COLMAP's own
undistorter changes the size by a pixel or more); poses do not change (`undistort=False` refuses such
cameras with an error instead). Spherical models (EQUIRECTANGULAR) cannot be made pinhole and are
refused.

Conversion: `image.cam_from_world()` (world-to-camera) -> camera-to-world with
`cameras.cam_to_world_from_world_to_cam`; `camera.calibration_matrix()` (pixels) -> normalised with
`cameras.intrinsics_norm_from_pixels` at the camera's size; the world frame is COLMAP's. Image bytes
are kept as they are (JPEG or PNG). Frames are ordered by image name; `source_name` is the name,
`source_frame` the number in the name when every name has a distinct one (else the position);
timestamps are 0 (COLMAP has none). near/far: given, or from the depths of each image's observed
3D points (0.5 x 1st percentile, 1.5 x 99th percentile; the method is kept in the meta). The scene
carries the model's observations (a `TrackedScene`), so its view overlap is measured from the tracks.
"""

from __future__ import annotations

import re
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from seeu_data.cameras import cam_to_world_from_world_to_cam, homogeneous_from_3x4, intrinsics_norm_from_pixels
from seeu_data.errors import SeeUError
from seeu_data.importers.common import ImportJob, ReadSettings, SkippedScene, probe_images, recorded_params
from seeu_data.limits import MAX_PIXELS
from seeu_data.settings import setting
from seeu_data.store.paths import contained_path
from seeu_data.store.posed import PosedScene, TrackedScene
from seeu_data.undistort import PinholeCamera, undistort_files

PINHOLE_MODELS = {"SIMPLE_PINHOLE", "PINHOLE"}
UNDISTORTABLE_MODELS = {
    "SIMPLE_RADIAL",
    "RADIAL",
    "OPENCV",
    "FULL_OPENCV",
    "SIMPLE_RADIAL_FISHEYE",
    "RADIAL_FISHEYE",
    "OPENCV_FISHEYE",
    "THIN_PRISM_FISHEYE",
    "RAD_TAN_THIN_PRISM_FISHEYE",
    "FOV",
    "SIMPLE_FISHEYE",
    "FISHEYE",
    "SIMPLE_DIVISION",
    "DIVISION",
    "EUCM",
}


@dataclass
class ColmapImportConfig(ReadSettings):
    model_dir: Path = setting(
        help="model directory (cameras/images/points3D .bin or .txt)", positional=True, metavar="model"
    )
    images_dir: Path = setting(help="image directory the model's names are relative to", flag="--images")
    scene_id: str | None = setting(None, "scene id (default: derived from the model path)")
    undistort: bool = setting(True, "refuse distorted camera models instead of undistorting with pycolmap")
    near: float | None = setting(None, "near plane (default: from the 3D points' depths)")
    far: float | None = setting(None, "far plane (default: from the 3D points' depths)")
    allow_outside_paths: bool = setting(
        False,
        "read image names that lead outside --images (../x.jpg, absolute, links); default: such images are "
        "dropped and counted",
    )

    def plan(self) -> ImportJob:
        params = recorded_params(self, "colmap")
        return ImportJob(import_plan(self), params, 1, [str(self.model_dir), str(self.images_dir)])


def default_scene_id(model_dir: Path) -> str:
    """`scene/sparse/0` -> `scene`; `scene/sparse` -> `scene`; otherwise the folder name."""
    parts = Path(model_dir).resolve().parts
    for i in range(len(parts) - 1, 0, -1):
        if parts[i] == "sparse":
            return parts[i - 1]
    return parts[-1]


def read_model(model_dir: Path):
    """pycolmap.Reconstruction of a model folder (SeeUError when missing or unreadable)."""
    import cv2  # noqa: F401  (load OpenCV's zlib/libpng before pycolmap's: the other order crashes PNG writes)
    import pycolmap

    model_dir = Path(model_dir)
    if not model_dir.is_dir():
        raise SeeUError("COLMAP model directory not found", model_dir)
    names = {p.name for p in model_dir.iterdir()}
    if not ({"cameras.bin", "images.bin"} <= names or {"cameras.txt", "images.txt"} <= names):
        raise SeeUError("not a COLMAP model (no cameras/images .bin or .txt)", model_dir)
    try:
        return pycolmap.Reconstruction(str(model_dir))
    except Exception as exc:  # pycolmap raises plain RuntimeError/ValueError on bad files
        raise SeeUError(f"unreadable COLMAP model ({str(exc).splitlines()[0][:160]})", model_dir) from None


def _distortion_free(camera) -> bool:
    name = camera.model.name
    if name in PINHOLE_MODELS:
        return True
    skip = set(camera.focal_length_idxs()) | set(camera.principal_point_idxs())
    extra = [p for i, p in enumerate(camera.params) if i not in skip]
    return name in {"SIMPLE_RADIAL", "RADIAL", "OPENCV", "FULL_OPENCV"} and np.allclose(extra, 0.0)


def needs_undistortion(rec, model_dir: Path) -> bool:
    """True when a camera of a registered image has distortion; SeeUError for unusable models."""
    used = {rec.image(i).camera_id for i in rec.reg_image_ids()}
    need = False
    for cid in sorted(used):
        cam = rec.camera(cid)
        name = cam.model.name
        if _distortion_free(cam):
            continue
        if name not in UNDISTORTABLE_MODELS:
            raise SeeUError(
                f"camera {cid} has the unsupported camera model {name} (pinhole-like models only)", model_dir
            )
        need = True
    return need


def _source_frames(names: list[str]) -> np.ndarray:
    nums = []
    for name in names:
        m = re.findall(r"\d+", Path(name).stem)
        nums.append(int(m[-1]) if m else None)
    if None not in nums and len(set(nums)) == len(nums):
        return np.asarray(nums, dtype=np.int64)
    return np.arange(len(names), dtype=np.int64)


def _near_far_from_points(rec, image_ids: list[int]) -> tuple[float, float] | None:
    depths = []
    for iid in image_ids:
        img = rec.image(iid)
        w2c = np.asarray(img.cam_from_world().matrix(), dtype=np.float64)
        pts = [rec.point3D(p.point3D_id).xyz for p in img.points2D if p.has_point3D()]
        if pts:
            z = (np.asarray(pts) @ w2c[:, :3].T + w2c[:, 3])[:, 2]
            depths.append(z[z > 0])
    if not depths or sum(len(d) for d in depths) == 0:
        return None
    d = np.concatenate(depths)
    return 0.5 * float(np.percentile(d, 1)), 1.5 * float(np.percentile(d, 99))


def outside_images(rec, cfg: ColmapImportConfig) -> dict[str, str]:
    """Registered image names that lead outside `cfg.images_dir` -> the one-line reason (none with
    `allow_outside_paths`). Such images are dropped, never read."""
    if cfg.allow_outside_paths:
        return {}
    out = {}
    for i in rec.reg_image_ids():
        name = rec.image(i).name
        try:
            contained_path(cfg.images_dir, name, "image name", cfg.model_dir)
        except SeeUError as exc:
            out[name] = str(exc)
    return out


def scene_from_model(
    rec,
    images_dir: Path,
    cfg: ColmapImportConfig,
    meta: dict,
    skip: dict[str, str] | None = None,
    undistorted: tuple[Path, dict[int, PinholeCamera]] | None = None,
) -> PosedScene:
    """`skip`: image names to leave out -> reason (kept in `meta["skipped_frames"]`). `undistorted`:
    (folder, {camera id: pinhole camera}) from `undistort_cameras`: the frames of those cameras are
    read from that folder, with the pinhole camera's intrinsics."""
    images_dir = Path(images_dir)
    skip = skip or {}
    und_dir, pinholes = undistorted or (images_dir, {})
    ids = sorted((i for i in rec.reg_image_ids() if rec.image(i).name not in skip), key=lambda i: rec.image(i).name)
    if skip:
        meta["skipped_frames"] = [{"frame": n, "reason": r} for n, r in sorted(skip.items())]
    if not ids:
        raise SeeUError(
            "the model has no registered images" + (" inside the image directory" if skip else ""), cfg.model_dir
        )
    names = [rec.image(i).name for i in ids]
    _check_present(names, images_dir)
    paths = [(und_dir if rec.image(i).camera_id in pinholes else images_dir) / n for i, n in zip(ids, names)]
    data = [p.read_bytes() for p in paths]
    fmt, width, height = probe_images(data, [str(p) for p in paths], cfg.verify_decode, cfg.max_pixels)
    w2c, intr = [], []
    for k, iid in enumerate(ids):
        img = rec.image(iid)
        cam = rec.camera(img.camera_id)
        if abs(width[k] / height[k] - cam.width / cam.height) > 1e-2 * cam.width / cam.height:
            raise SeeUError(f"image is {width[k]}x{height[k]} but its camera is {cam.width}x{cam.height}", paths[k])
        w2c.append(np.asarray(img.cam_from_world().matrix(), dtype=np.float64))
        pin = pinholes.get(img.camera_id)
        K = pin.matrix() if pin is not None else np.asarray(cam.calibration_matrix(), dtype=np.float64)
        intr.append(intrinsics_norm_from_pixels(K, cam.width, cam.height))
    near, far = cfg.near, cfg.far
    if near is None or far is None:
        est = _near_far_from_points(rec, ids)
        if est is None:
            raise SeeUError("the model has no 3D points to derive near/far from: pass --near and --far", cfg.model_dir)
        near = est[0] if near is None else near
        far = est[1] if far is None else far
        meta["near_far_method"] = "SfM point depths: 0.5 x 1st / 1.5 x 99th percentile"
    else:
        meta["near_far_method"] = "given"
    scene_id = cfg.scene_id or default_scene_id(cfg.model_dir)
    frame_of_obs, point_of_obs = [], []
    for k, iid in enumerate(ids):
        pids = [p.point3D_id for p in rec.image(iid).points2D if p.has_point3D()]
        frame_of_obs.append(np.full(len(pids), k, np.int64))
        point_of_obs.append(np.asarray(pids, np.int64))
    return TrackedScene(
        scene_id=scene_id,
        images=data,
        image_format=fmt,
        width=width,
        height=height,
        intrinsics_norm=np.stack(intr),
        cam_to_world=cam_to_world_from_world_to_cam(homogeneous_from_3x4(np.stack(w2c))),
        near=near,
        far=far,
        source_frame=_source_frames(names),
        timestamp_us=np.zeros(len(ids), dtype=np.int64),
        source_name=names,
        meta=meta,
        observations=(np.concatenate(frame_of_obs), np.concatenate(point_of_obs)),
    )


def undistort_cameras(
    rec, images_dir: Path, out_dir: Path, names: list[str], max_pixels: int = MAX_PIXELS
) -> dict[int, PinholeCamera]:
    """The registered frames `names` whose camera has lens distortion, undistorted from `images_dir`
    into `out_dir` (same relative names and encoding) with `seeu_data.undistort`: per camera, a pinhole
    camera of the same size. Returns {camera id: its PinholeCamera}; SeeUError when a frame is missing,
    unreadable or not its camera's size."""
    wanted = set(names)
    by_camera: dict[int, list[str]] = {}
    for i in rec.reg_image_ids():
        img = rec.image(i)
        if img.name in wanted and not _distortion_free(rec.camera(img.camera_id)):
            by_camera.setdefault(img.camera_id, []).append(img.name)
    _check_present(sorted(n for ns in by_camera.values() for n in ns), Path(images_dir))
    pinholes = {}
    for cid, frames in sorted(by_camera.items()):
        try:
            pinholes[cid] = undistort_files(rec.camera(cid), images_dir, sorted(frames), out_dir, max_pixels=max_pixels)
        except ValueError as exc:
            raise SeeUError(f"undistortion of camera {cid} failed ({str(exc)[:160]})", images_dir) from None
    return pinholes


def _check_present(names: list[str], images_dir: Path) -> None:
    missing = [n for n in names if not (images_dir / n).is_file()]
    if missing:
        raise SeeUError(
            f"{len(missing)} of {len(names)} registered images are missing (first: {missing[0]})", images_dir
        )


def _check_and_read(cfg: ColmapImportConfig):
    if not Path(cfg.images_dir).is_dir():
        raise SeeUError("image directory not found", cfg.images_dir)
    return read_model(cfg.model_dir)


def iter_scenes(cfg: ColmapImportConfig) -> Iterator[PosedScene | SkippedScene]:
    """One scene (or a SkippedScene when its images are unusable); model-level problems raise."""
    yield from _scene_items(cfg, _check_and_read(cfg))


def import_plan(cfg: ColmapImportConfig):
    """The import as one resumable unit (`importers.common.ImportPlan`) whose fingerprint covers the
    model's files and the registered images it names. Reads the model (SeeUError when unusable)."""
    from seeu_data.importers.common import ImportPlan, ImportUnit
    from seeu_data.store.resume import files_fingerprint

    rec = _check_and_read(cfg)
    model_files = sorted(p for p in Path(cfg.model_dir).iterdir() if p.is_file())
    outside = outside_images(rec, cfg)
    images = [
        Path(cfg.images_dir) / n for n in sorted(rec.image(i).name for i in rec.reg_image_ids()) if n not in outside
    ]
    scene_id = cfg.scene_id or default_scene_id(cfg.model_dir)
    return ImportPlan([ImportUnit(scene_id, files_fingerprint(model_files + images), lambda: _scene_items(cfg, rec))])


def _scene_items(cfg: ColmapImportConfig, rec) -> Iterator[PosedScene | SkippedScene]:
    scene_id = cfg.scene_id or default_scene_id(cfg.model_dir)
    meta: dict[str, Any] = {
        "dataset": "colmap",
        "model": str(Path(cfg.model_dir).resolve()),
        "camera_models": sorted({rec.camera(rec.image(i).camera_id).model.name for i in rec.reg_image_ids()}),
    }
    need = needs_undistortion(rec, cfg.model_dir)  # raises for models that cannot become pinhole
    if need and not cfg.undistort:
        raise SeeUError(
            f"camera models {meta['camera_models']} have lens distortion; undistort first "
            f"(COLMAP image_undistorter) or drop --no-undistort",
            cfg.model_dir,
        )
    outside = outside_images(rec, cfg)
    kept = sorted(n for n in (rec.image(i).name for i in rec.reg_image_ids()) if n not in outside)
    try:
        if need:
            with tempfile.TemporaryDirectory(prefix="seeu-undistort-") as tmp:
                if not kept:
                    raise SeeUError("the model has no registered images inside the image directory", cfg.model_dir)
                pinholes = undistort_cameras(rec, cfg.images_dir, Path(tmp), kept, cfg.max_pixels)
                meta["undistorted"] = "same-size pinhole, focal x scale (seeu_data.undistort)"
                meta["undistortion_scale"] = {str(cid): pin.scale for cid, pin in pinholes.items()}
                scene = scene_from_model(
                    rec, cfg.images_dir, cfg, meta, skip=outside, undistorted=(Path(tmp), pinholes)
                )
        else:
            scene = scene_from_model(rec, cfg.images_dir, cfg, meta, skip=outside)
    except SeeUError as exc:
        yield SkippedScene(scene_id, str(exc))
        return
    yield scene
