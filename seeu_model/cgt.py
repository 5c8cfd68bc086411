"""Conditional Gaussian Transformer (paper §3.2.2, appendix A: TinyDiT-style, 4 layers, hidden 256,
4 heads, MLP ratio 2).

    T_l = rearrange(Θ_l, "B V h w C -> B (V h w) C")
    Θ^_l = Θ_l + f_θ(Θ_l, E_CEA)

f_θ embeds each token linearly and adds a 2D sine position of its (row, column) on the latent grid
(the same for every view, so the refiner is equivariant to the order of the context views), then runs
DiT blocks:
    x <- x + (1 + g1) * SelfAttn(modulate(LN(x), shift1, scale1))     global over all V*h*w tokens
    x <- x + CrossAttn(LN(x), E)                                     the condition tokens
    x <- x + (1 + g2) * MLP(modulate(LN(x), shift2, scale2))
with (shift, scale, g) from an adaLN MLP of the mean condition token, first projected to the hidden
width as DiT embeds its condition. Unlike DiT's adaLN-Zero, the modulation starts near the identity
(weights N(0, 0.02), zero bias) rather than at zero, so that one optimiser step opens every gradient path;
only the output layer (adaLN-modulated LayerNorm, then a linear map to C) is zero-initialised, so at
initialisation the residual is exactly zero and the refined tokens equal the coarse ones.
"""

from __future__ import annotations

import torch
from torch import nn

from .attention import Attention, FeedForward, sine_positions_2d


def modulate(x: torch.Tensor, shift: torch.Tensor, scale: torch.Tensor) -> torch.Tensor:
    """x (B, T, C), shift/scale (B, C) -> x * (1 + scale) + shift."""
    return x * (1 + scale[:, None]) + shift[:, None]


class DiTBlock(nn.Module):
    """(B, T, hidden) tokens, condition tokens (B, L, cond_dim), pooled condition (B, hidden) -> (B, T, hidden)."""

    def __init__(self, hidden: int, heads: int, mlp_ratio: float, cond_dim: int):
        super().__init__()
        self.norm1 = nn.LayerNorm(hidden, elementwise_affine=False, eps=1e-6)
        self.self_attn = Attention(hidden, heads)
        self.norm_cross = nn.LayerNorm(hidden, eps=1e-6)
        self.cross_attn = Attention(hidden, heads, context_dim=cond_dim)
        self.norm2 = nn.LayerNorm(hidden, elementwise_affine=False, eps=1e-6)
        self.mlp = FeedForward(hidden, mlp_ratio)
        self.ada = nn.Sequential(nn.SiLU(), nn.Linear(hidden, 6 * hidden))
        ada = self.ada[-1]
        assert isinstance(ada, nn.Linear)
        nn.init.normal_(ada.weight, std=0.02)
        nn.init.zeros_(ada.bias)

    def forward(self, x: torch.Tensor, cond: torch.Tensor, pooled: torch.Tensor) -> torch.Tensor:
        s1, sc1, g1, s2, sc2, g2 = self.ada(pooled).chunk(6, dim=-1)
        x = x + (1 + g1[:, None]) * self.self_attn(modulate(self.norm1(x), s1, sc1))
        x = x + self.cross_attn(self.norm_cross(x), cond)
        return x + (1 + g2[:, None]) * self.mlp(modulate(self.norm2(x), s2, sc2))


class ConditionalGaussianTransformer(nn.Module):
    """latent (B, V, h, w, C), condition (B, L, cond_dim) -> residual (B, V, h, w, C), exactly 0 at init."""

    def __init__(
        self, channels: int, cond_dim: int, hidden: int = 256, layers: int = 4, heads: int = 4, mlp_ratio: float = 2.0
    ):
        super().__init__()
        self.hidden = hidden
        self.embed = nn.Linear(channels, hidden)
        self.cond_embed = nn.Linear(cond_dim, hidden)
        self.blocks = nn.ModuleList(DiTBlock(hidden, heads, mlp_ratio, cond_dim) for _ in range(layers))
        self.norm_out = nn.LayerNorm(hidden, elementwise_affine=False, eps=1e-6)
        self.ada_out = nn.Sequential(nn.SiLU(), nn.Linear(hidden, 2 * hidden))
        self.out = nn.Linear(hidden, channels)
        ada_out = self.ada_out[-1]
        assert isinstance(ada_out, nn.Linear)
        nn.init.normal_(ada_out.weight, std=0.02)
        nn.init.zeros_(ada_out.bias)
        nn.init.zeros_(self.out.weight)  # the residual is exactly zero at initialisation
        nn.init.zeros_(self.out.bias)

    def forward(self, latent: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:
        b, v, h, w, c = latent.shape
        pos = sine_positions_2d(h, w, self.hidden, latent.device, latent.dtype)  # (hw, hidden)
        x = self.embed(latent).reshape(b, v, h * w, self.hidden) + pos
        x = x.reshape(b, v * h * w, self.hidden)  # B (V h w) C
        pooled = self.cond_embed(cond.mean(1))  # (B, hidden)
        for block in self.blocks:
            x = block(x, cond, pooled)
        shift, scale = self.ada_out(pooled).chunk(2, dim=-1)
        return self.out(modulate(self.norm_out(x), shift, scale)).reshape(b, v, h, w, c)
