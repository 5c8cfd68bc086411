"""Footage for `benchmarks/ingest.py`, from a renderer of its own: not the tests' ray caster.

`seeu_data/synthetic.py` (what the tests and the demo use) ray-casts axis-aligned boxes with procedural
textures in numpy. This module draws scenes of arbitrary textured rectangles instead: each rectangle is
a plane, so the map from image pixels to its texture is a homography; every pixel gets its texture
coordinate and depth (1 / the third homogeneous coordinate) from it, a depth test keeps the nearest
plane, and the texture is sampled with OpenCV's `remap` from a mip pyramid (trilinear, the level from
the homography's Jacobian, so far and grazing surfaces do not alias). Textures are photographs
(scikit-image's sample images: astronaut, coffee, chelsea, rocket, ...) cut, tinted and tiled into
facades, plus the images' own grass, gravel and brick, every texture marked with unique strokes so no
two places look alike; light falls off from a point light; each frame
gets a little sensor noise. Ground truth (cam_to_world in OpenCV axes, normalised intrinsics) is written
in the format of `seeu_data.synthetic.load_ground_truth`, so `ingest_accuracy` reads it.

Kinds (`KINDS`; frames sample a fixed path, so more frames means denser frames, as in ingest_scaling):

    walk     a forward walk of 12 m down a street (two facades, the ground, parked boxes), swaying and
             turning a little; a video
    orbit    a full circle of radius 3.5 m around boxes on the ground inside a walled yard, looking at
             the centre; a video (its last frame is next to its first)
    pan      a tripod pan: the camera turns 70 deg about an axis 5 cm behind it in the street; a video
    photos   an unordered photo set: views from random places around the orbit scene, named in no
             order (an image folder)

    render_kind("walk", 90, (360, 640), "out/footage/walk")   # -> out/footage/walk/walk.mp4 + walk.json
    render_kind("photos", 11, (2048, 3072), "out/footage/big") # -> out/footage/big/photos/*.jpg + photos.json
"""

from __future__ import annotations

import functools
import json
import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

KINDS = ("walk", "orbit", "pan", "photos")
GT_FORMAT = "seeu.synthetic_ground_truth/1"  # the ground-truth file format seeu_data.synthetic reads
# scikit-image's bundled sample images (no download)
PHOTOS = ("astronaut.png", "coffee.png", "chelsea.png", "rocket.jpg", "motorcycle_left.png", "hubble_deep_field.jpg")
PHOTOS += ("retina.jpg", "ihc.png")
GROUNDS = ("gravel.png", "grass.png", "brick.png")


@dataclass
class Plane:
    """A textured rectangle: the points origin + a * edge_a + b * edge_b, a, b in [0, 1] (world, metres)."""

    origin: np.ndarray
    edge_a: np.ndarray
    edge_b: np.ndarray
    mips: list[np.ndarray]  # texture (h, w, 3) float32 and its halvings


@functools.cache
def _sample(name: str) -> np.ndarray:
    import skimage.data

    img = cv2.imread(str(Path(skimage.data.__file__).parent / name), cv2.IMREAD_COLOR)
    if img is None:
        raise FileNotFoundError(f"scikit-image's sample image {name} is missing")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def _marks(rng: np.random.Generator, img: np.ndarray, per_megatexel: float = 2000.0) -> None:
    """Unique marks drawn on `img` in place (lines, dots, strokes of random colour): the photos and ground
    textures are reused across tiles, and a scene of repeats gives SfM wrong matches between places."""
    h, w = img.shape[:2]
    for _ in range(int(per_megatexel * h * w / 1e6) + 1):
        colour = tuple(int(c) for c in rng.integers(0, 256, 3))
        x, y = int(rng.integers(0, w)), int(rng.integers(0, h))
        kind = rng.integers(0, 3)
        if kind == 0:
            cv2.line(img, (x, y), (x + int(rng.integers(-30, 30)), y + int(rng.integers(-30, 30))), colour, 2)
        elif kind == 1:
            cv2.circle(img, (x, y), int(rng.integers(2, 9)), colour, -1)
        else:
            pts = np.array(
                [[x, y], [x + int(rng.integers(-20, 20)), y + int(rng.integers(5, 25))], [x + 12, y]], np.int32
            )
            cv2.fillPoly(img, [pts], colour)


def _facade(rng: np.random.Generator, width_m: float, height_m: float, texels_per_m: float = 96.0) -> np.ndarray:
    """A wall of photo tiles (windows, posters) on a plaster of tinted noise, `(H, W, 3)` uint8."""
    h, w = int(height_m * texels_per_m), int(width_m * texels_per_m)
    base = rng.uniform(90, 190, 3)
    noise = cv2.resize(rng.normal(0, 25, (max(2, h // 16), max(2, w // 16), 3)).astype(np.float32), (w, h))
    wall = np.clip(base + noise, 0, 255).astype(np.uint8)
    x = int(rng.integers(10, 60))
    while x < w - 40:
        tw = int(rng.integers(60, 200))
        y = int(rng.integers(10, max(11, h // 3)))
        while y < h - 40:
            th = int(rng.integers(60, 200))
            src = _sample(PHOTOS[int(rng.integers(len(PHOTOS)))])
            sy, sx = int(rng.integers(0, src.shape[0] // 2)), int(rng.integers(0, src.shape[1] // 2))
            crop = src[sy : sy + src.shape[0] // 2, sx : sx + src.shape[1] // 2]
            tile = cv2.resize(crop, (min(tw, w - x), min(th, h - y)), interpolation=cv2.INTER_AREA)
            tint = rng.uniform(0.7, 1.2, 3)
            wall[y : y + tile.shape[0], x : x + tile.shape[1]] = np.clip(tile * tint, 0, 255).astype(np.uint8)
            y += th + int(rng.integers(20, 80))
        x += tw + int(rng.integers(20, 90))
    _marks(rng, wall)
    return wall


def _ground(rng: np.random.Generator, width_m: float, depth_m: float, texels_per_m: float = 64.0) -> np.ndarray:
    """Ground `(H, W, 3)`: the sample textures tiled with random flips and tints, marked (`_marks`)."""
    h, w = int(depth_m * texels_per_m), int(width_m * texels_per_m)
    out = np.zeros((h, w, 3), np.uint8)
    step = 256
    for y in range(0, h, step):
        for x in range(0, w, step):
            src = _sample(GROUNDS[int(rng.integers(len(GROUNDS)))])
            sy, sx = int(rng.integers(0, src.shape[0] - step)), int(rng.integers(0, src.shape[1] - step))
            tile = src[sy : sy + step, sx : sx + step]
            if rng.random() < 0.5:
                tile = tile[::-1]
            tile = np.clip(tile * rng.uniform(0.75, 1.15, 3), 0, 255)
            out[y : y + step, x : x + step] = tile[: h - y, : w - x].astype(np.uint8)
    _marks(rng, out)
    return out


def _plane(origin, edge_a, edge_b, texture: np.ndarray, light: np.ndarray) -> Plane:
    """A plane with its mip pyramid; the texture lit by a point light at `light` (1 / (1 + d^2 / 100))."""
    o, ea, eb = (np.asarray(v, np.float64) for v in (origin, edge_a, edge_b))
    h, w = texture.shape[:2]
    a = (np.arange(w) + 0.5) / w
    b = (np.arange(h) + 0.5) / h
    pts = o + a[None, :, None] * ea + b[:, None, None] * eb
    falloff = 0.55 + 0.6 / (1.0 + ((pts - light) ** 2).sum(-1) / 100.0)
    mips = [texture.astype(np.float32) * falloff[..., None].astype(np.float32)]
    while min(mips[-1].shape[:2]) > 8:
        mips.append(cv2.pyrDown(mips[-1]))
    return Plane(o, ea, eb, mips)


def _box(planes: list, rng, lo, hi, light, texels_per_m: float = 96.0) -> None:
    """The five visible faces of a box (no bottom), each with a photo facade texture."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    dx, dy, dz = hi - lo
    ex, ey, ez = np.array([dx, 0, 0]), np.array([0, dy, 0]), np.array([0, 0, dz])
    faces = [
        (lo, ex, ey, dx, dy),  # front (z = lo)
        (lo + ez, ex, ey, dx, dy),  # back
        (lo, ez, ey, dz, dy),  # x = lo
        (lo + ex, ez, ey, dz, dy),  # x = hi
        (lo, ex, ez, dx, dz),  # top (y = lo: +y is down)
    ]
    for origin, ea, eb, wa, wb in faces:
        planes.append(_plane(origin, ea, eb, _facade(rng, wa, wb, texels_per_m), light))


def street(seed: int = 0) -> list[Plane]:
    """Two facades 10 m apart, the ground 1.6 m below the eye (+y down), parked boxes, an end wall."""
    rng = np.random.default_rng(seed)
    light = np.array([0.0, -6.0, 20.0])
    planes = [
        _plane([-6, 1.6, -5], [12, 0, 0], [0, 0, 70], _ground(rng, 12, 70), light),
        _plane([-5, -7, -5], [0, 0, 70], [0, 8.6, 0], _facade(rng, 70, 8.6, 48), light),
        _plane([5, -7, 65], [0, 0, -70], [0, 8.6, 0], _facade(rng, 70, 8.6, 48), light),
        _plane([-6, -7, 65], [12, 0, 0], [0, 8.6, 0], _facade(rng, 12, 8.6, 48), light),
    ]
    for side in (-1, 1):
        z = float(rng.uniform(-2, 3))
        while z < 40:
            length = float(rng.uniform(3.5, 4.5))
            x0 = -3.0 if side < 0 else 1.3  # 1.7 m wide, 1.4 m high "cars" by the kerbs
            _box(planes, rng, [x0, 0.2, z], [x0 + 1.7, 1.6, z + length], light)
            z += length + float(rng.uniform(1.5, 6))
    return planes


def yard(seed: int = 0) -> list[Plane]:
    """Boxes of several sizes around the origin on the ground (y = 0, +y down), walls 9 m away."""
    rng = np.random.default_rng(seed + 1000)
    light = np.array([2.0, -5.0, -3.0])
    planes = [_plane([-9, 0, -9], [18, 0, 0], [0, 0, 18], _ground(rng, 18, 18), light)]
    for k in range(4):  # walls facing inward, 4 m high
        ang = k * math.pi / 2
        c, s = math.cos(ang), math.sin(ang)
        start = np.array([-9 * c + 9 * s, -4, -9 * s - 9 * c])
        planes.append(_plane(start, [18 * c, 0, 18 * s], [0, 4, 0], _facade(rng, 18, 4, 48), light))
    for lo, hi in [
        ([-0.6, -1.0, -0.5], [0.5, 0, 0.6]),
        ([0.7, -0.5, -1.2], [1.4, 0, -0.4]),
        ([-1.5, -0.4, 0.6], [-0.8, 0, 1.5]),
        ([0.4, -1.6, 0.9], [0.9, 0, 1.4]),
        ([-1.2, -0.7, -1.6], [-0.3, 0, -1.0]),
    ]:
        _box(planes, rng, lo, hi, light)
    return planes


def look_at(eye, target, up=(0.0, -1.0, 0.0)) -> np.ndarray:
    """cam_to_world `(4, 4)` in OpenCV axes (+x right, +y down, +z forward) looking from `eye` at `target`."""
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(-np.asarray(up, float), z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    out = np.eye(4)
    out[:3, :3] = np.stack([x, y, z], 1)
    out[:3, 3] = eye
    return out


def path(kind: str, n: int, seed: int = 0) -> np.ndarray:
    """`(n, 4, 4)` cam_to_world of kind's camera path."""
    t = np.linspace(0.0, 1.0, n)
    if kind == "walk":
        eyes = np.stack([0.15 * np.sin(2 * math.pi * 1.5 * t), 0.03 * np.sin(2 * math.pi * 6 * t), 12 * t], 1)
        yaw = np.radians(8) * np.sin(2 * math.pi * t)
        return np.stack([look_at(e, e + [math.sin(a), 0.05, math.cos(a)]) for e, a in zip(eyes, yaw)])
    if kind == "orbit":
        ang = 2 * math.pi * np.arange(n) / n
        return np.stack([look_at([3.5 * math.sin(a), -1.3, -3.5 * math.cos(a)], [0, -0.4, 0]) for a in ang])
    if kind == "pan":
        out = []
        for a in np.radians(-35 + 70 * t):
            fwd = np.array([math.sin(a), 0.0, math.cos(a)])
            eye = np.array([0.5, 0.0, 6.0]) + 0.05 * fwd  # the axis 5 cm behind the camera
            out.append(look_at(eye, eye + fwd + [0, 0.08, 0]))
        return np.stack(out)
    if kind == "photos":
        rng = np.random.default_rng(seed + 7)
        out = []
        for _ in range(n):
            a, r, h = rng.uniform(0, 2 * math.pi), rng.uniform(2.5, 5.0), rng.uniform(-2.2, -0.8)
            out.append(
                look_at([r * math.sin(a), h, -r * math.cos(a)], rng.uniform([-0.4, -0.6, -0.4], [0.4, -0.2, 0.4]))
            )
        return np.stack(out)
    raise ValueError(f"unknown kind {kind!r}; one of {', '.join(KINDS)}")


def intrinsics_norm(width: int, height: int, hfov_deg: float) -> np.ndarray:
    """(fx/W, fy/H, cx/W, cy/H) of a pinhole with square pixels and the centre at the image centre."""
    f = 0.5 * width / math.tan(math.radians(hfov_deg) / 2)
    return np.array([f / width, f / height, 0.5, 0.5])


def render(planes: list[Plane], cam_to_world: np.ndarray, intr: np.ndarray, width: int, height: int) -> np.ndarray:
    """RGB `(height, width, 3)` uint8 of `planes` seen by one camera (sky where nothing is hit)."""
    K = np.array([[intr[0] * width, 0, intr[2] * width], [0, intr[1] * height, intr[3] * height], [0, 0, 1.0]])
    R, C = cam_to_world[:3, :3], cam_to_world[:3, 3]
    sky = np.linspace(235, 170, height, dtype=np.float32)[:, None, None] * np.array([0.8, 0.9, 1.0], np.float32)
    image = np.broadcast_to(sky, (height, width, 3)).copy()
    zbuf = np.full((height, width), np.inf, np.float32)
    corners01 = np.array([[0, 0, 1], [1, 0, 1], [0, 1, 1], [1, 1, 1]], np.float64)
    for p in planes:
        # pixel (u, v, 1) ~ H (a, b, 1): H = K [R^T edge_a | R^T edge_b | R^T (origin - C)]
        H = K @ np.stack([R.T @ p.edge_a, R.T @ p.edge_b, R.T @ (p.origin - C)], 1)
        if abs(np.linalg.det(H)) < 1e-12:
            continue  # seen edge-on
        corners = corners01 @ H.T
        if (corners[:, 2] <= 0).all():
            continue  # behind the camera
        x0, y0, x1, y1 = 0, 0, width, height
        if (corners[:, 2] > 0).all():  # wholly in front: only the pixels of its projected corners' box
            px = corners[:, :2] / corners[:, 2:]
            x0, y0 = (max(0, int(np.floor(c))) for c in px.min(0))
            x1, y1 = min(width, int(np.ceil(px[:, 0].max())) + 1), min(height, int(np.ceil(px[:, 1].max())) + 1)
            if x0 >= x1 or y0 >= y1:
                continue
        u, v = np.meshgrid(np.arange(x0, x1) + 0.5, np.arange(y0, y1) + 0.5)
        Hi = np.linalg.inv(H)
        q = Hi[:, 0, None, None] * u + Hi[:, 1, None, None] * v + Hi[:, 2, None, None]  # (3, h, w)
        with np.errstate(divide="ignore", invalid="ignore"):
            depth = 1.0 / q[2]
            a, b = q[0] * depth, q[1] * depth
        m = (q[2] > 1e-6) & (depth > 0.05) & (a >= 0) & (a <= 1) & (b >= 0) & (b <= 1) & (depth < zbuf[y0:y1, x0:x1])
        if not m.any():
            continue
        qz = q[2]
        th, tw = p.mips[0].shape[:2]
        # texels per pixel: the larger column of the Jacobian of (a * tw, b * th) with respect to (u, v)
        da_du, db_du = (Hi[0, 0] - a * Hi[2, 0]) / qz * tw, (Hi[1, 0] - b * Hi[2, 0]) / qz * th
        da_dv, db_dv = (Hi[0, 1] - a * Hi[2, 1]) / qz * tw, (Hi[1, 1] - b * Hi[2, 1]) / qz * th
        rho = np.maximum(np.hypot(da_du, db_du), np.hypot(da_dv, db_dv))
        level = np.clip(np.log2(np.maximum(rho, 1e-6)), 0, len(p.mips) - 1.001).astype(np.float32)
        colour = np.zeros((*a.shape, 3), np.float32)
        for lv in range(int(level[m].min()), int(level[m].max()) + 2):
            if lv >= len(p.mips):
                break
            weight = np.clip(1.0 - np.abs(level - lv), 0, 1)
            if not (weight[m] > 0).any():
                continue
            tex = p.mips[lv]
            mx = (a * tex.shape[1] - 0.5).astype(np.float32)
            my = (b * tex.shape[0] - 0.5).astype(np.float32)
            colour += weight[..., None] * cv2.remap(tex, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        image[y0:y1, x0:x1][m] = colour[m]
        zbuf[y0:y1, x0:x1][m] = depth[m]
    return np.clip(image, 0, 255).astype(np.uint8)


def render_kind(kind: str, n_frames: int, size: tuple[int, int], out_dir: str | Path, seed: int = 0) -> Path:
    """Render `n_frames` of `kind` at `size` (H, W) into `out_dir`: `<kind>.mp4` (mp4v, 30 fps) or, for
    photos, the folder `photos/` of JPEGs (quality 95) named in no order; beside it `<kind>.json`, the
    ground truth (frame = the frame's index in the video, or in the folder's sorted names). Returns the
    video or folder. Reuses what an earlier call with the same arguments rendered."""
    out_dir = Path(out_dir)
    height, width = size
    target = out_dir / ("photos" if kind == "photos" else f"{kind}.mp4")
    gt_path = target.with_suffix(".json")
    stamp = {"kind": kind, "frames": n_frames, "size": [height, width], "seed": seed, "renderer": 2}
    if gt_path.exists() and target.exists() and json.loads(gt_path.read_text()).get("stamp") == stamp:
        return target
    out_dir.mkdir(parents=True, exist_ok=True)
    planes = yard(seed) if kind in ("orbit", "photos") else street(seed)
    poses = path(kind, n_frames, seed)
    intr = intrinsics_norm(width, height, 60.0 if kind == "photos" else 65.0)
    rng = np.random.default_rng(seed + 99)
    frames = []
    if kind == "photos":
        target.mkdir(exist_ok=True)
        for old in target.glob("*.jpg"):
            old.unlink()
        names = [f"IMG_{int(x):05d}.jpg" for x in rng.choice(90000, n_frames, replace=False) + 10000]
        order = {name: i for i, name in enumerate(sorted(names))}
    else:
        writer = cv2.VideoWriter(str(target), cv2.VideoWriter.fourcc(*"mp4v"), 30.0, (width, height))
    for i, pose in enumerate(poses):
        rgb = render(planes, pose, intr, width, height).astype(np.float32)
        bgr = cv2.cvtColor(np.clip(rgb + rng.normal(0, 1.5, rgb.shape), 0, 255).astype(np.uint8), cv2.COLOR_RGB2BGR)
        if kind == "photos":
            cv2.imwrite(str(target / names[i]), bgr, [cv2.IMWRITE_JPEG_QUALITY, 95])
            frame = order[names[i]]
        else:
            writer.write(bgr)
            frame = i
        frames.append({"frame": frame, "cam_to_world": pose.tolist(), "intrinsics_norm": intr.tolist()})
    if kind != "photos":
        writer.release()
    centres = poses[:, :3, 3]
    doc = {
        "format": GT_FORMAT,
        "stamp": stamp,
        "width": width,
        "height": height,
        "path_length": float(np.linalg.norm(np.diff(centres, axis=0), axis=1).sum()),
        "frames": sorted(frames, key=lambda f: f["frame"]),
    }
    gt_path.write_text(json.dumps(doc))
    return target
