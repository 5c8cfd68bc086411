"""gsplat (CUDA) backend: one batched `gsplat.rasterization` call for all scenes and views.

gsplat >= 1.5 takes leading batch dimensions (older 1.x: one call per scene): means (B, N, 3),
quats wxyz (B, N, 4), linear scales, opacities in [0, 1], SH coefficients (B, N, K, 3) with
`sh_degree`, world-to-camera `viewmats` (B, V, 4, 4), pixel `Ks` (B, V, 3, 3),
`render_mode="RGB+ED"` (last channel = sum w z / sum w), backgrounds (B, V, 3), `eps2d=0.3`,
`rasterize_mode` "classic" or "antialiased". It cannot run on CPU; the PyPI wheel compiles its
kernels on the first GPU call (minutes).
"""

from __future__ import annotations

import importlib.util

import torch

from seeu_data.cameras import intrinsics_pixels, world_to_cam_from_cam_to_world
from seeu_data.errors import SeeUError
from seeu_model.gaussians import Gaussians

INSTALL_HINT = "install the CUDA extra: pip install 'seeu[cuda]'"


def gsplat_installed() -> bool:
    return importlib.util.find_spec("gsplat") is not None


def gsplat_usable(device: torch.device) -> bool:
    """True when gsplat is installed, CUDA is available and the tensors live on a CUDA device."""
    return gsplat_installed() and torch.cuda.is_available() and device.type == "cuda"


def check_gsplat(device: torch.device) -> None:
    """Raise a one-line SeeUError saying why backend="gsplat" cannot run here."""
    if not torch.cuda.is_available():
        raise SeeUError(
            'rasterizer backend "gsplat" needs a CUDA GPU and none is available; use backend="torch" (or "auto") on CPU'
        )
    if not gsplat_installed():
        raise SeeUError(f'rasterizer backend "gsplat" needs the gsplat package, which is not installed; {INSTALL_HINT}')
    if device.type != "cuda":
        raise SeeUError(
            f'rasterizer backend "gsplat" needs the Gaussians on a CUDA device, got {device}; '
            'move them with .to("cuda") or use backend="torch"'
        )


def render_gsplat(
    gaussians: Gaussians,
    cam_to_world: torch.Tensor,
    intrinsics: torch.Tensor,
    width: int,
    height: int,
    background: torch.Tensor,
    near_plane: float,
    far_plane: float,
    antialiased: bool,
    tile_size: int,
    eps2d: float,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Render with gsplat. Shapes as `rasterize`; background (B, V, 3).

    Returns colour (B, V, H, W, 3) with the background composited, expected depth (B, V, H, W, 1)
    (alpha-normalised) and alpha (B, V, H, W, 1).
    """
    check_gsplat(gaussians.means.device)
    import gsplat  # noqa: PLC0415 - optional CUDA dependency

    dtype = torch.float32  # gsplat's kernels are float32
    args = dict(
        means=gaussians.means.to(dtype),
        quats=gaussians.rotations.to(dtype),
        scales=gaussians.scales.to(dtype),
        opacities=gaussians.opacities.to(dtype),
        colors=gaussians.sh.to(dtype),
        viewmats=world_to_cam_from_cam_to_world(cam_to_world.to(dtype)),
        Ks=intrinsics_pixels(intrinsics.to(dtype), width, height),
        backgrounds=background.to(dtype),
    )
    common = dict(
        width=width,
        height=height,
        near_plane=near_plane,
        far_plane=far_plane,
        eps2d=eps2d,
        sh_degree=gaussians.sh_degree,
        packed=False,
        tile_size=tile_size,
        render_mode="RGB+ED",
        rasterize_mode="antialiased" if antialiased else "classic",
    )
    if gsplat_supports_batch():
        colors, alphas, _meta = gsplat.rasterization(**{k: v.contiguous() for k, v in args.items()}, **common)
    else:  # gsplat 1.4: one scene (all its views) per call
        outs = [
            gsplat.rasterization(**{k: v[i].contiguous() for k, v in args.items()}, **common)
            for i in range(gaussians.means.shape[0])
        ]
        colors, alphas = torch.stack([o[0] for o in outs]), torch.stack([o[1] for o in outs])
    return colors[..., :3], colors[..., 3:4], alphas


def gsplat_supports_batch() -> bool:
    """gsplat >= 1.5 accepts leading batch dimensions (scenes) in `rasterization`."""
    import gsplat  # noqa: PLC0415

    parts = []
    for piece in str(getattr(gsplat, "__version__", "0")).split(".")[:2]:
        digits = "".join(ch for ch in piece if ch.isdigit())
        parts.append(int(digits or 0))
    return tuple(parts) >= (1, 5)
