"""Attention building blocks shared by the encoder, CEA and the refiners, and 2D sine positions.

Everything uses ``torch.nn.functional.scaled_dot_product_attention`` (flash / memory-efficient kernels
on CUDA, a fused kernel on CPU), so attention over the V*h*w Gaussian tokens never materialises the
full attention matrix when a fused kernel is available.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn


class Attention(nn.Module):
    """Multi-head (cross-)attention.

    query (N, Tq, dim), context (N, Tk, context_dim) or None (self-attention),
    mask: bool (Tq, Tk) / (N, 1, Tq, Tk) broadcastable, True = may attend  ->  (N, Tq, dim)
    """

    def __init__(self, dim: int, heads: int, context_dim: int | None = None, qkv_bias: bool = True):
        super().__init__()
        if dim % heads:
            raise ValueError(f"dim {dim} not divisible by heads {heads}")
        context_dim = context_dim or dim
        self.heads = heads
        self.to_q = nn.Linear(dim, dim, bias=qkv_bias)
        self.to_k = nn.Linear(context_dim, dim, bias=qkv_bias)
        self.to_v = nn.Linear(context_dim, dim, bias=qkv_bias)
        self.proj = nn.Linear(dim, dim)

    def project_kv(self, context: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.to_k(context), self.to_v(context)

    def attend(
        self, q: torch.Tensor, k: torch.Tensor, v: torch.Tensor, mask: torch.Tensor | None = None
    ) -> torch.Tensor:
        """Projected q (N, Tq, dim), k, v (N, Tk, dim) -> (N, Tq, dim), output projection applied."""
        n, tq, dim = q.shape
        h = self.heads

        def split(x: torch.Tensor) -> torch.Tensor:  # (N, T, dim) -> (N, heads, T, dim/heads)
            return x.reshape(x.shape[0], x.shape[1], h, dim // h).transpose(1, 2)

        out = F.scaled_dot_product_attention(split(q), split(k), split(v), attn_mask=mask)
        return self.proj(out.transpose(1, 2).reshape(n, tq, dim))

    def forward(
        self, x: torch.Tensor, context: torch.Tensor | None = None, mask: torch.Tensor | None = None
    ) -> torch.Tensor:
        context = x if context is None else context
        k, v = self.project_kv(context)
        return self.attend(self.to_q(x), k, v, mask)


class FeedForward(nn.Module):
    """(..., dim) -> (..., dim): Linear, GELU, Linear."""

    def __init__(self, dim: int, ratio: float = 4.0):
        super().__init__()
        hidden = int(dim * ratio)
        self.net = nn.Sequential(nn.Linear(dim, hidden), nn.GELU(), nn.Linear(hidden, dim))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x)


def sine_positions_2d(h: int, w: int, dim: int, device=None, dtype=torch.float32) -> torch.Tensor:
    """Fixed 2D sine/cosine position embedding (h*w, dim), row-major; dim must be divisible by 4.

    Half the channels encode the row, half the column, with geometric frequencies (Transformer style).
    The same table is used for every view, so view order never enters the model.
    """
    if dim % 4:
        raise ValueError(f"position embedding dim must be divisible by 4, got {dim}")
    quarter = dim // 4
    freqs = torch.exp(-math.log(10000.0) * torch.arange(quarter, device=device, dtype=torch.float32) / quarter)
    ys = torch.arange(h, device=device, dtype=torch.float32)[:, None] * freqs  # (h, q)
    xs = torch.arange(w, device=device, dtype=torch.float32)[:, None] * freqs  # (w, q)
    y_emb = torch.cat([ys.sin(), ys.cos()], -1)[:, None, :].expand(h, w, 2 * quarter)
    x_emb = torch.cat([xs.sin(), xs.cos()], -1)[None, :, :].expand(h, w, 2 * quarter)
    return torch.cat([y_emb, x_emb], -1).reshape(h * w, dim).to(dtype)
