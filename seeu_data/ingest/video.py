"""Input discovery and frame decoding: video files through OpenCV, or folders of images.

    sources = discover_sources(["clip.mp4", "photos/", "videos/"])   # one SceneSource per scene
    for frame in iter_frames(sources[0], stride=2):                   # DecodedFrame(rgb (H, W, 3) uint8, ...)
        ...

Bad input raises SeeUError naming the file: missing path, a file that is not a video (or an
unknown extension), a video OpenCV cannot open, one that stops decoding early (truncated or
corrupt), a frame or image over `max_pixels` (`--max-pixels`: a video's frame size from its stream
header, an image's from its file header, both before anything is decoded; images decode through the
image-size gate `image_header.decode_image`). A folder of videos gives one scene per video; a folder
of images is one scene (entries with an image name that cannot be read as images are left out and
named: `SceneSource.skipped`).

Variable frame rate (phone and screen recordings): frames are counted as the stream gives them and
each frame's `timestamp_us` is its presentation time from the container (OpenCV's
`CAP_PROP_POS_MSEC`), not index / fps. A container's frame count can be an estimate (Matroska:
duration x nominal rate), so a video counts as truncated only when decoding stops short of both the
header's frame count and the header's duration.
"""

from __future__ import annotations

import hashlib
import os
import re
import stat
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from seeu_data.errors import SeeUError
from seeu_data.limits import MAX_PIXELS
from seeu_data.store.image_header import check_pixels, read_image_file

# FFmpeg prints its own lines ("moov atom not found") on stderr, which would break the one-line error;
# OpenCV reads this when it first opens a video. Set OPENCV_FFMPEG_LOGLEVEL=24 to see them.
os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")

VIDEO_EXTENSIONS = {".mp4", ".mov", ".mkv", ".avi", ".m4v", ".webm"}
IMAGE_EXTENSIONS = {".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp"}
# The first bytes of the formats of IMAGE_EXTENSIONS (WebP: RIFF....WEBP, checked apart)
_IMAGE_MAGIC = (b"\xff\xd8\xff", b"\x89PNG\r\n\x1a\n", b"BM", b"II*\x00", b"MM\x00*")
# A video that decodes fewer frames than its header promises by more than this (and ends more than
# this many nominal frame intervals before the header's duration) is truncated.
_MISSING_FRAMES_TOLERANCE = 2


@dataclass(frozen=True)
class SceneSource:
    """One input scene: a video file or a folder of images (kind 'video' or 'images')."""

    name: str
    path: Path
    kind: str
    image_files: tuple[Path, ...] = ()
    skipped: tuple[tuple[str, str], ...] = ()  # (file name, reason): image-named entries that cannot be read

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


def _image_magic(head: bytes) -> bool:
    """True when `head` (a file's first bytes) starts like one of IMAGE_EXTENSIONS' formats."""
    return head.startswith(_IMAGE_MAGIC) or (head[:4] == b"RIFF" and head[8:12] == b"WEBP")


def unreadable_reason(path: Path) -> str | None:
    """Why the entry `path` of an image folder cannot be read as an image, or None when it can be.

    Never blocks: the type is checked (stat) before the file is opened, so a FIFO is never opened.
    Only the first bytes are read (the format's signature); a file that then fails to decode is
    still an error of the decode stage.
    """
    try:
        st = path.stat()
    except OSError as exc:
        return f"cannot be read ({exc.strerror})"
    if stat.S_ISDIR(st.st_mode):
        return "a directory"
    if stat.S_ISFIFO(st.st_mode):
        return "a FIFO"
    if not stat.S_ISREG(st.st_mode):
        return "not a regular file"
    try:
        with open(path, "rb") as fh:
            head = fh.read(16)
    except OSError as exc:
        return f"unreadable ({exc.strerror})"
    if not head:
        return "empty"
    return None if _image_magic(head) else "not an image (unknown bytes)"


def _sorted_images(folder: Path) -> tuple[list[Path], list[tuple[str, str]]]:
    """The image files of `folder` in natural order, and (name, reason) of the entries with an image
    name that cannot be read as images (see `unreadable_reason`)."""

    def key(p: Path):  # natural sort: frame2 before frame10
        return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", p.name)]

    images, skipped = [], []
    for p in sorted((p for p in folder.iterdir() if p.suffix.lower() in IMAGE_EXTENSIONS), key=key):
        reason = unreadable_reason(p)
        if reason is None:
            images.append(p)
        else:
            skipped.append((p.name, reason))
    return images, skipped


def skipped_line(skipped: tuple[tuple[str, str], ...] | list[tuple[str, str]], most: int = 3) -> str:
    """`skipped: N (name: reason; ...)`, naming the first `most` entries; "" when there are none."""
    if not skipped:
        return ""
    named = "; ".join(f"{name}: {reason}" for name, reason in skipped[:most])
    return f"skipped: {len(skipped)} ({named}{'; ...' if len(skipped) > most else ''})"


def discover_sources(inputs: list[str | Path], strict: bool = False) -> list[SceneSource]:
    """Resolve the command line's INPUT... into scenes. Raises SeeUError for unusable inputs.

    Entries of an image folder that cannot be read as images (a FIFO, a directory or an unreadable
    file with an image name, other bytes) are left out and listed in the scene's `skipped`; with
    `strict` the first of them is an error instead.
    """
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
        images, skipped = _sorted_images(path)
        if skipped and strict:
            name, reason = skipped[0]
            raise SeeUError(f"cannot be read as an image: {reason} (--strict)", path / name)
        videos = sorted(p for p in path.iterdir() if p.is_file() and p.suffix.lower() in VIDEO_EXTENSIONS)
        if images:
            sources.append(SceneSource(_scene_name(path), path, "images", tuple(images), tuple(skipped)))
        elif videos:
            sources.extend(SceneSource(_scene_name(v), v, "video") for v in videos)
        elif skipped:
            raise SeeUError(f"no readable images ({skipped_line(skipped)})", path)
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


def probe_video(path: str | Path, max_pixels: int = MAX_PIXELS) -> VideoInfo:
    """Open a video and read its header; SeeUError if OpenCV cannot read it as a video or its frames
    are over `max_pixels` (checked on the stream header's size, before a frame is decoded).
    `frame_count` is the container's (an estimate for some, e.g. Matroska: `iter_frames` counts)."""
    path = Path(path)
    cap = cv2.VideoCapture(str(path))
    try:
        if not cap.isOpened():
            raise SeeUError("cannot be opened as a video (not a video, or truncated/corrupt)", path)
        width, height = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        check_pixels(width, height, max_pixels, "video frame size", path)
        ok, frame = cap.read()
        if not ok or frame is None:
            raise SeeUError("no decodable video frames (not a video, or truncated/corrupt)", path)
        count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        fps = float(cap.get(cv2.CAP_PROP_FPS)) or 30.0
        return VideoInfo(max(count, 1), fps if np.isfinite(fps) and fps > 0 else 30.0, frame.shape[1], frame.shape[0])
    finally:
        cap.release()


def iter_frames(
    source: SceneSource, stride: int = 1, max_pixels: int = MAX_PIXELS, counted: list[int] | None = None
) -> Iterator[DecodedFrame]:
    """Decode every `stride`-th frame of a source as RGB. Raises SeeUError on decode failures and on
    frames over `max_pixels`. `counted`, when given, receives the number of frames the source holds
    (a video's as its stream gave them) once the iteration ends.

    Videos are read sequentially (grab() skips cheaply), each frame stamped with its container time;
    if decoding stops more than a couple of frames before both the header's frame count and its
    duration, the file is reported as truncated or corrupt.
    """
    if stride < 1:
        raise SeeUError(f"--stride must be >= 1, got {stride}")
    if source.kind == "images":
        for i, f in enumerate(source.image_files):
            if i % stride:
                continue
            # the EXIF orientation is applied (a phone's portrait photo stored landscape with
            # orientation 6 comes out upright, portrait)
            bgr = read_image_file(f, max_pixels)
            yield DecodedFrame(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), i, int(round(i * 1e6 / 30.0)), f.name)
        if counted is not None:
            counted.append(len(source.image_files))
        return
    info = probe_video(source.path, max_pixels)
    cap = cv2.VideoCapture(str(source.path))
    index, last_us = 0, -1
    try:
        while True:
            if index % stride:
                if not cap.grab():
                    break
                last_us = _frame_time_us(cap, index, info.fps, last_us)
                index += 1
                continue
            ok, bgr = cap.read()
            if not ok or bgr is None:
                break
            last_us = _frame_time_us(cap, index, info.fps, last_us)
            yield DecodedFrame(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), index, last_us)
            index += 1
    finally:
        cap.release()
    if index == 0:
        raise SeeUError("no decodable video frames (truncated or corrupt)", source.path)
    slack_us = (_MISSING_FRAMES_TOLERANCE + 1) * 1e6 / info.fps
    if info.frame_count - index > _MISSING_FRAMES_TOLERANCE and last_us < info.frame_count * 1e6 / info.fps - slack_us:
        raise SeeUError(
            f"decoding stopped after {index} frames ({last_us / 1e6:.2f} s) of the {info.frame_count} frames "
            f"({info.frame_count / info.fps:.2f} s) its header declares (truncated or corrupt video)",
            source.path,
        )
    if counted is not None:
        counted.append(index)


def _frame_time_us(cap, index: int, fps: float, previous_us: int) -> int:
    """The presentation time (microseconds from the stream's start) of the frame just grabbed: the
    container's timestamp; index / fps where the container gives none that moves forward."""
    ms = cap.get(cv2.CAP_PROP_POS_MSEC)
    us = int(round(ms * 1000.0)) if np.isfinite(ms) else -1
    return us if us > previous_us else max(previous_us + 1, int(round(index * 1e6 / fps)))


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
