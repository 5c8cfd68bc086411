"""Dense reference rasterizer: every Gaussian against every pixel, plain autograd.

Slow (O(pixels x Gaussians)) and only meant as the ground truth for the tiled backend and for
tiny renders. The compositing rules are the ones documented in `projection.py`: Gaussians sorted
front to back by camera z, `alpha = min(alpha_max, o exp(-power))`, alpha < 1/255 skipped, and a
pixel stops before the Gaussian that would bring its transmittance to <= 1e-4.
"""

from __future__ import annotations

import torch
from torch.utils.checkpoint import checkpoint

from seeu_model.rasterizer.projection import ALPHA_MAX, ALPHA_MIN, T_MIN, Projected


def _pixel_centres(width: int, height: int, dtype, device) -> torch.Tensor:
    """(H * W, 2) pixel centres (j + 0.5, i + 0.5), row-major."""
    ys, xs = torch.meshgrid(
        torch.arange(height, dtype=dtype, device=device) + 0.5,
        torch.arange(width, dtype=dtype, device=device) + 0.5,
        indexing="ij",
    )
    return torch.stack([xs.reshape(-1), ys.reshape(-1)], -1)


def composite_dense(
    pix: torch.Tensor,
    means2d: torch.Tensor,
    conics: torch.Tensor,
    opacities: torch.Tensor,
    feats: torch.Tensor,
    alpha_max: float = ALPHA_MAX,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Composite depth-sorted Gaussians at pixels.

    pix (P, 2); means2d (C, N, 2), conics (C, N, 3), opacities (C, N), feats (C, N, F), all sorted
    front to back along N. Returns accumulated features (C, P, F) and alpha (C, P).
    """
    dx = pix[None, :, None, 0] - means2d[:, None, :, 0]  # (C, P, N)
    dy = pix[None, :, None, 1] - means2d[:, None, :, 1]
    a, b, c = (conics[:, None, :, i] for i in range(3))
    power = 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy
    alpha = torch.clamp(opacities[:, None, :] * torch.exp(-power), max=alpha_max)
    alpha = torch.where((power >= 0) & (alpha >= ALPHA_MIN), alpha, torch.zeros_like(alpha))
    with torch.no_grad():
        keep = torch.cumprod(1.0 - alpha, dim=-1) > T_MIN
    alpha = torch.where(keep, alpha, torch.zeros_like(alpha))
    trans = torch.cumprod(1.0 - alpha, dim=-1)
    trans_before = torch.cat([torch.ones_like(trans[..., :1]), trans[..., :-1]], -1)
    weights = alpha * trans_before  # (C, P, N)
    return weights @ feats, weights.sum(-1)


def render_dense(
    proj: Projected, width: int, height: int, alpha_max: float = ALPHA_MAX, max_elements: int = 1 << 24
) -> tuple[torch.Tensor, torch.Tensor]:
    """Render projected Gaussians densely.

    Returns features (C, H, W, 4) = (r, g, b, sum w z) and alpha (C, H, W). Pixels are processed in
    chunks of at most `max_elements` (pixel, Gaussian) pairs per camera; with gradients on, each chunk
    is checkpointed so memory stays bounded (the backward pass recomputes it).
    """
    order = torch.sort(
        torch.where(proj.valid, proj.depths, torch.full_like(proj.depths, float("inf"))), dim=-1, stable=True
    ).indices  # (C, N)
    take = lambda t: torch.gather(t, 1, order.view(*order.shape, *([1] * (t.dim() - 2))).expand_as(t))  # noqa: E731
    means2d, conics, opac = take(proj.means2d), take(proj.conics), take(proj.opacities)
    feats = torch.cat([take(proj.colors), take(proj.depths)[..., None]], -1)  # (C, N, 4)
    pix = _pixel_centres(width, height, means2d.dtype, means2d.device)
    n_cam, n = opac.shape
    chunk = max(1, max_elements // max(1, n * n_cam))
    outs, alphas = [], []
    grad = torch.is_grad_enabled() and any(t.requires_grad for t in (means2d, conics, opac, feats))
    for start in range(0, pix.shape[0], chunk):
        p = pix[start : start + chunk]
        if grad and chunk < pix.shape[0]:
            o, a = checkpoint(composite_dense, p, means2d, conics, opac, feats, alpha_max, use_reentrant=False)
        else:
            o, a = composite_dense(p, means2d, conics, opac, feats, alpha_max)
        outs.append(o)
        alphas.append(a)
    out = torch.cat(outs, 1).reshape(n_cam, height, width, feats.shape[-1])
    return out, torch.cat(alphas, 1).reshape(n_cam, height, width)
