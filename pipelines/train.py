"""The training stage: SeeU (or any model of the config) on triple shards, one process or many (torchrun).

`train(TrainRunConfig(data=..., out=...))` loads the config (a file or a shipped preset by name,
then `section.key=value` overrides), streams the shards through the resumable loader and writes
OUT/config.json, OUT/checkpoints/ckpt-*.pt (atomic, last K kept), OUT/tb (TensorBoard),
OUT/train_summary.json and OUT/cache (the loader's verification stamps and downloads;
$SEEU_CACHE_DIR instead when set). `seeu train --help` lists the flags; each is a field here.

Example:
    from pipelines.train import TrainRunConfig, train

    summary = train(TrainRunConfig(data="out/shards/interp", out="runs/cpu", config="cpu_small",
                                   overrides=("optim.max_steps=200",), lpips=False))
    summary["checkpoint"], summary["final"]["psnr"]
"""

from __future__ import annotations

import json
import math
import os
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from seeu_data.errors import SeeUError
from seeu_data.limits import MAX_PIXELS, MAX_STEPS, check_range
from seeu_data.settings import setting
from seeu_data.store.out_lock import locks_output
from seeu_model.training.config import MAX_CONSECUTIVE_SKIPS, NONFINITE_POLICIES, TrainConfig


@dataclass(frozen=True, kw_only=True)
class TrainRunConfig:
    """One training run; each field declared with `setting` is a flag of `seeu train` (the training
    hyper-parameters are the config file's, changed by the `overrides`).

    data / val: training and validation triple shards (directories or object-storage URLs); out: the
    run directory; config: a config file or a preset name (None: the defaults, or the resumed
    checkpoint's config); overrides: `section.key=value` strings; max_steps: shortcut for
    `optim.max_steps`; resume: True (the newest checkpoint in OUT/checkpoints, none: start afresh) or
    a checkpoint file; init_from: a SeeU checkpoint whose model section (`model.*` overrides still
    apply) and weights the run starts from (ignored when resuming); lpips: False trains with MSE only
    (`loss.lpips_weight=0`); lpips_weights: torchvision's vgg16-397923af.pth; device: cpu, cuda,
    cuda:1 (None: this rank's GPU, else CPU); progress: a bar (None: the config's `log.progress`);
    on_nonfinite: shortcut for the config's `on_nonfinite` ("stop" or "skip-batch"; None: the config's).
    keep_effective_batch: keep the config's effective batch (data.batch_size x optim.accumulate, a preset
    being written for one device) on any number of processes (`seeu_model.training.effective_batch`).
    rank_timeout_s: the distributed watchdog's wait (`training.distributed.Watchdog`).
    stop_after: stop (with a checkpoint) at that step although the schedule runs on, as an interrupted
    run would; model_factory(model_section) -> (module, model_config_dict) replaces the SeeU model (tests).
    """

    data: str = setting(help="training triple shards (directory or object-storage URL)")
    val: str | None = setting(None, "validation triple shards (evaluated every log.val_every steps)")
    config: str | Path | None = setting(
        None, "config file, or a shipped preset by name: re10k_paper, cpu_small, cpu_tiny, demo (configs/*.json)"
    )
    out: str | Path
    resume: bool | str | Path | None = setting(
        None, "continue from the newest checkpoint in OUT (or from CKPT)", const=True, metavar="CKPT"
    )
    init_from: str | Path | None = setting(
        None,
        "start from the weights (and model config) of a SeeU checkpoint, e.g. one written by "
        "`seeu convert-checkpoint mvsplat`; step, optimizer and schedule start afresh",
        metavar="CKPT",
    )
    lpips_weights: str | None = setting(None, "torchvision's vgg16-397923af.pth", metavar="PATH")
    lpips: bool = setting(True, "train with MSE only (loss.lpips_weight=0)")
    device: str | None = setting(None, "cpu, cuda, cuda:1 (default: this rank's GPU, else CPU)")
    max_steps: int | None = setting(None, "shortcut for optim.max_steps=N")
    on_nonfinite: str | None = setting(
        None,
        "a step whose loss, gradients or weights hold NaN/inf: stop = exit 2 naming the step and the "
        "batch's samples, the last good checkpoint stays the newest; skip-batch = drop that batch's update "
        f"and go on ({MAX_CONSECUTIVE_SKIPS} such batches in a row stop the run as well; weights that went "
        f"non-finite always stop). Default: the config's on_nonfinite ({TrainConfig.on_nonfinite})",
        choices=NONFINITE_POLICIES,
    )
    keep_effective_batch: bool = setting(
        False,
        "keep the config's effective batch (data.batch_size x optim.accumulate, as for one device) and so the "
        "meaning of its learning rate on any number of processes: the per-process batch and the gradient "
        "accumulation steps are chosen to give it (otherwise the effective batch grows with the process count)",
    )
    rank_timeout_s: float = setting(
        300.0,
        "with several ranks: a rank whose heartbeat stops this long (frozen, stopped, cut off) ends the run on "
        "every rank with one line naming it",
        flag="--rank-timeout",
        metavar="SECONDS",
    )
    progress: bool | None = None
    overrides: tuple[str, ...] = setting(
        (), "config overrides, e.g. optim.lr=1e-4", positional=True, many=True, optional=True, metavar="KEY=VALUE"
    )
    stop_after: int | None = None
    model_factory: Callable | None = None

    def check(self) -> None:
        if self.stop_after is not None:
            check_range(self.stop_after, "stop_after", 1, MAX_STEPS)
        if self.max_steps is not None:
            check_range(self.max_steps, "--max-steps", 1, MAX_STEPS)
        if not (math.isfinite(self.rank_timeout_s) and self.rank_timeout_s >= 1):
            raise SeeUError(f"--rank-timeout must be a number of seconds >= 1, got {self.rank_timeout_s}")
        resume = self.resume
        if resume is not None and not isinstance(resume, (bool, str, Path)):
            raise SeeUError(f"resume must be True or a checkpoint path, got {resume!r}")
        if isinstance(resume, str) and re.fullmatch(r"[+-]?\d+", resume.strip()) and not Path(resume).exists():
            raise SeeUError(
                f"--resume takes a checkpoint file or directory (or nothing: the newest in OUT/checkpoints), "
                f"not a step number: {resume!r}"
            )
        if isinstance(self.overrides, str):
            raise SeeUError("overrides must be a sequence of key=value strings, not one string")

    def all_overrides(self) -> list[str]:
        """`overrides` with the shortcuts (`max_steps`, `lpips=False`, `on_nonfinite`) appended."""
        out = list(self.overrides)
        if self.max_steps is not None:
            out.append(f"optim.max_steps={self.max_steps}")
        if not self.lpips:
            out.append("loss.lpips_weight=0")
        if self.on_nonfinite is not None:
            out.append(f"on_nonfinite={self.on_nonfinite}")
        return out


def seed_everything(seed: int) -> None:
    import random

    import numpy as np
    import torch

    random.seed(seed)
    np.random.seed(seed % 2**32)
    torch.manual_seed(seed)


def make_train_loader(data: str, cfg, dist, cache_dir: str | None = None, batch_size: int | None = None) -> Any:
    """`cache_dir`: shard verification stamps and object-storage downloads (None: $SEEU_CACHE_DIR);
    `batch_size`: per process (None: the config's `data.batch_size`)."""
    from seeu_data.loader import make_loader

    return make_loader(
        data,
        batch_size or cfg.data.batch_size,
        num_workers=cfg.data.num_workers,
        rank=dist.rank,
        world_size=dist.world_size,
        seed=cfg.data.seed,
        image_hw=tuple(cfg.data.image_size),
        flip_p=0.5 if cfg.data.flip else 0.0,
        pin_memory=dist.device.type == "cuda",
        cache_dir=cache_dir,
        max_pixels=cfg.data.max_pixels,
    )


def make_eval_loader(
    data: str,
    image_hw,
    batch_size: int,
    num_workers: int = 0,
    cache_dir: str | None = None,
    max_pixels: int = MAX_PIXELS,
) -> Any:
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
        max_pixels=max_pixels,
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


@locks_output(lambda run: run.out if os.environ.get("RANK", "0") == "0" else None)  # rank 0 holds it
def train(run: TrainRunConfig) -> dict:
    """Train; returns a summary dict: rank, step, checkpoint, steps_per_s, seconds, final (last logged
    scalars), history, val, world_size, effective_batch, device (also OUT/train_summary.json from rank 0).

    The Python API of `seeu train` (used by `seeu demo` and `seeu ablate`).
    """
    import torch

    from seeu_data.store.arrow_io import atomic_write_text
    from seeu_model.training import checkpoint as ckpt_io
    from seeu_model.training.config import apply_overrides, config_from_dict, load_config
    from seeu_model.training.distributed import Watchdog, barrier, cleanup_distributed, setup_distributed
    from seeu_model.training.effective_batch import plan_batches
    from seeu_model.training.factory import build_model, encode_context, make_render_fn, render_gaussians
    from seeu_model.training.loop import Trainer, autocast_context

    run.check()
    out = Path(run.out)
    overrides = run.all_overrides()
    resume, config, init_from = run.resume, run.config, run.init_from
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
    if run.progress is not None:
        cfg.log.progress = run.progress
    init_ckpt = None
    if init_from is not None and resume_ckpt is None:
        init_ckpt = ckpt_io.load_checkpoint(init_from)
        model_overrides = [o for o in overrides if o.strip().startswith("model.")]
        section = apply_overrides({"model": _strip_none(init_ckpt["config"]["model"])}, model_overrides)["model"]
        cfg.model = section

    dist = setup_distributed(run.device)
    # every rank's heartbeat from the moment the group is joined (see training/distributed.py)
    watchdog = Watchdog(dist, run.rank_timeout_s).start() if dist.enabled and "MASTER_PORT" in os.environ else None
    try:
        if dist.device.type == "cuda" and cfg.precision == "bf16" and not torch.cuda.is_bf16_supported():
            raise SeeUError("precision=bf16 but this GPU does not support bfloat16 (use precision=fp32)")
        batches = plan_batches(cfg.data.batch_size, cfg.optim.accumulate, dist.world_size, run.keep_effective_batch)
        lpips_fn = make_lpips(cfg, run.lpips_weights)  # fail early: missing VGG weights, bad data
        loader = make_train_loader(run.data, cfg, dist, run_cache_dir(out), batches.per_device)
        seed_everything(cfg.seed)
        factory = run.model_factory or build_model
        model, model_cfg = factory(cfg.model)
        if init_ckpt is not None:
            _load_init_state(model, init_ckpt)
        seed_everything(cfg.seed + 1000 * dist.rank)

        eval_fn = None
        val = run.val
        if val is not None and dist.is_main:
            from seeu_model.evaluation import evaluate_model, summarize

            def eval_fn(m):  # noqa: F811 - closure over the validation data
                vl = make_eval_loader(
                    val,
                    cfg.data.image_size,
                    cfg.data.val_batch_size,
                    cache_dir=run_cache_dir(out),
                    max_pixels=cfg.data.max_pixels,
                )
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

        trainer = Trainer(
            model, cfg, out, make_render_fn(cfg.rasterizer), dist, lpips_fn, model_cfg, eval_fn, batches=batches
        )
        try:
            result = trainer.fit(loader, stop_after=run.stop_after, resume_from=resume_ckpt)
        except RuntimeError as exc:  # a collective failed: a peer that died is named, not an internal error
            dead = watchdog.dead_peer() if watchdog is not None else None
            if dead is None:
                raise
            _peer_died(dead, exc, dist)
        summary = {
            "rank": dist.rank,
            "step": result.step,
            "checkpoint": result.last_checkpoint,
            "steps_per_s": result.steps_per_s,
            "seconds": result.seconds,
            "final": result.history[-1] if result.history else {},
            "history": result.history,
            "val": result.val,
            "skipped_batches": result.skipped_batches,
            "world_size": dist.world_size,
            "effective_batch": batches.to_dict(),
            "device": str(dist.device),
        }
        if dist.is_main:
            atomic_write_text(out / "train_summary.json", json.dumps(summary, indent=2) + "\n")
        if watchdog is not None:  # every rank's heartbeats end before rank 0 closes the store with the group
            watchdog.stop()
            barrier(dist)
        return summary
    finally:
        if watchdog is not None:
            watchdog.stop()
        cleanup_distributed(dist)


def _peer_died(rank: int, exc: BaseException, dist) -> None:
    """End this rank after rank `rank` died: the lowest surviving rank says so in one line (exit 2), the
    others exit 2 quietly."""
    if dist.rank != min(r for r in range(dist.world_size) if r != rank):
        raise SystemExit(2)
    what = str(exc).strip().splitlines()[0][:160] if str(exc).strip() else type(exc).__name__
    raise SeeUError(f"rank {rank} died: the collective with it failed ({what}); resume with --resume") from None


def _load_init_state(model, ckpt: dict) -> None:
    """Load `ckpt`'s weights into a new run's model. Only a refiner (and its condition encoder) may be
    absent from the checkpoint: they keep their initialisation (the refiner's residual starts at zero, so
    step 0 renders what the checkpoint's model renders). Every tensor must be finite and of the model's
    shape (`checkpoint.check_tensors`)."""
    from seeu_model.training.checkpoint import check_tensors

    check_tensors(ckpt["model"], ckpt.get("path"), model.state_dict(), prefix="model")
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
