"""Raw RealEstate10K / ACID camera files + extracted frames -> posed scenes.

Camera file `CAMERAS_DIR/<scene>.txt` (the public release): line 0 is the YouTube URL, then one line
per frame of 19 whitespace-separated tokens::

    timestamp_us fx fy cx cy 0 0 r11 r12 r13 t1 r21 r22 r23 t2 r31 r32 r33 t3

intrinsics normalised by the image size, then the 3x4 **world-to-camera** matrix row-major.
Frames: `FRAMES_DIR/<scene>/<timestamp_us>.png` (or .jpg/.jpeg), the layout the public download
scripts leave (e.g. cashiwamochi/RealEstate10K_Downloader extracts one PNG per timestamp with
ffmpeg, possibly halving its size; normalised intrinsics do not depend on the size).

Conversion: intrinsics kept; camera-to-world = `cam_to_world_from_world_to_cam`; image bytes kept;
scene id = file stem; url in the meta; `source_frame` = line position (0-based frame in the file),
`source_name` = the frame's file name.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seeu_data.cameras import cam_to_world_from_world_to_cam, homogeneous_from_3x4
from seeu_data.errors import SeeUError
from seeu_data.importers.common import ImportJob, ReadSettings, SkippedScene, probe_images, recorded_params
from seeu_data.settings import parse_scene_list, setting
from seeu_data.store.posed import PosedScene

FRAME_EXTENSIONS = (".png", ".jpg", ".jpeg")


@dataclass
class Re10kTextImportConfig(ReadSettings):
    cameras_dir: Path = setting(help="directory of <scene>.txt camera files", flag="--cameras")
    frames_dir: Path = setting(
        help="directory of <scene>/<timestamp_us>.{png,jpg} frames (as the download scripts leave them)",
        flag="--frames",
    )
    scenes: frozenset[str] | None = setting(
        None, "keep only these scenes: a,b,c or @file.txt (default: all)", parse=parse_scene_list
    )
    dataset: str = setting("re10k", "the dataset's name kept in the meta", choices=("re10k", "acid"))
    near: float = setting(1.0, "near plane")
    far: float = setting(100.0, "far plane")
    allow_missing_frames: bool = setting(False, "drop frames whose image is missing instead of skipping the scene")

    def plan(self) -> ImportJob:
        files = camera_files(self)
        params = recorded_params(self, "re10k")
        return ImportJob(import_plan(self, files), params, len(files), [str(self.cameras_dir), str(self.frames_dir)])


@dataclass
class Re10kCameraFile:
    """A parsed camera file. N = frames; intrinsics_norm (N, 4); world_to_cam (N, 4, 4)."""

    url: str
    timestamps_us: np.ndarray
    intrinsics_norm: np.ndarray
    world_to_cam: np.ndarray


def parse_camera_file(path: Path) -> Re10kCameraFile:
    """Parse one RealEstate10K/ACID camera file exactly (19 tokens per frame line)."""
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise SeeUError(f"unreadable camera file ({exc})", path) from None
    if not lines or not lines[0].strip():
        raise SeeUError("empty camera file (line 1 must be the video URL)", path)
    url = lines[0].strip()
    if len(url.split()) != 1:
        raise SeeUError("line 1 must be the video URL alone", path)
    timestamps, rows = [], []
    for lineno, line in enumerate(lines[1:], start=2):
        tokens = line.split()
        if not tokens:
            continue
        if len(tokens) != 19:
            raise SeeUError(f"line {lineno}: {len(tokens)} tokens, expected 19", path)
        try:
            timestamps.append(int(tokens[0]))
            rows.append([float(t) for t in tokens[1:]])
        except ValueError:
            raise SeeUError(f"line {lineno}: not numbers", path) from None
    if not rows:
        raise SeeUError("no frame lines", path)
    values = np.asarray(rows, dtype=np.float64)
    n = len(rows)
    return Re10kCameraFile(
        url=url,
        timestamps_us=np.asarray(timestamps, dtype=np.int64),
        intrinsics_norm=values[:, :4].copy(),
        world_to_cam=homogeneous_from_3x4(values[:, 6:].reshape(n, 3, 4)),
    )


def camera_files(cfg: Re10kTextImportConfig) -> list[Path]:
    """The camera files to import (sorted), after the --scenes filter; checks the directories."""
    if not Path(cfg.cameras_dir).is_dir():
        raise SeeUError("camera directory not found", cfg.cameras_dir)
    if not Path(cfg.frames_dir).is_dir():
        raise SeeUError("frames directory not found", cfg.frames_dir)
    files = sorted(Path(cfg.cameras_dir).glob("*.txt"))
    if cfg.scenes is not None:
        files = [f for f in files if f.stem in cfg.scenes]
    if not files:
        raise SeeUError(
            "no <scene>.txt camera files" + (" for the requested scenes" if cfg.scenes else ""), cfg.cameras_dir
        )
    return files


def _frame_paths(scene_dir: Path) -> dict[int, Path]:
    """timestamp -> frame file in a scene's frame directory."""
    out: dict[int, Path] = {}
    if not scene_dir.is_dir():
        return out
    for p in scene_dir.iterdir():
        if p.suffix.lower() in FRAME_EXTENSIONS and p.stem.isdigit():
            out[int(p.stem)] = p
    return out


def scene_from_files(cam_file: Path, cfg: Re10kTextImportConfig) -> PosedScene:
    cams = parse_camera_file(cam_file)
    scene_id = cam_file.stem
    scene_dir = Path(cfg.frames_dir) / scene_id
    if not scene_dir.is_dir():
        raise SeeUError("no frame directory for this scene", scene_dir)
    frames = _frame_paths(scene_dir)
    keep = np.array([int(t) in frames for t in cams.timestamps_us])
    if not keep.all():
        missing = int((~keep).sum())
        if not cfg.allow_missing_frames or not keep.any():
            raise SeeUError(
                f"{missing} of {len(keep)} frames listed in {cam_file.name} have no image "
                f"(first: {cams.timestamps_us[~keep][0]}); --allow-missing-frames drops them",
                scene_dir,
            )
    if len(frames) > len(cams.timestamps_us) and not cfg.allow_missing_frames:
        extra = len(set(frames) - set(int(t) for t in cams.timestamps_us))
        if extra:
            raise SeeUError(f"{extra} frame images have no camera line in {cam_file.name}", scene_dir)
    idx = np.nonzero(keep)[0]
    paths = [frames[int(cams.timestamps_us[i])] for i in idx]
    try:
        images = [p.read_bytes() for p in paths]
    except OSError as exc:
        raise SeeUError(f"unreadable frame ({exc})", scene_dir) from None
    fmt, width, height = probe_images(images, [str(p) for p in paths], cfg.verify_decode, cfg.max_pixels)
    meta: dict[str, object] = {"url": cams.url, "dataset": cfg.dataset, "camera_file": str(cam_file)}
    if len(idx) < len(keep):
        meta["dropped_frames_without_image"] = int(len(keep) - len(idx))
    return PosedScene(
        scene_id=scene_id,
        images=images,
        image_format=fmt,
        width=width,
        height=height,
        intrinsics_norm=cams.intrinsics_norm[idx],
        cam_to_world=cam_to_world_from_world_to_cam(cams.world_to_cam[idx]),
        near=cfg.near,
        far=cfg.far,
        source_frame=idx.astype(np.int64),
        timestamp_us=cams.timestamps_us[idx],
        source_name=[p.name for p in paths],
        meta=meta,
    )


def _scene_items(cam_file: Path, cfg: Re10kTextImportConfig) -> Iterator[PosedScene | SkippedScene]:
    try:
        yield scene_from_files(cam_file, cfg)
    except SeeUError as exc:
        yield SkippedScene(cam_file.stem, str(exc))


def _scene_inputs(cam_file: Path, cfg: Re10kTextImportConfig) -> list[Path]:
    """The files a scene's import reads: its camera file and every frame file in its frame directory."""
    scene_dir = Path(cfg.frames_dir) / cam_file.stem
    frames = (
        sorted(p for p in scene_dir.iterdir() if p.suffix.lower() in FRAME_EXTENSIONS and p.stem.isdigit())
        if scene_dir.is_dir()
        else []
    )
    return [cam_file, *frames]


def import_plan(cfg: Re10kTextImportConfig, files: list[Path] | None = None):
    """The import as resumable units (`importers.common.ImportPlan`): one unit per camera file (its
    fingerprint covers the camera file and the scene's frame files), after the scenes asked for that
    have no camera file (reported on every run)."""
    from functools import partial

    from seeu_data.importers.common import ImportPlan, ImportUnit
    from seeu_data.store.resume import files_fingerprint

    files = files if files is not None else camera_files(cfg)
    missing = [
        SkippedScene(scene_id, f"no {scene_id}.txt camera file in {cfg.cameras_dir}")
        for scene_id in sorted(set(cfg.scenes or ()) - {f.stem for f in files})
    ]
    units = [ImportUnit(None, "", lambda: iter(missing))] if missing else []
    units += [
        ImportUnit(f.name, files_fingerprint(_scene_inputs(f, cfg)), partial(_scene_items, f, cfg)) for f in files
    ]
    return ImportPlan(units)


def iter_scenes(cfg: Re10kTextImportConfig, files: list[Path] | None = None) -> Iterator[PosedScene | SkippedScene]:
    for unit in import_plan(cfg, files).units:
        yield from unit.read()
