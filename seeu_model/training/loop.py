"""The training loop: AdamW + warm-up/cosine, gradient clipping, bf16 autocast on CUDA, DDP,
atomic checkpoints with exact resume, TensorBoard logs and a tqdm progress bar.

The loop never opens files of the dataset: it gets a loader object (``seeu_data.loader.make_loader``
or anything with ``__iter__``, ``state_dict()`` and ``load_state_dict()``) from the pipeline, and a
``render_fn(model, batch) -> (B, T, 3, H, W)`` that runs the model on a loader batch and returns
the rendered target views.

Non-finite guard: a step whose loss or gradients hold NaN / inf is found before the optimizer step
(the gradient norm the clipping computes anyway; the max-norm of the gradients only when that one is not
finite), and weights that became non-finite in the optimizer step right after it (one max-norm over the
parameters). `cfg.on_nonfinite` says what follows: "stop" raises SeeUError (one line naming the step
and the batch's sample ids; nothing of that step is saved), "skip-batch" drops the batch's update and
goes on, until `MAX_CONSECUTIVE_SKIPS` batches in a row were skipped. `save_checkpoint` refuses a
non-finite tensor as well.

Resume restores model, optimizer, scheduler, step, the loader position and the RNG states of
torch / CUDA / numpy / python of every rank, so a resumed run follows the same loss curve as an
uninterrupted one (tested in tests/test_training.py).
"""

from __future__ import annotations

import contextlib
import math
import sys
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from torch import nn

from seeu_data.errors import SeeUError
from seeu_data.loader.collate import batch_to_device
from seeu_model.training import checkpoint as ckpt_io
from seeu_model.training.checkpoint import load_model_state
from seeu_model.training.config import MAX_CONSECUTIVE_SKIPS, TrainConfig, save_config
from seeu_model.training.distributed import DistInfo, all_gather_objects, max_across, mean_across
from seeu_model.training.factory import model_state_for_checkpoint
from seeu_model.training.loss import LossParts, photometric_loss
from seeu_model.training.schedule import make_scheduler

RenderFn = Callable[[nn.Module, dict], torch.Tensor]
EvalFn = Callable[[nn.Module], dict]


@dataclass
class TrainResult:
    step: int
    out_dir: str
    last_checkpoint: str | None
    history: list[dict] = field(default_factory=list)  # logged scalars (rank 0)
    val: list[dict] = field(default_factory=list)  # validation summaries (rank 0)
    seconds: float = 0.0
    steps_per_s: float = 0.0
    skipped_batches: int = 0  # batches whose update was dropped (on_nonfinite="skip-batch")


class NonFiniteStep(Exception):
    """A training step whose `what` ("loss", "gradients" or "weights") is not finite.

    step: the step it would have been (1-based); samples: the sample ids of the batch on every rank;
    applied: whether the optimizer step had already changed the weights (then it cannot be undone)."""

    def __init__(self, what: str, step: int, samples: list[str], applied: bool):
        super().__init__(f"non-finite {what} at step {step}")
        self.what, self.step, self.samples, self.applied = what, step, samples, applied


_NONFINITE_WHAT = ("", "gradients", "loss")  # codes agreed across ranks (the larger wins)


def batch_sample_ids(batch: Any, limit: int = 8) -> str:
    """The batch's sample ids (padding left out) as one short text: "a, b, c (+5 more)"."""
    ids = list(batch.get("sample_id") or []) if isinstance(batch, dict) else []
    pad = batch.get("is_padding") if isinstance(batch, dict) else None
    if pad is not None and len(pad) == len(ids):
        ids = [i for i, p in zip(ids, pad.tolist()) if not p]
    if not ids:
        return "unknown"
    more = f" (+{len(ids) - limit} more)" if len(ids) > limit else ""
    return ", ".join(str(i) for i in ids[:limit]) + more


def batch_to(batch: Any, device: torch.device) -> Any:
    """Move every tensor of a (nested) loader batch to `device`; uint8 loader images become float32 in
    [0, 1] on the device (the loader's one helper for this: `seeu_data.loader.batch_to_device`)."""
    return batch_to_device(batch, device)


def autocast_context(precision: str, device: torch.device):
    """bf16 autocast on CUDA ("auto" or "bf16"); fp32 everywhere else."""
    if device.type == "cuda" and precision in ("auto", "bf16"):
        return torch.autocast("cuda", dtype=torch.bfloat16)
    return contextlib.nullcontext()


def parameter_groups(model: nn.Module, weight_decay: float) -> list[dict]:
    """AdamW groups: decay on weight matrices/kernels, none on biases, norms and embeddings of dim < 2."""
    decay: list[nn.Parameter] = []
    no_decay: list[nn.Parameter] = []
    for _, p in model.named_parameters():
        if not p.requires_grad:
            continue
        (decay if p.dim() >= 2 else no_decay).append(p)
    return [{"params": decay, "weight_decay": weight_decay}, {"params": no_decay, "weight_decay": 0.0}]


def _finite_max(tensors: Iterable[torch.Tensor | None]) -> bool:
    """Whether every value of `tensors` is finite: one fused max-norm (NaN and inf propagate; finite
    values cannot overflow it), one host sync."""
    ts = [t for t in tensors if t is not None]
    return not ts or bool(torch.isfinite(torch.nn.utils.get_total_norm(ts, float("inf"))))


def _progress_enabled(flag: bool | None) -> bool:
    return sys.stderr.isatty() if flag is None else bool(flag)


class Trainer:
    """Owns model, optimizer, scheduler and step; `fit(loader)` trains to `cfg.optim.max_steps`.

    model: an nn.Module (moved to `dist.device`; wrapped in DDP when the world size is > 1).
    model_config: stored in checkpoints so `seeu eval` / `seeu render` can rebuild the model.
    """

    def __init__(
        self,
        model: nn.Module,
        cfg: TrainConfig,
        out_dir: str | Path,
        render_fn: RenderFn,
        dist: DistInfo | None = None,
        lpips_fn: nn.Module | None = None,
        model_config: dict | None = None,
        eval_fn: EvalFn | None = None,
    ):
        self.cfg = cfg
        self.out_dir = Path(out_dir)
        self.ckpt_dir = self.out_dir / "checkpoints"
        self.dist = dist or DistInfo()
        self.device = self.dist.device
        self.render_fn = render_fn
        self.eval_fn = eval_fn
        self.model_config = dict(model_config or {})
        self.model = model.to(self.device)
        self.lpips_fn = lpips_fn.to(self.device) if lpips_fn is not None else None
        if self.dist.enabled:
            from torch.nn.parallel import DistributedDataParallel as DDP

            self.ddp: nn.Module = DDP(
                self.model,
                device_ids=[self.device] if self.device.type == "cuda" else None,
                find_unused_parameters=True,
            )
        else:
            self.ddp = self.model
        o = cfg.optim
        fused = self.device.type == "cuda"
        self.optimizer = torch.optim.AdamW(
            parameter_groups(self.model, o.weight_decay),
            lr=o.lr,
            betas=o.betas,
            eps=o.eps,
            **({"fused": True} if fused else {}),
        )
        self.scheduler = make_scheduler(self.optimizer, o.warmup_steps, o.max_steps, o.min_lr_ratio)
        self.step = 0
        self.history: list[dict] = []
        self.val_history: list[dict] = []
        self.last_checkpoint: str | None = None
        self.skipped_batches = 0  # in the whole run (kept across resume)
        self.skipped_in_a_row = 0

    # ------------------------------------------------------------------ checkpoints
    def _payload(self, loader) -> dict:
        rngs = all_gather_objects(ckpt_io.rng_state(), self.dist)
        return {
            "config": self.cfg.to_dict(),
            "model_config": self.model_config,
            "model": model_state_for_checkpoint(self.model, self.model_config),
            "optimizer": self.optimizer.state_dict(),
            "scheduler": self.scheduler.state_dict(),
            "loader": loader.state_dict() if hasattr(loader, "state_dict") else None,
            "rng": rngs[0],
            "rng_per_rank": rngs,
            "world_size": self.dist.world_size,
            "history_tail": self.history[-20:],
            "skipped_batches": self.skipped_batches,
        }

    def save(self, loader) -> str | None:
        payload = self._payload(loader)  # collective: every rank takes part
        path = None
        if self.dist.is_main:
            path = str(ckpt_io.save_checkpoint(self.ckpt_dir, self.step, payload, self.cfg.checkpoint.keep))
            self.last_checkpoint = path
        if self.dist.enabled:
            torch.distributed.barrier()
        return path

    def resume(self, source: str | Path | dict, loader) -> int:
        """Restore everything from a checkpoint (a file, a directory of them, or a loaded dict)."""
        ck = source if isinstance(source, dict) else ckpt_io.load_checkpoint(source)
        where = ck.get("path")
        load_model_state(self.model, ck["model"], where)
        try:
            self.optimizer.load_state_dict(ck["optimizer"])
            self.scheduler.load_state_dict(ck["scheduler"])
            if ck.get("loader") is not None and hasattr(loader, "load_state_dict"):
                loader.load_state_dict(ck["loader"])
            per_rank = ck.get("rng_per_rank") or [ck["rng"]]
            ckpt_io.set_rng_state(per_rank[self.dist.rank] if len(per_rank) == self.dist.world_size else per_rank[0])
        except (KeyError, TypeError, ValueError, IndexError, RuntimeError) as exc:
            msg = str(exc).splitlines()[0][:160] if str(exc) else ""
            raise SeeUError(
                f"checkpoint optimizer/scheduler/loader/RNG state does not fit this run ({type(exc).__name__}: {msg})",
                where,
            ) from None
        self.step = int(ck["step"])
        self.history = list(ck.get("history_tail", []))
        self.skipped_batches = int(ck.get("skipped_batches", 0))
        return self.step

    # ------------------------------------------------------------------ one step
    def train_step(self, batch: dict) -> tuple[LossParts, float]:
        """One optimizer step on a loader batch; returns the loss parts and the pre-clip grad norm.

        Raises NonFiniteStep when the loss or the gradients are not finite (the update is not applied:
        gradients zeroed, no optimizer or scheduler step, `self.step` unchanged) or when the weights are
        not finite after the optimizer step (applied=True)."""
        self.ddp.train()
        ids = batch_sample_ids(batch)
        batch = batch_to(batch, self.device)
        gt = batch["target"]["image"]
        valid = ~batch["is_padding"] if "is_padding" in batch else None
        with autocast_context(self.cfg.precision, self.device):
            pred = self.render_fn(self.ddp, batch)
            loss, parts = photometric_loss(
                pred, gt, valid, self.lpips_fn, self.cfg.loss.lpips_weight, mask=batch["target"].get("mask")
            )
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        params = [p for g in self.optimizer.param_groups for p in g["params"]]
        clip = self.cfg.optim.grad_clip
        grad_norm = float(torch.nn.utils.clip_grad_norm_(params, clip if clip > 0 else float("inf")))
        code = 2 if not math.isfinite(parts.loss) else 0
        if code == 0 and not math.isfinite(grad_norm) and not _finite_max(p.grad for p in params):
            code = 1  # not just a 2-norm overflowing: a gradient holds NaN / inf
        code = max_across(code, self.dist)  # a rank's bad loss stops (or skips) every rank
        if code:
            self.optimizer.zero_grad(set_to_none=True)
            raise NonFiniteStep(_NONFINITE_WHAT[code], self.step + 1, self._gather_ids(ids), applied=False)
        self.optimizer.step()
        if not _finite_max(params):
            raise NonFiniteStep("weights", self.step + 1, self._gather_ids(ids), applied=True)
        self.scheduler.step()
        self.step += 1
        self._last_pred = pred.detach()
        self._last_gt = gt
        return parts, grad_norm

    def _gather_ids(self, ids: str) -> list[str]:
        return [i for i in all_gather_objects(ids, self.dist) if i != "unknown"] or ["unknown"]

    def _nonfinite(self, bad: NonFiniteStep, writer, bar) -> None:
        """Skip the batch of `bad` (on_nonfinite="skip-batch", weights untouched, fewer than
        MAX_CONSECUTIVE_SKIPS in a row) or raise SeeUError: one line naming the step and the samples."""
        samples = ", ".join(bad.samples)
        self.skipped_in_a_row += 1
        if self.cfg.on_nonfinite == "skip-batch" and not bad.applied and self.skipped_in_a_row < MAX_CONSECUTIVE_SKIPS:
            self.skipped_batches += 1
            if self.dist.is_main:
                line = (
                    f"train: step {bad.step}: skipped a batch with non-finite {bad.what} (samples {samples}); "
                    f"{self.skipped_batches} batch(es) skipped so far"
                )
                if bar is not None:
                    bar.write(line, file=sys.stderr)
                else:
                    print(line, file=sys.stderr, flush=True)
                if writer is not None:
                    writer.add_scalar("train/skipped_batches", self.skipped_batches, self.step)
            return
        latest = ckpt_io.latest_checkpoint(self.ckpt_dir)
        kept = f"the newest checkpoint {latest.name} is the last good one" if latest else "no checkpoint was written"
        if bad.applied:
            what = "the weights became non-finite (NaN or inf) in the optimizer step"
            hint = "lower optim.lr, keep optim.grad_clip > 0"
        else:
            what = f"non-finite {bad.what} (NaN or inf)"
            hint = "check these samples (seeu validate), lower optim.lr, or --on-nonfinite skip-batch"
        if self.cfg.on_nonfinite == "skip-batch" and not bad.applied:  # the limit of skips in a row
            what += f" in {self.skipped_in_a_row} batches in a row, the last"
            hint = "check the data (seeu validate) and optim.lr"
        raise SeeUError(
            f"step {bad.step}: {what} on the batch of samples {samples}; stopped, nothing saved from this "
            f"step ({kept}; {hint})",
            self.out_dir,
        )

    # ------------------------------------------------------------------ the loop
    def fit(
        self,
        loader,
        val_loader: Iterable | None = None,
        stop_after: int | None = None,
        resume_from: str | Path | dict | None = None,
    ) -> TrainResult:
        """Train until `cfg.optim.max_steps` (or until step `stop_after`, for a planned interruption).

        A checkpoint is written every `cfg.checkpoint.every` steps and at the end.
        """
        cfg = self.cfg
        if resume_from is not None:
            self.resume(resume_from, loader)
        target = cfg.optim.max_steps if stop_after is None else min(stop_after, cfg.optim.max_steps)
        writer = None
        if self.dist.is_main:
            self.out_dir.mkdir(parents=True, exist_ok=True)
            ckpt_io.unlink_stale_temporaries(self.ckpt_dir)
            save_config(cfg, self.out_dir / "config.json")
            from torch.utils.tensorboard import SummaryWriter

            writer = SummaryWriter(str(self.out_dir / "tb"), purge_step=self.step if self.step else None)
        bar = None
        if self.dist.is_main and _progress_enabled(cfg.log.progress):
            from tqdm import tqdm

            bar = tqdm(
                total=target,
                initial=self.step,
                desc="train",
                unit="it",
                dynamic_ncols=True,
                file=sys.stderr,
                smoothing=0.1,
            )
        t_start = time.perf_counter()
        start_step = self.step
        t_log, s_log = t_start, self.step
        try:
            empty_passes = 0
            while self.step < target:
                got_batch = False
                for batch in loader:
                    got_batch = True
                    empty_passes = 0
                    try:
                        parts, gnorm = self.train_step(batch)
                    except NonFiniteStep as bad:
                        self._nonfinite(bad, writer, bar)  # returns only when the batch is skipped
                        continue
                    self.skipped_in_a_row = 0
                    if bar is not None:
                        bar.update(1)
                        bar.set_postfix(loss=f"{parts.loss:.4f}", psnr=f"{parts.psnr:.2f}", refresh=False)
                    if self.step % cfg.log.every == 0 or self.step == target:
                        now = time.perf_counter()
                        rec = {
                            "step": self.step,
                            "loss": mean_across(parts.loss, self.dist),
                            "mse": mean_across(parts.mse, self.dist),
                            "lpips": mean_across(parts.lpips, self.dist),
                            "psnr": mean_across(parts.psnr, self.dist),
                            "grad_norm": gnorm,
                            "lr": self.scheduler.get_last_lr()[0],
                            "it_per_s": (self.step - s_log) / max(now - t_log, 1e-9),
                        }
                        t_log, s_log = now, self.step
                        self.history.append(rec)
                        if writer is not None:
                            for k, v in rec.items():
                                if k != "step":
                                    writer.add_scalar(f"train/{k}", v, self.step)
                    if writer is not None and (self.step % cfg.log.image_every == 0 or self.step == 1):
                        self._log_images(writer)
                    if self.step % cfg.checkpoint.every == 0 and self.step < target:
                        self.save(loader)
                    if (
                        (val_loader is not None or self.eval_fn is not None)
                        and cfg.log.val_every > 0
                        and self.step % cfg.log.val_every == 0
                        and self.step < target
                    ):
                        self._validate(writer)
                    if self.step >= target:
                        break
                # one empty pass is the end of an epoch (a loader resumed right after an epoch's last
                # batch); two in a row mean the data yields nothing
                empty_passes += 0 if got_batch else 1
                if empty_passes >= 2:
                    raise SeeUError(
                        "the training data yielded no batch (empty dataset, or batch larger than "
                        "the dataset with remainder='drop')",
                        self.out_dir,
                    )
            if self.eval_fn is not None:
                self._validate(writer)
            self.save(loader)
        finally:
            if bar is not None:
                bar.close()
            if writer is not None:
                writer.flush()
                writer.close()
        seconds = time.perf_counter() - t_start
        return TrainResult(
            self.step,
            str(self.out_dir),
            self.last_checkpoint,
            self.history,
            self.val_history,
            seconds,
            (self.step - start_step) / max(seconds, 1e-9),
            self.skipped_batches,
        )

    def _validate(self, writer) -> None:
        if not self.dist.is_main or self.eval_fn is None:
            return
        summary = self.eval_fn(self.model)
        summary = {"step": self.step, **summary}
        self.val_history.append(summary)
        if writer is not None:
            for k, v in summary.items():
                if k != "step" and isinstance(v, (int, float)):
                    writer.add_scalar(f"val/{k}", v, self.step)

    def _log_images(self, writer) -> None:
        """Rendered vs ground truth of the first sample: a grid with one row per target view."""
        from torchvision.utils import make_grid

        pred = self._last_pred[0].float().clamp(0, 1).cpu()  # (T, 3, H, W)
        gt = self._last_gt[0].float().cpu()
        rows = torch.stack([gt, pred], dim=1).flatten(0, 1)  # gt, pred, gt, pred, ...
        writer.add_image("train/gt_vs_render", make_grid(rows, nrow=2, padding=2), self.step)
