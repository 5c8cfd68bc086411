"""Input discovery and frame decoding: video files through OpenCV, or folders of images.

    sources = discover_sources(["clip.mp4", "photos/", "videos/"])   # one SceneSource per scene
    for frame in iter_frames(sources[0], stride=2):                   # DecodedFrame(rgb (H, W, 3) uint8, ...)
        ...

Bad input raises SeeUError naming the file: missing path, a file that is not a video (or an
unknown extension), a video OpenCV cannot open, or one that stops decoding early (truncated or
corrupt). A folder of videos gives one scene per video; a folder of images is one scene.
"""

from __future__ import annotations

import hashlib
import os
import re
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

from .errors import SeeUError

# FFmpeg prints its own lines ("moov atom not found") on stderr, which would break the one-line error;
# OpenCV reads this when it first opens a video. Set OPENCV_FFMPEG_LOGLEVEL=24 to see them.
os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")

VIDEO_EXTENSIONS = {".mp4", ".mov", ".mkv", ".avi", ".m4v", ".webm"}
IMAGE_EXTENSIONS = {".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp"}
# A video that decodes fewer frames than its header promises by more than this is truncated.
_MISSING_FRAMES_TOLERANCE = 2


@dataclass(frozen=True)
class SceneSource:
    """One input scene: a video file or a folder of images (kind 'video' or 'images')."""

    name: str
    path: Path
    kind: str
    image_files: tuple[Path, ...] = ()

    def fingerprint(self) -> str:
        """Cheap content fingerprint: sizes, mtimes and the first/last MiB of each file."""
        digest = hashlib.sha256()
        files = [self.path] if self.kind == "video" else list(self.image_files)
        for f in files:
            st = f.stat()
            digest.update(f"{f.name}:{st.st_size}:{st.st_mtime_ns}".encode())
            with open(f, "rb") as fh:
                digest.update(fh.read(1 << 20))
                if st.st_size > 2 << 20:
                    fh.seek(-(1 << 20), 2)
                    digest.update(fh.read())
        return digest.hexdigest()


@dataclass
class DecodedFrame:
    """One decoded frame: rgb `(H, W, 3)` uint8; source_frame = index in the source sequence."""

    rgb: np.ndarray
    source_frame: int
    timestamp_us: int
    source_name: str = ""


@dataclass(frozen=True)
class VideoInfo:
    frame_count: int
    fps: float
    width: int
    height: int


def _scene_name(path: Path) -> str:
    name = re.sub(r"[^A-Za-z0-9_.-]+", "_", path.stem if path.is_file() else path.name).strip("._")
    return name or "scene"


def _sorted_images(folder: Path) -> list[Path]:
    def key(p: Path):  # natural sort: frame2 before frame10
        return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", p.name)]

    return sorted((p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS), key=key)


def discover_sources(inputs: list[str | Path]) -> list[SceneSource]:
    """Resolve the command line's INPUT... into scenes. Raises SeeUError for unusable inputs."""
    sources: list[SceneSource] = []
    for raw in inputs:
        path = Path(raw)
        if not path.exists():
            raise SeeUError("no such file or directory", path)
        if path.is_file():
            if path.suffix.lower() not in VIDEO_EXTENSIONS:
                raise SeeUError(
                    f"not a video file (expected one of {', '.join(sorted(VIDEO_EXTENSIONS))}) or an image folder", path
                )
            sources.append(SceneSource(_scene_name(path), path, "video"))
            continue
        images = _sorted_images(path)
        videos = sorted(p for p in path.iterdir() if p.is_file() and p.suffix.lower() in VIDEO_EXTENSIONS)
        if images:
            sources.append(SceneSource(_scene_name(path), path, "images", tuple(images)))
        elif videos:
            sources.extend(SceneSource(_scene_name(v), v, "video") for v in videos)
        else:
            raise SeeUError("folder holds neither images nor videos", path)
    return unique_scene_names(sources)


def unique_scene_names(sources: list[SceneSource]) -> list[SceneSource]:
    """Give inputs that share a scene name distinct names, so no scene overwrites another.

    Rule: a name held by one input stays (`clip.mp4` -> `clip`); inputs sharing a name are qualified by
    their parent folder (`a/images`, `b/images` -> `a-images`, `b-images`); any name still shared gets
    `-2`, `-3`, ... in input order. The same input path given twice is an error.
    """
    paths = [s.path.resolve() for s in sources]
    for i, p in enumerate(paths):
        if p in paths[:i]:
            raise SeeUError("the same input is given twice", sources[i].path)
    names = [s.name for s in sources]
    names = [f"{_scene_name(s.path.resolve().parent)}-{n}" if names.count(n) > 1 else n for s, n in zip(sources, names)]
    final: list[str] = []
    for n in names:
        k, cand = 1, n
        while cand in final:
            k += 1
            cand = f"{n}-{k}"
        final.append(cand)
    return [s if s.name == n else replace(s, name=n) for s, n in zip(sources, final)]


def probe_video(path: str | Path) -> VideoInfo:
    """Open a video and read its header; SeeUError if OpenCV cannot read it as a video."""
    path = Path(path)
    cap = cv2.VideoCapture(str(path))
    try:
        if not cap.isOpened():
            raise SeeUError("cannot be opened as a video (not a video, or truncated/corrupt)", path)
        ok, frame = cap.read()
        if not ok or frame is None:
            raise SeeUError("no decodable video frames (not a video, or truncated/corrupt)", path)
        count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        fps = float(cap.get(cv2.CAP_PROP_FPS)) or 30.0
        return VideoInfo(max(count, 1), fps if np.isfinite(fps) and fps > 0 else 30.0, frame.shape[1], frame.shape[0])
    finally:
        cap.release()


def iter_frames(source: SceneSource, stride: int = 1) -> Iterator[DecodedFrame]:
    """Decode every `stride`-th frame of a source as RGB. Raises SeeUError on decode failures.

    Videos are read sequentially (grab() skips cheaply); if decoding stops more than a couple of
    frames before the header's frame count the file is reported as truncated or corrupt.
    """
    if stride < 1:
        raise SeeUError(f"--stride must be >= 1, got {stride}")
    if source.kind == "images":
        for i, f in enumerate(source.image_files):
            if i % stride:
                continue
            bgr = cv2.imread(str(f), cv2.IMREAD_COLOR)
            if bgr is None:
                raise SeeUError("cannot be decoded as an image (corrupt?)", f)
            yield DecodedFrame(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), i, int(round(i * 1e6 / 30.0)), f.name)
        return
    info = probe_video(source.path)
    cap = cv2.VideoCapture(str(source.path))
    index = 0
    try:
        while True:
            if index % stride:
                if not cap.grab():
                    break
                index += 1
                continue
            ok, bgr = cap.read()
            if not ok or bgr is None:
                break
            yield DecodedFrame(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), index, int(round(index * 1e6 / info.fps)))
            index += 1
    finally:
        cap.release()
    if index == 0:
        raise SeeUError("no decodable video frames (truncated or corrupt)", source.path)
    if info.frame_count - index > _MISSING_FRAMES_TOLERANCE:
        raise SeeUError(
            f"decoding stopped after {index} of {info.frame_count} frames (truncated or corrupt video)", source.path
        )


def resize_max_side(rgb: np.ndarray, max_size: int | None) -> np.ndarray:
    """Downscale `(H, W, 3)` so its longer side is at most `max_size` (INTER_AREA); never upscales."""
    if not max_size:
        return rgb
    h, w = rgb.shape[:2]
    scale = max_size / max(h, w)
    if scale >= 1.0:
        return rgb
    return cv2.resize(rgb, (max(1, round(w * scale)), max(1, round(h * scale))), interpolation=cv2.INTER_AREA)


def sharpness(rgb: np.ndarray) -> float:
    """Variance of the Laplacian of the grey image (higher = sharper)."""
    grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    return float(cv2.Laplacian(grey, cv2.CV_64F).var())
