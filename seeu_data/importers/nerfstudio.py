"""nerfstudio / NeRF `transforms.json` -> one posed scene.

Keys read: `fl_x`, `fl_y`, `cx`, `cy`, `w`, `h` (top level, or per frame overriding it; NeRF-synthetic
files with only `camera_angle_x` get f = w / (2 tan(angle / 2)) and a centred principal point),
`camera_model` (OPENCV, the default, OPENCV_FISHEYE, PINHOLE or SIMPLE_PINHOLE), the distortion
`k1`, `k2`, `k3`, `p1`, `p2` (OPENCV) or `k1..k4` (OPENCV_FISHEYE), `frames[].file_path` (relative to
the JSON's folder and inside it, see `seeu_data.store.paths`; a missing extension tries .png/.jpg),
`frames[].transform_matrix` (4x4 or 3x4 OpenGL camera-to-world: +x right, +y up, +z backward),
`frames[].mask_path` (optional, relative to the JSON's folder like `file_path`: nerfstudio's mask,
0 = pixel ignored, nonzero = kept, as its dataparser reads it; stored as this toolkit's excluded-pixel
mask, undistorted with its frame) and `applied_transform` (3x4).

World frame written: `ns-process-data` stores `applied_transform @ c2w` (it swaps the COLMAP world's
y and z axes and negates the new z). By default this importer undoes it, so the poses are in the
*original* world (the COLMAP model's, when the data came from COLMAP): importing a COLMAP model and
the nerfstudio folder made from it gives the same cameras. `keep_applied_transform` keeps
nerfstudio's world instead. Axes: `cameras.opencv_from_opengl`; intrinsics:
`cameras.intrinsics_norm_from_pixels` at (w, h). Frames are sorted by file path (as nerfstudio's
dataparser does); image bytes are kept as they are, except for frames with lens distortion: those
are undistorted as the COLMAP importer and `seeu ingest` do it (`seeu_data.undistort`, camera OPENCV /
FULL_OPENCV / OPENCV_FISHEYE with nerfstudio's parameters): to a pinhole camera of the same width x
height and principal point, only the focal length scaled; poses do not change.
nerfstudio's OPENCV `k4` (an r^8 radial term) has no COLMAP counterpart and is refused.

Bad entries: a frame whose image is missing skips the scene unless `skip_missing` (then the frame
is dropped); a `file_path` leading outside the JSON's folder is dropped (unless
`allow_outside_paths`); dropped frames are listed in the scene's `meta["skipped_frames"]` and
counted in the import report. Malformed fields (non-numeric intrinsics, frames that are not
objects, a `seeu` block with non-numeric near/far) are one-line errors.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seeu_data.cameras import homogeneous_from_3x4, intrinsics_norm_from_pixels, invert_rigid, opencv_from_opengl
from seeu_data.errors import SeeUError
from seeu_data.importers.common import ImportJob, ReadSettings, SkippedScene, probe_images, recorded_params
from seeu_data.limits import MAX_PIXELS
from seeu_data.masks import encode_mask, read_mask_file, undistort_mask
from seeu_data.settings import setting
from seeu_data.store.json_file import read_json
from seeu_data.store.paths import contained_path
from seeu_data.store.posed import PosedScene
from seeu_data.undistort import undistort_files

PINHOLE_MODELS = {"OPENCV", "PINHOLE", "SIMPLE_PINHOLE", "OPENCV_FISHEYE"}
DISTORTION_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")


@dataclass
class NerfstudioImportConfig(ReadSettings):
    transforms: Path = setting(help="transforms.json", positional=True)
    scene_id: str | None = setting(None, "scene id (default: the folder name)")
    undo_applied_transform: bool = setting(
        True,
        "keep nerfstudio's world frame (default: undo applied_transform, i.e. the original, e.g. COLMAP, world)",
        flag="--keep-applied-transform",
    )
    # None: the `seeu` block's value (our exports), else DEFAULT_NEAR_FAR
    near: float | None = setting(None, "near plane (default: from a seeu export, else 0.1)")
    far: float | None = setting(None, "far plane (default: from a seeu export, else 100)")
    undistort: bool = setting(
        True, "refuse frames with lens distortion (k1, k2, k3, k4, p1, p2) instead of undistorting them"
    )
    skip_missing: bool = setting(
        False, "drop frames whose image is missing (counted in the report) instead of skipping the scene"
    )
    allow_outside_paths: bool = setting(
        False,
        "read file_paths that lead outside the JSON's folder (../x.png, absolute, links); default: such frames "
        "are dropped and counted",
    )

    def plan(self) -> ImportJob:
        params = recorded_params(self, "nerfstudio")
        return ImportJob(import_plan(self), params, 1, [str(self.transforms)])


DEFAULT_NEAR_FAR = (0.1, 100.0)


class CameraModelError(SeeUError):
    """The camera model cannot be imported at all (raised, not a skipped scene)."""


def _number(value, key: str, path: Path, positive: bool = False) -> float:
    """A JSON number (not a string, not a bool), finite (and > 0 with `positive`), else SeeUError."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise SeeUError(f"{key} must be a finite number, got {value!r:.40}", path)
    if positive and value <= 0:
        raise SeeUError(f"{key} must be positive, got {value!r}", path)
    return float(value)


def _matrix(value, rows_ok: tuple[int, ...], where: str, path: Path) -> np.ndarray:
    try:
        m = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise SeeUError(f"{where} is not a numeric matrix", path) from None
    if m.ndim != 2 or m.shape[1] != 4 or m.shape[0] not in rows_ok:
        raise SeeUError(f"{where} has shape {m.shape}, expected {' or '.join(f'{r}x4' for r in rows_ok)}", path)
    if not np.isfinite(m).all():
        raise SeeUError(f"{where} has non-finite values", path)
    return homogeneous_from_3x4(m[:3]) if m.shape[0] == 3 else m


def _resolve_image(base: Path, file_path: str) -> Path:
    p = base / file_path
    if p.suffix == "" or not p.exists():
        for ext in (".png", ".jpg", ".jpeg", ".JPG", ".PNG"):
            if p.with_name(p.name + ext).exists():
                return p.with_name(p.name + ext)
    return p


def load_transforms(path: Path) -> dict:
    """transforms.json, its shape checked: a `frames` list of objects with a string `file_path` and
    a `transform_matrix`, an object `seeu` block when present (SeeUError otherwise)."""
    path = Path(path)
    if not path.is_file():
        raise SeeUError("transforms.json not found", path)
    doc = read_json(path, "transforms.json")
    if not isinstance(doc, dict) or not isinstance(doc.get("frames"), list) or not doc["frames"]:
        raise SeeUError("no 'frames' list", path)
    for k, f in enumerate(doc["frames"]):
        if not isinstance(f, dict) or "file_path" not in f or "transform_matrix" not in f:
            raise SeeUError(f"frames[{k}] is not an object with file_path and transform_matrix", path)
        if not isinstance(f["file_path"], str) or not f["file_path"]:
            raise SeeUError(f"frames[{k}].file_path must be a non-empty string, got {f['file_path']!r:.40}", path)
    extra = doc.get("seeu")
    if extra is not None:
        if not isinstance(extra, dict):
            raise SeeUError("the 'seeu' block must be an object", path)
        for key in ("near", "far"):
            if key in extra:
                _number(extra[key], f"seeu.{key}", path, positive=True)
        if not isinstance(extra.get("meta", {}), dict):
            raise SeeUError("seeu.meta must be an object", path)
    return doc


def frame_masks(
    cfg: NerfstudioImportConfig, frames: list[dict], path: Path, width: np.ndarray, height: np.ndarray
) -> list[np.ndarray | None] | None:
    """Each frame's `mask_path` mask as (H, W) bool, True = excluded (nerfstudio: 0 = ignore), None for a
    frame without one; None when no frame has one. SeeUError naming the mask when it cannot be read,
    leads outside the JSON's folder (unless `allow_outside_paths`) or is not its frame's size."""
    if not any("mask_path" in f for f in frames):
        return None
    out: list[np.ndarray | None] = []
    for k, f in enumerate(frames):
        if f.get("mask_path") is None:
            out.append(None)
            continue
        mpath = contained_path(path.parent, f["mask_path"], "frame mask_path", path, cfg.allow_outside_paths)
        mask = read_mask_file(mpath, "keep", cfg.max_pixels)
        if mask.shape != (int(height[k]), int(width[k])):
            raise SeeUError(f"mask is {mask.shape[1]}x{mask.shape[0]}, its frame {width[k]}x{height[k]}", mpath)
        out.append(mask)
    return out


def frame_paths(cfg: NerfstudioImportConfig, doc: dict) -> tuple[list[Path | None], dict[str, str]]:
    """Each frame's image path (doc order), None for a `file_path` leading outside the JSON's folder
    (unless `allow_outside_paths`), and those file_paths -> the one-line reason."""
    path = Path(cfg.transforms)
    base = path.parent
    paths: list[Path | None] = []
    outside: dict[str, str] = {}
    for f in doc["frames"]:
        name = f["file_path"]
        try:
            contained_path(base, name, "frame file_path", path, allow_outside=cfg.allow_outside_paths)
        except SeeUError as exc:
            outside[name] = str(exc)
            paths.append(None)
            continue
        image = _resolve_image(base, name)
        if not cfg.allow_outside_paths:  # the extension found may be a link leading out
            try:
                contained_path(base, str(image.relative_to(base)), "frame file_path", path)
            except SeeUError as exc:
                outside[name] = str(exc)
                paths.append(None)
                continue
        paths.append(image)
    return paths, outside


def _camera(
    doc: dict, frame: dict, path: Path, image_size: tuple[int, int] | None
) -> tuple[np.ndarray, int, int, str, dict]:
    """Pixel K (3, 3), w, h, camera model and non-zero distortion {key: value} of a frame (frame
    keys override the top level)."""

    def get(key):
        return frame.get(key, doc.get(key))

    model = get("camera_model") or "OPENCV"
    if model not in PINHOLE_MODELS:
        raise CameraModelError(
            f"unsupported camera_model {model!r:.40} (OPENCV, OPENCV_FISHEYE, PINHOLE or "
            "SIMPLE_PINHOLE; undistort the images first)",
            path,
        )
    dist = {k: _number(get(k), k, path) for k in DISTORTION_KEYS if get(k) is not None}
    dist = {k: v for k, v in dist.items() if v != 0.0}
    if dist and model in ("PINHOLE", "SIMPLE_PINHOLE"):
        raise CameraModelError(f"camera_model {model} with distortion {dist}", path)
    if model == "OPENCV" and "k4" in dist:
        raise CameraModelError(
            f"OPENCV distortion k4={dist['k4']} (nerfstudio's r^8 term) has no COLMAP camera "
            "model: undistort the images first",
            path,
        )
    if model == "OPENCV_FISHEYE" and ({"p1", "p2"} & set(dist)):
        raise CameraModelError("OPENCV_FISHEYE with tangential distortion p1/p2", path)
    w, h = get("w"), get("h")
    if (w is None or h is None) and image_size is not None:
        w, h = image_size
    if w is None or h is None:
        raise SeeUError("no image size (w, h)", path)
    w, h = _number(w, "w", path, positive=True), _number(h, "h", path, positive=True)
    fx, fy = get("fl_x"), get("fl_y")
    if fx is None and get("camera_angle_x") is not None:
        fx = 0.5 * w / math.tan(0.5 * _number(get("camera_angle_x"), "camera_angle_x", path, positive=True))
    if fx is None:
        raise SeeUError("no focal length (fl_x or camera_angle_x)", path)
    fx = _number(fx, "fl_x", path, positive=True)
    if fy is None:
        fy = (
            0.5 * h / math.tan(0.5 * _number(get("camera_angle_y"), "camera_angle_y", path, positive=True))
            if get("camera_angle_y") is not None
            else fx
        )
    fy = _number(fy, "fl_y", path, positive=True)
    cx = _number(get("cx"), "cx", path) if get("cx") is not None else 0.5 * w
    cy = _number(get("cy"), "cy", path) if get("cy") is not None else 0.5 * h
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    return K, int(w), int(h), model, dist


def colmap_camera(K: np.ndarray, model: str, dist: dict) -> tuple[str, list[float]]:
    """nerfstudio camera -> COLMAP camera model name and parameters (OPENCV: fx fy cx cy k1 k2 p1 p2;
    FULL_OPENCV when k3 is set: ... k3 k4 k5 k6 with k4..k6 = 0; OPENCV_FISHEYE: fx fy cx cy k1..k4)."""
    d = lambda k: float(dist.get(k, 0.0))  # noqa: E731
    base = [float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])]
    if model == "OPENCV_FISHEYE":
        return "OPENCV_FISHEYE", base + [d("k1"), d("k2"), d("k3"), d("k4")]
    if d("k3") != 0.0:
        return "FULL_OPENCV", base + [d("k1"), d("k2"), d("p1"), d("p2"), d("k3"), 0.0, 0.0, 0.0]
    return "OPENCV", base + [d("k1"), d("k2"), d("p1"), d("p2")]


def _pycolmap_camera(model: str, params: list[float], width: int, height: int):
    import pycolmap

    return pycolmap.Camera(model=model, width=width, height=height, params=params)


def undistort_frames(
    paths: list[Path], cameras: list[tuple[str, list[float], int, int]], max_pixels: int = MAX_PIXELS
) -> tuple[list[bytes], list[np.ndarray], list[tuple[int, int]]]:
    """Undistort frames as the COLMAP importer does (`seeu_data.undistort`: same size, focal scaled).

    `cameras[k]`: (COLMAP model, params, w, h) of frame k. The frames of each distinct camera are linked
    into a temporary folder and undistorted together. Returns the undistorted encoded images (the
    frame's own format), pixel K (3, 3) and (w, h) per frame.
    """
    import tempfile

    data: list[bytes] = [b""] * len(paths)
    Ks: list[np.ndarray] = [np.eye(3)] * len(paths)
    groups: dict[tuple, list[int]] = {}
    for k, (name, params, w, h) in enumerate(cameras):
        groups.setdefault((name, tuple(params), w, h), []).append(k)
    with tempfile.TemporaryDirectory(prefix="seeu-ns-undistort-") as tmp_name:
        links, out = Path(tmp_name) / "in", Path(tmp_name) / "out"
        links.mkdir()
        link = lambda k: f"{k:06d}{paths[k].suffix.lower()}"  # noqa: E731
        for k, p in enumerate(paths):
            (links / link(k)).symlink_to(Path(p).resolve())
        for (name, params, w, h), ks in groups.items():
            camera = _pycolmap_camera(name, list(params), w, h)
            try:
                pin = undistort_files(camera, links, [link(k) for k in ks], out, max_pixels=max_pixels)
            except ValueError as exc:
                raise SeeUError(f"undistortion failed ({str(exc)[:160]})", paths[ks[0]]) from None
            for k in ks:
                data[k], Ks[k] = (out / link(k)).read_bytes(), pin.matrix()
    return data, Ks, [(w, h) for _, _, w, h in cameras]


def import_plan(cfg: NerfstudioImportConfig):
    """The import as one resumable unit (`importers.common.ImportPlan`) whose fingerprint covers
    transforms.json and the frame images it names."""
    from seeu_data.importers.common import ImportPlan, ImportUnit
    from seeu_data.store.resume import files_fingerprint

    path = Path(cfg.transforms)
    doc = load_transforms(path)
    images = [p for p in frame_paths(cfg, doc)[0] if p is not None]
    return ImportPlan([ImportUnit(path.name, files_fingerprint([path, *sorted(images)]), lambda: iter_scenes(cfg))])


def iter_scenes(cfg: NerfstudioImportConfig) -> Iterator[PosedScene | SkippedScene]:
    path = Path(cfg.transforms)
    doc = load_transforms(path)
    extra = doc.get("seeu") or {}
    scene_id = cfg.scene_id or extra.get("scene_id") or path.parent.resolve().name
    all_paths, outside = frame_paths(cfg, doc)
    yield from scene_from_doc(cfg, doc, str(scene_id), all_paths, outside, {"dataset": "nerfstudio"})


def scene_from_doc(
    cfg: NerfstudioImportConfig,
    doc: dict,
    scene_id: str,
    all_paths: list[Path | None],
    outside: dict[str, str],
    meta_base: dict,
) -> Iterator[PosedScene | SkippedScene]:
    """One scene from a checked transforms.json `doc` (`load_transforms`) read from `cfg.transforms`:
    `all_paths[k]` is frame k's image (None: dropped, its reason in `outside` by file_path), `meta_base`
    starts the scene's meta (e.g. {"dataset": "nerfstudio"}). Yields the PosedScene, or a SkippedScene
    with the one-line reason."""
    path = Path(cfg.transforms)
    extra = doc.get("seeu") or {}
    dropped = [{"frame": n, "reason": r} for n, r in sorted(outside.items())]
    pairs = sorted(
        ((f, p) for f, p in zip(doc["frames"], all_paths) if p is not None), key=lambda fp: fp[0]["file_path"]
    )
    applied = None
    if doc.get("applied_transform") is not None:
        applied = _matrix(doc["applied_transform"], (3, 4), "applied_transform", path)
        if np.abs(applied[:3, :3].T @ applied[:3, :3] - np.eye(3)).max() > 1e-6:
            raise SeeUError("applied_transform is not a rigid transform (scaled poses are not supported)", path)
    try:
        missing = [(f, p) for f, p in pairs if not p.is_file()]
        if missing and not cfg.skip_missing:
            raise SeeUError(
                f"{len(missing)} of {len(pairs)} frame images are missing (first: {missing[0][1]}); "
                "pass --skip-missing to drop those frames",
                path,
            )
        dropped += [{"frame": f["file_path"], "reason": f"image missing: {p}"} for f, p in missing]
        pairs = [(f, p) for f, p in pairs if p.is_file()]
        if not pairs:
            raise SeeUError("no frame left to import" + (f" ({len(dropped)} dropped)" if dropped else ""), path)
        frames = [f for f, _ in pairs]
        paths = [p for _, p in pairs]
        images = [p.read_bytes() for p in paths]
        fmt, width, height = probe_images(images, [str(p) for p in paths], cfg.verify_decode, cfg.max_pixels)
        masks = frame_masks(cfg, frames, path, width, height)
        Ks, sizes, c2w_gl, distorted = [], [], [], {}
        for k, f in enumerate(frames):
            K, w, h, model, dist = _camera(doc, f, path, (int(width[k]), int(height[k])))
            if abs(width[k] / height[k] - w / h) > 1e-2 * w / h:
                raise SeeUError(f"image is {width[k]}x{height[k]}, transforms.json says {w}x{h}", paths[k])
            if dist:
                if not cfg.undistort:
                    raise CameraModelError(
                        f"non-zero distortion {dist}: undistort the images first (e.g. COLMAP "
                        "image_undistorter) or drop --no-undistort",
                        path,
                    )
                if (int(width[k]), int(height[k])) != (w, h):
                    raise SeeUError(f"image is {width[k]}x{height[k]}, its distorted camera is {w}x{h}", paths[k])
                distorted[k] = (*colmap_camera(K, model, dist), w, h)
            Ks.append(K)
            sizes.append((w, h))
            c2w_gl.append(_matrix(f["transform_matrix"], (3, 4), f"transform_matrix of {f['file_path']}", path))
        if distorted:
            keys = sorted(distorted)
            data, und_K, und_sizes = undistort_frames(
                [paths[k] for k in keys], [distorted[k] for k in keys], cfg.max_pixels
            )
            for j, k in enumerate(keys):
                images[k], Ks[k], sizes[k] = data[j], und_K[j], und_sizes[j]
                mask = None if masks is None else masks[k]
                if mask is not None:
                    masks[k] = undistort_mask(mask, _pycolmap_camera(*distorted[k]))  # type: ignore[index]
            fmt, width, height = probe_images(images, [str(p) for p in paths], cfg.verify_decode, cfg.max_pixels)
        intr = [intrinsics_norm_from_pixels(K, w, h) for K, (w, h) in zip(Ks, sizes)]
        names = [f["file_path"] for f in frames]
        if all("seeu_source_frame" in f for f in frames):
            source_frame = np.asarray(
                [int(_number(f["seeu_source_frame"], "seeu_source_frame", path)) for f in frames], dtype=np.int64
            )
        else:
            nums = [re.findall(r"\d+", Path(n).stem) for n in names]
            vals = [int(m[-1]) if m else None for m in nums]
            source_frame = (
                np.asarray(vals, dtype=np.int64)
                if None not in vals and len(set(vals)) == len(vals)
                else np.arange(len(names), dtype=np.int64)
            )
        timestamps = np.asarray(
            [int(_number(f.get("seeu_timestamp_us", 0), "seeu_timestamp_us", path)) for f in frames], dtype=np.int64
        )
    except CameraModelError:
        raise
    except SeeUError as exc:
        yield SkippedScene(str(scene_id), str(exc))
        return
    c2w_gl_n4 = np.stack(c2w_gl)  # (N, 4, 4) OpenGL camera-to-world
    if applied is not None and cfg.undo_applied_transform:
        c2w_gl_n4 = invert_rigid(applied) @ c2w_gl_n4
    meta: dict[str, object] = {
        **meta_base,
        "transforms": str(path.resolve()),
        "world": "nerfstudio (applied_transform kept)"
        if applied is not None and not cfg.undo_applied_transform
        else "original (applied_transform undone)"
        if applied is not None
        else "as stored",
    }
    meta.update(extra.get("meta", {}))
    if distorted:
        meta["undistorted"] = f"same-size pinhole, focal x scale (seeu_data.undistort; {len(distorted)} frames)"
    if dropped:
        meta["skipped_frames"] = dropped
    near = float(cfg.near if cfg.near is not None else extra.get("near", DEFAULT_NEAR_FAR[0]))
    far = float(cfg.far if cfg.far is not None else extra.get("far", DEFAULT_NEAR_FAR[1]))
    yield PosedScene(
        scene_id=str(scene_id),
        images=images,
        image_format=fmt,
        width=width,
        height=height,
        intrinsics_norm=np.stack(intr),
        cam_to_world=opencv_from_opengl(c2w_gl_n4),
        near=near,
        far=far,
        source_frame=source_frame,
        timestamp_us=timestamps,
        source_name=[str(f.get("seeu_source_name", n)) for f, n in zip(frames, names)],
        meta=meta,
        masks=None if masks is None else [None if m is None else encode_mask(m) for m in masks],
    )
