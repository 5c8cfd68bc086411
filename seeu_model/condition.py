"""Condition tokens for the refiner, one module per ablation of the paper's table 5. Every variant
ends in the same token space (B, L, condition_dim) and feeds the same cross-attention interface.

* ``cea``:  Cross-view Entropy-Aware embedding from the frozen DINOv3 (the full model), L = latent queries.
* ``cls``:  the frozen DINOv3 class embedding of each view, linearly projected; L = V.
* ``clip``: the frozen CLIP image embedding of each view (timm image tower), linearly projected; L = V.
* ``blip2``: the frozen BLIP-2 image features of each view (ViT-g + Q-Former through ``transformers``, the
  optional ``blip2`` extra): the Q query tokens per view, linearly projected; L = V * Q (Q = 32 for
  Salesforce/blip2-opt-2.7b).
"""

from __future__ import annotations

import torch
from torch import nn

from .cea import CEAEmbedding
from .config import SeeUConfig
from .semantic import FrozenBLIP2ImageEncoder, FrozenCLIPImageEncoder, FrozenViTEncoder


class ConditionEncoder(nn.Module):
    """images (B, V, 3, H, W) in [0, 1], entropy (B, V, h, w) -> condition tokens (B, L, condition_dim).

    ``semantic`` holds the frozen encoder (excluded from trainable state); the rest is trainable.
    """

    def __init__(self, cfg: SeeUConfig):
        super().__init__()
        self.mode = cfg.condition
        if cfg.condition == "clip":
            self.semantic: nn.Module = FrozenCLIPImageEncoder(
                cfg.clip_backbone, cfg.clip_weights, cfg.semantic_pretrained, cfg.clip_model_kwargs
            )
            self.project = nn.Linear(self.semantic.embed_dim, cfg.condition_dim)
        elif cfg.condition == "blip2":
            self.semantic = FrozenBLIP2ImageEncoder(
                cfg.blip2_model, cfg.blip2_weights, cfg.semantic_pretrained, cfg.blip2_model_kwargs
            )
            self.project = nn.Linear(self.semantic.embed_dim, cfg.condition_dim)
        else:
            self.semantic = FrozenViTEncoder(
                cfg.semantic_backbone, cfg.semantic_weights, cfg.semantic_pretrained, cfg.semantic_model_kwargs
            )
            if cfg.condition == "cls":
                self.project = nn.Linear(self.semantic.embed_dim, cfg.condition_dim)
            else:
                self.cea = CEAEmbedding(
                    self.semantic.embed_dim, cfg.condition_dim, cfg.condition_heads, cfg.num_latent_queries
                )
        self.norm = nn.LayerNorm(cfg.condition_dim) if cfg.condition in ("cls", "clip", "blip2") else nn.Identity()

    def forward(self, images: torch.Tensor, entropy: torch.Tensor) -> torch.Tensor:
        if self.mode in ("clip", "blip2"):  # (B, V, D_clip) / (B, V * Q, D_q) -> (B, L, condition_dim)
            return self.norm(self.project(self.semantic(images)))
        cls, patches = self.semantic(images)
        if self.mode == "cls":
            return self.norm(self.project(cls))
        return self.cea(cls, patches, entropy)
