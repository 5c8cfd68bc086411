"""DTU in the MVSNet layout -> posed scenes (one per scan).

Layout::

    ROOT/Cameras/train/00000000_cam.txt ... 00000048_cam.txt   (view ids 0-based)
    ROOT/Rectified/scanN_train/rect_001_3_r5000.png ...         (1-based in the name; lighting 3)
    ROOT/Depths/scanN_train/depth_map_0000.pfm ...              (optional, ground-truth depth, mm)
    ROOT/Points/stl/stl001_total.ply, ROOT/ObsMask/ObsMask1_10.mat (optional, DTUeval)

`cam.txt`: a line `extrinsic`, four lines of a 4x4 world-to-camera (millimetres), a line
`intrinsic`, three lines of a 3x3 K for 160x128 images (so x4 for the 640x512 rectified PNGs),
then `DEPTH_MIN DEPTH_INTERVAL` (mm, for 192 planes).

Conversion as MVSplat's DTU converter does it: translations x `scale` (1/200), world-to-camera ->
camera-to-world; intrinsics normalised by the 160x128 size the K is given for (identical to x4 then
/640x512); near/far 2.125/4.525 (MVSplat's DTU config). Images are kept as PNG bytes. Scene id
`scanN`; timestamps = view ids (as in MVSplat's DTU chunks); `source_frame` = view id. Ground-truth
paths found next to the data go into the scene meta for evaluation (depth maps are in mm: multiply
by `scale` for scene units).
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np

from seeu_data.cameras import cam_to_world_from_world_to_cam
from seeu_data.errors import SeeUError
from seeu_data.importers.common import ImportJob, ReadSettings, SkippedScene, probe_images, recorded_params
from seeu_data.settings import parse_int_list, setting
from seeu_data.store.posed import PosedScene

CAM_FILE_SIZE = (160, 128)  # width, height the Cameras/train K is given for
DEPTH_PLANES = 192


@dataclass
class DtuImportConfig(ReadSettings):
    root: Path = setting(help="directory holding Cameras/ and Rectified/", positional=True)
    scans: tuple[int, ...] | None = setting(
        None, "scan numbers, e.g. 1,8,21 (default: every Rectified/scanN_train)", parse=parse_int_list
    )
    lighting: int = setting(3, "lighting index of the rectified images")
    scale: float = setting(1 / 200, "translation scale (MVSplat's 1/200)")
    near: float = setting(2.125, "near plane")
    far: float = setting(4.525, "far plane")

    def plan(self) -> ImportJob:
        found = scan_list(self)
        params = recorded_params(self, "dtu", scans=found)
        return ImportJob(import_plan(self, found), params, len(found), [str(self.root)])


@dataclass
class DtuCamera:
    """One MVSNet cam.txt: world_to_cam (4, 4) in mm, K (3, 3) pixels at 160x128, depth_min/interval (mm)."""

    world_to_cam: np.ndarray
    K: np.ndarray
    depth_min: float
    depth_interval: float


def parse_cam_file(path: Path) -> DtuCamera:
    """Parse an MVSNet `cam.txt` exactly (keywords, 4x4, 3x3, depth line)."""
    try:
        lines = [ln.strip() for ln in path.read_text().splitlines()]
    except (OSError, UnicodeDecodeError) as exc:
        raise SeeUError(f"unreadable camera file ({exc})", path) from None

    def block(keyword: str, rows: int, cols: int) -> tuple[np.ndarray, int]:
        if keyword not in lines:
            raise SeeUError(f"no '{keyword}' line", path)
        start = lines.index(keyword) + 1
        body = lines[start : start + rows]
        try:
            mat = np.array([[float(v) for v in ln.split()] for ln in body], dtype=np.float64)
        except ValueError:
            raise SeeUError(f"'{keyword}' block is not numbers", path) from None
        if mat.shape != (rows, cols):
            raise SeeUError(f"'{keyword}' block must be {rows}x{cols}, got {mat.shape}", path)
        return mat, start + rows

    extrinsic, _ = block("extrinsic", 4, 4)
    K, end = block("intrinsic", 3, 3)
    depth_line = next((ln for ln in lines[end:] if ln), None)
    try:
        depth = [float(v) for v in depth_line.split()] if depth_line else []
    except ValueError:
        depth = []
    if len(depth) < 2:
        raise SeeUError("no 'DEPTH_MIN DEPTH_INTERVAL' line after the intrinsics", path)
    if not np.allclose(extrinsic[3], [0, 0, 0, 1]):
        raise SeeUError("extrinsic last row is not 0 0 0 1", path)
    return DtuCamera(world_to_cam=extrinsic, K=K, depth_min=depth[0], depth_interval=depth[1])


def _scan_dir(root: Path, scan: int) -> Path | None:
    for name in (f"scan{scan}_train", f"scan{scan}"):
        if (root / "Rectified" / name).is_dir():
            return root / "Rectified" / name
    return None


def scan_list(cfg: DtuImportConfig) -> list[int]:
    """Scans to import: the requested ones, or every Rectified/scanN[_train] directory (sorted)."""
    root = Path(cfg.root)
    if not (root / "Rectified").is_dir():
        raise SeeUError("no Rectified/ directory (expected the MVSNet DTU layout)", root)
    if not (root / "Cameras" / "train").is_dir():
        raise SeeUError("no Cameras/train/ directory (expected the MVSNet DTU layout)", root)
    if cfg.scans is not None:
        return sorted(set(cfg.scans))
    found = set()
    for p in (root / "Rectified").iterdir():
        m = re.fullmatch(r"scan(\d+)(_train)?", p.name)
        if m and p.is_dir():
            found.add(int(m.group(1)))
    if not found:
        raise SeeUError("no scanN_train directories", root / "Rectified")
    return sorted(found)


def read_cameras(root: Path) -> dict[int, DtuCamera]:
    """view id -> camera, from Cameras/train/{view:08d}_cam.txt."""
    cams = {}
    for p in sorted((Path(root) / "Cameras" / "train").glob("*_cam.txt")):
        m = re.fullmatch(r"(\d{8})_cam\.txt", p.name)
        if m:
            cams[int(m.group(1))] = parse_cam_file(p)
    if not cams:
        raise SeeUError("no NNNNNNNN_cam.txt files", Path(root) / "Cameras" / "train")
    return cams


def ground_truth_paths(root: Path, scan: int) -> dict:
    """Paths of the evaluation ground truth present for a scan (depth maps, STL points, obs. masks)."""
    out: dict = {}
    for name in (f"scan{scan}_train", f"scan{scan}"):
        d = root / "Depths" / name
        if d.is_dir() and any(d.glob("depth_map_*.pfm")):
            out["gt_depth_dir"] = str(d.resolve())
            out["gt_depth_pattern"] = "depth_map_{view:04d}.pfm"
            out["gt_depth_units"] = "mm"
            break
    pts = root / "Points" / "stl" / f"stl{scan:03d}_total.ply"
    if pts.exists():
        out["gt_points"] = str(pts.resolve())
    for key, name in (("obs_mask", f"ObsMask{scan}_10.mat"), ("obs_plane", f"Plane{scan}.mat")):
        if (root / "ObsMask" / name).exists():
            out[key] = str((root / "ObsMask" / name).resolve())
    return out


def scene_for_scan(scan: int, cams: dict[int, DtuCamera], cfg: DtuImportConfig) -> PosedScene:
    root = Path(cfg.root)
    scan_dir = _scan_dir(root, scan)
    if scan_dir is None:
        raise SeeUError(f"no Rectified/scan{scan}_train directory", root / "Rectified")
    views = sorted(cams)
    paths = [scan_dir / f"rect_{v + 1:03d}_{cfg.lighting}_r5000.png" for v in views]
    missing = [p.name for p in paths if not p.exists()]
    if missing:
        raise SeeUError(
            f"{len(missing)} of {len(paths)} images missing for the {len(views)} cameras (first: {missing[0]})",
            scan_dir,
        )
    images = [p.read_bytes() for p in paths]
    fmt, width, height = probe_images(images, [str(p) for p in paths], cfg.verify_decode, cfg.max_pixels)
    w0, h0 = CAM_FILE_SIZE
    if not np.allclose(width / height, w0 / h0, rtol=1e-3):
        raise SeeUError(f"images are {width[0]}x{height[0]}; the cameras are for a {w0}x{h0} aspect", scan_dir)
    w2c = np.stack([cams[v].world_to_cam for v in views]).copy()
    w2c[:, :3, 3] *= cfg.scale
    K = np.stack([cams[v].K for v in views])
    intr = np.stack([K[:, 0, 0] / w0, K[:, 1, 1] / h0, K[:, 0, 2] / w0, K[:, 1, 2] / h0], axis=1)
    dmin = np.array([cams[v].depth_min for v in views])
    dmax = dmin + np.array([cams[v].depth_interval for v in views]) * DEPTH_PLANES
    meta = {
        "dataset": "dtu",
        "scan": scan,
        "lighting": cfg.lighting,
        "scale": cfg.scale,
        "near_far_method": "fixed (MVSplat DTU)",
        "cam_file_depth_range": [float(dmin.min() * cfg.scale), float(dmax.max() * cfg.scale)],
        **ground_truth_paths(root, scan),
    }
    view_ids = np.asarray(views, dtype=np.int64)
    return PosedScene(
        scene_id=f"scan{scan}",
        images=images,
        image_format=fmt,
        width=width,
        height=height,
        intrinsics_norm=intr,
        cam_to_world=cam_to_world_from_world_to_cam(w2c),
        near=cfg.near,
        far=cfg.far,
        source_frame=view_ids,
        timestamp_us=view_ids,
        source_name=[p.name for p in paths],
        meta=meta,
    )


def camera_paths(root: Path) -> list[Path]:
    """Cameras/train/NNNNNNNN_cam.txt files (sorted), the ones `read_cameras` parses."""
    return [
        p
        for p in sorted((Path(root) / "Cameras" / "train").glob("*_cam.txt"))
        if re.fullmatch(r"\d{8}_cam\.txt", p.name)
    ]


def _scan_inputs(root: Path, scan: int, views: list[int], lighting: int) -> list[Path]:
    """What a scan's import reads or records: its images and the ground truth it looks for."""
    scan_dir = _scan_dir(root, scan)
    names = (f"scan{scan}_train", f"scan{scan}")
    paths = (
        [root / "Rectified" / n for n in names]
        if scan_dir is None
        else [scan_dir / f"rect_{v + 1:03d}_{lighting}_r5000.png" for v in views]
    )
    paths += [root / "Depths" / n for n in names]  # a directory's mtime changes as depth maps come and go
    paths += [
        root / "Points" / "stl" / f"stl{scan:03d}_total.ply",
        root / "ObsMask" / f"ObsMask{scan}_10.mat",
        root / "ObsMask" / f"Plane{scan}.mat",
    ]
    return paths


def import_plan(cfg: DtuImportConfig, scans: list[int] | None = None):
    """The import as resumable units (`importers.common.ImportPlan`): one unit per scan (fingerprint:
    its images and ground-truth files); the camera files, shared by every scan, are the plan's
    fingerprint and are read once, by the first scan not resumed."""
    from seeu_data.importers.common import ImportPlan, ImportUnit
    from seeu_data.store.resume import files_fingerprint

    scans = scans if scans is not None else scan_list(cfg)
    root = Path(cfg.root)
    cam_paths = camera_paths(root)
    views = [int(p.name[:8]) for p in cam_paths]
    cams: dict[int, DtuCamera] = {}

    def read(scan: int) -> Iterator[PosedScene | SkippedScene]:
        if not cams:
            cams.update(read_cameras(root))
        try:
            yield scene_for_scan(scan, cams, cfg)
        except SeeUError as exc:
            yield SkippedScene(f"scan{scan}", str(exc))

    units = [
        ImportUnit(
            f"scan{scan}",
            files_fingerprint(_scan_inputs(root, scan, views, cfg.lighting)),
            partial(read, scan),
        )
        for scan in scans
    ]
    return ImportPlan(units, fingerprint=files_fingerprint(cam_paths))


def iter_scenes(cfg: DtuImportConfig, scans: list[int] | None = None) -> Iterator[PosedScene | SkippedScene]:
    for unit in import_plan(cfg, scans).units:
        yield from unit.read()
