"""Train SeeU on triple shards (single process, or many with torchrun).

Examples:
  seeu train --data data/re10k/train --val data/re10k/test --config configs/re10k_paper.json --out runs/re10k
  seeu train --data out/shards/interp --config configs/cpu_small.json --out runs/cpu optim.max_steps=200
  seeu train --data ... --config ... --out runs/re10k --resume          # continue from the newest checkpoint
  seeu train --data ... --config configs/re10k_paper.json --out runs/ft --init-from runs/mvsplat/checkpoints
  torchrun --nproc_per_node=8 -m pipelines.cli train --data ... --config configs/re10k_paper.json --out runs/ddp
  (multi-node: torchrun --nnodes=N --node_rank=R --rdzv_endpoint=HOST:PORT --nproc_per_node=G -m pipelines.cli train ...)

Overrides are `section.key=value` after the options (optim.lr=1e-4 data.batch_size=4 model.refiner=unet
loss.lpips_weight=0). Writes OUT/config.json, OUT/checkpoints/ckpt-*.pt (atomic, last K kept),
OUT/tb (TensorBoard: losses, PSNR, lr, rendered vs ground-truth images, validation), OUT/train_summary.json
and OUT/cache (the loader's shard verification stamps and object-storage downloads; $SEEU_CACHE_DIR instead when set).
LPIPS(VGG) needs torchvision's vgg16-397923af.pth in $TORCH_HOME/hub/checkpoints or --lpips-weights PATH;
--no-lpips trains with MSE only.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any, Callable, Sequence


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--data", required=True, help="training triple shards (directory or object-storage URL)")
    parser.add_argument("--val", default=None, help="validation triple shards (evaluated every log.val_every steps)")
    parser.add_argument(
        "--config",
        default=None,
        help="config file, or a shipped preset by name: re10k_paper, cpu_small, cpu_tiny, demo (configs/*.json)",
    )
    parser.add_argument("--out", required=True, help="run directory (checkpoints, TensorBoard, config)")
    parser.add_argument(
        "--resume",
        nargs="?",
        const=True,
        default=None,
        metavar="CKPT",
        help="continue from the newest checkpoint in OUT (or from CKPT)",
    )
    parser.add_argument(
        "--init-from",
        default=None,
        metavar="CKPT",
        help="start from the weights (and model config) of a SeeU checkpoint, e.g. one written by "
        "`seeu convert-checkpoint mvsplat`; step, optimizer and schedule start afresh",
    )
    parser.add_argument("--lpips-weights", default=None, metavar="PATH", help="torchvision's vgg16-397923af.pth")
    parser.add_argument("--no-lpips", action="store_true", help="train with MSE only (loss.lpips_weight=0)")
    parser.add_argument("--device", default=None, help="cpu, cuda, cuda:1 (default: this rank's GPU, else CPU)")
    parser.add_argument("--max-steps", type=int, default=None, help="shortcut for optim.max_steps=N")
    parser.add_argument(
        "--progress", action=argparse.BooleanOptionalAction, default=None, help="progress bar (default: on a terminal)"
    )
    parser.add_argument("overrides", nargs="*", metavar="KEY=VALUE", help="config overrides, e.g. optim.lr=1e-4")


def run(args: argparse.Namespace) -> int:
    overrides = list(args.overrides)
    if args.max_steps is not None:
        overrides.append(f"optim.max_steps={args.max_steps}")
    result = train(
        args.data,
        args.out,
        config=args.config,
        overrides=overrides,
        val=args.val,
        resume=args.resume,
        lpips_weights=args.lpips_weights,
        no_lpips=args.no_lpips,
        device=args.device,
        progress=args.progress,
        init_from=args.init_from,
    )
    if result.get("rank", 0) == 0:
        print(json.dumps({k: result[k] for k in ("step", "checkpoint", "steps_per_s", "final")}, indent=2))
    return 0


def seed_everything(seed: int) -> None:
    import random

    import numpy as np
    import torch

    random.seed(seed)
    np.random.seed(seed % 2**32)
    torch.manual_seed(seed)


def make_train_loader(data: str, cfg, dist, cache_dir: str | None = None) -> Any:
    """`cache_dir`: shard verification stamps and object-storage downloads (None: $SEEU_CACHE_DIR)."""
    from seeu_data.loader import make_loader

    return make_loader(
        data,
        cfg.data.batch_size,
        num_workers=cfg.data.num_workers,
        rank=dist.rank,
        world_size=dist.world_size,
        seed=cfg.data.seed,
        image_hw=tuple(cfg.data.image_size),
        flip_p=0.5 if cfg.data.flip else 0.0,
        pin_memory=dist.device.type == "cuda",
        cache_dir=cache_dir,
    )


def make_eval_loader(data: str, image_hw, batch_size: int, num_workers: int = 0, cache_dir: str | None = None) -> Any:
    """Every sample once, in manifest order, on this process alone (no flip, padded last batch)."""
    from seeu_data.loader import make_loader

    return make_loader(
        data,
        batch_size,
        num_workers=num_workers,
        rank=0,
        world_size=1,
        seed=0,
        image_hw=tuple(image_hw),
        flip_p=0.0,
        shuffle=False,
        remainder="pad",
        cache_dir=cache_dir,
    )


def run_cache_dir(out: Path) -> str | None:
    """The loader cache of a run: $SEEU_CACHE_DIR/loader when set (shared), else OUT/cache."""
    import os

    return None if os.environ.get("SEEU_CACHE_DIR") else str(Path(out) / "cache")


def make_lpips(cfg, lpips_weights: str | None = None):
    """The frozen LPIPS(VGG) module of the config, or None when LPIPS is off."""
    if cfg.loss.lpips_weight <= 0:
        return None
    from seeu_model.lpips_loss import LPIPS

    return LPIPS(weights=lpips_weights or cfg.loss.lpips_weights, random_trunk=cfg.loss.lpips_random_trunk)


def train(
    data: str,
    out: str | Path,
    config: str | Path | None = None,
    overrides: Sequence[str] = (),
    val: str | None = None,
    resume: bool | str | None = None,
    lpips_weights: str | None = None,
    no_lpips: bool = False,
    device: str | None = None,
    progress: bool | None = None,
    stop_after: int | None = None,
    model_factory: Callable | None = None,
    init_from: str | Path | None = None,
) -> dict:
    """Train and return a summary dict: step, checkpoint, steps_per_s, final (last logged scalars), history, val.

    Python API of `seeu train` (used by `seeu demo` and `seeu ablate`). `stop_after`: stop (with a
    checkpoint) at that step although the schedule runs to optim.max_steps, as an interrupted run
    would. `model_factory(model_section) -> (module, model_config_dict)` replaces the SeeU model (tests).
    `init_from`: a SeeU checkpoint whose model section (``model.*`` overrides still apply) and weights the
    run starts from; ignored when the run resumes from its own checkpoint.
    """
    import torch

    from seeu_data.arrow_io import atomic_write_text
    from seeu_data.errors import SeeUError
    from seeu_model.training import checkpoint as ckpt_io
    from seeu_model.training.config import config_from_dict, load_config, apply_overrides
    from seeu_model.training.distributed import cleanup_distributed, setup_distributed
    from seeu_model.training.factory import build_model, encode_context, make_render_fn, render_gaussians
    from seeu_model.training.loop import Trainer, autocast_context

    out = Path(out)
    overrides = list(overrides)
    if no_lpips:
        overrides.append("loss.lpips_weight=0")
    resume_ckpt = None
    if resume:
        location = out / "checkpoints" if resume is True else Path(resume)
        if resume is True and ckpt_io.latest_checkpoint(location) is None:
            resume_ckpt = None  # nothing to resume: start from scratch (a re-run of a run that never saved)
        else:
            resume_ckpt = ckpt_io.load_checkpoint(location)
    elif ckpt_io.latest_checkpoint(out / "checkpoints") is not None:
        raise SeeUError(
            "the run directory already has checkpoints: pass --resume to continue, or choose another --out", out
        )
    if config is None and resume_ckpt is not None:
        cfg = config_from_dict(apply_overrides(_strip_none(resume_ckpt["config"]), overrides))
    else:
        cfg = load_config(config, overrides)
    if progress is not None:
        cfg.log.progress = progress
    init_ckpt = None
    if init_from is not None and resume_ckpt is None:
        init_ckpt = ckpt_io.load_checkpoint(init_from)
        model_overrides = [o for o in overrides if o.strip().startswith("model.")]
        section = apply_overrides({"model": _strip_none(init_ckpt["config"]["model"])}, model_overrides)["model"]
        cfg.model = section

    dist = setup_distributed(device)
    try:
        if dist.device.type == "cuda" and cfg.precision == "bf16" and not torch.cuda.is_bf16_supported():
            raise SeeUError("precision=bf16 but this GPU does not support bfloat16 (use precision=fp32)")
        lpips_fn = make_lpips(cfg, lpips_weights)  # fail early: missing VGG weights, bad data
        loader = make_train_loader(data, cfg, dist, run_cache_dir(out))
        seed_everything(cfg.seed)
        factory = model_factory or build_model
        model, model_cfg = factory(cfg.model)
        if init_ckpt is not None:
            _load_init_state(model, init_ckpt)
        seed_everything(cfg.seed + 1000 * dist.rank)

        eval_fn = None
        if val is not None and dist.is_main:
            from seeu_model.evaluation import evaluate_model, summarize

            def eval_fn(m):  # noqa: F811 - closure over the validation data
                vl = make_eval_loader(val, cfg.data.image_size, cfg.data.val_batch_size, cache_dir=run_cache_dir(out))
                res = evaluate_model(
                    m,
                    vl,
                    dist.device,
                    encode_context,
                    lambda g, t: render_gaussians(g, t, cfg.rasterizer),
                    lpips_fn=lpips_fn,
                    max_samples=cfg.data.val_max_samples,
                    warmup=0,
                    autocast=lambda: autocast_context(cfg.precision, dist.device),
                )
                s = summarize(res.records)
                return {k: s[k] for k in ("psnr", "ssim", "lpips", "num_targets") if not _isnan(s[k])}

        trainer = Trainer(model, cfg, out, make_render_fn(cfg.rasterizer), dist, lpips_fn, model_cfg, eval_fn)
        result = trainer.fit(loader, stop_after=stop_after, resume_from=resume_ckpt)
        summary = {
            "rank": dist.rank,
            "step": result.step,
            "checkpoint": result.last_checkpoint,
            "steps_per_s": result.steps_per_s,
            "seconds": result.seconds,
            "final": result.history[-1] if result.history else {},
            "history": result.history,
            "val": result.val,
            "world_size": dist.world_size,
            "device": str(dist.device),
        }
        if dist.is_main:
            atomic_write_text(out / "train_summary.json", json.dumps(summary, indent=2) + "\n")
        return summary
    finally:
        cleanup_distributed(dist)


def _load_init_state(model, ckpt: dict) -> None:
    """Load `ckpt`'s weights into a new run's model. Only a refiner (and its condition encoder) may be
    absent from the checkpoint: they keep their initialisation (the refiner's residual starts at zero, so
    step 0 renders what the checkpoint's model renders)."""
    from seeu_data.errors import SeeUError

    missing, unexpected = model.load_state_dict(ckpt["model"], strict=False)
    frozen = {n for n, p in model.named_parameters() if not p.requires_grad}
    missing = [k for k in missing if k not in frozen and not k.startswith(("refiner.", "condition."))]
    if missing or unexpected:
        raise SeeUError(
            f"--init-from: checkpoint does not match the model (missing {missing[:3]}, unexpected "
            f"{list(unexpected)[:3]})",
            ckpt.get("path"),
        )


def _strip_none(d: dict) -> dict:
    return json.loads(json.dumps(d))


def _isnan(x) -> bool:
    return isinstance(x, float) and math.isnan(x)
