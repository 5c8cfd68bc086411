"""Evaluate a checkpoint: PSNR / SSIM / LPIPS by the peers' protocol, timing and peak memory.

Examples:
  seeu eval --checkpoint runs/re10k/checkpoints --data data/re10k/test_eval --out runs/re10k/eval
  seeu eval --checkpoint runs/cpu/checkpoints/ckpt-00000300.pt --data out/shards/extrap --no-lpips

Protocol (as pixelSplat / MVSplat / SeeU compute it): renders and ground truth clipped to [0, 1];
PSNR per image from its MSE; SSIM with an 11-pixel Gaussian window (sigma 1.5) as scikit-image
computes it; LPIPS(VGG) on [0, 1] inputs. Each metric is averaged over the targets of a scene, then
over scenes (summary.json also has the plain mean over all targets). Encoder (context -> Gaussians)
and renderer (Gaussians -> target views) are timed separately per sample after `--warmup` batches;
peak memory is CUDA's max allocated, or the process's peak RSS on CPU.
With ground truth (DTU, synthetic): --depth-gt gives the depth RMSE of the rendered expected depth
per target; --points-gt the DTUeval Chamfer distance (accuracy / completeness / overall, thinned to
0.2, distances < 20, observation mask when given) of the Gaussian centres with opacity >= 0.5.
Shards built from DTU imported with `seeu import dtu` need neither: the ground-truth paths the
importer records in the scene meta (Depths/*.pfm in mm, Points/stl, ObsMask/Plane .mat) are found
through the shards' manifest and used automatically (depth RMSE in scene units, Chamfer in mm).
Writes OUT/per_scene.csv, OUT/per_target.csv (OUT/chamfer.csv) and OUT/summary.json (written last).
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import math
from pathlib import Path
from typing import Any
from pipelines.options import parse_dims


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--checkpoint", required=True, help="a ckpt-*.pt file or a directory (its newest checkpoint)")
    parser.add_argument(
        "--data", required=True, help="evaluation triple shards (seeu build --mode eval, or interp/extrap)"
    )
    parser.add_argument("--out", default=None, help="output directory (default: RUN/eval/<data name>)")
    parser.add_argument("--batch-size", type=int, default=1)
    parser.add_argument("--image-size", default=None, metavar="HxW", help="default: the training image size")
    parser.add_argument("--max-samples", type=int, default=0, help="evaluate at most N samples (0: all)")
    parser.add_argument("--warmup", type=int, default=2, help="batches run before timing starts")
    parser.add_argument("--lpips-weights", default=None, metavar="PATH", help="torchvision's vgg16-397923af.pth")
    parser.add_argument("--no-lpips", action="store_true", help="skip LPIPS (reported as null)")
    parser.add_argument("--device", default=None, help="cpu or cuda (default: cuda when available)")
    parser.add_argument("--rasterizer", default=None, help="auto | torch | gsplat (default: the training config's)")
    parser.add_argument("--num-workers", type=int, default=0)
    parser.add_argument(
        "--depth-gt",
        default=None,
        metavar="DIR",
        help="ground-truth depth maps DIR/<scene_id>/<frame_index:06d>.npy|.pfm -> depth RMSE",
    )
    parser.add_argument(
        "--points-gt",
        default=None,
        metavar="DIR",
        help="ground-truth points DIR/<scene_id>/points.npy|.ply [+ obs_mask.npz] -> DTUeval Chamfer",
    )
    parser.add_argument(
        "--geometry-scale",
        type=float,
        default=1.0,
        help="multiply predicted points by this before Chamfer (DTU: 200 -> mm)",
    )
    parser.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None)


def run(args: argparse.Namespace) -> int:
    hw = parse_dims(args.image_size, "--image-size") if args.image_size else None
    summary = evaluate(
        args.checkpoint,
        args.data,
        args.out,
        batch_size=args.batch_size,
        image_hw=hw,
        max_samples=args.max_samples,
        warmup=args.warmup,
        lpips=not args.no_lpips,
        lpips_weights=args.lpips_weights,
        device=args.device,
        rasterizer=args.rasterizer,
        num_workers=args.num_workers,
        progress=args.progress,
        depth_gt=args.depth_gt,
        points_gt=args.points_gt,
        geometry_scale=args.geometry_scale,
    )
    print(json.dumps({k: summary[k] for k in ("metrics", "timing", "out")}, indent=2))
    return 0


def check_image_size(model, hw: tuple[int, int]) -> None:
    """Usage error (one line) when the model cannot take images of size `hw` (H, W)."""
    from seeu_data.errors import SeeUError

    unit = getattr(model, "size_unit", 1)
    if hw[0] % unit or hw[1] % unit:
        raise SeeUError(
            f"--image-size {hw[0]}x{hw[1]}: this model needs height and width divisible by {unit} "
            f"(e.g. {max(unit, hw[0] // unit * unit)}x{max(unit, hw[1] // unit * unit)})"
        )


def csv_text(rows: list[dict]) -> str:
    buf = io.StringIO()
    if rows:
        w = csv.DictWriter(buf, fieldnames=list(rows[0].keys()), lineterminator="\n")
        w.writeheader()
        for r in rows:
            w.writerow(
                {
                    k: ("" if isinstance(v, float) and math.isnan(v) else (f"{v:.6f}" if isinstance(v, float) else v))
                    for k, v in r.items()
                }
            )
    return buf.getvalue()


def _nan_to_none(obj: Any) -> Any:
    if isinstance(obj, float) and math.isnan(obj):
        return None
    if isinstance(obj, dict):
        return {k: _nan_to_none(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_nan_to_none(v) for v in obj]
    return obj


def evaluate_on_data(
    model,
    data: str,
    image_hw: tuple[int, int],
    *,
    device=None,
    batch_size: int = 1,
    max_samples: int = 0,
    warmup: int = 2,
    lpips_fn=None,
    rasterizer: str = "auto",
    precision: str = "auto",
    num_workers: int = 0,
    progress: bool | None = None,
    keep_renders: int = 0,
    depth_gt=None,
    points_gt=None,
    geometry_scale: float = 1.0,
):
    """Evaluate an in-memory model on triple shards; returns `seeu_model.evaluation.EvalOutput`."""
    import sys

    import torch

    from pipelines.train import make_eval_loader
    from seeu_model.evaluation import evaluate_model
    from seeu_model.training.factory import encode_context, render_gaussians
    from seeu_model.training.loop import autocast_context

    device = torch.device(device) if device is not None else next(model.parameters()).device
    loader = make_eval_loader(data, image_hw, batch_size, num_workers)
    return evaluate_model(
        model,
        loader,
        device,
        encode_context,
        lambda g, t: render_gaussians(g, t, rasterizer),
        lpips_fn=lpips_fn,
        max_samples=max_samples,
        warmup=warmup,
        keep_renders=keep_renders,
        progress=sys.stderr.isatty() if progress is None else progress,
        autocast=lambda: autocast_context(precision, device),
        depth_fn=make_depth_fn(depth_gt, image_hw) if depth_gt is not None else None,
        geometry_fn=make_geometry_fn(points_gt, geometry_scale) if points_gt is not None else None,
    )


def write_results(out: Path, res, extra: dict) -> dict:
    """per_target.csv, per_scene.csv, then summary.json (last). Returns the summary document."""
    from dataclasses import asdict

    from seeu_data.arrow_io import atomic_write_text
    from seeu_model.evaluation import per_scene, summarize, timing_dict

    out.mkdir(parents=True, exist_ok=True)
    (out / "summary.json").unlink(missing_ok=True)  # being rewritten: not complete
    atomic_write_text(out / "per_target.csv", csv_text([asdict(r) for r in res.records]))
    scenes = [{"scene_id": s, **row} for s, row in per_scene(res.records).items()]
    atomic_write_text(out / "per_scene.csv", csv_text(scenes))
    metrics = summarize(res.records)
    if res.geometry:
        atomic_write_text(out / "chamfer.csv", csv_text(res.geometry))
        by_scene: dict[str, list[dict]] = {}
        for g in res.geometry:
            by_scene.setdefault(g["scene_id"], []).append(g)
        for key in ("accuracy", "completeness", "overall"):
            vals = [sum(g[key] for g in gs) / len(gs) for gs in by_scene.values()]
            metrics[f"chamfer_{key}"] = sum(vals) / len(vals)
    summary = {
        **extra,
        "metrics": metrics,
        "timing": timing_dict(res.timing),
        "out": str(out),
        "protocol": {
            "psnr": "clip [0,1], per-image MSE, -10 log10",
            "ssim": "11-px Gaussian window, sigma 1.5, scikit-image (sample covariance)",
            "lpips": "LPIPS(VGG) on [0,1] inputs (normalize=True)",
            "aggregation": "mean over the targets of a scene, then over scenes",
            "timing": "ms per sample, encoder and renderer separately, after warm-up",
        },
    }
    summary = _nan_to_none(summary)
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=2) + "\n")
    return summary


def evaluate(
    checkpoint: str | Path,
    data: str,
    out: str | Path | None = None,
    *,
    batch_size: int = 1,
    image_hw: tuple[int, int] | None = None,
    max_samples: int = 0,
    warmup: int = 2,
    lpips: bool = True,
    lpips_weights: str | None = None,
    device: str | None = None,
    rasterizer: str | None = None,
    num_workers: int = 0,
    progress: bool | None = None,
    depth_gt=None,
    points_gt=None,
    geometry_scale: float = 1.0,
) -> dict:
    """Python API of `seeu eval`; returns the summary document (also written to OUT/summary.json)."""
    import torch

    from seeu_data.errors import SeeUError
    from seeu_model.lpips_loss import LPIPS
    from seeu_model.training import checkpoint as ckpt_io
    from seeu_model.training.config import config_from_dict
    from seeu_model.training.factory import model_from_checkpoint

    ck = ckpt_io.load_checkpoint(checkpoint)
    cfg = config_from_dict(json.loads(json.dumps(ck["config"])))
    dev = torch.device(device) if device else torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if batch_size < 1:
        raise SeeUError("--batch-size must be >= 1")
    if max_samples < 0 or warmup < 0 or num_workers < 0:
        raise SeeUError("--max-samples, --warmup and --num-workers must be >= 0")
    if not (math.isfinite(geometry_scale) and geometry_scale > 0):
        raise SeeUError(f"--geometry-scale must be a finite number > 0, got {geometry_scale}")
    model = model_from_checkpoint(ck, dev)
    lpips_fn = None
    lpips_kind = "off"
    if lpips:
        lpips_fn = LPIPS(weights=lpips_weights or cfg.loss.lpips_weights).to(dev)
        lpips_kind = "vgg"
    hw = tuple(image_hw or cfg.data.image_size)
    check_image_size(model, hw)
    if out is None:
        run_dir = Path(ck["path"]).parent.parent
        out = run_dir / "eval" / Path(str(data).rstrip("/")).name
    geometry_note = None
    if depth_gt is None and points_gt is None:
        found = posed_ground_truth(data)
        if found is not None:  # DTU: ground truth recorded by the importer
            depth_gt, points_gt, geometry_scale = found
            geometry_note = "ground truth from the posed scenes' meta (depth RMSE in scene units, Chamfer in mm)"
    res = evaluate_on_data(
        model,
        data,
        hw,
        device=dev,
        batch_size=batch_size,
        max_samples=max_samples,
        warmup=warmup,
        lpips_fn=lpips_fn,
        rasterizer=rasterizer or cfg.rasterizer,
        precision=cfg.precision,
        num_workers=num_workers,
        progress=progress,
        depth_gt=depth_gt,
        points_gt=points_gt,
        geometry_scale=geometry_scale,
    )
    if not res.records:
        raise SeeUError("the evaluation data yielded no sample", data)
    extra = {
        "checkpoint": ck["path"],
        "step": ck["step"],
        "data": str(data),
        "image_hw": list(hw),
        "lpips": lpips_kind,
        "device": str(dev),
        "geometry": geometry_note,
    }
    return write_results(Path(out), res, extra)


# ------------------------------------------------------------------------------------------------
# Ground-truth geometry (DTU and any dataset that has it)
# ------------------------------------------------------------------------------------------------


def read_pfm(path: Path):
    """A PFM depth map (MVSNet / DTU 'Depths') -> (H, W) float32, rows top to bottom."""
    import numpy as np

    with open(path, "rb") as fh:
        header = fh.readline().decode("latin-1").strip()
        if header not in ("Pf", "PF"):
            raise ValueError("not a PFM file")
        w, h = (int(v) for v in fh.readline().decode("latin-1").split())
        scale = float(fh.readline().decode("latin-1").strip())
        data = np.frombuffer(fh.read(), dtype="<f4" if scale < 0 else ">f4")
    ch = 3 if header == "PF" else 1
    return np.flipud(data[: h * w * ch].reshape(h, w, ch)[..., 0]).astype(np.float32)


def load_depth_map(root: Path, scene_id: str, frame_index: int):
    """Ground-truth depth of a frame: ROOT/<scene_id>/<frame_index:06d>.npy|.pfm (or without zero padding)."""
    import numpy as np

    for name in (f"{frame_index:06d}", f"{frame_index}", f"depth_map_{frame_index:04d}"):
        for ext in (".npy", ".pfm"):
            p = root / scene_id / f"{name}{ext}"
            if p.is_file():
                return np.load(p).astype(np.float32) if ext == ".npy" else read_pfm(p)
    return None


def make_depth_fn(root_or_loader, image_hw: tuple[int, int]):
    """depth_fn for `evaluate_model`: RMSE of the rendered expected depth against ground-truth depth maps
    (resized to the evaluation size with the loader's cover-crop, nearest neighbour; pixels with
    depth <= 0 or not finite are ignored). Targets without ground truth give NaN.

    root_or_loader: a directory (ROOT/<scene_id>/<frame_index:06d>.npy|.pfm, scene units) or a
    callable (scene_id, frame_index) -> (H, W) depth in scene units or None."""
    import cv2
    import numpy as np
    import torch

    from seeu_data.cameras import cover_crop_geometry
    from seeu_model.geometry_metrics import depth_rmse

    if callable(root_or_loader):
        load = root_or_loader
    else:
        root = Path(root_or_loader)
        load = lambda scene, frame: load_depth_map(root, scene, frame)  # noqa: E731
    h, w = image_hw

    def fit(depth: np.ndarray) -> np.ndarray:
        (sh, sw), (oy, ox) = cover_crop_geometry(depth.shape[:2], (h, w))
        if (sh, sw) != depth.shape[:2]:
            depth = cv2.resize(depth, (sw, sh), interpolation=cv2.INTER_NEAREST)
        return depth[oy : oy + h, ox : ox + w]

    def depth_fn(batch, render):
        b, t = batch["target"]["frame_index"].shape
        out = torch.full((b, t), float("nan"))
        for k in range(b):
            for j in range(t):
                gt = load(batch["scene_id"][k], int(batch["target"]["frame_index"][k, j]))
                if gt is not None:
                    out[k, j] = depth_rmse(render.depth[k, j, 0].float().cpu(), torch.from_numpy(fit(gt).copy()))
        return out

    return depth_fn


def _read_ply_points(path: Path):
    import numpy as np
    from plyfile import PlyData

    v = PlyData.read(str(path))["vertex"]
    return np.stack([v["x"], v["y"], v["z"]], -1).astype(np.float64)


def make_geometry_fn(
    root_or_loader, scale: float = 1.0, min_opacity: float = 0.5, density: float = 0.2, max_dist: float = 20.0
):
    """geometry_fn for `evaluate_model`: DTUeval Chamfer between the Gaussian centres (opacity >=
    `min_opacity`, multiplied by `scale`, e.g. 200 to undo DTU's 1/200 camera scaling -> mm) and the
    ground-truth points.

    root_or_loader: a directory (ROOT/<scene_id>/points.npy (M, 3) or points.ply, optional
    obs_mask.npz with DTU's ObsMask/BB/Res[/Plane]) or a callable scene_id -> (points, in_mask_fn,
    above_plane_bool) or None."""
    import numpy as np

    from seeu_model.geometry_metrics import chamfer_dtueval, dtu_observation_filter

    cache: dict = {}

    def from_dir(scene: str):
        d = Path(root_or_loader) / scene
        pts = None
        if (d / "points.npy").is_file():
            pts = np.load(d / "points.npy").reshape(-1, 3)
        elif (d / "points.ply").is_file():
            pts = _read_ply_points(d / "points.ply")
        if pts is None:
            return None
        mask = above = None
        if (d / "obs_mask.npz").is_file():
            z = np.load(d / "obs_mask.npz")
            mask, above_fn = dtu_observation_filter(
                z["ObsMask"], z["BB"], float(z["Res"]), z["Plane"] if "Plane" in z else None
            )
            above = above_fn(pts)
        return pts, mask, above

    load = root_or_loader if callable(root_or_loader) else from_dir

    def geometry_fn(batch, gaussians, k):
        scene = batch["scene_id"][k]
        if scene not in cache:
            cache[scene] = load(scene)
        if cache[scene] is None:
            return None
        pts, mask, above = cache[scene]
        keep = gaussians.opacities[k] >= min_opacity
        pred = (gaussians.means[k][keep].double().cpu().numpy()) * scale
        r = chamfer_dtueval(pred, pts, mask, above, density=density, max_dist=max_dist)
        return {"accuracy": r.accuracy, "completeness": r.completeness, "overall": r.overall, "num_pred": r.num_pred}

    return geometry_fn


def posed_ground_truth(data: str):
    """Ground truth recorded by an importer (DTU) in the scene meta of the posed frames the triple
    shards were built from (found through the shards' manifest). Returns (depth_loader,
    points_loader, units note) or None when no scene has any.

    Depth maps in mm are converted to scene units with the scene's `scale`; Chamfer compares in mm
    (predicted centres divided by `scale`), with DTU's ObsMask / Plane .mat files when present."""
    import numpy as np

    from seeu_data.posed import PosedDataset

    manifest = Path(str(data)) / "manifest.json"
    if not manifest.is_file():
        return None
    try:
        inputs = json.loads(manifest.read_text()).get("params", {}).get("inputs", []) or []
    except json.JSONDecodeError:
        return None
    scenes: dict[str, tuple] = {}
    for inp in inputs:
        try:
            ds = PosedDataset(inp)
        except Exception:  # noqa: BLE001 - inputs moved or unreadable: no ground truth
            continue
        for sid in ds.scene_ids:
            meta = (ds.scene_info(sid) or {}).get("meta") or {}
            if any(k in meta for k in ("gt_depth_dir", "gt_points")):
                scenes[sid] = (ds, meta)
    if not scenes:
        return None
    frames_cache: dict[str, np.ndarray] = {}

    def depth_loader(scene: str, frame_index: int):
        if scene not in scenes or "gt_depth_dir" not in scenes[scene][1]:
            return None
        ds, meta = scenes[scene]
        if scene not in frames_cache:
            frames_cache[scene] = np.asarray(ds.load_scene(scene).source_frame)
        src = frames_cache[scene]
        view = int(src[frame_index]) if frame_index < len(src) else frame_index
        p = Path(meta["gt_depth_dir"]) / meta.get("gt_depth_pattern", "depth_map_{view:04d}.pfm").format(view=view)
        if not p.is_file():
            return None
        depth = read_pfm(p)
        return depth * float(meta.get("scale", 1.0)) if meta.get("gt_depth_units") == "mm" else depth

    def points_loader(scene: str):
        if scene not in scenes or "gt_points" not in scenes[scene][1]:
            return None
        meta = scenes[scene][1]
        pts = _read_ply_points(Path(meta["gt_points"]))
        mask = None
        above = None
        if "obs_mask" in meta:
            from seeu_model.geometry_metrics import dtu_observation_filter

            try:
                from scipy.io import loadmat
            except ImportError:
                loadmat = None
            if loadmat is not None:
                om = loadmat(meta["obs_mask"])
                plane = loadmat(meta["obs_plane"])["P"] if "obs_plane" in meta else None
                mask, above_fn = dtu_observation_filter(om["ObsMask"], om["BB"], float(np.ravel(om["Res"])[0]), plane)
                above = above_fn(pts)
        return pts, mask, above

    scale = next((float(m.get("scale", 1.0)) for _, m in scenes.values()), 1.0)
    return depth_loader, points_loader, 1.0 / scale
