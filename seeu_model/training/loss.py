"""The photometric training loss: MSE + lambda * LPIPS(VGG) over the rendered target views (paper eq. 9).

Masked target pixels (the loader's `mask`, True = excluded: moving or transient content) take no part:
MSE is the mean over the kept pixels only (per-pixel weights); for LPIPS, whose features see a
neighbourhood, the target's masked pixels are replaced by the (detached) prediction, so the two images
agree there and what the target holds under the mask cannot reach the loss or its gradient.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from seeu_model.metrics import fill_masked, psnr


@dataclass
class LossParts:
    """Scalars of one step (Python floats, this process's batch): loss, mse, lpips, psnr."""

    loss: float
    mse: float
    lpips: float
    psnr: float


def photometric_loss(
    pred: torch.Tensor,
    target: torch.Tensor,
    valid: torch.Tensor | None = None,
    lpips_fn: torch.nn.Module | None = None,
    lpips_weight: float = 0.05,
    mask: torch.Tensor | None = None,
) -> tuple[torch.Tensor, LossParts]:
    """pred, target: (B, T, 3, H, W) in [0, 1]; valid: (B,) bool (False for loader padding samples);
    mask: (B, T, H, W) bool, True = excluded pixel (module docstring), or None.

    Every term is a mean over the valid samples of this process (each sample's terms are means over
    its T targets and (kept) pixels), so DDP's gradient averaging over P processes of batch b equals one
    process of batch P*b. LPIPS is skipped entirely when `lpips_fn` is None or the weight is 0.
    """
    b = pred.shape[0]
    w = torch.ones(b, device=pred.device) if valid is None else valid.to(pred.device, torch.float32)
    denom = w.sum().clamp_min(1.0)
    pred32 = pred.float()
    if mask is None:
        per_sample_mse = (pred32 - target).pow(2).flatten(1).mean(1)  # (B,)
    else:
        keep = (~mask).unsqueeze(2).to(pred32.dtype)  # (B, T, 1, H, W)
        kept = (keep.flatten(1).sum(1) * pred.shape[2]).clamp_min(1.0)  # kept values per sample
        per_sample_mse = ((pred32 - target).pow(2) * keep).flatten(1).sum(1) / kept
        target = fill_masked(pred32.detach(), target, mask)
    mse = (per_sample_mse * w).sum() / denom
    loss = mse
    lp_value = 0.0
    if lpips_fn is not None and lpips_weight > 0:
        per_sample_lp = lpips_fn(pred32, target).flatten(1).mean(1)  # (B,)
        lp = (per_sample_lp * w).sum() / denom
        loss = loss + lpips_weight * lp
        lp_value = float(lp.detach())
    with torch.no_grad():
        p = psnr(pred32.detach(), target, mask=mask).flatten(1).mean(1)
        p_value = float((p * w).sum() / denom)
    return loss, LossParts(float(loss.detach()), float(mse.detach()), lp_value, p_value)
