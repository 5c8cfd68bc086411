"""Differentiable Gaussian rasterization: one function, three backends.

* ``"torch"`` - pure-PyTorch tiled rasterizer (`tiled.py`), CPU or CUDA, exact gradients.
* ``"gsplat"`` - gsplat's CUDA kernels (`gsplat_backend.py`); needs a CUDA GPU and the `cuda` extra.
* ``"dense"`` - every Gaussian against every pixel (`dense.py`); the reference, small renders only.
* ``"auto"`` - gsplat when the Gaussians are on a CUDA device and gsplat is installed, else torch.

All backends share the formula: EWA projection with the 0.3 px^2 low-pass, Gaussians sorted front
to back by camera z, `alpha = min(alpha_max, o exp(-power))`, alpha < 1/255 skipped, a pixel stops
before the Gaussian that would bring its transmittance to <= 1e-4. Colour from SH is
`clamp_min(0.5 + SH(d), 0)` with d from the camera centre to the mean.

Outputs: colour `C + (1 - A) * background`; depth is the **alpha-normalised expected camera z**
`sum_i w_i z_i / max(A, 1e-10)` (gsplat's "ED"; 0 where nothing was hit), alpha `A = sum_i w_i`.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from seeu_model.gaussians import Gaussians
from seeu_model.rasterizer.gsplat_backend import check_gsplat, gsplat_usable, render_gsplat
from seeu_model.rasterizer.projection import ALPHA_MAX, EPS2D, project_gaussians

BACKENDS = ("auto", "torch", "gsplat", "dense")
TORCH_TILE_SIZE = 4  # default tile edge of the torch backend


@dataclass
class RenderOutput:
    """color (B, V, 3, H, W) with background, depth (B, V, 1, H, W) expected z, alpha (B, V, 1, H, W)."""

    color: torch.Tensor
    depth: torch.Tensor
    alpha: torch.Tensor


def resolve_backend(backend: str, device: torch.device) -> str:
    """The backend that `rasterize(..., backend=backend)` uses for tensors on `device`."""
    if backend not in BACKENDS:
        raise ValueError(f"unknown rasterizer backend {backend!r}; choose one of {', '.join(BACKENDS)}")
    if backend == "auto":
        return "gsplat" if gsplat_usable(device) else "torch"
    if backend == "gsplat":
        check_gsplat(device)
    return backend


def _background(background, b: int, v: int, dtype, device) -> torch.Tensor:
    if background is None:
        return torch.zeros(b, v, 3, dtype=dtype, device=device)
    bg = torch.as_tensor(background, dtype=dtype, device=device)
    if bg.shape == (3,):
        return bg.expand(b, v, 3)
    if bg.shape == (b, 3):
        return bg[:, None].expand(b, v, 3)
    if bg.shape == (b, v, 3):
        return bg
    raise ValueError(f"background must be (3,), (B, 3) or (B, V, 3) with B={b}, V={v}; got {tuple(bg.shape)}")


def rasterize(
    gaussians: Gaussians,
    cam_to_world: torch.Tensor,
    intrinsics: torch.Tensor,
    width: int,
    height: int,
    background: torch.Tensor | None = None,
    backend: str = "auto",
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    antialiased: bool = False,
    tile_size: int | None = None,
    alpha_max: float = ALPHA_MAX,
    eps2d: float = EPS2D,
    max_elements: int = 1 << 22,
) -> RenderOutput:
    """Render Gaussians (B, N, ...) into cameras `cam_to_world` (B, V, 4, 4) (OpenCV axes) with
    normalised `intrinsics` (B, V, 3, 3) at `width` x `height`.

    background: (3,), (B, 3) or (B, V, 3) colour behind the Gaussians (default black).
    antialiased: Mip-Splatting opacity compensation (gsplat's rasterize_mode="antialiased").
    alpha_max: per-Gaussian alpha clamp, 0.99 as in 3DGS (torch/dense only: gsplat's kernel is
        fixed at 0.999; the backends agree exactly while opacities stay below 0.99).
    tile_size: tile edge in pixels; default 16 for gsplat (the only size it tests) and 4 for the torch
        backend (smaller tiles waste fewer (pixel, Gaussian) pairs; 3x faster than 16 on CPU).
    max_elements: (pixel, Gaussian) pairs processed at once by the torch/dense backends (memory bound).
    Returns `RenderOutput` (see module docstring for the depth definition). Runs in float64 when the
    Gaussians are float64, else float32 (half inputs are upcast and autocast is disabled inside).
    """
    with torch.autocast(device_type=gaussians.means.device.type, enabled=False):  # positions need float32+
        return _rasterize(
            gaussians.map(_at_least_float32),
            cam_to_world,
            intrinsics,
            width,
            height,
            background,
            backend,
            near_plane,
            far_plane,
            antialiased,
            tile_size,
            alpha_max,
            eps2d,
            max_elements,
        )


def _at_least_float32(t: torch.Tensor) -> torch.Tensor:
    return t.float() if t.dtype in (torch.float16, torch.bfloat16) else t


def _rasterize(
    gaussians,
    cam_to_world,
    intrinsics,
    width,
    height,
    background,
    backend,
    near_plane,
    far_plane,
    antialiased,
    tile_size,
    alpha_max,
    eps2d,
    max_elements,
) -> RenderOutput:
    means = gaussians.means
    b, n = means.shape[:2]
    v = cam_to_world.shape[1] if cam_to_world.dim() == 4 else -1
    if cam_to_world.shape != (b, v, 4, 4) or intrinsics.shape != (b, v, 3, 3):
        raise ValueError(
            f"cam_to_world must be (B, V, 4, 4) and intrinsics (B, V, 3, 3) with B={b}; got "
            f"{tuple(cam_to_world.shape)} and {tuple(intrinsics.shape)}"
        )
    if width <= 0 or height <= 0:
        raise ValueError(f"image size must be positive, got {width}x{height}")
    name = resolve_backend(backend, means.device)
    bg = _background(background, b, v, means.dtype, means.device)

    if name == "gsplat":
        color, depth, alpha = render_gsplat(
            gaussians,
            cam_to_world,
            intrinsics,
            width,
            height,
            bg,
            near_plane,
            far_plane,
            antialiased,
            tile_size or 16,
            eps2d,
        )
        to_chw = lambda t: t.permute(0, 1, 4, 2, 3)  # noqa: E731
        return RenderOutput(to_chw(color), to_chw(depth), to_chw(alpha))

    proj = project_gaussians(
        gaussians, cam_to_world, intrinsics, width, height, near_plane, far_plane, eps2d=eps2d, antialiased=antialiased
    )
    if name == "dense":
        from seeu_model.rasterizer.dense import render_dense

        feats, alpha = render_dense(proj, width, height, alpha_max=alpha_max, max_elements=max_elements)
    else:
        from seeu_model.rasterizer.tiled import render_tiled

        feats, alpha = render_tiled(
            proj, width, height, tile_size=tile_size or TORCH_TILE_SIZE, alpha_max=alpha_max, max_elements=max_elements
        )
    feats = feats.reshape(b, v, height, width, feats.shape[-1])
    alpha = alpha.reshape(b, v, height, width)
    color = feats[..., :3] + (1.0 - alpha)[..., None] * bg[:, :, None, None, :]
    depth = feats[..., 3] / alpha.clamp_min(1e-10)
    return RenderOutput(color=color.permute(0, 1, 4, 2, 3), depth=depth[:, :, None], alpha=alpha[:, :, None])


__all__ = ["BACKENDS", "RenderOutput", "rasterize", "resolve_backend"]
