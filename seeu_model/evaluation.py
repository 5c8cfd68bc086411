"""Evaluation loop: per-target PSNR / SSIM / LPIPS (and optional depth metrics), encoder and renderer
timed separately after warm-up, peak memory, and the peers' aggregation (mean over the targets of a
scene, then over scenes).

Where the target views have masks (the loader's `mask`: excluded pixels, moving or transient
content), every target is also measured without its masked pixels (`seeu_model.metrics`: PSNR over
the kept pixels, SSIM and LPIPS against the target with its masked pixels filled from the prediction,
SSIM averaged over windows centred on kept pixels): `psnr_kept`, `ssim_kept`, `lpips_kept` and the
`masked_fraction` of the target. The plain metrics stay over all pixels, as the peers compute them.

The loop gets batches (the loader's layout, docs/ARCHITECTURE.md) from the pipeline and two callables:
``encode_fn(model, context) -> Gaussians`` and ``render_fn(gaussians, target) -> RenderOutput``.
"""

from __future__ import annotations

import contextlib
import math
import resource
import sys
import time
from collections import OrderedDict
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass, field

import torch
from torch import nn

from seeu_model.metrics import fill_masked, psnr, ssim

METRICS = ("psnr", "ssim", "lpips")
KEPT_METRICS = ("psnr_kept", "ssim_kept", "lpips_kept", "masked_fraction")  # only where the data has masks


@dataclass
class TargetRecord:
    """Metrics of one rendered target view."""

    scene_id: str
    sample_id: str
    target: int  # position among the sample's targets
    frame_index: int
    psnr: float
    ssim: float
    lpips: float = math.nan
    depth_rmse: float = math.nan  # only with ground-truth depth
    # without the masked pixels (module docstring); NaN where the batch has no mask (the target's own
    # may be all kept: masked_fraction 0, the kept metrics then equal the plain ones)
    psnr_kept: float = math.nan
    ssim_kept: float = math.nan
    lpips_kept: float = math.nan
    masked_fraction: float = math.nan


@dataclass
class Timing:
    """Milliseconds per sample (mean over timed batches; the first `warmup` batches are not timed)."""

    encoder_ms: float = math.nan
    renderer_ms: float = math.nan
    total_ms: float = math.nan
    timed_batches: int = 0
    warmup_batches: int = 0
    peak_memory_mb: float = math.nan
    memory_kind: str = ""  # "cuda_max_allocated" or "cpu_max_rss"
    device: str = ""


@dataclass
class EvalOutput:
    records: list[TargetRecord] = field(default_factory=list)
    timing: Timing = field(default_factory=Timing)
    renders: list[dict] = field(default_factory=list)  # kept renders (first `keep_renders` samples), CPU tensors
    geometry: list[dict] = field(default_factory=list)  # per-sample geometry metrics (geometry_fn)


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def peak_memory_mb(device: torch.device) -> tuple[float, str]:
    """CUDA: max allocated since the last reset; CPU: the process's peak resident set size."""
    if device.type == "cuda":
        return torch.cuda.max_memory_allocated(device) / 2**20, "cuda_max_allocated"
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # KiB on Linux, bytes on macOS
    return (rss / 2**20 if sys.platform == "darwin" else rss / 1024), "cpu_max_rss"


@torch.no_grad()
def evaluate_model(
    model: nn.Module,
    batches: Iterable[dict],
    device: torch.device,
    encode_fn: Callable,
    render_fn: Callable,
    lpips_fn: nn.Module | None = None,
    max_samples: int = 0,
    warmup: int = 1,
    keep_renders: int = 0,
    depth_fn: Callable | None = None,
    progress: bool = False,
    autocast=None,
    geometry_fn: Callable | None = None,
) -> EvalOutput:
    """Run the model over `batches` and measure every target view.

    depth_fn(batch, render) -> (B, T) depth RMSE or None: optional geometry metric (DTU).
    geometry_fn(batch, gaussians, k) -> dict or None: per-sample geometry (Chamfer), kept in `geometry`.
    autocast: a context-manager factory for mixed precision (None: fp32).
    """
    from seeu_model.training.loop import batch_to

    model.eval()
    out = EvalOutput()
    enc_t, ren_t = [], []
    seen = 0
    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats(device)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=max_samples or None, desc="eval", unit="sample", file=sys.stderr, dynamic_ncols=True)
    try:
        for i, batch in enumerate(batches):
            batch = batch_to(batch, device)
            ctx = autocast() if autocast is not None else contextlib.nullcontext()
            _sync(device)
            t0 = time.perf_counter()
            with ctx:
                gaussians = encode_fn(model, batch["context"])
            _sync(device)
            t1 = time.perf_counter()
            with ctx:
                render = render_fn(gaussians, batch["target"])
            _sync(device)
            t2 = time.perf_counter()
            b = batch["target"]["image"].shape[0]
            if i >= warmup:
                enc_t.append((t1 - t0) / b)
                ren_t.append((t2 - t1) / b)
            pred = render.color.float().clamp(0, 1)
            gt = batch["target"]["image"].float()
            p = psnr(pred, gt)  # (B, T)
            s = ssim(pred, gt)
            lp = lpips_fn(pred, gt) if lpips_fn is not None else None
            d = depth_fn(batch, render) if depth_fn is not None else None
            mask = batch["target"].get("mask")  # (B, T, H, W) bool or None
            if mask is not None:
                frac = mask.flatten(2).float().mean(-1)  # (B, T)
                kept = {
                    "psnr_kept": psnr(pred, gt, mask=mask),
                    "ssim_kept": ssim(pred, gt, mask=mask),
                    "lpips_kept": lpips_fn(pred, fill_masked(pred, gt, mask)) if lpips_fn is not None else None,
                }
            pad = batch.get("is_padding")
            for k in range(b):
                if pad is not None and bool(pad[k]):
                    continue
                if max_samples and seen >= max_samples:
                    break
                for j in range(pred.shape[1]):
                    record = TargetRecord(
                        batch["scene_id"][k],
                        batch["sample_id"][k],
                        j,
                        int(batch["target"]["frame_index"][k, j]),
                        float(p[k, j]),
                        float(s[k, j]),
                        float(lp[k, j]) if lp is not None else math.nan,
                        float(d[k, j]) if d is not None else math.nan,
                    )
                    if mask is not None:
                        record.masked_fraction = float(frac[k, j])
                        for name, values in kept.items():
                            if values is not None and record.masked_fraction < 1.0:
                                setattr(record, name, float(values[k, j]))
                    out.records.append(record)
                if geometry_fn is not None:
                    gm = geometry_fn(batch, gaussians, k)
                    if gm is not None:
                        out.geometry.append(
                            {"scene_id": batch["scene_id"][k], "sample_id": batch["sample_id"][k], **gm}
                        )
                if len(out.renders) < keep_renders:
                    out.renders.append(
                        {
                            "scene_id": batch["scene_id"][k],
                            "sample_id": batch["sample_id"][k],
                            "pred": pred[k].cpu(),
                            "gt": gt[k].cpu(),
                            "depth": render.depth[k].float().cpu(),
                            "context": batch["context"]["image"][k].float().cpu(),
                        }
                    )
                seen += 1
                if bar is not None:
                    bar.update(1)
            if max_samples and seen >= max_samples:
                break
    finally:
        if bar is not None:
            bar.close()
    mem, kind = peak_memory_mb(device)
    mean = lambda xs: 1000.0 * sum(xs) / len(xs) if xs else math.nan  # noqa: E731
    out.timing = Timing(
        mean(enc_t),
        mean(ren_t),
        mean([a + b for a, b in zip(enc_t, ren_t)]),
        len(enc_t),
        min(warmup, len(enc_t) + warmup),
        mem,
        kind,
        str(device),
    )
    return out


def _reported(records: list[TargetRecord]) -> tuple[str, ...]:
    """The metrics to aggregate: the kept-pixel ones too when any target was measured with a mask."""
    masked = any(not math.isnan(r.masked_fraction) for r in records)
    return (*METRICS, "depth_rmse", *(KEPT_METRICS if masked else ()))


def _value(r: TargetRecord, m: str) -> float:
    """Metric `m` of a target; a target measured without a mask (its batch had none) counts for the
    kept-pixel metrics with its plain values (masked_fraction 0)."""
    if m in KEPT_METRICS and math.isnan(r.masked_fraction):
        return 0.0 if m == "masked_fraction" else getattr(r, m.removesuffix("_kept"))
    return getattr(r, m)


def per_scene(records: list[TargetRecord]) -> OrderedDict[str, dict]:
    """scene_id -> {num_targets, psnr, ssim, lpips, depth_rmse (, KEPT_METRICS)}: means over the scene's targets."""
    groups: OrderedDict[str, list[TargetRecord]] = OrderedDict()
    for r in records:
        groups.setdefault(r.scene_id, []).append(r)
    out: OrderedDict[str, dict] = OrderedDict()
    for scene, rs in groups.items():
        row: dict[str, float] = {"num_targets": len(rs)}
        for m in _reported(records):
            vals = [v for v in (_value(r, m) for r in rs) if not math.isnan(v)]
            row[m] = sum(vals) / len(vals) if vals else math.nan
        out[scene] = row
    return out


def summarize(records: list[TargetRecord]) -> dict:
    """The peers' numbers: mean over targets within each scene, then over scenes; plus the plain
    mean over all targets (`*_all_targets`) for reference."""
    scenes = per_scene(records)
    out: dict = {
        "num_scenes": len(scenes),
        "num_samples": len({r.sample_id for r in records}),
        "num_targets": len(records),
    }
    for m in _reported(records):
        vals = [row[m] for row in scenes.values() if not math.isnan(row[m])]
        out[m] = sum(vals) / len(vals) if vals else math.nan
        flat = [v for v in (_value(r, m) for r in records) if not math.isnan(v)]
        out[f"{m}_all_targets"] = sum(flat) / len(flat) if flat else math.nan
    return out


def timing_dict(t: Timing) -> dict:
    return asdict(t)
