"""Cross-view Entropy-Aware (CEA) embedding (paper §3.2.1).

Per view i, with the frozen ViT's class embedding E^i_CLS (D_s) and patch map F^i (D_s, h_p, w_p):

    w^i(p)   = H(P^i(. | p)) / log D                    matching entropy on the latent h x w grid
    F~^i(p)  = w^i(p) F^i(p)                            (F^i resampled bilinearly to h x w)
    E~^i     = E^i + CrossAttn(Q = E^i W_Q, K = F~^i W_K, V = F~^i W_V)   (+ a feed-forward)
    E_CEA    = CrossAttn(Q_l, K_mv, V_mv) over the concatenated {E~^i}    (Perceiver latents Q_l, + FFN)

Implementation note: K = (w F) W_K = w (F W_K), and bilinear resampling is linear per channel, so keys
and values are projected on the ViT's patch grid, resampled to h x w, then weighted by w (biases added
after the weighting). This equals projecting the resampled, weighted features, at 1/16 of the cost.
Two documented choices beyond the paper's equations: the per-view attention output is added to the
(projected) class embedding, and both stages carry a pre-norm feed-forward, as in Perceiver blocks.
Views enter as an unordered set, so E_CEA is invariant to the order of the context views.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from .attention import Attention, FeedForward


class EntropyAwareViewEmbedding(nn.Module):
    """cls (B, V, D_s), patches (B, V, D_s, h_p, w_p), entropy (B, V, h, w) -> E~ (B, V, dim)."""

    def __init__(self, semantic_dim: int, dim: int, heads: int):
        super().__init__()
        self.cls_in = nn.Linear(semantic_dim, dim)
        self.norm_q = nn.LayerNorm(dim)
        self.norm_kv = nn.LayerNorm(semantic_dim)
        self.attn = Attention(dim, heads, context_dim=semantic_dim)
        self.norm_ffn = nn.LayerNorm(dim)
        self.ffn = FeedForward(dim, 2.0)

    def forward(self, cls: torch.Tensor, patches: torch.Tensor, entropy: torch.Tensor) -> torch.Tensor:
        b, v, ds, hp, wp = patches.shape
        h, w = entropy.shape[-2:]
        e = self.cls_in(cls)  # (B, V, dim)
        tokens = self.norm_kv(patches.permute(0, 1, 3, 4, 2))  # (B, V, hp, wp, Ds)

        def project(lin: nn.Linear) -> torch.Tensor:  # -> (B*V, h*w, dim): w * resample(F W) + b
            y = F.linear(tokens, lin.weight)  # (B, V, hp, wp, dim)
            y = y.permute(0, 1, 4, 2, 3).reshape(b * v, -1, hp, wp)
            y = F.interpolate(y, size=(h, w), mode="bilinear", align_corners=False)
            y = y * entropy.reshape(b * v, 1, h, w).to(y.dtype)
            y = y.flatten(2).transpose(1, 2)
            return y + lin.bias if lin.bias is not None else y

        k, val = project(self.attn.to_k), project(self.attn.to_v)
        q = self.attn.to_q(self.norm_q(e)).reshape(b * v, 1, -1)
        e = e + self.attn.attend(q, k, val).reshape(b, v, -1)
        return e + self.ffn(self.norm_ffn(e))


class PerceiverAggregator(nn.Module):
    """Learnable latent queries cross-attending a set of tokens: (B, S, dim) -> (B, L, dim)."""

    def __init__(self, dim: int, heads: int, num_latents: int):
        super().__init__()
        self.latents = nn.Parameter(torch.randn(num_latents, dim) * 0.02)
        self.norm_q = nn.LayerNorm(dim)
        self.norm_kv = nn.LayerNorm(dim)
        self.attn = Attention(dim, heads)
        self.norm_ffn = nn.LayerNorm(dim)
        self.ffn = FeedForward(dim, 2.0)
        self.norm_out = nn.LayerNorm(dim)

    def forward(self, tokens: torch.Tensor) -> torch.Tensor:
        b = tokens.shape[0]
        lat = self.latents[None].expand(b, -1, -1)
        lat = lat + self.attn(self.norm_q(lat), self.norm_kv(tokens))
        lat = lat + self.ffn(self.norm_ffn(lat))
        return self.norm_out(lat)


class CEAEmbedding(nn.Module):
    """cls (B, V, D_s), patches (B, V, D_s, h_p, w_p), entropy (B, V, h, w) -> E_CEA (B, L, dim)."""

    def __init__(self, semantic_dim: int, dim: int, heads: int, num_latents: int):
        super().__init__()
        self.view = EntropyAwareViewEmbedding(semantic_dim, dim, heads)
        self.aggregate = PerceiverAggregator(dim, heads, num_latents)

    def forward(self, cls: torch.Tensor, patches: torch.Tensor, entropy: torch.Tensor) -> torch.Tensor:
        return self.aggregate(self.view(cls, patches, entropy))
