"""The render stage: novel views along camera paths and the Gaussians (.ply) from a trained checkpoint.

Context views come from a triple shard example (`data` + `sample`: index in manifest order or
sample_id) or from your own images with cameras (`cameras`: a JSON file, layout in `seeu render
--help` and `load_user_views`). The camera path goes from the first to the last context camera
(rotation along the geodesic, centre on the line): `interp` covers t in [0, 1], `extrap` t in
[-e, 1 + e] with e = `extrapolate`. Writes OUT/frames/{interp,extrap}_NNN.png, OUT/interp.mp4,
OUT/extrap.mp4, OUT/gaussians.ply (standard 3DGS layout) with OUT/cameras.json and OUT/gaussians.json,
OUT/context.png, OUT/targets.png (shard examples) and OUT/render.json (written last).

Example:
    from pipelines.render import RenderConfig, render

    report = render(RenderConfig(checkpoint="runs/cpu/checkpoints", out="out/render", data="out/shards/eval"))
    report["extrap"]["mp4"], report["ply"], report["timing_s"]["encode"]
"""

from __future__ import annotations

import json
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from seeu_data.errors import SeeUError
from seeu_data.limits import (
    MAX_CONTEXT_VIEWS,
    MAX_IMAGE_SIDE,
    MAX_PIXELS,
    MAX_PIXELS_CEILING,
    MAX_RENDER_FRAMES,
    check_range,
)
from seeu_data.settings import parse_dims, setting
from seeu_data.store.json_file import read_json

if TYPE_CHECKING:
    import torch


@dataclass(frozen=True, kw_only=True)
class RenderConfig:
    """One `seeu render` run: exactly one of `data` (triple shards; `sample` picks the example) and
    `cameras` (a cameras JSON); `frames` per path; `extrapolate` e; `fps` of the MP4s; `image_size`
    (H, W) (None: the training size); `device` (None: cuda when available); `rasterizer` auto | torch
    | gsplat (None: the training config's)."""

    checkpoint: str | Path = setting(help="a ckpt-*.pt file or a directory (its newest checkpoint)")
    data: str | None = setting(None, "triple shards to take the context views from", required=True, exclusive="source")
    cameras: str | Path | None = setting(
        None, "JSON with your own context images and cameras (see above)", required=True, exclusive="source"
    )
    sample: str = setting("0", "with --data: sample index (in manifest order) or sample_id")
    out: str | Path
    frames: int = setting(30, "frames per path")
    extrapolate: float = setting(0.5, "extrapolated path runs from t=-e to 1+e")
    fps: float = setting(10.0, "frame rate of the MP4s")
    image_size: tuple[int, int] | None = setting(
        None, "default: the training image size", parse=parse_dims, metavar="HxW"
    )
    device: str | None = setting(None, "default: cuda when available")
    rasterizer: str | None = setting(None, "auto | torch | gsplat (default: the training config's)")
    max_pixels: int = MAX_PIXELS  # largest image (width x height) decoded, `--max-pixels`

    def check(self) -> None:
        check_range(self.frames, "--frames", 2, MAX_RENDER_FRAMES)
        check_range(self.max_pixels, "--max-pixels", 1, MAX_PIXELS_CEILING)
        if self.image_size is not None:
            for side in self.image_size:
                check_range(side, "--image-size", 1, MAX_IMAGE_SIDE)
        if not (math.isfinite(self.extrapolate) and self.extrapolate >= 0):
            raise SeeUError(f"--extrapolate must be a finite number >= 0, got {self.extrapolate}")
        if not (math.isfinite(self.fps) and self.fps > 0):
            raise SeeUError(f"--fps must be a finite number > 0, got {self.fps}")
        if (self.data is None) == (self.cameras is None):
            raise SeeUError("give exactly one of --data (a shard example) or --cameras (your own views)")


def context_from_views(images: list, cam_to_world, intrinsics_norm, near: float, far: float, image_hw) -> dict:
    """The model's context dict (B = 1) from V decoded (H_i, W_i, 3) uint8 RGB images, (V, 4, 4) OpenCV
    camera-to-world, (V, 4) normalised intrinsics of the images as given, and the scene's near/far:
    every image resized to cover `image_hw` (H, W) and centre-cropped (the peers' crop), its intrinsics
    updated. Returns the loader's layout: image (1, V, 3, H, W) uint8 (`training.loop.batch_to` makes
    it float in [0, 1] as for shard examples), cam_to_world (1, V, 4, 4), intrinsics (1, V, 3, 3)
    normalised, near/far (1, V) (float32), frame_index (1, V) = 0 .. V-1."""
    import numpy as np
    import torch

    from seeu_data.cameras import intrinsics_norm_matrix
    from seeu_data.image_ops import resize_cover_crop, resized_intrinsics

    if not (np.isfinite(near) and np.isfinite(far) and 0 < near < far):
        raise SeeUError(f"need finite 0 < near < far, got near={near}, far={far}")
    resized = [resize_cover_crop(img, image_hw) for img in images]
    intrs = [
        intrinsics_norm_matrix(resized_intrinsics(k, img.shape[:2], image_hw))
        for img, k in zip(images, intrinsics_norm)
    ]
    v = len(images)
    return {
        "image": torch.from_numpy(np.stack(resized)).permute(0, 3, 1, 2)[None].contiguous(),
        "cam_to_world": torch.tensor(np.stack(cam_to_world), dtype=torch.float32)[None],
        "intrinsics": torch.tensor(np.stack(intrs), dtype=torch.float32)[None],
        "near": torch.full((1, v), float(near)),
        "far": torch.full((1, v), float(far)),
        "frame_index": torch.arange(v)[None],
    }


def check_view_sizes(path: str | Path, max_pixels: int = MAX_PIXELS) -> None:
    """The image-size gate (`image_header.check_pixels` on each header) for the images a cameras JSON
    names, before the model is loaded: a header bomb is refused without the model's memory. Anything
    else wrong with the file is left to `load_user_views`, which says it."""
    from seeu_data.store.image_header import check_pixels, header_size

    path = Path(path)
    try:
        frames = json.loads(path.read_text())["frames"]
    except (OSError, ValueError, KeyError, TypeError, RecursionError):
        return
    for i, f in enumerate(frames if isinstance(frames, list) else []):
        img_path = path.parent / f["image"] if isinstance(f, dict) and isinstance(f.get("image"), str) else None
        if img_path is not None and img_path.is_file():
            where = f"{img_path.resolve()} (frame {i})"
            w, h = header_size(img_path.read_bytes(), where)
            check_pixels(w, h, max_pixels, "image header declares", where)


def load_user_views(path: str | Path, image_hw: tuple[int, int], max_pixels: int = MAX_PIXELS) -> dict:
    """Context dict (B=1) from a cameras JSON and its images (each at most `max_pixels`, checked
    before it is decoded), resized/cropped to `image_hw`."""
    import numpy as np

    from seeu_data.cameras import intrinsics_norm_from_pixels, rotation_orthonormality_error
    from seeu_data.image_ops import decode_rgb

    path = Path(path)
    if not path.is_file():
        raise SeeUError("cameras file not found", path)
    doc = read_json(path, "cameras file")
    frames = doc.get("frames") if isinstance(doc, dict) else None
    if not isinstance(frames, list) or len(frames) < 2:
        raise SeeUError("need a 'frames' list with at least two context views", path)
    check_range(len(frames), "context views in 'frames'", 2, MAX_CONTEXT_VIEWS, path)
    try:
        near, far = float(doc["near"]), float(doc["far"])
    except (KeyError, TypeError, ValueError):
        raise SeeUError("need numeric 'near' and 'far' (scene depth range in the cameras' units)", path) from None
    if not (np.isfinite(near) and np.isfinite(far) and 0 < near < far):
        raise SeeUError(f"need finite 0 < near < far, got near={near}, far={far}", path)
    images, poses, intrs = [], [], []
    for i, f in enumerate(frames):
        where = f"{path} frame {i}"
        if not isinstance(f, dict) or not isinstance(f.get("image"), str):
            raise SeeUError(
                f"frame {i}: must be an object with an 'image' path, 'cam_to_world' and intrinsics, "
                f"got {type(f).__name__}",
                path,
            )
        img_path = (path.parent / f["image"]).resolve()
        if not img_path.is_file():
            raise SeeUError(f"frame {i}: image not found", img_path)
        img = decode_rgb(img_path.read_bytes(), f"{img_path} (frame {i})", max_pixels)
        try:
            pose = np.asarray(f["cam_to_world"], dtype=np.float64).reshape(4, 4)
        except (KeyError, ValueError, TypeError):
            raise SeeUError(f"frame {i}: 'cam_to_world' must be a 4x4 matrix", path) from None
        if not np.isfinite(pose).all():
            raise SeeUError(f"frame {i}: 'cam_to_world' has non-finite values (NaN or inf)", path)
        if not np.allclose(pose[3], [0, 0, 0, 1], atol=1e-6):
            raise SeeUError(f"frame {i}: 'cam_to_world' last row must be [0, 0, 0, 1]", path)
        if not rotation_orthonormality_error(pose) <= 1e-3:
            raise SeeUError(f"frame {i}: 'cam_to_world' rotation is not orthonormal (R^T R = I, det R = 1)", path)
        h, w = img.shape[:2]
        try:
            if "intrinsics_norm" in f:
                k = np.asarray(f["intrinsics_norm"], dtype=np.float64).reshape(4)
            else:
                k = intrinsics_norm_from_pixels(np.asarray(f["K"], dtype=np.float64).reshape(3, 3), w, h)
        except (KeyError, ValueError, TypeError):
            raise SeeUError(
                f"frame {i}: give 'intrinsics_norm' [fx/W, fy/H, cx/W, cy/H] or a pixel 'K' 3x3", where
            ) from None
        if not np.isfinite(k).all():
            raise SeeUError(f"frame {i}: intrinsics have non-finite values (NaN or inf)", path)
        if not (k[0] > 0 and k[1] > 0):
            raise SeeUError(f"frame {i}: focal lengths must be positive, got fx/W={k[0]:g}, fy/H={k[1]:g}", path)
        images.append(img)
        poses.append(pose)
        intrs.append(k)
    return context_from_views(images, poses, intrs, near, far, image_hw)


def shard_sample(data: str, sample: str, image_hw, max_pixels: int = MAX_PIXELS) -> dict:
    """The batch (B=1) of one example of triple shards: `sample` is its index in manifest order or its sample_id."""
    from pipelines.train import make_eval_loader

    loader = make_eval_loader(data, image_hw, 1, max_pixels=max_pixels)
    index = int(sample) if sample.isdigit() else None
    for i, batch in enumerate(loader):
        if (index is not None and i == index) or (index is None and batch["sample_id"][0] == sample):
            return batch
    raise SeeUError(f"no sample {sample!r} in this dataset", data)


def to_uint8(img):
    """(3, H, W) float in [0, 1] -> (H, W, 3) uint8 RGB."""
    return (img.clamp(0, 1) * 255.0 + 0.5).byte().permute(1, 2, 0).cpu().numpy()


def write_png(path: Path, rgb) -> None:
    import cv2

    from seeu_data.store.arrow_io import atomic_write_bytes

    ok, buf = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    if not ok:  # pragma: no cover
        raise RuntimeError("PNG encoding failed")
    atomic_write_bytes(path, buf.tobytes())


def write_mp4(path: Path, frames: list, fps: float) -> None:
    """(H, W, 3) uint8 RGB frames -> MP4 (mp4v), written to a temporary name and renamed."""
    import cv2

    h, w = frames[0].shape[:2]
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp.mp4")
    writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter.fourcc(*"mp4v"), float(fps), (w, h))
    if not writer.isOpened():
        raise RuntimeError(f"OpenCV cannot write MP4 files here ({path})")
    try:
        for f in frames:
            writer.write(cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
    finally:
        writer.release()
    os.replace(tmp, path)


def render_views(
    model, context: dict, cam_to_world, intrinsics, image_hw, rasterizer: str, gaussians=None, chunk: int = 8
):
    """Render (N, 4, 4) poses / (N, 3, 3) normalised intrinsics -> list of (H, W, 3) uint8 frames."""
    import torch

    from seeu_model.training.factory import encode_context, render_gaussians

    dev = next(model.parameters()).device
    with torch.no_grad():
        g = gaussians if gaussians is not None else encode_context(model, context)
        frames = []
        for s in range(0, len(cam_to_world), chunk):
            c2w = torch.as_tensor(cam_to_world[s : s + chunk], dtype=torch.float32, device=dev)[None]
            k = torch.as_tensor(intrinsics[s : s + chunk], dtype=torch.float32, device=dev)[None]
            target = {
                "cam_to_world": c2w,
                "intrinsics": k,
                "image": torch.empty(1, c2w.shape[1], 3, *image_hw, device=dev),
            }
            out = render_gaussians(g, target, rasterizer)
            frames += [to_uint8(c) for c in out.color[0]]
    return frames, g


@dataclass
class LoadedModel:
    """A checkpoint's model ready to render: `ck` the checkpoint dict (`checkpoint.load_checkpoint`),
    `model` in eval mode on `device`, `image_hw` (H, W) the model's input size (asked for, else the
    training size), `backend` the rasterizer (asked for, else the training config's)."""

    ck: dict
    model: torch.nn.Module
    image_hw: tuple[int, int]
    backend: str
    device: torch.device


def load_model(
    checkpoint: str | Path, image_size: tuple[int, int] | None = None, device: str | None = None, rasterizer=None
) -> LoadedModel:
    """The checkpoint loading of `seeu render` and `seeu predict` (a ckpt-*.pt file or a directory: its
    newest; a converted MVSplat checkpoint the same way). `device` None: cuda when available."""
    import torch

    from pipelines.evaluate import check_image_size
    from seeu_model.training import checkpoint as ckpt_io
    from seeu_model.training.config import config_from_dict
    from seeu_model.training.factory import model_from_checkpoint

    ck = ckpt_io.load_checkpoint(checkpoint)
    train_cfg = config_from_dict(json.loads(json.dumps(ck["config"])))
    hw: tuple[int, int] = image_size or train_cfg.data.image_size
    dev = torch.device(device or ("cuda" if torch.cuda.is_available() else "cpu"))
    model = model_from_checkpoint(ck, dev)
    check_image_size(model, hw)
    return LoadedModel(ck, model, hw, rasterizer or train_cfg.rasterizer, dev)


def render_paths(
    loaded: LoadedModel, ctx: dict, g, out: Path, frames: int, extrapolate: float, fps: float | None, report: dict
) -> None:
    """The camera paths from the first to the last context camera (`camera_path`): `interp` t in [0, 1]
    and `extrap` t in [-e, 1 + e], `frames` views each, rendered from the Gaussians `g` into
    OUT/frames/{interp,extrap}_NNN.png (and OUT/{interp,extrap}.mp4 when `fps` is given). Fills
    `report[name]` and `report["timing_s"]["render_<name>_per_frame"]`."""
    from seeu_model.camera_path import camera_path, path_parameters

    c2w = ctx["cam_to_world"][0].double().cpu().numpy()
    intr = ctx["intrinsics"][0].double().cpu().numpy()
    for name, e in (("interp", 0.0), ("extrap", extrapolate)):
        ts = path_parameters(frames, e)
        poses, ks = camera_path(c2w[0], c2w[-1], intr[0], intr[-1], ts)
        t0 = time.perf_counter()
        imgs, g = render_views(loaded.model, ctx, poses, ks, loaded.image_hw, loaded.backend, g)
        report["timing_s"][f"render_{name}_per_frame"] = (time.perf_counter() - t0) / len(imgs)
        pngs = []
        for i, img in enumerate(imgs):
            pngs.append(out / "frames" / f"{name}_{i:03d}.png")
            write_png(pngs[-1], img)
        report[name] = {"frames": len(imgs), "t": [float(ts[0]), float(ts[-1])]}
        if fps is not None:
            write_mp4(out / f"{name}.mp4", imgs, fps)
            report[name] = {"mp4": str(out / f"{name}.mp4"), **report[name]}
        else:
            report[name]["png"] = [str(p) for p in pngs]


def export_gaussians(out: Path, g, batch: dict, image_hw) -> dict:
    """OUT/gaussians.ply + cameras.json (3DGS viewers' layout: the context cameras, then the sample's
    targets) + gaussians.json (SH degree, count). Returns the report entries."""
    import numpy as np

    from seeu_model.ply import save_ply_bundle

    c2w, intr, names = [], [], []
    for part in ("context", "target"):
        if part in batch:
            views = batch[part]
            c2w.append(views["cam_to_world"][0].double().cpu().numpy())
            intr.append(views["intrinsics"][0].double().cpu().numpy())
            names += [f"{part}_{i}" for i in range(len(c2w[-1]))]
    side = save_ply_bundle(
        g.map(lambda t: t.detach().float().cpu()),
        out,
        np.concatenate(c2w),
        np.concatenate(intr),
        image_hw[1],
        image_hw[0],
        names,
    )
    return {"ply": str(out / side["ply"]), "cameras_json": str(out / side["cameras"]), "sh_degree": side["sh_degree"]}


def render(cfg: RenderConfig) -> dict:
    """Python API of `seeu render`; returns the report (also OUT/render.json)."""
    cfg.check()
    if cfg.cameras is not None:
        check_view_sizes(cfg.cameras, cfg.max_pixels)
    import numpy as np
    import torch

    from seeu_data.store.arrow_io import atomic_write_text
    from seeu_model.training.factory import encode_context
    from seeu_model.training.loop import batch_to

    loaded = load_model(cfg.checkpoint, cfg.image_size, cfg.device, cfg.rasterizer)
    ck, model, hw, backend, dev = loaded.ck, loaded.model, loaded.image_hw, loaded.backend, loaded.device
    data, cameras, frames, extrapolate, fps = cfg.data, cfg.cameras, cfg.frames, cfg.extrapolate, cfg.fps
    if data is not None:
        batch = shard_sample(data, str(cfg.sample), hw, cfg.max_pixels)
    else:
        assert cameras is not None  # cfg.check: one of the two
        batch = {"context": load_user_views(cameras, hw, cfg.max_pixels)}
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "render.json").unlink(missing_ok=True)
    batch = batch_to(batch, dev)
    ctx = batch["context"]
    report: dict = {
        "checkpoint": ck["path"],
        "step": ck["step"],
        "image_hw": list(hw),
        "fps": fps,
        "source": data or str(cameras),
        "sample_id": batch.get("sample_id", [None])[0],
    }
    t0 = time.perf_counter()
    with torch.no_grad():
        g = encode_context(model, ctx)
    report["timing_s"] = {"encode": time.perf_counter() - t0}
    render_paths(loaded, ctx, g, out, frames, extrapolate, fps, report)
    write_png(out / "context.png", np.concatenate([to_uint8(v) for v in ctx["image"][0]], axis=1))
    if "target" in batch:  # ground truth (top) over the model's renders of the sample's targets
        tgt = batch["target"]
        renders, _ = render_views(
            model, ctx, tgt["cam_to_world"][0].cpu().numpy(), tgt["intrinsics"][0].cpu().numpy(), hw, backend, g
        )
        top = np.concatenate([to_uint8(v) for v in tgt["image"][0]], axis=1)
        write_png(out / "targets.png", np.concatenate([top, np.concatenate(renders, axis=1)], axis=0))
    report.update(export_gaussians(out, g, batch, hw))
    report["num_gaussians"] = int(g.means.shape[1])
    atomic_write_text(out / "render.json", json.dumps(report, indent=2) + "\n")
    return report
