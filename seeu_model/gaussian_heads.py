"""Latent Gaussian parameters: their channel layout, the light coarse heads that predict them from the
matched features, and the activation that turns raw parameters on a pixel grid into `Gaussians`.

A latent Gaussian token (paper §3.2.2, Θ_l of shape (B, V, h, w, C)) holds raw parameters:

    [ depth (1) | opacity (1) | scale (3) | rotation (4) | sh (3K) | free features (F) ]

* depth: logit of the unit disparity t in (0, 1) (linear in inverse depth: t = 1 at near, 0 at far), so
  any residual keeps the depth inside [near, far];
* opacity: logit; scale: logit of the position inside [scale_min, scale_max] pixel footprints;
* rotation: an unnormalised quaternion (w, x, y, z); sh: K = (degree + 1)^2 coefficients per colour
  channel, channel-minor (k, rgb) as in `Gaussians.sh`; the DC term starts at the image colour;
* free features: F channels of latent state that the refiner and the decoder may use.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from seeu_data.cameras import unproject_pixels

from .cost_volume import depth_from_unit_disparity, pixel_centres, unit_disparity_from_depth
from .gaussians import Gaussians

SH_C0 = 0.28209479177387814  # Y_0^0: colour = 0.5 + SH_C0 * sh_dc (the 3DGS convention)


def rgb_to_sh_dc(rgb: torch.Tensor) -> torch.Tensor:
    """Colour in [0, 1] -> the degree-0 SH coefficient that renders it."""
    return (rgb - 0.5) / SH_C0


@dataclass(frozen=True)
class LatentLayout:
    """Channel slices of a latent Gaussian token."""

    sh_coeffs: int
    features: int

    @property
    def params(self) -> int:
        """Number of raw Gaussian parameter channels (everything but the free features)."""
        return 1 + 1 + 3 + 4 + 3 * self.sh_coeffs

    @property
    def channels(self) -> int:
        return self.params + self.features

    depth = slice(0, 1)
    opacity = slice(1, 2)
    scale = slice(2, 5)
    rotation = slice(5, 9)

    @property
    def sh(self) -> slice:
        return slice(9, 9 + 3 * self.sh_coeffs)

    @property
    def sh_dc(self) -> slice:
        """The three DC channels (k = 0, rgb) inside the sh block."""
        return slice(9, 12)

    @property
    def feature(self) -> slice:
        return slice(self.params, self.channels)


class CoarseGaussianHead(nn.Module):
    """Light heads on the matched features (paper §3.1.2: "other Gaussian parameters are predicted by
    additional lightweight heads from feature maps").

    features (B, V, C, h, w), posterior (B, V, D, h, w), depth (B, V, h, w), images_lowres (B, V, 3, h, w),
    near/far (B, V)  ->  latent tokens (B, V, h, w, layout.channels)
    The depth channel is the matched depth itself (no learned change); the rest is predicted.
    """

    def __init__(
        self, feature_dim: int, num_depths: int, layout: LatentLayout, hidden: int, initial_scale: float = 0.0
    ):
        super().__init__()
        self.layout = layout
        out = layout.channels - 1
        self.net = nn.Sequential(
            nn.Conv2d(feature_dim + num_depths + 3, hidden, 3, padding=1),
            nn.GELU(),
            nn.Conv2d(hidden, hidden, 3, padding=1),
            nn.GELU(),
            nn.Conv2d(hidden, out, 1),
        )
        last = self.net[-1]
        assert isinstance(last, nn.Conv2d) and last.bias is not None
        with torch.no_grad():  # identity rotations (bias w = 1) and scales near `initial_scale` (raw units)
            last.bias.zero_()
            last.bias[layout.rotation.start - 1] = 1.0
            last.bias[layout.scale.start - 1 : layout.scale.stop - 1] = initial_scale

    def forward(self, features, posterior, depth, images_lowres, near, far) -> torch.Tensor:
        b, v, c, h, w = features.shape
        lay = self.layout
        x = torch.cat([features, posterior.to(features.dtype), images_lowres.to(features.dtype)], 2)
        # Latent tokens are kept in float32 (also under autocast): the depth logit needs the precision.
        raw = self.net(x.reshape(b * v, -1, h, w)).reshape(b, v, -1, h, w).float()
        t = unit_disparity_from_depth(depth.float(), near.float(), far.float()).clamp(1e-4, 1 - 1e-4)
        depth_raw = torch.logit(t)[:, :, None]
        latent = torch.cat([depth_raw, raw], 2)  # (B, V, C_l, h, w)
        dc = torch.zeros_like(latent)
        dc[:, :, lay.sh_dc] = rgb_to_sh_dc(images_lowres.float())
        latent = latent + dc
        return latent.permute(0, 1, 3, 4, 2)


def gaussians_from_params(
    params: torch.Tensor,
    cam_to_world: torch.Tensor,
    intrinsics: torch.Tensor,
    near: torch.Tensor,
    far: torch.Tensor,
    layout: LatentLayout,
    scale_min: float,
    scale_max: float,
) -> tuple[Gaussians, torch.Tensor]:
    """Raw parameters on a pixel grid -> world-space Gaussians, one per pixel, view-major.

    params (B, V, P, H', W') with P >= layout.params, cam_to_world (B, V, 4, 4), intrinsics (B, V, 3, 3)
    normalised, near/far (B, V)  ->  (Gaussians with N = V*H'*W', depth (B, V, H', W')).
    Centres are the pixel centres unprojected at the depth; scales are in pixel footprints
    (depth / focal length in pixels) of this grid.
    """
    b, v, _, hh, ww = params.shape
    lay = layout
    p = params.float()
    depth = depth_from_unit_disparity(torch.sigmoid(p[:, :, lay.depth.start]), near.float(), far.float())  # (B,V,H',W')
    uv = pixel_centres(hh, ww, params.device)[None, None].expand(b, v, hh * ww, 2)
    means = unproject_pixels(uv, depth.reshape(b, v, -1), cam_to_world.float(), intrinsics.float(), ww, hh)
    footprint = 0.5 * (1.0 / (intrinsics[..., 0, 0].float() * ww) + 1.0 / (intrinsics[..., 1, 1].float() * hh))
    scale_unit = scale_min + (scale_max - scale_min) * torch.sigmoid(p[:, :, lay.scale])  # (B,V,3,H',W')
    scales = scale_unit * (depth[:, :, None] * footprint[..., None, None, None])
    rot = p[:, :, lay.rotation]
    rot = rot / rot.norm(dim=2, keepdim=True).clamp_min(1e-8)
    opac = torch.sigmoid(p[:, :, lay.opacity.start])
    sh = p[:, :, lay.sh].reshape(b, v, lay.sh_coeffs, 3, hh, ww)

    def flat(x: torch.Tensor, tail: tuple[int, ...]) -> torch.Tensor:  # (B, V, *tail, H', W') -> (B, V*H'*W', *tail)
        nd = len(tail)
        perm = (0, 1, 2 + nd, 3 + nd) + tuple(range(2, 2 + nd))
        return x.permute(*perm).reshape(b, v * hh * ww, *tail)

    gaussians = Gaussians(
        means=means.reshape(b, v * hh * ww, 3),
        scales=flat(scales, (3,)),
        rotations=flat(rot, (4,)),
        opacities=opac.reshape(b, v * hh * ww),
        sh=flat(sh, (lay.sh_coeffs, 3)),
    )
    return gaussians, depth
