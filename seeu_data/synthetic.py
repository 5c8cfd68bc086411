"""The built-in synthetic scene: a seedable textured corridor with boxes, rendered by numpy ray casting.

Exact ground truth for tests, the demo and benchmarks: every rendered view comes with its OpenCV
camera-to-world pose, normalised intrinsics and per-pixel camera depth (z, not ray length).

World frame: OpenCV-like, +x right, +y *down*, +z along the corridor. The scene is a set of
axis-aligned textured rectangles (the room's inward-facing walls/floor/ceiling and the faces of
several boxes at varied depths: floor boxes, pillars, a hanging box, boxes ahead of the path), so
views have occlusions and a real depth range. Textures are procedural (random shapes on a
noisy base, slightly blurred) and rich in corners, so SIFT finds many stable features. Shading is
Lambertian with a fixed light, constant per face (view-independent, as SfM assumes).

    scene = make_scene(seed=0)
    poses = camera_path(90)                       # (90, 4, 4) walk-through that translates and turns
    intr = default_intrinsics_norm(640, 360)      # (4,) fx/W, fy/H, cx/W, cy/H
    rgb, depth = render_view(scene, poses[0], intr, 640, 360)   # (360, 640, 3) uint8, (360, 640) float32
    write_clip("clip.mp4", n_frames=90, size=(360, 640), seed=0)   # + clip.json ground truth
    write_clip("wall.mp4", n_frames=30, size=(180, 320), scene="planar")  # one dominant plane
    write_clip("pan.mp4", n_frames=24, size=(180, 320), scene="pan")  # tripod pan in the corridor
    write_clip("box.mp4", n_frames=90, movers="box")   # + box.masks.npz: where the moving box is seen
    posed = synthetic_posed_scene(24, 90, 160, seed=0)                    # PosedScene, no SfM
    pts = surface_points(scene, poses[:3], np.tile(intr, (3, 1)), 640, 360)  # (180, 3) exact surface points
"""

from __future__ import annotations

import io
import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from seeu_data.cameras import intrinsics_pixels, project_points, unproject_pixels
from seeu_data.errors import SeeUError
from seeu_data.limits import MAX_VIDEO_FRAMES, MAX_VIDEO_SIDE, check_range
from seeu_data.settings import parse_video_dims, setting
from seeu_data.store.json_file import read_json
from seeu_data.store.out_lock import locks_output
from seeu_data.store.paths import contained_path

GT_FORMAT = "seeu.synthetic_ground_truth/1"
SCENES = ("corridor", "planar", "pan")
TEXELS_PER_METRE = 128.0


@dataclass(frozen=True)
class SceneConfig:
    """Layout of the synthetic corridor (metres, world +y down)."""

    room_min: tuple[float, float, float] = (-2.6, -1.3, -2.5)
    room_max: tuple[float, float, float] = (2.6, 1.4, 16.0)
    n_floor_boxes: int = 8
    n_pillars: int = 2
    n_ahead_boxes: int = 3
    light_dir: tuple[float, float, float] = (0.4, -0.8, 0.45)  # towards the light (up, right, ahead)


@dataclass
class Scene:
    """Axis-aligned textured rectangles. R = number of rectangles.

    axis: (R,) int, the constant axis of the rectangle; coord: (R,) its value; lo/hi: (R, 2) the
    bounds on the two other axes (in increasing axis order); facing: (R,) +1/-1, the side the
    visible surface faces along `axis`; shade: (R,) Lambert factor; textures: R float32 images
    (Ht, Wt, 3) in [0, 255] covering the rectangle at TEXELS_PER_METRE.
    """

    axis: np.ndarray
    coord: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    facing: np.ndarray
    shade: np.ndarray
    textures: list[np.ndarray]
    boxes: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)  # (min, max) per box
    seed: int = 0

    def __len__(self) -> int:
        return len(self.axis)

    def face_centres(self) -> np.ndarray:
        """Centre of every rectangle, `(R, 3)` world points on the visible surfaces."""
        out = np.zeros((len(self), 3))
        for k in range(len(self)):
            a = int(self.axis[k])
            others = [i for i in range(3) if i != a]
            out[k, a] = self.coord[k]
            out[k, others] = 0.5 * (self.lo[k] + self.hi[k])
        return out


def _make_texture(rng: np.random.Generator, h: int, w: int, detail: float = 1.0) -> np.ndarray:
    """Procedural corner-rich texture `(h, w, 3)` float32 in [0, 255]; `detail` times the shapes."""
    base = rng.uniform(60, 200, size=3)
    coarse = rng.normal(0, 28, size=(max(2, h // 24), max(2, w // 24), 3)).astype(np.float32)
    img = np.clip(base + cv2.resize(coarse, (w, h), interpolation=cv2.INTER_CUBIC), 0, 255).astype(np.uint8)
    n_shapes = int(detail * h * w / 900) + 4
    for _ in range(n_shapes):
        color = tuple(int(c) for c in rng.integers(0, 256, size=3))
        kind = rng.integers(0, 4)
        cx, cy = int(rng.integers(0, w)), int(rng.integers(0, h))
        size = int(rng.integers(4, 28))
        if kind == 0:
            cv2.rectangle(img, (cx, cy), (cx + size, cy + int(rng.integers(4, 28))), color, -1)
        elif kind == 1:
            cv2.circle(img, (cx, cy), size // 2 + 2, color, -1)
        elif kind == 2:
            pts = np.array(
                [
                    [cx, cy],
                    [cx + size, cy + int(rng.integers(-size, size))],
                    [cx + int(rng.integers(-size, size)), cy + size],
                ],
                np.int32,
            )
            cv2.fillPoly(img, [pts], color)
        else:
            cv2.line(img, (cx, cy), (cx + int(rng.integers(-40, 40)), cy + int(rng.integers(-40, 40))), color, 2)
    return cv2.GaussianBlur(img, (0, 0), 0.8).astype(np.float32)


def _add_rect(
    rects: list, rng, axis: int, coord: float, lo, hi, facing: int, light: np.ndarray, detail: float = 1.0
) -> None:
    normal = np.zeros(3)
    normal[axis] = facing
    shade = 0.55 + 0.45 * max(0.0, float(normal @ light))
    others = [i for i in range(3) if i != axis]
    # texture rows follow the second other axis, columns the first
    w = max(8, int(round((hi[0] - lo[0]) * TEXELS_PER_METRE)))
    h = max(8, int(round((hi[1] - lo[1]) * TEXELS_PER_METRE)))
    texture = _make_texture(rng, h, w, detail)
    rects.append((axis, coord, np.asarray(lo, float), np.asarray(hi, float), facing, shade, texture))
    del others


def _add_box(
    rects: list, rng, bmin: np.ndarray, bmax: np.ndarray, light: np.ndarray, inward: bool = False, detail: float = 1.0
) -> None:
    for axis in range(3):
        others = [i for i in range(3) if i != axis]
        lo, hi = bmin[others], bmax[others]
        # the face at bmin faces -axis from outside (+axis when seen from inside), and vice versa
        _add_rect(rects, rng, axis, bmin[axis], lo, hi, +1 if inward else -1, light, detail)
        _add_rect(rects, rng, axis, bmax[axis], lo, hi, -1 if inward else +1, light, detail)


def make_scene(seed: int = 0, config: SceneConfig | None = None) -> Scene:
    """Build the seeded corridor scene: room + floor boxes + pillars + a hanging box + boxes ahead."""
    cfg = config or SceneConfig()
    rng = np.random.default_rng(seed)
    light = np.asarray(cfg.light_dir, float)
    light /= np.linalg.norm(light)
    rmin, rmax = np.asarray(cfg.room_min, float), np.asarray(cfg.room_max, float)
    rects: list = []
    _add_box(rects, rng, rmin, rmax, light, inward=True)
    boxes = []
    floor = rmax[1]
    for i in range(cfg.n_floor_boxes):  # along both walls, clear of the path (|x| <= 0.9)
        side = -1 if i % 2 == 0 else 1
        sx, sy, sz = rng.uniform(0.35, 0.9), rng.uniform(0.3, 1.3), rng.uniform(0.35, 1.0)
        x0 = side * rng.uniform(1.15, rmax[0] - sx - 0.05)
        x0 = x0 if side > 0 else x0 - sx
        z0 = rng.uniform(0.5, 13.5) if i >= 2 else rng.uniform(1.0, 4.0)
        boxes.append((np.array([x0, floor - sy, z0]), np.array([x0 + sx, floor, z0 + sz])))
    for i in range(cfg.n_pillars):
        side = 1 if i % 2 == 0 else -1
        x0 = side * rng.uniform(1.3, 1.9)
        z0 = rng.uniform(2.5, 9.0)
        boxes.append((np.array([x0 - 0.15, rmin[1], z0]), np.array([x0 + 0.15, rmax[1], z0 + 0.3])))
    # a box hanging from the ceiling above the path's end, and boxes ahead of the path's end
    hz = rng.uniform(9.0, 10.5)
    boxes.append((np.array([-0.4, rmin[1], hz]), np.array([0.4, rmin[1] + 0.5, hz + 0.6])))
    for i in range(cfg.n_ahead_boxes):
        sx, sy, sz = rng.uniform(0.4, 0.9), rng.uniform(0.5, 1.6), rng.uniform(0.4, 0.8)
        x0 = rng.uniform(-1.6, 1.6 - sx)
        z0 = 9.5 + 2.0 * i + rng.uniform(0, 1.0)
        boxes.append((np.array([x0, floor - sy, z0]), np.array([x0 + sx, floor, z0 + sz])))
    return _scene_of(rects, rng, boxes, light, seed)


def _scene_of(rects: list, rng, boxes: list, light: np.ndarray, seed: int) -> Scene:
    """The Scene of `rects` plus the faces of `boxes` (textured and shaded with `light`)."""
    for bmin, bmax in boxes:
        _add_box(rects, rng, bmin, bmax, light)
    return Scene(
        axis=np.array([r[0] for r in rects], np.int64),
        coord=np.array([r[1] for r in rects]),
        lo=np.stack([r[2] for r in rects]),
        hi=np.stack([r[3] for r in rects]),
        facing=np.array([r[4] for r in rects], np.int64),
        shade=np.array([r[5] for r in rects]),
        textures=[r[6] for r in rects],
        boxes=boxes,
        seed=seed,
    )


def make_planar_scene(seed: int = 0, width_m: float = 7.0) -> Scene:
    """A scene dominated by one plane: a large textured wall (z = 4 m, 4 x 4 m margin beyond a path
    `width_m` wide) with three small boxes (0.3-0.5 m) floating 0.4-1 m in front of it. Most image
    pairs of a walk along the wall are explained by a homography, the case where SfM can settle on a
    wrong but clean-looking model. Viewed by `planar_camera_path`."""
    rng = np.random.default_rng(seed)
    light = np.array([0.3, -0.5, -0.8])
    light /= np.linalg.norm(light)
    half = width_m / 2 + 4.0
    rects: list = []
    _add_rect(rects, rng, 2, 4.0, (-half, -3.5), (half, 3.5), -1, light)  # the wall, facing the camera (-z)
    boxes = []
    for i in range(3):
        size = rng.uniform(0.3, 0.5, size=3)
        x0 = -width_m / 3 + i * width_m / 3 + rng.uniform(-0.3, 0.3)
        y0, z0 = rng.uniform(-0.8, 0.4), rng.uniform(3.0, 3.6 - size[2])
        boxes.append((np.array([x0, y0, z0]), np.array([x0, y0, z0]) + size))
    return _scene_of(rects, rng, boxes, light, seed)


# ---------------------------------------------------------------------------------------------
# Cameras
# ---------------------------------------------------------------------------------------------


def default_intrinsics_norm(width: int, height: int, hfov_deg: float = 70.0) -> np.ndarray:
    """Square-pixel pinhole, principal point at the centre: `(4,)` (fx/W, fy/H, cx/W, cy/H)."""
    fx_n = 0.5 / np.tan(np.radians(hfov_deg) / 2)
    return np.array([fx_n, fx_n * width / height, 0.5, 0.5])


def _look_along(eye: np.ndarray, forward: np.ndarray) -> np.ndarray:
    z = forward / np.linalg.norm(forward)
    down = np.array([0.0, 1.0, 0.0])
    x = np.cross(down, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = x, y, z, eye
    return m


def camera_path(n_frames: int, length: float = 7.0) -> np.ndarray:
    """Walk-through camera path `(n_frames, 4, 4)` OpenCV camera-to-world.

    Walks `length` metres along +z, weaving sideways by +-0.6 m with a slight bob, and turns
    (yaw +-22 degrees, small pitch changes) like a person looking around while walking.
    """
    if n_frames < 1:
        raise SeeUError(f"n_frames must be >= 1, got {n_frames}")
    t = np.linspace(0.0, 1.0, n_frames)
    poses = []
    for ti in t:
        eye = np.array([0.6 * np.sin(1.5 * np.pi * ti), 0.04 * np.sin(6 * np.pi * ti), length * ti])
        yaw = np.radians(22.0) * np.sin(2 * np.pi * ti + 0.4)
        pitch = np.radians(6.0) * np.sin(3 * np.pi * ti)
        forward = np.array([np.sin(yaw) * np.cos(pitch), np.sin(pitch), np.cos(yaw) * np.cos(pitch)])
        poses.append(_look_along(eye, forward))
    return np.stack(poses)


def planar_camera_path(n_frames: int, length: float = 7.0) -> np.ndarray:
    """Walk along the wall of `make_planar_scene`: `(n_frames, 4, 4)` OpenCV camera-to-world, `length`
    metres along +x at 4 m from the wall, with a slight bob, turning +-12 degrees and pitching +-5."""
    if n_frames < 1:
        raise SeeUError(f"n_frames must be >= 1, got {n_frames}")
    poses = []
    for ti in np.linspace(0.0, 1.0, n_frames):
        eye = np.array([length * (ti - 0.5), 0.05 * np.sin(5 * np.pi * ti), 0.3 * np.sin(np.pi * ti)])
        yaw = np.radians(12.0) * np.sin(2 * np.pi * ti + 0.3)
        pitch = np.radians(5.0) * np.sin(3 * np.pi * ti)
        forward = np.array([np.sin(yaw) * np.cos(pitch), np.sin(pitch), np.cos(yaw) * np.cos(pitch)])
        poses.append(_look_along(eye, forward))
    return np.stack(poses)


def pan_camera_path(n_frames: int, sweep_deg: float = 60.0, arm_m: float = 0.3, jitter_m: float = 0.03) -> np.ndarray:
    """A tripod pan in the corridor of `make_scene`: `(n_frames, 4, 4)` OpenCV camera-to-world. The head
    stands at (0, 0, 2) and turns, yaw sweeping `sweep_deg` (centred on +z) with a slight pitch; the
    camera centre sits `arm_m` in front of the head's axis (so it moves on an arc, as a camera does on
    a tripod) and wobbles smoothly by at most `jitter_m` metres. Its widest baseline over the median
    depth stays far below `seeu_data.ingest.report.LOW_PARALLAX` (depths about 1-14 m)."""
    if n_frames < 1:
        raise SeeUError(f"n_frames must be >= 1, got {n_frames}")
    poses = []
    for ti in np.linspace(0.0, 1.0, n_frames):
        wobble = jitter_m * np.array([np.sin(3 * np.pi * ti), np.sin(5 * np.pi * ti + 1.0), np.cos(4 * np.pi * ti)])
        yaw = np.radians(sweep_deg) * (ti - 0.5)
        pitch = np.radians(3.0) * np.sin(2 * np.pi * ti)
        forward = np.array([np.sin(yaw) * np.cos(pitch), np.sin(pitch), np.cos(yaw) * np.cos(pitch)])
        eye = np.array([0.0, 0.0, 2.0]) + arm_m * np.array([np.sin(yaw), 0.0, np.cos(yaw)]) + wobble
        poses.append(_look_along(eye, forward))
    return np.stack(poses)


def make_orbit_scene(seed: int = 0) -> Scene:
    """A room (8 x 8 m, 2.7 m high, floor at y = 1.2) with a cluster of boxes in its middle (within 0.9 m
    of the room's vertical axis, up to 1.3 m tall) and boxes along the walls: an object to walk around,
    with a textured background on every side. Viewed by `orbit_camera_path` and `wide_camera_set`."""
    rng = np.random.default_rng(seed)
    light = np.array([0.3, -0.8, 0.5])
    light /= np.linalg.norm(light)
    rmin, rmax = np.array([-4.0, -1.5, -4.0]), np.array([4.0, 1.2, 4.0])
    rects: list = []
    _add_box(rects, rng, rmin, rmax, light, inward=True)
    boxes = []
    for i in range(5):  # the object: boxes of several heights around the axis
        a = 2 * np.pi * i / 5 + rng.uniform(-0.3, 0.3)
        sx, sy, sz = rng.uniform(0.3, 0.6), rng.uniform(0.4, 1.3), rng.uniform(0.3, 0.6)
        cx, cz = 0.45 * np.cos(a), 0.45 * np.sin(a)
        boxes.append(
            (np.array([cx - sx / 2, rmax[1] - sy, cz - sz / 2]), np.array([cx + sx / 2, rmax[1], cz + sz / 2]))
        )
    for i in range(8):  # along the walls
        a = 2 * np.pi * i / 8 + rng.uniform(-0.2, 0.2)
        s = rng.uniform(0.4, 0.9, size=3)
        cx, cz = 3.3 * np.cos(a), 3.3 * np.sin(a)
        boxes.append(
            (
                np.array([cx - s[0] / 2, rmax[1] - s[1] - 0.3, cz - s[2] / 2]),
                np.array([cx + s[0] / 2, rmax[1], cz + s[2] / 2]),
            )
        )
    return _scene_of(rects, rng, boxes, light, seed)


ORBIT_TARGET = np.array([0.0, 0.5, 0.0])  # the middle of `make_orbit_scene`'s object


def _look_at(eye: np.ndarray, target: np.ndarray = ORBIT_TARGET) -> np.ndarray:
    return _look_along(np.asarray(eye, float), np.asarray(target, float) - np.asarray(eye, float))


def orbit_camera_path(n_frames: int, radius: float = 2.4, height: float = -0.3) -> np.ndarray:
    """A full circle around `make_orbit_scene`'s object: `(n_frames, 4, 4)` OpenCV camera-to-world, evenly
    spaced, at `radius` metres from the room's axis and y = `height` (above the object), looking at it."""
    if n_frames < 1:
        raise SeeUError(f"n_frames must be >= 1, got {n_frames}")
    angles = 2 * np.pi * np.arange(n_frames) / n_frames
    return np.stack([_look_at(np.array([radius * np.sin(a), height, -radius * np.cos(a)])) for a in angles])


def wide_camera_set(n_frames: int = 10, seed: int = 0) -> np.ndarray:
    """Photos taken around `make_orbit_scene`'s object from scattered places: `(n_frames, 4, 4)`, azimuths
    spread over the circle (about 360 / n degrees apart, jittered by a quarter of that), 1.9-3.0 m
    from the axis, y between -0.6 and 0.1, each aimed near the object; in a shuffled (non-path) order."""
    rng = np.random.default_rng(seed)
    step = 2 * np.pi / n_frames
    angles = step * np.arange(n_frames) + rng.uniform(-0.25, 0.25, n_frames) * step
    poses = []
    for a in angles:
        r, y = rng.uniform(1.9, 3.0), rng.uniform(-0.6, 0.1)
        aim = ORBIT_TARGET + rng.uniform(-0.25, 0.25, 3) * np.array([1.0, 0.4, 1.0])
        poses.append(_look_at(np.array([r * np.sin(a), y, -r * np.cos(a)]), aim))
    return np.stack(poses)[rng.permutation(n_frames)]


def path_length(cam_to_world: np.ndarray) -> float:
    """Sum of distances between consecutive camera centres of `(N, 4, 4)` poses."""
    c = np.asarray(cam_to_world)[:, :3, 3]
    return float(np.linalg.norm(np.diff(c, axis=0), axis=1).sum())


# ---------------------------------------------------------------------------------------------
# Moving objects
# ---------------------------------------------------------------------------------------------

MOVER_PATHS = ("sideways", "circle", "crossing")
# A mover's faces carry this many times the shapes of the room's: seen up close, as rich in corners
# (SIFT features) as the walls seen from afar, like a poster on a cart or a patterned shirt.
MOVER_DETAIL = 8.0


@dataclass(frozen=True)
class Mover:
    """A textured box (`size` x, y, z in metres) moving independently of the static scene. At frame
    i, with a = 2 pi i / `period` + `phase` (`period` in frames: a slow mover has a long one) and z_i
    the camera centre's z (its progress along the walk), its centre is

        sideways: (x0 + amplitude sin a, y0, z_i + distance)                     ahead of the camera
        circle:   (x0 + amplitude sin a, y0, z_i + distance + amplitude cos a)   ahead, nearing and receding
        crossing: (x0 + amplitude sin a, y0, distance)                           across the room at z = distance
    """

    size: tuple[float, float, float]
    distance: float
    amplitude: float
    period: float
    path: str = "sideways"
    x0: float = 0.0
    y0: float = 0.1
    phase: float = 0.0

    def centre(self, frame: int, camera_z: float) -> np.ndarray:
        """World centre `(3,)` at `frame`, the camera's centre then at z = `camera_z`."""
        a = 2 * np.pi * frame / self.period + self.phase
        z = self.distance if self.path == "crossing" else camera_z + self.distance
        if self.path == "circle":
            z += self.amplitude * np.cos(a)
        return np.array([self.x0 + self.amplitude * np.sin(a), self.y0, z])


# `seeu synth --movers`: box is about a tenth of a 16:9 frame at 70 deg, swinging at up to 3 m/s;
# large crosses the room 3.5 m along the walk, up to about 60 % of the frame as the camera nears it, out
# of the way when it passes; slow moves at most 0.3 m/s; several: three of other sizes, speeds and paths; far: a
# smaller one crossing 7.5 m along the walk, in view over most of the clip.
MOVER_PRESETS: dict[str, tuple[Mover, ...]] = {
    "none": (),
    "box": (Mover((0.6, 0.6, 0.6), distance=2.0, amplitude=0.7, period=45),),
    "large": (
        Mover((1.6, 1.5, 0.3), distance=3.5, amplitude=1.6, period=90, path="crossing", y0=0.0, phase=np.pi / 2),
    ),
    "slow": (Mover((0.6, 0.6, 0.6), distance=2.5, amplitude=0.3, period=180),),
    "several": (
        Mover((0.3, 0.3, 0.3), distance=3.0, amplitude=1.0, period=30, y0=-0.3),
        Mover((0.5, 0.5, 0.5), distance=2.5, amplitude=0.5, period=60, path="circle", y0=0.35, phase=1.0),
        Mover((0.8, 0.9, 0.5), distance=5.0, amplitude=0.9, period=120, path="crossing", y0=0.95, phase=2.0),
    ),
    "far": (Mover((1.4, 1.4, 0.3), distance=7.5, amplitude=1.6, period=90, path="crossing", y0=0.0, phase=np.pi / 2),),
}


def mover_boxes(movers: tuple[Mover, ...] | list[Mover], seed: int = 0) -> Scene:
    """The movers' boxes centred on the origin, 6 rectangles each in mover order, textured from their own
    generator (the static scene of `seed` stays the same with or without them)."""
    light = np.asarray(SceneConfig().light_dir, float)
    light /= np.linalg.norm(light)
    rng = np.random.default_rng([seed, 7919])
    rects: list = []
    for m in movers:
        half = np.asarray(m.size, float) / 2
        _add_box(rects, rng, -half, half, light, detail=MOVER_DETAIL)
    return _scene_of(rects, rng, [], light, seed)


def place_movers(scene: Scene, boxes: Scene, centres: np.ndarray) -> Scene:
    """`scene` with the movers' `boxes` (`mover_boxes`) moved to `centres` `(M, 3)`, their rectangles
    appended after the scene's own (so a rendered face index >= len(scene) is a mover)."""
    axis = boxes.axis
    c = np.asarray(centres, float)[np.arange(len(boxes)) // 6]  # (R, 3) each rectangle's mover centre
    others = np.array([[i for i in range(3) if i != a] for a in axis], np.int64).reshape(-1, 2)
    shift = np.take_along_axis(c, others, 1)
    return Scene(
        axis=np.concatenate([scene.axis, axis]),
        coord=np.concatenate([scene.coord, boxes.coord + c[np.arange(len(boxes)), axis]]),
        lo=np.concatenate([scene.lo, boxes.lo + shift]),
        hi=np.concatenate([scene.hi, boxes.hi + shift]),
        facing=np.concatenate([scene.facing, boxes.facing]),
        shade=np.concatenate([scene.shade, boxes.shade]),
        textures=scene.textures + boxes.textures,
        boxes=scene.boxes,
        seed=scene.seed,
    )


# ---------------------------------------------------------------------------------------------
# Rendering
# ---------------------------------------------------------------------------------------------


def _rect_pixel_bbox(scene: Scene, k: int, cam_to_world, intr, width: int, height: int):
    """Pixel bounding box (x0, x1, y0, y1) of rectangle k, or None when it is behind the camera."""
    a = int(scene.axis[k])
    others = [i for i in range(3) if i != a]
    corners = np.zeros((4, 3))
    corners[:, a] = scene.coord[k]
    lo, hi = scene.lo[k], scene.hi[k]
    corners[:, others] = [[lo[0], lo[1]], [hi[0], lo[1]], [lo[0], hi[1]], [hi[0], hi[1]]]
    uv, depth = project_points(corners, cam_to_world, intr, width, height)
    if (depth <= 1e-6).all():
        return None
    if (depth <= 1e-6).any():  # crosses the camera plane: test the whole image
        return 0, width, 0, height
    x0 = int(np.clip(np.floor(uv[:, 0].min()) - 1, 0, width))
    x1 = int(np.clip(np.ceil(uv[:, 0].max()) + 1, 0, width))
    y0 = int(np.clip(np.floor(uv[:, 1].min()) - 1, 0, height))
    y1 = int(np.clip(np.ceil(uv[:, 1].max()) + 1, 0, height))
    if x0 >= x1 or y0 >= y1:
        return None
    return x0, x1, y0, y1


def _bilinear(tex: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Sample `(Ht, Wt, 3)` at continuous texel coordinates (corner-at-origin), clamped: `(M, 3)`."""
    ht, wt = tex.shape[:2]
    x = np.clip(u - 0.5, 0, wt - 1.001)
    y = np.clip(v - 0.5, 0, ht - 1.001)
    x0 = x.astype(np.int64)
    y0 = y.astype(np.int64)
    fx = (x - x0)[:, None]
    fy = (y - y0)[:, None]
    top = tex[y0, x0] * (1 - fx) + tex[y0, x0 + 1] * fx
    bot = tex[y0 + 1, x0] * (1 - fx) + tex[y0 + 1, x0 + 1] * fx
    return top * (1 - fy) + bot * fy


def render_view(
    scene: Scene,
    cam_to_world: np.ndarray,
    intrinsics_norm: np.ndarray,
    width: int,
    height: int,
    background: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Ray-cast one view.

    cam_to_world: `(4, 4)` OpenCV; intrinsics_norm: `(4,)`. Rays go through pixel centres
    (j + 0.5, i + 0.5). Returns rgb `(H, W, 3)` uint8 and depth `(H, W)` float32 camera z-depth
    (inf where nothing is hit, which cannot happen inside the closed room).
    """
    rgb, depth, _ = render_view_faces(scene, cam_to_world, intrinsics_norm, width, height, background)
    return rgb, depth


def render_view_faces(
    scene: Scene,
    cam_to_world: np.ndarray,
    intrinsics_norm: np.ndarray,
    width: int,
    height: int,
    background: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`render_view`, and which rectangle each pixel's ray hits first: `(H, W)` int32, -1 for none."""
    c2w = np.asarray(cam_to_world, np.float64)
    K = intrinsics_pixels(np.asarray(intrinsics_norm, np.float64), width, height)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    xs = ((np.arange(width) + 0.5 - cx) / fx).astype(np.float32)
    ys = ((np.arange(height) + 0.5 - cy) / fy).astype(np.float32)
    rot = c2w[:3, :3].astype(np.float32)
    origin = c2w[:3, 3]
    # ray directions with camera-z = 1, so the ray parameter t is the camera depth: (3, H, W)
    dirs = rot[:, 0, None, None] * xs[None, None, :] + rot[:, 1, None, None] * ys[None, :, None] + rot[:, 2, None, None]
    depth = np.full((height, width), np.inf, np.float32)
    face = np.full((height, width), -1, np.int32)
    for k in range(len(scene)):
        a = int(scene.axis[k])
        if (origin[a] - scene.coord[k]) * scene.facing[k] <= 0:
            continue  # back-facing: the camera is behind this surface
        bbox = _rect_pixel_bbox(scene, k, c2w, intrinsics_norm, width, height)
        if bbox is None:
            continue
        x0, x1, y0, y1 = bbox
        b0, b1 = [i for i in range(3) if i != a]
        da = dirs[a, y0:y1, x0:x1]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (scene.coord[k] - origin[a]) / da
        p0 = origin[b0] + t * dirs[b0, y0:y1, x0:x1]
        p1 = origin[b1] + t * dirs[b1, y0:y1, x0:x1]
        lo, hi = scene.lo[k], scene.hi[k]
        dslice = depth[y0:y1, x0:x1]
        hit = (t > 1e-6) & (t < dslice) & (p0 >= lo[0]) & (p0 <= hi[0]) & (p1 >= lo[1]) & (p1 <= hi[1])
        dslice[hit] = t[hit]
        face[y0:y1, x0:x1][hit] = k
    rgb = np.full((height, width, 3), background, np.float32)
    flat_face = face.reshape(-1)
    order = np.argsort(flat_face, kind="stable")
    ids, starts = np.unique(flat_face[order], return_index=True)
    ends = np.append(starts[1:], len(order))
    flat_depth = depth.reshape(-1)
    flat_dirs = dirs.reshape(3, -1)
    flat_rgb = rgb.reshape(-1, 3)
    for k, s, e in zip(ids, starts, ends):
        if k < 0:
            continue
        idx = order[s:e]
        a = int(scene.axis[k])
        b0, b1 = [i for i in range(3) if i != a]
        t = flat_depth[idx]
        u = (origin[b0] + t * flat_dirs[b0, idx] - scene.lo[k, 0]) * TEXELS_PER_METRE
        v = (origin[b1] + t * flat_dirs[b1, idx] - scene.lo[k, 1]) * TEXELS_PER_METRE
        flat_rgb[idx] = _bilinear(scene.textures[k], u, v) * scene.shade[k]
    return np.clip(rgb + 0.5, 0, 255).astype(np.uint8), depth, face


def surface_points(
    scene: Scene,
    cam_to_world: np.ndarray,
    intrinsics_norm: np.ndarray,
    width: int,
    height: int,
    grid: tuple[int, int] = (6, 10),
    margin: float = 8.0,
) -> np.ndarray:
    """Exact world points on the scene's surfaces: a `grid` (rows, columns) of pixels of each view,
    `margin` pixels from the border, lifted by the view's rendered depth at the pixel's centre.

    cam_to_world `(N, 4, 4)`, intrinsics_norm `(N, 4)` -> `(N * rows * columns, 3)`.
    """
    ys, xs = np.meshgrid(
        np.linspace(margin, height - margin, grid[0]), np.linspace(margin, width - margin, grid[1]), indexing="ij"
    )
    pixel = np.stack([xs.ravel(), ys.ravel()], -1).astype(int)
    centre = pixel + 0.5  # the depth is that of the ray through the pixel's centre
    out = []
    for c2w, intr in zip(np.asarray(cam_to_world, np.float64), np.asarray(intrinsics_norm, np.float64)):
        _, depth = render_view(scene, c2w, intr, width, height)
        d = depth[pixel[:, 1], pixel[:, 0]].astype(np.float64)
        out.append(unproject_pixels(centre, d, c2w, intr, width, height))
    return np.concatenate(out)


# ---------------------------------------------------------------------------------------------
# Clips and posed scenes
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ClipConfig:
    """Parameters of a synthetic clip (the ground-truth JSON records them, `size` as width and height)."""

    n_frames: int = setting(90, f"number of frames (at most {MAX_VIDEO_FRAMES})", flag="--frames")
    size: tuple[int, int] = setting(
        (360, 640), f"frame size HxW (sides 16..{MAX_VIDEO_SIDE})", parse=parse_video_dims, metavar="HxW"
    )
    seed: int = setting(0, "scene seed: textures and box layout")
    fps: float = setting(30.0, "frame rate written to the video")
    hfov_deg: float = 70.0
    path_length_m: float = 7.0
    scene: str = setting(
        "corridor",
        "corridor; planar: one large textured wall with three small boxes, seen by a camera walking "
        "along it at 4 m (a scene dominated by one plane); pan: the corridor seen by a camera turning 60 deg "
        "on a tripod (little parallax)",
        choices=SCENES,
    )  # planar: make_planar_scene + planar_camera_path; pan: the corridor + pan_camera_path
    movers: str = setting(
        "none",
        "independently moving boxes, with their exact per-frame masks in <stem>.masks.npz: box: one box of about "
        "a tenth of the frame swinging side to side 2 m ahead of the camera; large: one crossing the room, up to "
        "more than half of the frame; slow: one moving at most 0.3 m/s; several: three of other sizes, speeds "
        "and paths; far: one crossing the room far ahead, in view over most of the clip",
        choices=tuple(MOVER_PRESETS),
    )

    @property
    def height(self) -> int:
        return self.size[0]

    @property
    def width(self) -> int:
        return self.size[1]


def ground_truth_path(video_path: str | Path) -> Path:
    """Where the ground-truth JSON of a clip lives: `clip.mp4` -> `clip.json`."""
    return Path(video_path).with_suffix(".json")


@locks_output(lambda video_path, *_, **__: Path(video_path).parent)
def write_clip(video_path: str | Path, config: ClipConfig | None = None, progress: bool = False, **overrides) -> dict:
    """Render the clip to `video_path` (mp4v) and its ground truth to `<stem>.json`; both atomically.

    Returns the ground-truth document: {"format", "config", "width", "height", "fps",
    "path_length", "frames": [{"frame", "timestamp_us", "cam_to_world" (4x4), "intrinsics_norm" (4)}]}; with
    movers (`config.movers`) also "masks" (the file name of `masks_path`, written before the JSON) and "movers"
    [{the `Mover`'s fields, "centres" (N x 3, world)}].
    """
    from tqdm import tqdm

    from seeu_data.store.arrow_io import atomic_write_bytes, atomic_write_text, tmp_path_for

    cfg = config or ClipConfig()
    if overrides:
        cfg = ClipConfig(**{**cfg.__dict__, **overrides})
    check_range(cfg.n_frames, "--frames", 1, MAX_VIDEO_FRAMES)
    check_range(cfg.width, "--size", 16, MAX_VIDEO_SIDE)
    check_range(cfg.height, "--size", 16, MAX_VIDEO_SIDE)
    if not (math.isfinite(cfg.fps) and cfg.fps > 0):
        raise SeeUError(f"--fps must be a finite number > 0, got {cfg.fps}")
    video_path = Path(video_path)
    video_path.parent.mkdir(parents=True, exist_ok=True)
    if cfg.scene not in SCENES:
        raise SeeUError(f"scene must be one of {', '.join(SCENES)}, got {cfg.scene!r}")
    if cfg.scene == "planar":
        scene, poses = (
            make_planar_scene(cfg.seed, cfg.path_length_m),
            planar_camera_path(cfg.n_frames, cfg.path_length_m),
        )
    elif cfg.scene == "pan":
        scene, poses = make_scene(cfg.seed), pan_camera_path(cfg.n_frames)
    else:
        scene, poses = make_scene(cfg.seed), camera_path(cfg.n_frames, cfg.path_length_m)
    intr = default_intrinsics_norm(cfg.width, cfg.height, cfg.hfov_deg)
    movers = MOVER_PRESETS[cfg.movers]
    boxes = mover_boxes(movers, cfg.seed) if movers else None
    centres = np.array([[m.centre(i, poses[i][2, 3]) for m in movers] for i in range(cfg.n_frames)]).reshape(
        cfg.n_frames, len(movers), 3
    )
    masks = np.zeros((cfg.n_frames, cfg.height, cfg.width), bool) if movers else None
    tmp = tmp_path_for(video_path).with_suffix(".tmp.mp4")
    writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter.fourcc(*"mp4v"), cfg.fps, (cfg.width, cfg.height))
    if not writer.isOpened():
        raise SeeUError("OpenCV cannot write mp4v video here", video_path)
    frames = []
    try:
        for i in tqdm(range(cfg.n_frames), desc="render", unit="frame", disable=not progress):
            view = scene if boxes is None else place_movers(scene, boxes, centres[i])
            rgb, _, face = render_view_faces(view, poses[i], intr, cfg.width, cfg.height)
            if masks is not None:
                masks[i] = face >= len(scene)
            writer.write(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
            frames.append(
                {
                    "frame": i,
                    "timestamp_us": int(round(i * 1e6 / cfg.fps)),
                    "cam_to_world": poses[i].tolist(),
                    "intrinsics_norm": intr.tolist(),
                }
            )
        writer.release()
        tmp.replace(video_path)
    except BaseException:
        writer.release()
        tmp.unlink(missing_ok=True)
        raise
    doc = {
        "format": GT_FORMAT,
        "config": {**{k: v for k, v in cfg.__dict__.items() if k != "size"}, "width": cfg.width, "height": cfg.height},
        "video": video_path.name,
        "width": cfg.width,
        "height": cfg.height,
        "fps": cfg.fps,
        "path_length": path_length(poses),
        "frames": frames,
    }
    if masks is not None:  # before the JSON, which names them: a clip is complete once its JSON is there
        buf = io.BytesIO()
        np.savez_compressed(buf, masks=masks)
        atomic_write_bytes(masks_path(video_path), buf.getvalue())
        doc["masks"] = masks_path(video_path).name
        doc["movers"] = [{**asdict(m), "centres": centres[:, j].tolist()} for j, m in enumerate(movers)]
    atomic_write_text(ground_truth_path(video_path), json.dumps(doc, indent=1) + "\n")
    return doc


def masks_path(video_path: str | Path) -> Path:
    """Where the movers' masks of a clip live: `clip.mp4` -> `clip.masks.npz` (`masks`: (N, H, W) bool)."""
    return Path(video_path).with_suffix(".masks.npz")


def load_ground_truth(path: str | Path) -> dict:
    """Read a clip's ground-truth JSON (the video path or the JSON path) with numpy arrays added:
    `cam_to_world` `(N, 4, 4)`, `intrinsics_norm` `(N, 4)`, `frame` `(N,)`, and for a clip with movers
    `mask` `(N, H, W)` bool (True where a mover is seen)."""
    path = Path(path)
    if path.suffix != ".json":
        path = ground_truth_path(path)
    if not path.exists():
        raise SeeUError("ground-truth JSON not found", path)
    doc = read_json(path, "ground-truth JSON")
    if not isinstance(doc, dict) or doc.get("format") != GT_FORMAT:
        raise SeeUError(
            "not a synthetic ground-truth file (format {!r})".format(
                doc.get("format") if isinstance(doc, dict) else None
            ),
            path,
        )
    doc["cam_to_world"] = np.array([f["cam_to_world"] for f in doc["frames"]], np.float64)
    doc["intrinsics_norm"] = np.array([f["intrinsics_norm"] for f in doc["frames"]], np.float64)
    doc["frame"] = np.array([f["frame"] for f in doc["frames"]], np.int64)
    if doc.get("masks"):
        with np.load(contained_path(path.parent, doc["masks"], "masks file", path)) as z:
            doc["mask"] = z["masks"]
    return doc


def synthetic_posed_scene(
    n_frames: int = 24,
    height: int = 90,
    width: int = 160,
    seed: int = 0,
    scene_id: str | None = None,
    fps: float = 30.0,
    jpeg_quality: int = 95,
    hfov_deg: float = 70.0,
    path_length_m: float = 7.0,
    world: str = "corridor",
    poses: np.ndarray | None = None,
    tracks: bool = False,
):
    """A ground-truth `PosedScene` of a synthetic scene (JPEG images, exact cameras, no SfM): `world`
    corridor (`make_scene`, walked by `camera_path`) or orbit (`make_orbit_scene`, circled by
    `orbit_camera_path`); `poses` `(n, 4, 4)` replace the path (then `n_frames` is their number);
    `tracks`: a `TrackedScene` with the exact observations of `exact_observations` (its view overlap
    then is measured from them, as from an ingest's SfM tracks).

    near/far are the min/max rendered depth over all frames with a 10 % margin (recorded in meta).
    """
    from seeu_data.store.posed import PosedScene, TrackedScene

    scene = world_scene(world, seed)
    if poses is None:
        poses = orbit_camera_path(n_frames) if world == "orbit" else camera_path(n_frames, path_length_m)
    poses = np.asarray(poses, np.float64)
    n_frames = len(poses)
    intr = default_intrinsics_norm(width, height, hfov_deg)
    images, dmin, dmax = [], np.inf, 0.0
    for pose in poses:
        rgb, depth = render_view(scene, pose, intr, width, height)
        ok, buf = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality])
        if not ok:  # pragma: no cover - OpenCV always encodes uint8 RGB
            raise SeeUError("JPEG encoding failed")
        images.append(buf.tobytes())
        finite = depth[np.isfinite(depth)]
        dmin, dmax = min(dmin, float(finite.min())), max(dmax, float(finite.max()))
    extra: dict[str, Any] = (
        {"observations": exact_observations(scene, poses, np.tile(intr, (n_frames, 1)))} if tracks else {}
    )
    return (TrackedScene if tracks else PosedScene)(
        **extra,
        scene_id=scene_id or f"synthetic_s{seed}",
        images=images,
        image_format="jpeg",
        width=np.full(n_frames, width),
        height=np.full(n_frames, height),
        intrinsics_norm=np.tile(intr, (n_frames, 1)),
        cam_to_world=poses,
        near=0.9 * dmin,
        far=1.1 * dmax,
        source_frame=np.arange(n_frames, dtype=np.int64),
        timestamp_us=np.round(np.arange(n_frames) * 1e6 / fps).astype(np.int64),
        source_name=[""] * n_frames,
        meta={
            "synthetic": True,
            "world": world,
            "seed": seed,
            "ground_truth": True,
            "near_far_method": "min/max rendered depth over the frames with a 10% margin",
        },
    )


def ingest_accuracy(posed_dir: str | Path, video_path: str | Path, registered: int, selected: int) -> dict:
    """How well an ingest of a synthetic clip posed it, against the clip's ground truth, read from what
    the ingest wrote (the posed frames in `posed_dir`: cameras, source frame numbers, the camera as
    mapped) — for the demo's report, the benchmarks and the tests; ingest itself knows no ground truth.

    Returns {"file": the ground-truth JSON, "registered_pct": registered / selected frames in %,
    "chunks": [{"scene_id", **PoseAccuracy.as_dict()}] for every chunk of at least 3 frames,
    "largest": the entry of the chunk with most frames, or None}."""
    from seeu_data.ingest.pose_eval import pose_accuracy
    from seeu_data.store.posed import PosedDataset

    gt = load_ground_truth(video_path)
    index = {int(f): i for i, f in enumerate(gt["frame"])}
    chunks: list[dict] = []
    ds = PosedDataset(posed_dir)
    for sid in ds.scene_ids:
        scene = ds.load_scene(sid)
        src = [int(s) for s in scene.source_frame]
        if len(src) < 3 or any(s not in index for s in src):
            continue
        rows = [index[s] for s in src]
        # Normalised focal lengths survive --max-size and --size; undistortion may crop a few pixels
        # without resampling, so the camera as mapped (on the decoded frames) is compared with the truth.
        m = scene.meta["camera_as_mapped"]
        intr = np.array([m["fx"] / m["width"], m["fy"] / m["height"], m["cx"] / m["width"], m["cy"] / m["height"]])
        acc = pose_accuracy(
            scene.cam_to_world, gt["cam_to_world"][rows], np.tile(intr, (len(rows), 1)), gt["intrinsics_norm"][rows]
        )
        chunks.append({"scene_id": sid, **acc.as_dict()})
    return {
        "file": str(ground_truth_path(video_path)),
        "registered_pct": 100.0 * registered / max(selected, 1),
        "chunks": chunks,
        "largest": max(chunks, key=lambda c: c["num_frames"]) if chunks else None,
    }


def mask_accuracy(posed_dir: str | Path, video_path: str | Path, min_truth: float = 0.01) -> dict:
    """How well the masks written with the posed frames in `posed_dir` (an ingest of the clip with movers
    at `video_path`) find its movers: every posed frame's mask (none: nothing masked) against the clip's
    exact one (`load_ground_truth`'s "mask"; none for a clip without movers: every masked pixel is then
    a false positive), at the posed frames' size.

    Returns {"frames", "iou" (pooled: all frames' intersection over all frames' union; nan without
    movers), "frame_iou_mean" (over the frames whose truth covers at least `min_truth` of the frame),
    "recall" (of the movers' pixels), "false_positive_pct" (masked pixels outside the truth, % of all
    pixels, mean over frames), "false_positive_max_pct" (the worst frame)}."""
    from seeu_data.masks import decode_mask, resize_mask
    from seeu_data.store.posed import PosedDataset

    gt = load_ground_truth(video_path)
    index = {int(f): i for i, f in enumerate(gt["frame"])}
    inter = union = truth_px = 0
    frame_iou, fp = [], []
    ds = PosedDataset(posed_dir)
    for sid in ds.scene_ids:
        scene = ds.load_scene(sid)
        for k, src in enumerate(scene.source_frame):
            h, w = int(scene.height[k]), int(scene.width[k])
            found = scene.masks[k] if scene.masks is not None else None
            got = decode_mask(found) if found is not None else np.zeros((h, w), bool)
            truth = gt["mask"][index[int(src)]] if "mask" in gt else np.zeros((h, w), bool)
            if truth.shape != (h, w):
                truth = resize_mask(truth, (h, w))
            inter += int((got & truth).sum())
            union += int((got | truth).sum())
            truth_px += int(truth.sum())
            fp.append(100.0 * float((got & ~truth).mean()))
            if truth.mean() >= min_truth:
                frame_iou.append(float((got & truth).sum() / (got | truth).sum()))
    return {
        "frames": len(fp),
        "iou": inter / union if truth_px else float("nan"),
        "frame_iou_mean": float(np.mean(frame_iou)) if frame_iou else float("nan"),
        "recall": inter / truth_px if truth_px else float("nan"),
        "false_positive_pct": float(np.mean(fp)) if fp else float("nan"),
        "false_positive_max_pct": float(np.max(fp)) if fp else float("nan"),
    }


def accuracy_line(acc: dict) -> str:
    """The ground-truth figures of `ingest_accuracy` as one line (the demo's output, the benchmarks)."""
    best = acc["largest"]
    if best is None:
        return "vs ground truth: no chunk to compare"
    return (
        f"vs ground truth: centre RMSE {best['centre_rmse_pct_path']:.3f}% of path, "
        f"rel. rotation {best['rel_rot_err_mean_deg']:.3f} deg, focal {best['focal_err_pct']:.2f}%"
    )


# ---------------------------------------------------------------------------------------------
# Ground-truth view overlap
# ---------------------------------------------------------------------------------------------

WORLDS = ("corridor", "orbit")  # the scenes `synthetic_posed_scene` and `world_scene` build


def world_scene(world: str, seed: int = 0) -> Scene:
    """The scene named `world` (one of WORLDS)."""
    if world not in WORLDS:
        raise SeeUError(f"world must be one of {', '.join(WORLDS)}, got {world!r}")
    return make_orbit_scene(seed) if world == "orbit" else make_scene(seed)


def _visible(
    points: np.ndarray, cam_to_world: np.ndarray, intr: np.ndarray, depth: np.ndarray, tol: float
) -> np.ndarray:
    """(M,) which world points `(M, 3)` a view sees: in front, inside its image, and not hidden (their
    depth within `tol` (relative) of the view's rendered `depth` (H, W) at their pixel)."""
    height, width = depth.shape
    uv, z = project_points(points, cam_to_world, intr, width, height)
    inside = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < width) & (uv[:, 1] >= 0) & (uv[:, 1] < height)
    px = np.clip(np.floor(np.where(inside[:, None], uv, 0)).astype(int), 0, [width - 1, height - 1])
    return inside & (np.abs(z - depth[px[:, 1], px[:, 0]]) <= tol * np.abs(z))


def _lifted(depth: np.ndarray, cam_to_world: np.ndarray, intr: np.ndarray, step: int = 1) -> np.ndarray:
    """World points `(M, 3)` of every `step`-th pixel centre of a view, at its rendered `depth` (H, W)."""
    height, width = depth.shape
    jj, ii = np.meshgrid(np.arange(step // 2, width, step), np.arange(step // 2, height, step), indexing="xy")
    centres = np.stack([jj.ravel() + 0.5, ii.ravel() + 0.5], -1)
    return unproject_pixels(
        centres, depth[ii.ravel(), jj.ravel()].astype(np.float64), cam_to_world, intr, width, height
    )


def _depths(scene: Scene, cam_to_world: np.ndarray, intr: np.ndarray, width: int, height: int) -> np.ndarray:
    return np.stack([render_view(scene, c, k, width, height)[1] for c, k in zip(cam_to_world, intr)])


def true_overlap(
    scene: Scene,
    cam_to_world: np.ndarray,
    intrinsics_norm: np.ndarray,
    width: int = 64,
    height: int = 48,
    depth_tolerance: float = 0.02,
) -> np.ndarray:
    """The exact view overlap of `seeu_data.overlap` for a synthetic scene: `(N, N)`, [a, b] = the share
    of view a's pixels whose surface point view b sees (in front, inside its image and not hidden:
    its depth in b within `depth_tolerance` (relative) of b's rendered depth at that pixel).
    Views rendered at `width` x `height`; cam_to_world `(N, 4, 4)`, intrinsics_norm `(N, 4)`."""
    c2w = np.asarray(cam_to_world, np.float64)
    intr = np.asarray(intrinsics_norm, np.float64)
    depth = _depths(scene, c2w, intr, width, height)
    out = np.eye(len(c2w))
    for a in range(len(c2w)):
        pts = _lifted(depth[a], c2w[a], intr[a])
        for b in range(len(c2w)):
            if a != b:
                out[a, b] = _visible(pts, c2w[b], intr[b], depth[b], depth_tolerance).mean()
    return out


def exact_observations(
    scene: Scene,
    cam_to_world: np.ndarray,
    intrinsics_norm: np.ndarray,
    width: int = 64,
    height: int = 48,
    step: int = 4,
    depth_tolerance: float = 0.02,
) -> tuple[np.ndarray, np.ndarray]:
    """Exact "SfM tracks" of a synthetic scene: surface points lifted from every `step`-th pixel of each
    view, each observed by every view that sees it (`true_overlap`'s visibility test). Returns (frame
    index (M,), point id (M,)) of every observation, as `overlap.overlap_from_observations` takes them."""
    c2w = np.asarray(cam_to_world, np.float64)
    intr = np.asarray(intrinsics_norm, np.float64)
    depth = _depths(scene, c2w, intr, width, height)
    pts = np.concatenate([_lifted(depth[a], c2w[a], intr[a], step) for a in range(len(c2w))])
    seen = np.stack([_visible(pts, c2w[b], intr[b], depth[b], depth_tolerance) for b in range(len(c2w))])
    frame, point = np.nonzero(seen)
    return frame.astype(np.int64), point.astype(np.int64)
