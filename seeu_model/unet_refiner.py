"""2D UNet refiner: the paper's "w/ UNet Backbone" ablation (table 4), in place of the Conditional
Gaussian Transformer. It sees each view's latent grid as an image (the convolutional grid prior the
paper argues against), is conditioned through the same cross-attention interface (at its bottleneck),
and predicts a residual whose output convolution is zero-initialised (exactly 0 at initialisation).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from .attention import Attention


def _groups(ch: int) -> int:
    for g in (8, 4, 2, 1):
        if ch % g == 0:
            return g
    return 1


class ConvBlock(nn.Module):
    """(N, Cin, H, W) -> (N, Cout, H, W): two GroupNorm-SiLU-3x3 convolutions with a skip."""

    def __init__(self, cin: int, cout: int):
        super().__init__()
        self.net = nn.Sequential(
            nn.GroupNorm(_groups(cin), cin),
            nn.SiLU(),
            nn.Conv2d(cin, cout, 3, padding=1),
            nn.GroupNorm(_groups(cout), cout),
            nn.SiLU(),
            nn.Conv2d(cout, cout, 3, padding=1),
        )
        self.skip = nn.Conv2d(cin, cout, 1) if cin != cout else nn.Identity()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.skip(x) + self.net(x)


class UNetRefiner(nn.Module):
    """latent (B, V, h, w, C), condition (B, L, cond_dim) -> residual (B, V, h, w, C), 0 at init.
    h and w must be divisible by 2^(len(channels) - 1)."""

    def __init__(self, channels_in: int, cond_dim: int, channels: tuple[int, ...] = (128, 256), heads: int = 4):
        super().__init__()
        self.inp = nn.Conv2d(channels_in, channels[0], 3, padding=1)
        self.down = nn.ModuleList()
        self.pool = nn.ModuleList()
        for i, ch in enumerate(channels):
            prev = channels[max(i - 1, 0)]
            self.down.append(ConvBlock(prev, ch))
            if i < len(channels) - 1:
                self.pool.append(nn.Conv2d(ch, ch, 3, stride=2, padding=1))
        mid = channels[-1]
        self.norm_cross = nn.GroupNorm(_groups(mid), mid)
        self.cross_attn = Attention(mid, heads if mid % heads == 0 else 1, context_dim=cond_dim)
        self.up = nn.ModuleList()
        for i in range(len(channels) - 2, -1, -1):
            self.up.append(ConvBlock(channels[i + 1] + channels[i], channels[i]))
        self.out = nn.Conv2d(channels[0], channels_in, 3, padding=1)
        assert self.out.bias is not None
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)
        self.levels = len(channels)

    def forward(self, latent: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:
        b, v, h, w, c = latent.shape
        if h % 2 ** (self.levels - 1) or w % 2 ** (self.levels - 1):
            raise ValueError(f"latent grid {h}x{w} not divisible by {2 ** (self.levels - 1)}")
        x = self.inp(latent.permute(0, 1, 4, 2, 3).reshape(b * v, c, h, w))
        skips = []
        for i, block in enumerate(self.down):
            x = block(x)
            if i < self.levels - 1:
                skips.append(x)
                x = self.pool[i](x)
        n, ch, hh, ww = x.shape
        ctx = cond[:, None].expand(b, v, *cond.shape[1:]).reshape(b * v, *cond.shape[1:])
        tokens = self.norm_cross(x).flatten(2).transpose(1, 2)
        x = x + self.cross_attn(tokens, ctx).transpose(1, 2).reshape(n, ch, hh, ww)
        for block in self.up:
            skip = skips.pop()
            x = block(torch.cat([F.interpolate(x, size=skip.shape[-2:], mode="nearest"), skip], 1))
        return self.out(x).reshape(b, v, c, h, w).permute(0, 1, 3, 4, 2)
