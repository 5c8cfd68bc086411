"""The view stage: look at posed frames, triple shards, Gaussians and a model's prediction in the browser (viser).

`detect_view_kind(path)` tells what PATH is:

* posed frames ('posed'; `seeu ingest` / `seeu import` output, manifest.json) and the foreign
  formats `seeu check-cameras` reads ('nerfstudio', 'colmap', 'pixelsplat', through their
  importers): camera frustums with image thumbnails, the trajectory line, the SfM points an ingest
  kept (`points3d` in the scene's meta); a scene dropdown and a frame slider (the frame drawn large);
* triple shards ('triples'; `seeu build` output): one triple, context frustums blue and target
  frustums orange, the context gap and target offsets written beside them; next / previous buttons;
* a render directory ('render'; `seeu render` / `seeu demo` output: gaussians.ply + cameras.json)
  or a '.ply' file: the Gaussians (centres, covariances, colours of SH degree 0, opacities) with
  the cameras.json cameras beside it; a point-cloud .ply (x y z red green blue) as points.

With `checkpoint` (posed frames or shards), the model's prediction for the chosen sample is drawn
as Gaussians and the browser's current camera is rendered live by our rasterizer (seeu_model, on
the CPU unless `device` says otherwise) at LIVE_RENDER_WIDTH pixels into the side panel.

Large scenes are subsampled, with one printed note: at most MAX_FRAMES frustums, MAX_POINTS points,
MAX_GAUSSIANS Gaussians (the most opaque), MAX_SCENES scenes in the dropdown.

Example:
    from pathlib import Path
    from pipelines.view import ViewConfig, build_scene, serve

    server, notes = build_scene(ViewConfig(path=Path("data/posed/clip"), port=0))
    print(server.get_port(), notes)
"""

from __future__ import annotations

import contextlib
import errno
import math
import socket
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from seeu_data.errors import SeeUError
from seeu_data.settings import setting

if TYPE_CHECKING:
    import viser

    from seeu_model.gaussians import Gaussians

DEFAULT_HOST = "127.0.0.1"  # `--host`: only this machine can connect
DEFAULT_PORT = 8080  # `--port`: viser's default
MAX_FRAMES = 300  # camera frustums drawn per scene (evenly spaced beyond it)
MAX_POINTS = 200_000  # SfM points drawn per scene (evenly spaced beyond it)
MAX_GAUSSIANS = 300_000  # Gaussians drawn (the most opaque beyond it)
MAX_SCENES = 200  # scenes offered in the dropdown (the first ones)
THUMB_SIDE = 96  # px: longest side of a frustum's image thumbnail
FRAME_SIDE = 320  # px: longest side of the image on the frame the slider picks
LIVE_RENDER_WIDTH = 160  # px: width of the live render of the browser's camera (--checkpoint)
SCREENSHOT_SIZE = (1000, 700)  # px (width, height) of `--screenshot`
SCREENSHOT_WAIT_MS = 8000  # chromium's virtual-time budget for the page to load and draw (doubled per retry)
SCREENSHOT_ATTEMPTS = 3
CONTEXT_RGB = (40, 90, 230)
TARGET_RGB = (240, 140, 20)
FRAME_RGB = (220, 30, 30)
KINDS = ("posed", "nerfstudio", "colmap", "pixelsplat", "triples", "render", "ply")


@dataclass(frozen=True)
class ViewConfig:
    """One `seeu view` run. `path`: what to show (kind detected); `host`/`port`: where to serve
    (port 0: any free port); `save`: write the scene as a .viser file and do not serve;
    `checkpoint`: also show the model's prediction (posed frames or shards); `sample`: the shard
    sample (index or sample_id) first shown; `device`: of the model (None: cpu); `screenshot`: a PNG of
    the page in headless chromium (the CLI serves on a free port, shoots and stops)."""

    path: Path = setting(help="posed frames, triple shards, a render directory or a .ply file", positional=True)
    host: str = setting(DEFAULT_HOST, "address to serve on")
    port: int = setting(DEFAULT_PORT, "port (0: any free port)")
    checkpoint: Path | None = setting(None, "also show this checkpoint's prediction (posed frames or shards)")
    sample: str = setting("0", "triple shards: sample shown first, index or sample_id")
    device: str | None = setting(None, "--checkpoint: the model's device (default cpu)")
    save: Path | None = setting(None, "write the scene as a .viser file and exit", metavar="FILE", exclusive="out")
    screenshot: Path | None = setting(
        None, "screenshot the page in headless chromium and exit", metavar="PNG", exclusive="out"
    )

    def check(self) -> None:
        if not 0 <= self.port <= 65535:
            raise SeeUError(f"--port must be in 0..65535, got {self.port}")


# ---------------------------------------------------------------------------------------------
# What PATH is
# ---------------------------------------------------------------------------------------------


def detect_view_kind(path: Path) -> str:
    """One of KINDS; SeeUError (one line) for anything else."""
    from seeu_data.camera_check import detect_kind
    from seeu_data.store.json_file import read_json

    path = Path(path)
    if not path.exists():
        raise SeeUError("not found", path)
    if path.is_file() and path.suffix.lower() == ".ply":
        return "ply"
    if path.is_dir() and (path / "cameras.json").is_file() and any(path.glob("*.ply")):
        return "render"
    if path.is_dir() and (path / "manifest.json").is_file():
        doc = read_json(path / "manifest.json", "manifest")
        schema = doc.get("schema") if isinstance(doc, dict) else None
        if schema == "seeu.triples":
            return "triples"
        if schema == "seeu.posed_frames":
            return "posed"
    try:
        return detect_kind(path)
    except SeeUError:
        raise SeeUError(
            "unknown kind: expected posed frames or triple shards (manifest.json), a render directory "
            "(.ply + cameras.json), a .ply file, nerfstudio transforms.json, a COLMAP model or pixelSplat chunks",
            path,
        ) from None


# ---------------------------------------------------------------------------------------------
# Drawing helpers
# ---------------------------------------------------------------------------------------------


def evenly(n: int, limit: int) -> np.ndarray:
    """Indices of at most `limit` of n items, evenly spaced, first and last kept."""
    if n <= limit:
        return np.arange(n)
    return np.unique(np.round(np.linspace(0, n - 1, limit)).astype(int))


def thumbnail(encoded, side: int, mask=None) -> np.ndarray:
    """Encoded image bytes -> (h, w, 3) uint8 RGB with its longest side at most `side`; the pixels of
    `mask` (the frame's stored mask PNG, or None) tinted (`masks.tint_masked`)."""
    import cv2

    from seeu_data.image_ops import decode_rgb
    from seeu_data.masks import tint_masked

    img = tint_masked(decode_rgb(bytes(encoded)), mask)
    h, w = img.shape[:2]
    s = min(1.0, side / max(h, w))
    if s < 1.0:
        img = cv2.resize(img, (max(1, round(w * s)), max(1, round(h * s))), interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(img)


def frustum_scale(centres: np.ndarray) -> float:
    """Frustum size in world units: a twentieth of the cameras' extent (0.1 for a single camera)."""
    extent = float(np.ptp(centres, axis=0).max()) if len(centres) > 1 else 0.0
    return 0.05 * extent if extent > 0 else 0.1


def add_frustum(
    server: viser.ViserServer,
    name: str,
    c2w: np.ndarray,
    intrinsics_norm: np.ndarray,
    wh: tuple[int, int],
    scale: float,
    color: tuple[int, int, int],
    image: np.ndarray | None = None,
) -> None:
    """One OpenCV camera (c2w (4, 4), intrinsics_norm (4,) fx/W, fy/H, cx/W, cy/H) as a frustum."""
    import viser.transforms as vtf

    fov = 2.0 * math.atan(0.5 / float(intrinsics_norm[1]))
    server.scene.add_camera_frustum(
        name,
        fov=fov,
        aspect=wh[0] / wh[1],
        scale=scale,
        thickness=scale * 0.04,
        color=color,
        image=image,
        wxyz=vtf.SO3.from_matrix(c2w[:3, :3]).wxyz,
        position=c2w[:3, 3],
    )


def gaussian_arrays(g) -> dict[str, np.ndarray]:
    """Scene 0 of `Gaussians` (B, N, ...) as viser's splat arrays: centers (N, 3), covariances
    (N, 3, 3) = R diag(s^2) R^T, rgbs (N, 3) = 0.5 + C0 * sh_dc clipped to [0, 1], opacities (N, 1)."""
    from seeu_model.rasterizer.sh import C0

    means = g.means[0].detach().double().cpu().numpy()
    scales = g.scales[0].detach().double().cpu().numpy()
    q = g.rotations[0].detach().double().cpu().numpy()
    q = q / np.maximum(np.linalg.norm(q, axis=-1, keepdims=True), 1e-12)
    w, x, y, z = q.T
    rot = np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )
    cov = (rot * scales[:, None, :] ** 2) @ np.swapaxes(rot, -1, -2)
    rgb = np.clip(0.5 + C0 * g.sh[0, :, 0, :].detach().double().cpu().numpy(), 0.0, 1.0)
    opac = g.opacities[0].detach().double().cpu().numpy()[:, None]
    return {"centers": means, "covariances": cov, "rgbs": rgb, "opacities": opac}


def aim(server: viser.ViserServer, xyz: np.ndarray) -> None:
    """Point the initial (and "Reset View") camera at the points `xyz` (P, 3) from behind and above
    (OpenCV world: -z behind, -y up), far enough back to see their extent."""
    xyz = np.asarray(xyz, np.float64).reshape(-1, 3)
    xyz = xyz[np.isfinite(xyz).all(1)]
    if not len(xyz):
        return
    lo, hi = np.percentile(xyz, [5, 95], axis=0)
    centre = (lo + hi) / 2
    extent = max(float((hi - lo).max()), 0.1)
    server.initial_camera.look_at = tuple(centre)
    server.initial_camera.position = tuple(centre + np.array([0.3, -0.8, -1.5]) * extent)


class Notes:
    """The subsampling notes of one run, each printed once."""

    def __init__(self, out: Callable[[str], None] = print):
        self.seen: set[str] = set()
        self.out = out

    def __call__(self, text: str) -> None:
        if text not in self.seen:
            self.seen.add(text)
            self.out(f"note: {text}")


def add_splats(server: viser.ViserServer, name: str, g, notes: Notes) -> int:
    """Draw Gaussians (at most MAX_GAUSSIANS, the most opaque); returns how many were drawn."""
    arrays = gaussian_arrays(g)
    n = len(arrays["centers"])
    if n > MAX_GAUSSIANS:
        keep = np.sort(np.argpartition(-arrays["opacities"][:, 0], MAX_GAUSSIANS)[:MAX_GAUSSIANS])
        arrays = {k: v[keep] for k, v in arrays.items()}
        notes(f"{n} Gaussians, drawing the {MAX_GAUSSIANS} most opaque (MAX_GAUSSIANS)")
    server.scene.add_gaussian_splats(
        name, arrays["centers"], arrays["covariances"], arrays["rgbs"], arrays["opacities"]
    )
    return len(arrays["centers"])


# ---------------------------------------------------------------------------------------------
# The three views
# ---------------------------------------------------------------------------------------------


class SceneSource:
    """The scenes of a posed-frames folder (or a format check-cameras reads), loaded on demand."""

    def __init__(self, path: Path, kind: str, notes: Notes):
        self.path, self.kind = Path(path), kind
        self._cache: dict[str, Any] = {}
        if kind == "posed":
            from seeu_data.store.posed import PosedDataset

            self.ds = PosedDataset(path)
            ids = self.ds.scene_ids
        else:
            from seeu_data.camera_check import CameraCheckConfig, iter_scenes

            items = list(iter_scenes(CameraCheckConfig(path=path, max_scenes=MAX_SCENES), kind))
            for item in items:
                if not isinstance(item, tuple):
                    self._cache[item.scene_id] = item
            ids = list(self._cache)
        if not ids:
            raise SeeUError("no scene to show", path)
        if len(ids) > MAX_SCENES:
            notes(f"{len(ids)} scenes, offering the first {MAX_SCENES} (MAX_SCENES)")
        self.scene_ids = ids[:MAX_SCENES]

    def load(self, scene_id: str):
        """The scene `scene_id` (posed frames: read now, only the last one kept)."""
        if scene_id not in self._cache:
            self._cache = {scene_id: self.ds.load_scene(scene_id)}
        return self._cache[scene_id]

    def points(self, scene) -> tuple[np.ndarray, np.ndarray] | None:
        """The scene's kept SfM points ((P, 3), (P, 3) uint8) or None."""
        from seeu_data.ingest.points import read_points_ply

        rel = scene.meta.get("points3d") if isinstance(scene.meta, dict) else None
        if not isinstance(rel, str) or not (self.path / rel).is_file():
            return None
        return read_points_ply(self.path / rel)


def show_posed(server: viser.ViserServer, source: SceneSource, notes: Notes, on_scene=None) -> None:
    """Scene dropdown + frame slider; draws the chosen scene under /scene."""
    state: dict[str, Any] = {}

    def draw_frame(k: int) -> None:
        scene = state["scene"]
        k = int(np.clip(k, 0, len(scene) - 1))
        wh = (int(scene.width[k]), int(scene.height[k]))
        add_frustum(
            server,
            "/scene/frame",
            scene.cam_to_world[k],
            scene.intrinsics_norm[k],
            wh,
            state["scale"] * 2.0,
            FRAME_RGB,
            thumbnail(scene.images[k], FRAME_SIDE, scene.masks[k] if scene.masks else None),
        )
        info.content = f"**{scene.scene_id}**: frame {k} of {len(scene)} (source frame {int(scene.source_frame[k])})"

    def draw_scene(scene_id: str) -> None:
        scene = source.load(scene_id)
        state["scene"] = scene
        server.scene.remove_by_name("/scene")  # the last scene, children included
        server.scene.add_frame("/scene", show_axes=False)
        c2w = np.asarray(scene.cam_to_world)
        centres = c2w[:, :3, 3]
        scale = frustum_scale(centres)
        state["scale"] = scale
        idx = evenly(len(scene), MAX_FRAMES)
        if len(idx) < len(scene):
            notes(f"{len(scene)} frames in a scene, drawing {len(idx)} frustums (MAX_FRAMES)")
        for i in idx:
            wh = (int(scene.width[i]), int(scene.height[i]))
            add_frustum(
                server,
                f"/scene/cams/{i:06d}",
                c2w[i],
                scene.intrinsics_norm[i],
                wh,
                scale,
                CONTEXT_RGB,
                thumbnail(scene.images[i], THUMB_SIDE, scene.masks[i] if scene.masks else None),
            )
        if len(centres) > 1:
            server.scene.add_line_segments(
                "/scene/trajectory",
                np.stack([centres[:-1], centres[1:]], 1).astype(np.float32),
                colors=(60, 60, 60),
                thickness=2.0,
                thickness_units="screen",
            )
        pts = source.points(scene)
        if pts is not None:
            xyz, rgb = pts
            keep = evenly(len(xyz), MAX_POINTS)
            if len(keep) < len(xyz):
                notes(f"{len(xyz)} SfM points, drawing {len(keep)} (MAX_POINTS)")
            server.scene.add_point_cloud(
                "/scene/points", xyz[keep].astype(np.float32), rgb[keep], point_size=scale * 0.1
            )
        aim(server, centres)
        slider.max = max(1, len(scene) - 1)
        slider.value = 0  # type: ignore[misc]  # viser's setter; mypy misses asymmetric properties
        draw_frame(0)
        if on_scene is not None:
            on_scene(scene)

    picker = server.gui.add_dropdown("Scene", tuple(source.scene_ids), initial_value=source.scene_ids[0])
    slider = server.gui.add_slider("Frame", min=0, max=1, step=1, initial_value=0)
    info = server.gui.add_markdown("")
    picker.on_update(lambda _: draw_scene(picker.value))
    slider.on_update(lambda _: draw_frame(int(slider.value)))
    draw_scene(source.scene_ids[0])


def shard_rows(path: Path) -> tuple[Any, list[tuple[int, int]]]:
    """(TripleShards, [(shard, row in shard)] of every sample in manifest order)."""
    from seeu_data.build.triples import TripleShards

    shards = TripleShards(path)
    where = [(s, r) for s, e in enumerate(shards.manifest["files"]) for r in range(int(e["rows"]))]
    if not where:
        raise SeeUError("no samples in these shards", path)
    return shards, where


def read_row(shards, at: tuple[int, int]):
    from seeu_data.store.triple_row import TripleRow

    table = shards.read_shard(at[0]).slice(at[1], 1)
    return TripleRow.from_pydict(table.to_pylist()[0])


def sample_index(rows: list, sample: str, shards) -> int:
    """Index of `sample` (an index or a sample_id) among the rows."""
    if sample.isdigit():
        if int(sample) >= len(rows):
            raise SeeUError(f"no sample {sample} (the shards hold {len(rows)})", shards.root)
        return int(sample)
    ids = shards.read_columns(["sample_id"]).column("sample_id").to_pylist()
    if sample not in ids:
        raise SeeUError(f"no sample {sample!r} in these shards", shards.root)
    return ids.index(sample)


def show_triple(server: viser.ViserServer, path: Path, sample: str, on_row=None) -> None:
    """One triple under /triple; next / previous buttons."""
    shards, rows = shard_rows(path)
    state = {"i": sample_index(rows, sample, shards)}
    info = server.gui.add_markdown("")
    prev_b = server.gui.add_button("Previous sample")
    next_b = server.gui.add_button("Next sample")

    def draw(i: int) -> None:
        state["i"] = i % len(rows)
        row = read_row(shards, rows[state["i"]])
        c2w = np.asarray(row.cam_to_world)
        scale = frustum_scale(c2w[:, :3, 3])
        v = row.num_context
        for k in range(len(c2w)):
            ctx = k < v
            add_frustum(
                server,
                f"/triple/{'context' if ctx else 'target'}_{k}",
                c2w[k],
                row.intrinsics_norm[k],
                (int(row.width[k]), int(row.height[k])),
                scale,
                CONTEXT_RGB if ctx else TARGET_RGB,
                thumbnail(row.images[k], THUMB_SIDE, row.masks[k] if row.masks else None),
            )
            label = f"frame {int(row.frame_index[k])}" + ("" if ctx else f" (offset {int(row.target_offset[k - v])})")
            server.scene.add_label(f"/triple/label_{k}", label, position=tuple(c2w[k, :3, 3]))
        for k in range(len(c2w), state.get("drawn", 0)):  # fewer views than the last sample
            server.scene.remove_by_name(f"/triple/target_{k}")
            server.scene.remove_by_name(f"/triple/label_{k}")
        state["drawn"] = len(c2w)
        aim(server, c2w[:, :3, 3])
        first, last = c2w[0, :3, 3], c2w[v - 1, :3, 3]
        server.scene.add_line_segments(
            "/triple/gap",
            np.stack([first, last])[None].astype(np.float32),
            colors=CONTEXT_RGB,
            thickness=3.0,
            thickness_units="screen",
        )
        server.scene.add_label("/triple/gap_label", f"gap {row.gap} frames", position=tuple((first + last) / 2))
        info.content = (
            f"**{row.sample_id}** ({state['i'] + 1} of {len(rows)}): {row.mode}, context frames "
            f"{[int(f) for f in row.frame_index[:v]]} (gap {row.gap}), target frames "
            f"{[int(f) for f in row.frame_index[v:]]} (offsets {[int(o) for o in row.target_offset]}); "
            "context blue, targets orange"
        )
        if on_row is not None:
            on_row(state["i"])

    prev_b.on_click(lambda _: draw(state["i"] - 1))
    next_b.on_click(lambda _: draw(state["i"] + 1))
    draw(state["i"])


def read_cameras_json(path: Path) -> list[dict]:
    """The cameras of a 3DGS cameras.json (`seeu_model.ply.cameras_json` layout)."""
    from seeu_data.store.json_file import read_json

    doc = read_json(path, "cameras.json")
    if not isinstance(doc, list):
        raise SeeUError("cameras.json must be a list of cameras", path)
    return doc


def show_ply(server: viser.ViserServer, path: Path, notes: Notes) -> None:
    """A 3DGS .ply as Gaussians (a point-cloud .ply as points) with cameras.json's cameras beside it."""
    from plyfile import PlyData, PlyParseError

    ply = path if path.is_file() else sorted(path.glob("*.ply"))[0]
    try:
        names = {p.name for p in PlyData.read(str(ply))["vertex"].properties}
    except (OSError, KeyError, ValueError, IndexError, PlyParseError) as exc:
        raise SeeUError(f"not a readable .ply with a vertex element ({exc})", ply) from exc
    if "f_dc_0" in names:
        from seeu_model.ply import load_ply

        g = load_ply(ply)
        n = add_splats(server, "/gaussians", g, notes)
        aim(server, g.means[0].numpy())
        what = f"{n} Gaussians"
    else:
        from seeu_data.ingest.points import read_points_ply

        xyz, rgb = read_points_ply(ply)
        keep = evenly(len(xyz), MAX_POINTS)
        if len(keep) < len(xyz):
            notes(f"{len(xyz)} points, drawing {len(keep)} (MAX_POINTS)")
        size = 0.005 * float(np.ptp(xyz, axis=0).max()) if len(xyz) > 1 else 0.01
        server.scene.add_point_cloud("/points", xyz[keep].astype(np.float32), rgb[keep], point_size=size)
        aim(server, xyz[keep])
        what = f"{len(keep)} points"
    cams_path = ply.parent / "cameras.json"
    cams = read_cameras_json(cams_path) if cams_path.is_file() else []
    if cams:
        c2w = np.zeros((len(cams), 4, 4))
        c2w[:, 3, 3] = 1.0
        try:
            for i, c in enumerate(cams):
                c2w[i, :3, :3] = np.asarray(c["rotation"], np.float64).reshape(3, 3)
                c2w[i, :3, 3] = np.asarray(c["position"], np.float64).reshape(3)
            scale = frustum_scale(c2w[:, :3, 3])
            for i, c in enumerate(cams):
                w, h = int(c["width"]), int(c["height"])
                k = np.array([c["fx"] / w, c["fy"] / h, 0.5, 0.5])
                name = str(c.get("img_name", i))
                color = TARGET_RGB if name.startswith("target") else CONTEXT_RGB
                add_frustum(server, f"/cameras/{i:04d}", c2w[i], k, (w, h), scale, color)
        except (KeyError, TypeError, ValueError, ZeroDivisionError) as exc:
            raise SeeUError(
                f"camera entries need rotation, position, width, height, fx, fy ({exc})", cams_path
            ) from None
    server.gui.add_markdown(f"**{ply.name}**: {what}, {len(cams)} cameras (context blue, targets orange)")


# ---------------------------------------------------------------------------------------------
# The model's prediction (--checkpoint)
# ---------------------------------------------------------------------------------------------


def view_camera(
    wxyz, position, fov: float, aspect: float, width: int
) -> tuple[np.ndarray, np.ndarray, tuple[int, int]]:
    """A viser camera as ours. viser's `client.camera` follows OpenCV: `wxyz` / `position` are R / t of
    `P_world = [R | t] p_camera` (camera-to-world, +z forward, -y up), `fov` the vertical field of view
    (radians), `aspect` width / height. Returns c2w (4, 4), normalised intrinsics (3, 3) with square
    pixels and a centred principal point, and (H, W) with W = `width`."""
    import viser.transforms as vtf

    h = max(8, round(width / max(float(aspect), 1e-3)))
    c2w = np.eye(4)
    c2w[:3, :3] = vtf.SO3(np.asarray(wxyz, np.float64)).as_matrix()
    c2w[:3, 3] = np.asarray(position, np.float64)
    fy = 0.5 / math.tan(float(fov) / 2.0)  # focal length / image height
    k = np.array([[fy * h / width, 0.0, 0.5], [0.0, fy, 0.5], [0.0, 0.0, 1.0]])
    return c2w, k, (h, width)


def look_at_wxyz(position, look_at, up=(0.0, -1.0, 0.0)) -> np.ndarray:
    """The (4,) wxyz rotation (camera-to-world, OpenCV axes) of a camera at `position` looking at
    `look_at` with `up` (world) up in its image; `up` defaults to the OpenCV world's -y."""
    import viser.transforms as vtf

    z = np.asarray(look_at, np.float64) - np.asarray(position, np.float64)
    z /= max(float(np.linalg.norm(z)), 1e-12)
    down = -np.asarray(up, np.float64)
    y = down - (down @ z) * z
    if float(np.linalg.norm(y)) < 1e-9:  # looking straight along `up`: any image down will do
        y = np.cross(z, [1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0])
    y /= float(np.linalg.norm(y))
    return vtf.SO3.from_matrix(np.stack([np.cross(y, z), y, z], 1)).wxyz


class Prediction:
    """A checkpoint's model: Gaussians for a context, and live renders of the browsers' cameras.

    Renders run one at a time; a camera that moves during a render is rendered when it ends (the
    latest pose of each client), so the panel always ends on the view the browser shows."""

    def __init__(self, server: viser.ViserServer, checkpoint: Path, device: str | None, notes: Notes):
        from pipelines.render import load_model

        self.server, self.notes = server, notes
        loaded = load_model(checkpoint, device=device or "cpu")
        self.model, self.hw = loaded.model, loaded.image_hw
        self.backend = "torch" if loaded.device.type == "cpu" else loaded.backend
        self.g: Gaussians | None = None
        self.lock = threading.Lock()
        self.pending: dict[int, viser.ClientHandle] = {}
        self.image = server.gui.add_image(
            np.zeros((LIVE_RENDER_WIDTH * 3 // 4, LIVE_RENDER_WIDTH, 3), np.uint8), label="SeeU render (your view)"
        )

    def predict(self, context: dict) -> None:
        """Encode `context` (B=1 views) and draw the Gaussians under /prediction."""
        import torch

        from seeu_model.training.factory import encode_context
        from seeu_model.training.loop import batch_to

        dev = next(self.model.parameters()).device
        with torch.no_grad():
            self.g = encode_context(self.model, batch_to(context, dev))
        add_splats(self.server, "/prediction", self.g, self.notes)
        # the panel shows the start view at once (a browser's live render replaces it when it comes)
        start = self.server.initial_camera
        wxyz = look_at_wxyz(start.position, start.look_at, start.up if start.up is not None else (0.0, -1.0, 0.0))
        self.image.image = self.render_camera(wxyz, start.position, start.fov, 4.0 / 3.0)
        for client in self.server.get_clients().values():
            self.render_for(client)

    def render_camera(self, wxyz, position, fov: float, aspect: float, width: int = LIVE_RENDER_WIDTH) -> np.ndarray:
        """The predicted Gaussians seen by a viser camera (`view_camera`): (H, W, 3) uint8 RGB."""
        from pipelines.render import render_views

        if self.g is None:
            raise SeeUError("no prediction yet")
        c2w, k, hw = view_camera(wxyz, position, fov, aspect, width)
        frames, _ = render_views(self.model, {}, c2w[None], k[None], hw, self.backend, self.g)
        return frames[0]

    def render_for(self, client: viser.ClientHandle) -> None:
        """Render the client's current camera into the panel (or leave it to the render running now,
        which renders it next)."""
        self.pending[client.client_id] = client
        while self.g is not None and self.pending and self.lock.acquire(blocking=False):
            try:
                while self.pending:
                    _, c = self.pending.popitem()
                    cam = c.camera
                    self.image.image = self.render_camera(cam.wxyz, cam.position, cam.fov, cam.aspect)
            finally:
                self.lock.release()


def posed_context(scene, hw) -> dict:
    """A two-view context of a posed scene: the pair `seeu predict --auto-context` picks."""
    from pipelines.predict import auto_context_pair
    from pipelines.render import context_from_views
    from seeu_data.image_ops import decode_rgb

    ids = list(auto_context_pair(len(scene)))
    return context_from_views(
        [decode_rgb(bytes(scene.images[i])) for i in ids],
        np.asarray(scene.cam_to_world)[ids],
        np.asarray(scene.intrinsics_norm)[ids],
        float(scene.near),
        float(scene.far),
        hw,
    )


# ---------------------------------------------------------------------------------------------
# Serving
# ---------------------------------------------------------------------------------------------


def check_port_free(host: str, port: int) -> None:
    """SeeUError when (host, port) cannot be bound (viser would silently take the next port)."""
    if port == 0:
        return
    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE:
                raise SeeUError(
                    f"port {port} on {host} is in use (choose another with --port, 0: any free one)"
                ) from None
            raise SeeUError(f"cannot serve on {host}:{port} ({exc.strerror})") from None


@contextlib.contextmanager
def quiet_viser() -> Iterator[None]:
    """Silence viser's own stdout lines (its start banner and "(viser) Server stopped" go through
    rich.print whatever `verbose` says), so `seeu view` prints one URL line of its own."""
    import rich

    console = rich.get_console()
    was, console.quiet = console.quiet, True
    try:
        yield
    finally:
        console.quiet = was


def stop_server(server: viser.ViserServer) -> None:
    """Stop a viser server without its "(viser) Server stopped" line."""
    with quiet_viser():
        server.stop()


def server_url(host: str, port: int) -> str:
    """http://HOST:PORT, an IPv6 address in brackets (http://[::1]:8080)."""
    return f"http://[{host}]:{port}" if ":" in host else f"http://{host}:{port}"


def build_scene(cfg: ViewConfig, out: Callable[[str], None] = print) -> tuple[viser.ViserServer, str]:
    """Start the viser server of `cfg` and draw PATH into it; returns (server, kind). Notes and
    clients connecting / disconnecting are written with `out`."""
    import viser

    cfg.check()
    kind = detect_view_kind(cfg.path)
    if cfg.checkpoint is not None and kind in ("render", "ply"):
        raise SeeUError("--checkpoint needs posed frames or triple shards, not Gaussians")
    notes = Notes(out)
    host, port = (DEFAULT_HOST, 0) if cfg.save is not None else (cfg.host, cfg.port)
    check_port_free(host, port)
    with quiet_viser():
        server = viser.ViserServer(host=host, port=port, verbose=False)
    if port != 0 and server.get_port() != port:  # taken between the check and the bind
        stop_server(server)
        raise SeeUError(f"port {port} on {host} is in use (choose another with --port, 0: any free one)")
    server.on_client_connect(lambda c: out(f"client {c.client_id} connected"))
    server.on_client_disconnect(lambda c: out(f"client {c.client_id} disconnected"))
    try:
        server.scene.set_up_direction("-y")  # OpenCV worlds: y down
        pred = Prediction(server, cfg.checkpoint, cfg.device, notes) if cfg.checkpoint is not None else None
        if pred is not None:

            def live(client: viser.ClientHandle) -> None:
                client.camera.on_update(lambda _: pred.render_for(client))

            server.on_client_connect(live)
        if kind in ("render", "ply"):
            show_ply(server, cfg.path, notes)
        elif kind == "triples":
            on_row = None
            if pred is not None:
                from pipelines.render import shard_sample

                on_row = lambda i: pred.predict(shard_sample(str(cfg.path), str(i), pred.hw)["context"])  # noqa: E731
            show_triple(server, cfg.path, cfg.sample, on_row)
        else:
            on_scene = None if pred is None else (lambda scene: pred.predict(posed_context(scene, pred.hw)))
            show_posed(server, SceneSource(cfg.path, kind, notes), notes, on_scene)
    except BaseException:
        stop_server(server)
        raise
    return server, kind


def save_scene(server: viser.ViserServer, path: Path) -> int:
    """Write the server's scene as a .viser file (viser's scene serializer); returns its bytes."""
    from seeu_data.store.arrow_io import atomic_write_bytes

    data = server.get_scene_serializer().serialize()
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, data)
    return len(data)


def chromium_screenshot(
    url: str, png: Path, size: tuple[int, int] = SCREENSHOT_SIZE, ready: Callable[[], bool] | None = None
) -> None:
    """Open `url` in headless chromium (software WebGL), wait SCREENSHOT_WAIT_MS of virtual time,
    write the page to `png`. `ready()` tells whether that screenshot shows the page as served (e.g. the
    server saw the client: on a busy machine the websocket may connect after the virtual time ran out);
    when it does not, chromium runs again with twice the time, SCREENSHOT_ATTEMPTS runs in all. SeeUError
    when chromium is missing or writes nothing, or the page never got ready."""
    import shutil

    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    if exe is None:
        raise SeeUError("chromium not found: install it (apt-get install chromium) to take screenshots")
    png = Path(png).resolve()
    png.parent.mkdir(parents=True, exist_ok=True)
    png.unlink(missing_ok=True)
    for attempt in range(SCREENSHOT_ATTEMPTS):
        png.unlink(missing_ok=True)
        argv = [
            exe,
            "--headless",
            "--no-sandbox",  # as root (CI containers) chromium refuses to start with its sandbox
            "--use-angle=swiftshader",
            "--enable-unsafe-swiftshader",
            "--hide-scrollbars",
            f"--window-size={size[0]},{size[1]}",
            f"--virtual-time-budget={SCREENSHOT_WAIT_MS * 2**attempt}",
            f"--screenshot={png}",
            url,
        ]
        done = subprocess.run(argv, capture_output=True, text=True, timeout=240)
        if not png.is_file():
            raise SeeUError(f"chromium wrote no screenshot (exit {done.returncode}): {done.stderr.strip()[-300:]}", png)
        if ready is None or ready():
            return
    raise SeeUError(f"the page did not load in chromium ({SCREENSHOT_ATTEMPTS} tries)", url)


def serve(server: viser.ViserServer, out: Callable[[str], None] = print, stop: threading.Event | None = None) -> None:
    """Wait until Ctrl-C / SIGTERM (or `stop`), then stop the server."""
    from seeu_data.interrupts import Terminated

    try:
        while stop is None or not stop.is_set():
            time.sleep(0.2)
    except (KeyboardInterrupt, Terminated):
        out("stopped")
    finally:
        stop_server(server)
