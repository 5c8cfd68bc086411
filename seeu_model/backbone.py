"""Shallow ResNet to an s-fold downsampled feature map (paper §3.1.1; MVSplat's CNN, InstanceNorm).

A 7x7 stem, then one residual stage per entry of ``channels``; log2(s) of the stages (stem
included) halve the resolution. Views are processed independently (weights shared).
"""

from __future__ import annotations

import math

import torch
from torch import nn


class ResidualBlock(nn.Module):
    """Two 3x3 convolutions with InstanceNorm and a (projected) skip. (N, Cin, H, W) -> (N, Cout, H/stride, W/stride)."""

    def __init__(self, in_channels: int, out_channels: int, stride: int = 1):
        super().__init__()
        self.conv1 = nn.Conv2d(in_channels, out_channels, 3, stride=stride, padding=1, bias=False)
        self.norm1 = nn.InstanceNorm2d(out_channels, affine=True)
        self.conv2 = nn.Conv2d(out_channels, out_channels, 3, padding=1, bias=False)
        self.norm2 = nn.InstanceNorm2d(out_channels, affine=True)
        self.act = nn.ReLU(inplace=True)
        self.skip: nn.Module = nn.Identity()
        if stride != 1 or in_channels != out_channels:
            self.skip = nn.Sequential(
                nn.Conv2d(in_channels, out_channels, 1, stride=stride, bias=False),
                nn.InstanceNorm2d(out_channels, affine=True),
            )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.act(self.norm1(self.conv1(x)))
        y = self.norm2(self.conv2(y))
        return self.act(y + self.skip(x))


class ResNetBackbone(nn.Module):
    """images (B, V, 3, H, W) in [0, 1] -> features (B, V, C, H/s, W/s), C = channels[-1]."""

    mean: torch.Tensor  # (1, 3, 1, 1) buffers: the input normalisation
    std: torch.Tensor

    def __init__(self, channels: tuple[int, ...] = (64, 96, 128), downsample: int = 4):
        super().__init__()
        n_down = int(math.log2(downsample))
        if n_down > len(channels):
            raise ValueError(f"downsample {downsample} needs at least {n_down} stages, got {len(channels)}")
        # Stride 2 in the stem and in the first n_down - 1 stages after it.
        self.stem = nn.Sequential(
            nn.Conv2d(3, channels[0], 7, stride=2 if n_down >= 1 else 1, padding=3, bias=False),
            nn.InstanceNorm2d(channels[0], affine=True),
            nn.ReLU(inplace=True),
        )
        stages = []
        in_ch = channels[0]
        for i, out_ch in enumerate(channels):
            stride = 2 if 1 <= i < n_down else 1
            stages.append(nn.Sequential(ResidualBlock(in_ch, out_ch, stride), ResidualBlock(out_ch, out_ch)))
            in_ch = out_ch
        self.stages = nn.Sequential(*stages)
        self.out = nn.Conv2d(in_ch, in_ch, 1)
        self.out_channels = in_ch
        self.downsample = downsample
        # ImageNet statistics (the peers' input normalisation).
        self.register_buffer("mean", torch.tensor([0.485, 0.456, 0.406]).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor([0.229, 0.224, 0.225]).view(1, 3, 1, 1), persistent=False)

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        b, v, _, h, w = images.shape
        x = (images.reshape(b * v, 3, h, w) - self.mean) / self.std
        x = self.out(self.stages(self.stem(x)))
        return x.reshape(b, v, *x.shape[1:])
