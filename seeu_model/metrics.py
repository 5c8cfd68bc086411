"""Image metrics as the peers compute them (pixelSplat / MVSplat evaluation protocol).

* PSNR: images clipped to [0, 1], per-image MSE, ``-10 log10(MSE)``; callers average over targets,
  then over scenes.
* SSIM: scikit-image's ``structural_similarity(win_size=11, gaussian_weights=True, sigma=1.5,
  data_range=1.0, channel_axis=...)`` re-implemented in torch, *including* the sample-covariance
  correction ``N / (N - 1)`` (N = 121) that scikit-image applies by default and the peers keep.
  Only the "valid" region (5 px from each border) is averaged, exactly as scikit-image crops it, so
  the border mode of the filter does not matter.
* LPIPS: see `seeu_model.lpips_loss`.

All functions take images ``(..., 3, H, W)`` in [0, 1] and return one value per image ``(...)``.

Masks (``(..., H, W)`` bool, True = excluded pixel: moving or transient content) leave pixels out:
PSNR averages the squared error over the kept pixels; SSIM and LPIPS, whose windows and features see
a neighbourhood, compare the prediction with the target whose masked pixels are replaced by the
prediction (`fill_masked`), so nothing under the mask counts; SSIM then averages its map over the
windows centred on kept pixels, LPIPS (`seeu_model.lpips_loss`) over the whole image as usual.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

SSIM_WIN_SIZE = 11
SSIM_SIGMA = 1.5
SSIM_K1 = 0.01
SSIM_K2 = 0.03


def psnr(
    pred: torch.Tensor, target: torch.Tensor, eps: float = 1e-10, mask: torch.Tensor | None = None
) -> torch.Tensor:
    """Per-image PSNR in dB. pred, target: ``(..., C, H, W)`` -> ``(...)``. Inputs are clipped to [0, 1].
    mask: ``(..., H, W)`` bool, True = excluded pixel: the MSE is the mean over the kept pixels only
    (an image with none kept gets MSE 0, i.e. the `eps` bound)."""
    if pred.shape != target.shape:
        raise ValueError(f"psnr: shape mismatch {tuple(pred.shape)} vs {tuple(target.shape)}")
    err = (pred.clamp(0, 1) - target.clamp(0, 1)).pow(2)
    if mask is None:
        mse = err.flatten(-3).mean(-1)
    else:
        keep = (~mask).unsqueeze(-3).to(err.dtype)
        mse = (err * keep).flatten(-3).sum(-1) / (keep.flatten(-3).sum(-1) * err.shape[-3]).clamp_min(1.0)
    return -10.0 * torch.log10(mse.clamp_min(eps))


def fill_masked(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """`target` ``(..., C, H, W)`` with its masked pixels (mask ``(..., H, W)`` True) taken from `pred`."""
    return torch.where(mask.unsqueeze(-3), pred, target)


def gaussian_window_1d(
    win_size: int = SSIM_WIN_SIZE, sigma: float = SSIM_SIGMA, dtype: torch.dtype = torch.float64, device=None
) -> torch.Tensor:
    """Normalised 1-D Gaussian taps ``(win_size,)``, as scipy.ndimage.gaussian_filter1d builds them."""
    radius = win_size // 2
    x = torch.arange(-radius, radius + 1, dtype=torch.float64)
    w = torch.exp(-0.5 * (x / sigma) ** 2)
    return (w / w.sum()).to(dtype=dtype, device=device)


def _filter_valid(x: torch.Tensor, taps: torch.Tensor) -> torch.Tensor:
    """Separable Gaussian filter, 'valid' region only. x: ``(N, C, H, W)`` -> ``(N, C, H-k+1, W-k+1)``."""
    c = x.shape[1]
    k = taps.numel()
    wy = taps.view(1, 1, k, 1).expand(c, 1, k, 1)
    wx = taps.view(1, 1, 1, k).expand(c, 1, 1, k)
    return F.conv2d(F.conv2d(x, wy, groups=c), wx, groups=c)


def ssim(
    pred: torch.Tensor,
    target: torch.Tensor,
    data_range: float = 1.0,
    win_size: int = SSIM_WIN_SIZE,
    sigma: float = SSIM_SIGMA,
    use_sample_covariance: bool = True,
    clip: bool = True,
    mask: torch.Tensor | None = None,
) -> torch.Tensor:
    """Per-image SSIM matching scikit-image's Gaussian-window SSIM (mean over channels and valid pixels).

    pred, target: ``(..., C, H, W)`` -> ``(...)``. Computed in float64 for parity with scikit-image.
    mask: ``(..., H, W)`` bool, True = excluded pixel: SSIM of `pred` and `fill_masked(pred, target,
    mask)`, averaged over the windows centred on kept pixels (NaN for an image with none).
    """
    if mask is not None:
        target = fill_masked(pred, target, mask)
    if pred.shape != target.shape:
        raise ValueError(f"ssim: shape mismatch {tuple(pred.shape)} vs {tuple(target.shape)}")
    if min(pred.shape[-2:]) < win_size:
        raise ValueError(f"ssim: image {tuple(pred.shape[-2:])} smaller than the {win_size}-pixel window")
    lead = pred.shape[:-3]
    c, h, w = pred.shape[-3:]
    x = pred.reshape(-1, c, h, w).double()
    y = target.reshape(-1, c, h, w).double()
    if clip:
        x, y = x.clamp(0, 1), y.clamp(0, 1)
    taps = gaussian_window_1d(win_size, sigma, dtype=x.dtype, device=x.device)
    n_px = win_size * win_size
    cov_norm = n_px / (n_px - 1) if use_sample_covariance else 1.0
    # One grouped conv over the five moment maps.
    stack = torch.cat([x, y, x * x, y * y, x * y], dim=1)
    ux, uy, uxx, uyy, uxy = _filter_valid(stack, taps).split(c, dim=1)
    vx = cov_norm * (uxx - ux * ux)
    vy = cov_norm * (uyy - uy * uy)
    vxy = cov_norm * (uxy - ux * uy)
    c1 = (SSIM_K1 * data_range) ** 2
    c2 = (SSIM_K2 * data_range) ** 2
    s = ((2 * ux * uy + c1) * (2 * vxy + c2)) / ((ux * ux + uy * uy + c1) * (vx + vy + c2))
    if mask is None:
        return s.flatten(1).mean(-1).to(pred.dtype).reshape(lead)
    r = win_size // 2  # the valid region's window centres
    keep = (~mask.reshape(-1, 1, h, w))[..., r : h - r, r : w - r].expand_as(s).to(s.dtype)
    return ((s * keep).flatten(1).sum(-1) / keep.flatten(1).sum(-1)).to(pred.dtype).reshape(lead)


def mse_to_psnr(mse: float) -> float:
    """Closed form, for logging: ``-10 log10(mse)``."""
    return -10.0 * math.log10(max(mse, 1e-10))
