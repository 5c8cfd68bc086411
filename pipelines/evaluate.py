"""The evaluation stage: a checkpoint on triple shards, by the peers' protocol, with timing and memory.

`evaluate(EvalConfig(checkpoint=..., data=...))` writes OUT/per_target.csv, OUT/per_scene.csv
(OUT/chamfer.csv) and OUT/summary.json (last) and returns the summary. Protocol (pixelSplat / MVSplat /
SeeU): renders and ground truth clipped to [0, 1]; PSNR per image from its MSE; SSIM with an 11-pixel
Gaussian window (sigma 1.5) as scikit-image computes it; LPIPS(VGG) on [0, 1] inputs; each metric
averaged over the targets of a scene, then over scenes. Encoder and renderer are timed separately
per sample after `warmup` batches. With ground truth (`seeu_data.dtu_gt`): depth RMSE of the rendered
expected depth, and the DTUeval Chamfer distance of the Gaussian centres with opacity >= 0.5.
`evaluate_on_data` evaluates a model already in memory (the demo, tests).

Example:
    from pipelines.evaluate import EvalConfig, evaluate

    summary = evaluate(EvalConfig(checkpoint="runs/cpu/checkpoints", data="out/shards/eval", lpips=False))
    summary["metrics"]["psnr"], summary["timing"]["encoder_ms"]
"""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from seeu_data.errors import SeeUError
from seeu_data.limits import MAX_BATCH_SIZE, MAX_IMAGE_SIDE, MAX_PIXELS, MAX_SAMPLES, MAX_WORKERS, check_range
from seeu_data.settings import parse_dims, setting
from seeu_data.store.out_lock import locks_output


@dataclass(frozen=True, kw_only=True)
class EvalConfig:
    """One `seeu eval` run.

    checkpoint: a ckpt-*.pt file or a directory (its newest); data: evaluation triple shards; out:
    the output directory (None: RUN/eval/<data name>); image_size: (H, W) (None: the training size);
    max_samples: at most this many samples (0: all); warmup: batches before timing starts; lpips:
    False skips LPIPS (reported as null); device: cpu or cuda (None: cuda when available);
    rasterizer: auto | torch | gsplat (None: the training config's); num_workers: loader workers;
    progress: a bar; depth_gt / points_gt: ground-truth directories (`seeu_data.dtu_gt` layouts; None:
    what the DTU importer recorded, if anything); geometry_scale: predicted points are multiplied by
    it before Chamfer (DTU: 200 -> mm).
    """

    checkpoint: str | Path = setting(help="a ckpt-*.pt file or a directory (its newest checkpoint)")
    data: str = setting(help="evaluation triple shards (seeu build --mode eval, or interp/extrap)")
    out: str | Path | None = setting(None, "output directory (default: RUN/eval/<data name>)", metavar="OUT")
    batch_size: int = setting(1, "samples per batch")
    image_size: tuple[int, int] | None = setting(
        None, "default: the training image size", parse=parse_dims, metavar="HxW"
    )
    max_samples: int = setting(0, "evaluate at most N samples; 0: all")
    warmup: int = setting(2, "batches run before timing starts")
    lpips_weights: str | None = setting(None, "torchvision's vgg16-397923af.pth", metavar="PATH")
    lpips: bool = setting(True, "skip LPIPS (reported as null)")
    device: str | None = setting(None, "cpu or cuda (default: cuda when available)")
    rasterizer: str | None = setting(None, "auto | torch | gsplat (default: the training config's)")
    num_workers: int = setting(0, "data loader worker processes")
    progress: bool = False
    depth_gt: str | Path | None = setting(
        None, "ground-truth depth maps DIR/<scene_id>/<frame_index:06d>.npy|.pfm -> depth RMSE", metavar="DIR"
    )
    points_gt: str | Path | None = setting(
        None, "ground-truth points DIR/<scene_id>/points.npy|.ply [+ obs_mask.npz] -> DTUeval Chamfer", metavar="DIR"
    )
    geometry_scale: float = setting(1.0, "multiply predicted points by this before Chamfer (DTU: 200 -> mm)")
    max_pixels: int = MAX_PIXELS  # largest image (width x height) decoded, `--max-pixels`

    def check(self) -> None:
        check_range(self.batch_size, "--batch-size", 1, MAX_BATCH_SIZE)
        check_range(self.max_samples, "--max-samples", 0, MAX_SAMPLES)
        check_range(self.warmup, "--warmup", 0, MAX_SAMPLES)
        check_range(self.num_workers, "--num-workers", 0, MAX_WORKERS)
        for side in self.image_size or ():
            check_range(side, "--image-size", 1, MAX_IMAGE_SIDE)
        if not (math.isfinite(self.geometry_scale) and self.geometry_scale > 0):
            raise SeeUError(f"--geometry-scale must be a finite number > 0, got {self.geometry_scale}")


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
    max_pixels: int = MAX_PIXELS,
):
    """Evaluate an in-memory model on triple shards; returns `seeu_model.evaluation.EvalOutput`."""
    import sys

    import torch

    from pipelines.train import make_eval_loader
    from seeu_model.evaluation import evaluate_model
    from seeu_model.training.factory import encode_context, render_gaussians
    from seeu_model.training.loop import autocast_context

    device = torch.device(device) if device is not None else next(model.parameters()).device
    loader = make_eval_loader(data, image_hw, batch_size, num_workers, max_pixels=max_pixels)
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


@locks_output(lambda out, *_: out)
def write_results(out: Path, res, extra: dict) -> dict:
    """per_target.csv, per_scene.csv, then summary.json (last). Returns the summary document."""
    from dataclasses import asdict

    from seeu_data.store.arrow_io import atomic_write_text
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
    if "masked_fraction" in metrics:
        summary["protocol"]["kept"] = (
            "*_kept: without the masked pixels (PSNR over kept pixels; SSIM, LPIPS against the target with "
            "its masked pixels filled from the prediction, SSIM over windows centred on kept pixels)"
        )
    summary = _nan_to_none(summary)
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=2) + "\n")
    return summary


def evaluate(cfg: EvalConfig) -> dict:
    """Python API of `seeu eval`; returns the summary document (also written to OUT/summary.json)."""
    import torch

    from seeu_data.dtu_gt import posed_ground_truth
    from seeu_model.lpips_loss import LPIPS
    from seeu_model.training import checkpoint as ckpt_io
    from seeu_model.training.config import config_from_dict
    from seeu_model.training.factory import model_from_checkpoint

    cfg.check()
    ck = ckpt_io.load_checkpoint(cfg.checkpoint)
    train_cfg = config_from_dict(json.loads(json.dumps(ck["config"])))
    dev = torch.device(cfg.device or ("cuda" if torch.cuda.is_available() else "cpu"))
    model = model_from_checkpoint(ck, dev)
    lpips_fn = None
    lpips_kind = "off"
    if cfg.lpips:
        lpips_fn = LPIPS(weights=cfg.lpips_weights or train_cfg.loss.lpips_weights).to(dev)
        lpips_kind = "vgg"
    hw: tuple[int, int] = cfg.image_size or train_cfg.data.image_size
    check_image_size(model, hw)
    out = cfg.out
    if out is None:
        run_dir = Path(ck["path"]).parent.parent
        out = run_dir / "eval" / Path(str(cfg.data).rstrip("/")).name
    depth_gt: Any = cfg.depth_gt  # a directory, or the importer's loader (below)
    points_gt: Any = cfg.points_gt
    geometry_scale = cfg.geometry_scale
    geometry_note = None
    if depth_gt is None and points_gt is None:
        found = posed_ground_truth(cfg.data)
        if found is not None:  # DTU: ground truth recorded by the importer
            depth_gt, points_gt, geometry_scale = found
            geometry_note = "ground truth from the posed scenes' meta (depth RMSE in scene units, Chamfer in mm)"
    res = evaluate_on_data(
        model,
        cfg.data,
        hw,
        device=dev,
        batch_size=cfg.batch_size,
        max_samples=cfg.max_samples,
        warmup=cfg.warmup,
        lpips_fn=lpips_fn,
        rasterizer=cfg.rasterizer or train_cfg.rasterizer,
        precision=train_cfg.precision,
        num_workers=cfg.num_workers,
        progress=cfg.progress,
        depth_gt=depth_gt,
        points_gt=points_gt,
        geometry_scale=geometry_scale,
        max_pixels=cfg.max_pixels,
    )
    if not res.records:
        raise SeeUError("the evaluation data yielded no sample", cfg.data)
    extra = {
        "checkpoint": ck["path"],
        "step": ck["step"],
        "data": str(cfg.data),
        "image_hw": list(hw),
        "lpips": lpips_kind,
        "device": str(dev),
        "geometry": geometry_note,
    }
    return write_results(Path(out), res, extra)


# ------------------------------------------------------------------------------------------------
# Ground-truth geometry (the readers: seeu_data.dtu_gt)
# ------------------------------------------------------------------------------------------------


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
    from seeu_data.dtu_gt import load_depth_map
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


def make_geometry_fn(
    root_or_loader, scale: float = 1.0, min_opacity: float = 0.5, density: float = 0.2, max_dist: float = 20.0
):
    """geometry_fn for `evaluate_model`: DTUeval Chamfer between the Gaussian centres (opacity >=
    `min_opacity`, multiplied by `scale`, e.g. 200 to undo DTU's 1/200 camera scaling -> mm) and the
    ground-truth points, restricted to DTU's observation mask when there is one.

    root_or_loader: a directory (ROOT/<scene_id>/points.npy (M, 3) or points.ply, optional
    obs_mask.npz with DTU's ObsMask/BB/Res[/Plane]) or a callable scene_id ->
    `seeu_data.dtu_gt.GroundTruthPoints` or None."""
    from seeu_data.dtu_gt import GroundTruthPoints, read_points_dir
    from seeu_model.geometry_metrics import chamfer_dtueval, dtu_observation_filter

    cache: dict = {}

    def load(scene: str):
        gt: GroundTruthPoints | None = (
            root_or_loader(scene) if callable(root_or_loader) else read_points_dir(Path(root_or_loader) / scene)
        )
        if gt is None:
            return None
        mask = above = None
        if gt.observation is not None:
            o = gt.observation
            mask, above_fn = dtu_observation_filter(o.obs_mask, o.bbox, o.res, o.plane)
            above = above_fn(gt.points)
        return gt.points, mask, above

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
