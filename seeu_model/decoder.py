"""Upsampling decoder (paper §3, "Gaussian decoding"): latent Gaussian tokens on the h x w grid ->
one Gaussian per input pixel (N = V*H*W).

The raw parameters are upsampled bilinearly and corrected by a small convolutional network that sees
the upsampled latent tokens and the full-resolution image; the SH DC term additionally receives the
image's own high frequencies (its colour minus its s-fold average, upsampled), so fine texture is
carried by the Gaussians from the start. Views are decoded independently (weights shared).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from .gaussian_heads import LatentLayout, gaussians_from_params, rgb_to_sh_dc
from .gaussians import Gaussians


class UpsamplingDecoder(nn.Module):
    """latent (B, V, h, w, C_l), images (B, V, 3, H, W), cameras, near/far (B, V)
    -> (Gaussians with N = V*H*W, depth (B, V, H, W))."""

    def __init__(self, layout: LatentLayout, hidden: int, scale_min: float, scale_max: float):
        super().__init__()
        self.layout = layout
        self.scale_min, self.scale_max = scale_min, scale_max
        self.latent_in = nn.Conv2d(layout.channels, hidden, 3, padding=1)
        self.image_in = nn.Sequential(
            nn.Conv2d(3, hidden, 3, padding=1), nn.GELU(), nn.Conv2d(hidden, hidden, 3, padding=1)
        )
        self.fuse = nn.Sequential(
            nn.GELU(), nn.Conv2d(hidden, hidden, 3, padding=1), nn.GELU(), nn.Conv2d(hidden, layout.params, 1)
        )
        last = self.fuse[-1]
        assert isinstance(last, nn.Conv2d) and last.bias is not None
        with torch.no_grad():  # start as plain upsampling; the network learns its corrections
            last.weight.mul_(0.1)
            last.bias.zero_()

    def forward(self, latent, images, cam_to_world, intrinsics, near, far) -> tuple[Gaussians, torch.Tensor]:
        b, v, h, w, c = latent.shape
        hh, ww = images.shape[-2:]
        lay = self.layout
        x = latent.permute(0, 1, 4, 2, 3).reshape(b * v, c, h, w)
        img = images.reshape(b * v, 3, hh, ww).to(x.dtype)
        up = F.interpolate(x[:, : lay.params], size=(hh, ww), mode="bilinear", align_corners=False)
        ctx = F.interpolate(self.latent_in(x), size=(hh, ww), mode="bilinear", align_corners=False)
        delta = self.fuse(ctx + self.image_in(img))
        # Image high frequencies into the DC term: colour minus its s-fold average, as SH.
        low = F.interpolate(F.adaptive_avg_pool2d(img, (h, w)), size=(hh, ww), mode="bilinear", align_corners=False)
        detail = torch.zeros_like(up)
        detail[:, lay.sh_dc] = rgb_to_sh_dc(img) - rgb_to_sh_dc(low)
        params = (up + delta + detail).reshape(b, v, lay.params, hh, ww)
        return gaussians_from_params(params, cam_to_world, intrinsics, near, far, lay, self.scale_min, self.scale_max)
