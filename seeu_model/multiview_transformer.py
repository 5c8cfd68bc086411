"""Multi-view transformer: Swin-style shifted-window self-attention plus cross-view attention
(paper §3.1.1; MVSplat/GMFlow-style layers: 2x2 windows, odd layers shifted by half a window).

Each layer, for every view i and every window:
    x_i <- x_i + SelfAttn(x_i)                           (tokens of view i in that window)
    x_i <- x_i + CrossAttn(x_i, {x_j : j != i})          (the same window of every other view)
    x_i <- x_i + FFN(x_i)
Keys of the cross-view attention are the concatenated tokens of all other views, an unordered set
for softmax attention, so the encoder is equivariant to permutations of the views. Shifted windows
carry Swin's mask so that tokens wrapped around by the cyclic shift never attend to each other.
"""

from __future__ import annotations

import torch
from torch import nn

from .attention import Attention, FeedForward, sine_positions_2d


def other_view_index(num_views: int, device=None) -> torch.Tensor:
    """(V, V-1) long: row i lists the views j != i in increasing order."""
    idx = torch.arange(num_views, device=device)
    return torch.stack([torch.cat([idx[:i], idx[i + 1 :]]) for i in range(num_views)])


def window_partition(x: torch.Tensor, windows: int) -> torch.Tensor:
    """(B, V, h, w, C) -> (B, V, windows^2, (h/windows)*(w/windows), C)."""
    b, v, h, w, c = x.shape
    wh, ww = h // windows, w // windows
    x = x.reshape(b, v, windows, wh, windows, ww, c).permute(0, 1, 2, 4, 3, 5, 6)
    return x.reshape(b, v, windows * windows, wh * ww, c)


def window_reverse(x: torch.Tensor, windows: int, h: int, w: int) -> torch.Tensor:
    """Inverse of `window_partition`: (B, V, windows^2, T, C) -> (B, V, h, w, C)."""
    b, v, _, _, c = x.shape
    wh, ww = h // windows, w // windows
    x = x.reshape(b, v, windows, windows, wh, ww, c).permute(0, 1, 2, 4, 3, 5, 6)
    return x.reshape(b, v, h, w, c)


def shifted_window_mask(h: int, w: int, windows: int, device=None) -> torch.Tensor:
    """Swin's mask for cyclically shifted windows: bool (windows^2, T, T), True = may attend."""
    wh, ww = h // windows, w // windows
    sh, sw = wh // 2, ww // 2
    region = torch.zeros(h, w, device=device)
    label = 0
    for hs in (slice(0, -wh), slice(-wh, -sh), slice(-sh, None)):
        for ws in (slice(0, -ww), slice(-ww, -sw), slice(-sw, None)):
            region[hs, ws] = label
            label += 1
    ids = window_partition(region[None, None, :, :, None], windows)[0, 0, :, :, 0]  # (nW, T)
    return ids[:, :, None] == ids[:, None, :]


class MultiViewLayer(nn.Module):
    """One layer over windowed tokens: (B, V, nW, T, C) -> same shape."""

    def __init__(self, dim: int, heads: int, ffn_ratio: float):
        super().__init__()
        self.norm_self = nn.LayerNorm(dim)
        self.self_attn = Attention(dim, heads)
        self.norm_cross = nn.LayerNorm(dim)
        self.cross_attn = Attention(dim, heads)
        self.norm_ffn = nn.LayerNorm(dim)
        self.ffn = FeedForward(dim, ffn_ratio)

    def forward(self, x: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
        b, v, nw, t, c = x.shape
        flat = x.reshape(b * v * nw, t, c)
        # Self-attention within each window; mask (nW, T, T) -> (B*V*nW, 1, T, T).
        self_mask = None if mask is None else mask[None, None].expand(b, v, nw, t, t).reshape(b * v * nw, 1, t, t)
        flat = flat + self.self_attn(self.norm_self(flat), mask=self_mask)
        x = flat.reshape(b, v, nw, t, c)
        # Cross-view attention: queries of view i, keys/values of the same window in all views j != i.
        if v > 1:
            normed = self.norm_cross(x)
            k, val = self.cross_attn.project_kv(normed)  # (B, V, nW, T, C)
            others = other_view_index(v, x.device)  # (V, V-1)

            def gather(y: torch.Tensor) -> torch.Tensor:  # (B, V, nW, T, C) -> (B*V*nW, (V-1)*T, C)
                y = y[:, others]  # (B, V, V-1, nW, T, C)
                return y.permute(0, 1, 3, 2, 4, 5).reshape(b * v * nw, (v - 1) * t, c)

            cross_mask = None
            if mask is not None:
                cross_mask = mask.repeat(1, 1, v - 1)[None, None].expand(b, v, nw, t, (v - 1) * t)
                cross_mask = cross_mask.reshape(b * v * nw, 1, t, (v - 1) * t)
            q = self.cross_attn.to_q(normed).reshape(b * v * nw, t, c)
            x = x + self.cross_attn.attend(q, gather(k), gather(val), cross_mask).reshape(b, v, nw, t, c)
        return x + self.ffn(self.norm_ffn(x))


class MultiViewTransformer(nn.Module):
    """features (B, V, C, h, w) -> features (B, V, C, h, w); h and w divisible by ``windows``
    (and by 2 * windows when shifted layers are used)."""

    def __init__(self, dim: int, layers: int = 6, heads: int = 1, ffn_ratio: float = 4.0, windows: int = 2):
        super().__init__()
        self.windows = windows
        self.layers = nn.ModuleList(MultiViewLayer(dim, heads, ffn_ratio) for _ in range(layers))
        self.norm = nn.LayerNorm(dim)

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        b, v, c, h, w = features.shape
        nw = self.windows
        if h % nw or w % nw:
            raise ValueError(f"latent grid {h}x{w} not divisible by {nw} windows per side")
        x = features.permute(0, 1, 3, 4, 2)  # (B, V, h, w, C)
        x = x + sine_positions_2d(h, w, c, x.device, x.dtype).reshape(h, w, c)
        shift = (h // nw // 2, w // nw // 2)
        mask = shifted_window_mask(h, w, nw, x.device) if nw > 1 and min(shift) > 0 else None
        for i, layer in enumerate(self.layers):
            shifted = i % 2 == 1 and mask is not None
            if shifted:
                x = torch.roll(x, shifts=(-shift[0], -shift[1]), dims=(2, 3))
            x = window_reverse(layer(window_partition(x, nw), mask if shifted else None), nw, h, w)
            if shifted:
                x = torch.roll(x, shifts=shift, dims=(2, 3))
        return self.norm(x).permute(0, 1, 4, 2, 3).contiguous()
