"""MVSplat's feature extractor: ImageNet normalisation, a 7x7 stem and three residual stages to H/4
(instance norm without affine parameters), a 1x1 projection, sine positions per attention window, and
the multi-view transformer (self-attention, then cross-attention to the other views with a feed-forward
layer; 2x2 windows, odd layers shifted by half a window, Swin style).

Shapes: images (B, V, 3, H, W) in [0, 1] -> transformer features and CNN features, both (B, V, C, H/4, W/4).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


class _Residual(nn.Module):
    def __init__(self, cin: int, cout: int, stride: int):
        super().__init__()
        self.conv1 = nn.Conv2d(cin, cout, 3, stride, 1, bias=False)
        self.conv2 = nn.Conv2d(cout, cout, 3, 1, 1, bias=False)
        self.shortcut = nn.Conv2d(cin, cout, 1, stride) if (stride != 1 or cin != cout) else None

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = F.relu(F.instance_norm(self.conv1(x)))
        y = F.relu(F.instance_norm(self.conv2(y)))
        if self.shortcut is not None:
            x = F.instance_norm(self.shortcut(x))
        return F.relu(x + y)


class MVSplatCNN(nn.Module):
    """(N, 3, H, W) normalised -> (N, C, H/4, W/4)."""

    def __init__(self, channels: tuple[int, int, int], out_dim: int):
        super().__init__()
        c0, c1, c2 = channels
        self.stem = nn.Conv2d(3, c0, 7, 2, 3, bias=False)  # H/2
        self.stages = nn.ModuleList(
            [
                nn.Sequential(_Residual(c0, c0, 1), _Residual(c0, c0, 1)),  # H/2
                nn.Sequential(_Residual(c0, c1, 2), _Residual(c1, c1, 1)),  # H/4
                nn.Sequential(_Residual(c1, c2, 1), _Residual(c2, c2, 1)),  # H/4
            ]
        )
        self.proj = nn.Conv2d(c2, out_dim, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = F.relu(F.instance_norm(self.stem(x)))
        for stage in self.stages:
            x = stage(x)
        return self.proj(x)


def window_sine_positions(h: int, w: int, channels: int, device=None) -> torch.Tensor:
    """Sine/cosine positions of a (h, w) window, normalised to (0, 2 pi], y half then x half -> (channels, h, w)."""
    half = channels // 2
    eps, scale = 1e-6, 2 * math.pi
    ys = torch.arange(1, h + 1, dtype=torch.float32, device=device)
    xs = torch.arange(1, w + 1, dtype=torch.float32, device=device)
    ys = ys / (float(h) + eps) * scale
    xs = xs / (float(w) + eps) * scale
    freq = 10000 ** (2 * (torch.arange(half, dtype=torch.float32, device=device) // 2) / half)

    def encode(t: torch.Tensor) -> torch.Tensor:  # (n,) -> (n, half): sin on even, cos on odd channels
        a = t[:, None] / freq
        return torch.stack([a[:, 0::2].sin(), a[:, 1::2].cos()], -1).flatten(1)

    py = encode(ys)[:, None, :].expand(h, w, half)
    px = encode(xs)[None, :, :].expand(h, w, half)
    return torch.cat([py, px], -1).permute(2, 0, 1)


def to_windows(x: torch.Tensor, k: int) -> torch.Tensor:
    """(N, H, W, C) -> (N*k*k, H/k, W/k, C), windows row-major inside each sample."""
    n, h, w, c = x.shape
    return x.reshape(n, k, h // k, k, w // k, c).permute(0, 1, 3, 2, 4, 5).reshape(n * k * k, h // k, w // k, c)


def from_windows(x: torch.Tensor, k: int) -> torch.Tensor:
    """Inverse of `to_windows`."""
    nk, hh, ww, c = x.shape
    n = nk // (k * k)
    return x.reshape(n, k, k, hh, ww, c).permute(0, 1, 3, 2, 4, 5).reshape(n, k * hh, k * ww, c)


def shifted_window_bias(h: int, w: int, k: int, device=None) -> torch.Tensor:
    """Additive attention bias of the shifted windows: 0 inside one region of the rolled map, -100 across
    regions -> (k*k, L, L), L = (h/k)(w/k)."""
    wh, ww = h // k, w // k
    sh, sw = wh // 2, ww // 2
    label = torch.zeros(1, h, w, 1, device=device)
    n = 0
    for hs in (slice(0, -wh), slice(-wh, -sh), slice(-sh, None)):
        for ws in (slice(0, -ww), slice(-ww, -sw), slice(-sw, None)):
            label[:, hs, ws, :] = n
            n += 1
    win = to_windows(label, k).reshape(k * k, wh * ww)
    diff = win[:, None, :] - win[:, :, None]
    return torch.where(diff != 0, torch.full_like(diff, -100.0), torch.zeros_like(diff))


class _AttentionLayer(nn.Module):
    """Single-head windowed attention; with ``ffn`` the message goes through an MLP on [x, message]."""

    def __init__(self, dim: int, ffn_ratio: int, ffn: bool):
        super().__init__()
        self.q = nn.Linear(dim, dim, bias=False)
        self.k = nn.Linear(dim, dim, bias=False)
        self.v = nn.Linear(dim, dim, bias=False)
        self.out = nn.Linear(dim, dim, bias=False)
        self.norm = nn.LayerNorm(dim)
        self.ffn = None
        if ffn:
            self.ffn = nn.Sequential(
                nn.Linear(2 * dim, 2 * dim * ffn_ratio, bias=False),
                nn.GELU(),
                nn.Linear(2 * dim * ffn_ratio, dim, bias=False),
            )
            self.ffn_norm = nn.LayerNorm(dim)

    def forward(self, x: torch.Tensor, others: torch.Tensor, k: int, shift: bool, bias: torch.Tensor | None):
        """x (N, H, W, C) queries; others (N, M, H, W, C) keys/values (M views) -> (N, H, W, C)."""
        n, h, w, c = x.shape
        m = others.shape[1]
        q, kk, vv = self.q(x), self.k(others), self.v(others)
        sh, sw = (h // k) // 2, (w // k) // 2
        if shift:
            q = torch.roll(q, (-sh, -sw), (1, 2))
            kk = torch.roll(kk, (-sh, -sw), (2, 3))
            vv = torch.roll(vv, (-sh, -sw), (2, 3))
        qw = to_windows(q, k).reshape(n * k * k, -1, c)  # (N', L, C)
        # keys of all other views in the same window: token-major, view-minor (L*M)
        kw = to_windows(kk.permute(0, 2, 3, 1, 4).reshape(n, h, w, m * c), k).reshape(n * k * k, -1, m, c)
        vw = to_windows(vv.permute(0, 2, 3, 1, 4).reshape(n, h, w, m * c), k).reshape(n * k * k, -1, m, c)
        kw, vw = kw.reshape(n * k * k, -1, c), vw.reshape(n * k * k, -1, c)
        scores = q_k = qw @ kw.transpose(1, 2) / (c**0.5)  # (N', L, L*M)
        if shift and bias is not None:
            # the window bias is tiled view-major over the keys (as in MVSplat), whatever their order
            q_k = scores + bias.repeat(n, 1, m)
        msg = torch.softmax(q_k, -1) @ vw  # (N', L, C)
        msg = from_windows(msg.reshape(n * k * k, h // k, w // k, c), k)
        if shift:
            msg = torch.roll(msg, (sh, sw), (1, 2))
        msg = self.norm(self.out(msg))
        if self.ffn is not None:
            msg = self.ffn_norm(self.ffn(torch.cat([x, msg], -1)))
        return x + msg


class MVSplatTransformer(nn.Module):
    """Layers of [self-attention, cross-attention + FFN]; odd layers use shifted windows."""

    def __init__(self, dim: int, layers: int, ffn_ratio: int, windows: int):
        super().__init__()
        self.windows = windows
        self.self_attn = nn.ModuleList([_AttentionLayer(dim, ffn_ratio, ffn=False) for _ in range(layers)])
        self.cross_attn = nn.ModuleList([_AttentionLayer(dim, ffn_ratio, ffn=True) for _ in range(layers)])

    def forward(self, feats: torch.Tensor) -> torch.Tensor:
        """feats (B, V, C, h, w) with positions added -> (B, V, C, h, w)."""
        b, v, c, h, w = feats.shape
        k = self.windows
        bias = shifted_window_bias(h, w, k, feats.device) if k > 1 else None
        x = feats.permute(1, 0, 3, 4, 2)  # (V, B, h, w, C)
        for i, (sa, ca) in enumerate(zip(self.self_attn, self.cross_attn)):
            shift = k > 1 and i % 2 == 1
            others = torch.stack([torch.stack([x[j] for j in range(v) if j != t], 1) for t in range(v)])
            others = others.reshape(v * b, v - 1, h, w, c)  # (V*B, V-1, h, w, C), other views in order
            y = x.reshape(v * b, h, w, c)
            y = sa(y, y[:, None], k, shift, bias)
            y = ca(y, others, k, shift, bias)
            x = y.reshape(v, b, h, w, c)
        return x.permute(1, 0, 4, 2, 3)


class MVSplatBackbone(nn.Module):
    """images (B, V, 3, H, W) in [0, 1] -> (transformer features, CNN features), each (B, V, C, H/4, W/4)."""

    def __init__(self, cnn_channels: tuple[int, int, int], dim: int, layers: int, ffn_ratio: int, windows: int):
        super().__init__()
        self.dim = dim
        self.windows = windows
        self.cnn = MVSplatCNN(cnn_channels, dim)
        self.transformer = MVSplatTransformer(dim, layers, ffn_ratio, windows)

    def forward(self, images: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        b, v, _, hh, ww = images.shape
        mean = torch.tensor(IMAGENET_MEAN, device=images.device).view(3, 1, 1)
        std = torch.tensor(IMAGENET_STD, device=images.device).view(3, 1, 1)
        cnn = self.cnn(((images - mean) / std).reshape(b * v, 3, hh, ww))
        _, c, h, w = cnn.shape
        cnn = cnn.reshape(b, v, c, h, w)
        k = self.windows
        pos = window_sine_positions(h // k, w // k, c, images.device).repeat(1, k, k)  # tiled per window
        return self.transformer(cnn + pos), cnn
