"""MVSplat's refinement UNet (a diffusion-style 2D UNet without time embedding): post-norm residual
blocks (conv -> GroupNorm -> SiLU, twice, plus the skip), strided-conv down / nearest+conv up sampling,
and at the chosen downsampling rates a post-norm self-attention block whose tokens span every view of
a sample (cross-view attention), 32 channels per head.

Shapes: x (B*V, C_in, h, w) with the V views of each sample adjacent (b-major), V given at call time
(MVSplat fixes it when building the model; with that V both are the same) -> (B*V, C_out, h, w);
h and w divisible by 2^(levels - 1).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn


def group_norm(channels: int) -> nn.GroupNorm:
    return nn.GroupNorm(8 if channels % 8 == 0 else 4, channels)


class ResBlock(nn.Module):
    def __init__(self, cin: int, cout: int):
        super().__init__()
        self.conv1, self.norm1 = nn.Conv2d(cin, cout, 3, 1, 1), group_norm(cout)
        self.conv2, self.norm2 = nn.Conv2d(cout, cout, 3, 1, 1), group_norm(cout)
        self.skip = nn.Conv2d(cin, cout, 1) if cin != cout else None

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h = F.silu(self.norm1(self.conv1(x)))
        h = F.silu(self.norm2(self.conv2(h)))
        return (x if self.skip is None else self.skip(x)) + h


class CrossViewAttention(nn.Module):
    """Multi-head attention over all pixels of all views of a sample; post-norm residual."""

    def __init__(self, channels: int, head_channels: int = 32):
        super().__init__()
        if channels % head_channels:
            raise ValueError(f"attention needs channels divisible by {head_channels}, got {channels}")
        self.heads = channels // head_channels
        self.qkv = nn.Conv1d(channels, 3 * channels, 1)
        self.proj = nn.Conv1d(channels, channels, 1)
        self.norm = group_norm(channels)

    def forward(self, x: torch.Tensor, v: int) -> torch.Tensor:
        """x (B*V, C, h, w), v = V -> (B*V, C, h, w)."""
        n, c, h, w = x.shape
        flat = x.reshape(n, c, h * w)
        qkv = self.qkv(flat)  # (B*V, 3C, T)
        b = n // v
        t = h * w
        qkv = qkv.reshape(b, v, 3 * c, t).permute(0, 2, 1, 3).reshape(b, 3 * c, v * t)  # views joined
        # channels are grouped by head first, then (q, k, v) inside a head
        q, k, val = qkv.reshape(b * self.heads, 3 * c // self.heads, v * t).chunk(3, 1)  # (B*heads, ch, VT)
        ch = c // self.heads
        s = 1 / math.sqrt(math.sqrt(ch))
        att = torch.softmax(torch.einsum("nct,ncs->nts", q * s, k * s), -1)
        out = torch.einsum("nts,ncs->nct", att, val).reshape(b, c, v, t).permute(0, 2, 1, 3).reshape(n, c, t)
        return (flat + self.norm(self.proj(out))).reshape(n, c, h, w)


class Down(nn.Module):
    def __init__(self, c: int):
        super().__init__()
        self.conv = nn.Conv2d(c, c, 3, 2, 1)

    def forward(self, x):
        return self.conv(x)


class Up(nn.Module):
    def __init__(self, c: int):
        super().__init__()
        self.conv = nn.Conv2d(c, c, 3, 1, 1)

    def forward(self, x):
        return self.conv(F.interpolate(x, scale_factor=2, mode="nearest"))


class RefineUNet(nn.Module):
    """One residual block per level, attention where the downsampling rate is in ``attention_at``."""

    def __init__(self, channels: int, mult: tuple[int, ...], attention_at: tuple[int, ...]):
        super().__init__()
        c0 = channels
        self.enc = nn.ModuleList([nn.Sequential(nn.Conv2d(c0, c0, 3, 1, 1))])
        skips = [c0]
        ch, rate = c0, 1
        for level, m in enumerate(mult):
            layers: list[nn.Module] = [ResBlock(ch, m * c0)]
            ch = m * c0
            if rate in attention_at:
                layers.append(CrossViewAttention(ch))
            self.enc.append(nn.Sequential(*layers))
            skips.append(ch)
            if level != len(mult) - 1:
                self.enc.append(nn.Sequential(Down(ch)))
                skips.append(ch)
                rate *= 2
        self.mid = nn.Sequential(ResBlock(ch, ch), ResBlock(ch, ch))
        self.dec = nn.ModuleList()
        for level, m in list(enumerate(mult))[::-1]:
            for i in range(2):
                layers = [ResBlock(ch + skips.pop(), c0 * m)]
                ch = c0 * m
                if rate in attention_at:
                    layers.append(CrossViewAttention(ch))
                if level and i == 1:
                    layers.append(Up(ch))
                    rate //= 2
                self.dec.append(nn.Sequential(*layers))
        self.head_conv = nn.Conv2d(c0, c0, 3, 1, 1)
        self.head_norm = group_norm(c0)

    @staticmethod
    def _run(block: nn.Module, x: torch.Tensor, views: int) -> torch.Tensor:
        for layer in block.children():
            x = layer(x, views) if isinstance(layer, CrossViewAttention) else layer(x)
        return x

    def forward(self, x: torch.Tensor, views: int) -> torch.Tensor:
        """x (B*V, C, h, w), views = V -> (B*V, C, h, w)."""
        skips = []
        for block in self.enc:
            x = self._run(block, x, views)
            skips.append(x)
        x = self.mid(x)
        for block in self.dec:
            x = self._run(block, torch.cat([x, skips.pop()], 1), views)
        return F.silu(self.head_norm(self.head_conv(x)))
