"""Typed configuration of the SeeU model, with the paper's defaults and its ablation switches.

Paper defaults (seeu-paper.tex §3 and appendix A): 256x256 inputs, two views, s = 4 (64x64 latent
grid), a frozen DINOv3 ViT-B/16 semantic encoder, a Conditional Gaussian Transformer with 4 layers,
hidden 256, 4 heads, MLP ratio 2. Where the paper is silent the MVSplat numbers are used (REFERENCE.md):
128-channel H/4 CNN, 6 multi-view transformer layers with 2x2 shifted windows, 128 depth candidates
uniform in inverse depth, SH degree 4. Those choices are marked "(MVSplat)" below.

Ablation switches (paper tables 4 and 5):
* ``refiner``: ``"transformer"`` (the Conditional Gaussian Transformer, full model), ``"unet"`` (a 2D UNet
  in its place, "w/ UNet Backbone"), ``"none"`` ("w/o Refinement": the coarse Gaussians are decoded
  directly).
* ``condition``: ``"cea"`` (Cross-view Entropy-Aware embedding, full model), ``"cls"`` (DINOv3 class
  embeddings only), ``"clip"`` (a frozen CLIP image tower through timm; needs its own weights), ``"blip2"``
  (BLIP-2's frozen image side, ViT-g + Q-Former query tokens, through Hugging Face ``transformers``: the
  optional extra ``pip install -e '.[blip2]'``; weights from the hub repo ``blip2_model`` or the local
  directory ``blip2_weights``).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace
from typing import Any, Literal

Encoder = Literal["seeu", "mvsplat"]
Refiner = Literal["none", "unet", "transformer"]
Condition = Literal["cls", "cea", "clip", "blip2"]

ENCODERS = ("seeu", "mvsplat")
REFINERS = ("none", "unet", "transformer")
CONDITIONS = ("cls", "cea", "clip", "blip2")


@dataclass
class SeeUConfig:
    # ---- input / latent grid ----------------------------------------------------------------
    image_size: int = 256  # nominal H = W (informational: the model accepts any size divisible by s * windows)
    downsample: int = 4  # s: latent grid is (H/s, W/s)

    # ---- coarse encoder ----------------------------------------------------------------------
    # "seeu": this toolkit's encoder (below); "mvsplat": MVSplat's encoder exactly (seeu_model/mvsplat/),
    # whose released checkpoints `seeu convert-checkpoint mvsplat` converts. The mvsplat_* fields give its
    # structure (MVSplat's RE10K/ACID release by default); it also uses mv_layers, mv_ffn_ratio,
    # mv_windows, num_depth_candidates, sh_degree, scale_min and scale_max.
    encoder: Encoder = "seeu"
    mvsplat_cnn_channels: tuple[int, ...] = (64, 96, 128)
    mvsplat_feature_dim: int = 128
    mvsplat_cost_unet_channels: int = 128
    mvsplat_cost_unet_levels: int = 3
    mvsplat_cost_unet_attention: tuple[int, ...] = (4,)  # downsampling rates with cross-view attention
    mvsplat_depth_unet_channels: int = 32
    mvsplat_depth_unet_levels: int = 5
    mvsplat_depth_unet_attention: tuple[int, ...] = (16,)

    # ---- multi-view encoder ------------------------------------------------------------------
    backbone_channels: tuple[int, ...] = (64, 96, 128)  # ResNet stages; last = feature dim C (MVSplat)
    mv_layers: int = 6  # multi-view transformer layers (MVSplat)
    mv_heads: int = 1  # (MVSplat)
    mv_ffn_ratio: int = 4  # (MVSplat)
    mv_windows: int = 2  # windows per side (2x2 windows, odd layers shifted by half a window) (MVSplat)

    # ---- coarse matching ---------------------------------------------------------------------
    num_depth_candidates: int = 128  # D, uniform in inverse depth between near and far (MVSplat)

    # ---- Gaussians ---------------------------------------------------------------------------
    sh_degree: int = 4  # (MVSplat)
    latent_feature_dim: int = 64  # free feature channels carried by each latent Gaussian token
    head_hidden: int = 128  # hidden width of the light Gaussian heads
    scale_min: float = 0.5  # Gaussian scale range, in pixel footprints at the Gaussian's depth
    scale_max: float = 15.0
    decoder_hidden: int = 64  # width of the full-resolution upsampling decoder

    # ---- semantic encoder (frozen) ----------------------------------------------------------
    semantic_backbone: str = "vit_base_patch16_dinov3.lvd1689m"
    semantic_weights: str | None = None  # local weights file (offline); None = the hub name
    semantic_pretrained: bool = True  # False = random initialisation (tests / CPU demo only)
    semantic_model_kwargs: dict[str, Any] = field(default_factory=dict)  # e.g. {"depth": 2} for tests
    clip_backbone: str = "vit_base_patch16_clip_224.openai"
    clip_weights: str | None = None
    clip_model_kwargs: dict[str, Any] = field(default_factory=dict)
    blip2_model: str = "Salesforce/blip2-opt-2.7b"  # hub repo; only its image side (ViT-g + Q-Former) is loaded
    blip2_weights: str | None = None  # local directory (config.json + *.safetensors) for offline use
    blip2_model_kwargs: dict[str, Any] = field(default_factory=dict)  # Blip2Config fields, random init (tests)

    # ---- condition ---------------------------------------------------------------------------
    condition: Condition = "cea"
    condition_dim: int = 768  # shared token space of every condition ("linearly projected into 768-d")
    condition_heads: int = 8
    num_latent_queries: int = 16  # Perceiver-style latent queries of CEA (paper silent)

    # ---- refiner -----------------------------------------------------------------------------
    refiner: Refiner = "transformer"
    cgt_layers: int = 4  # paper appendix A (TinyDiT)
    cgt_hidden: int = 256
    cgt_heads: int = 4
    cgt_mlp_ratio: float = 2.0
    unet_channels: tuple[int, ...] = (128, 256)  # UNet refiner ablation

    def __post_init__(self) -> None:
        if self.encoder not in ENCODERS:
            raise ValueError(f"encoder must be one of {ENCODERS}, got {self.encoder!r}")
        for name in ("mvsplat_cnn_channels", "mvsplat_cost_unet_attention", "mvsplat_depth_unet_attention"):
            setattr(self, name, tuple(getattr(self, name)))
        if self.encoder == "mvsplat":
            if self.downsample != 4 or self.mv_heads != 1:
                raise ValueError('encoder "mvsplat" needs downsample 4 and mv_heads 1 (MVSplat\'s structure)')
        if self.refiner not in REFINERS:
            raise ValueError(f"refiner must be one of {REFINERS}, got {self.refiner!r}")
        if self.condition not in CONDITIONS:
            raise ValueError(f"condition must be one of {CONDITIONS}, got {self.condition!r}")
        if self.downsample < 1 or self.downsample & (self.downsample - 1):
            raise ValueError(f"downsample must be a power of two, got {self.downsample}")
        if self.num_depth_candidates < 2:
            raise ValueError("num_depth_candidates must be >= 2")
        self.backbone_channels = tuple(self.backbone_channels)
        self.unet_channels = tuple(self.unet_channels)

    # ---- presets -----------------------------------------------------------------------------
    @classmethod
    def paper(cls, **overrides: Any) -> SeeUConfig:
        """The paper's model (frozen pretrained DINOv3 ViT-B/16 semantic encoder)."""
        return cls(**overrides)

    @classmethod
    def cpu_small(cls, **overrides: Any) -> SeeUConfig:
        """A small model for the CPU demo: same architecture, narrower and shallower everywhere,
        32 depth candidates, SH degree 2, DINOv3 ViT-S/16 semantic encoder (pretrained unless
        ``semantic_pretrained=False`` is passed)."""
        base: dict[str, Any] = dict(
            backbone_channels=(32, 48, 64),
            mv_layers=2,
            mv_heads=1,
            mv_ffn_ratio=2,
            num_depth_candidates=32,
            sh_degree=2,
            latent_feature_dim=32,
            head_hidden=64,
            decoder_hidden=32,
            semantic_backbone="vit_small_patch16_dinov3.lvd1689m",
            condition_dim=384,
            condition_heads=4,
            num_latent_queries=8,
            cgt_layers=2,
            cgt_hidden=128,
            cgt_heads=4,
            unet_channels=(64, 128),
        )
        base.update(overrides)
        return cls(**base)

    @classmethod
    def tiny(cls, **overrides: Any) -> SeeUConfig:
        """The unit-test model: tiny widths, 16 depth candidates, SH degree 1, a randomly initialised
        2-block DINOv3 ViT-S/16 as the semantic encoder. Not meant to be trained for quality."""
        base: dict[str, Any] = dict(
            backbone_channels=(16, 24, 32),
            mv_layers=2,
            mv_heads=2,
            mv_ffn_ratio=2,
            num_depth_candidates=16,
            sh_degree=1,
            latent_feature_dim=8,
            head_hidden=32,
            decoder_hidden=16,
            semantic_backbone="vit_small_patch16_dinov3.lvd1689m",
            semantic_pretrained=False,
            semantic_model_kwargs={"depth": 2},
            condition_dim=64,
            condition_heads=4,
            num_latent_queries=4,
            cgt_layers=2,
            cgt_hidden=32,
            cgt_heads=4,
            cgt_mlp_ratio=2.0,
            unet_channels=(16, 32),
        )
        base.update(overrides)
        return cls(**base)

    @classmethod
    def mvsplat(cls, **overrides: Any) -> SeeUConfig:
        """MVSplat's encoder as released for RE10K / ACID (128 disparity candidates, SH degree 4), without a
        refiner: what a converted MVSplat checkpoint runs as ("SeeU w/o refinement"). With
        ``refiner="transformer"`` (and the paper's condition) SeeU's refiner sits on MVSplat's latent tokens."""
        base: dict[str, Any] = dict(
            encoder="mvsplat",
            refiner="none",
            num_depth_candidates=128,
            sh_degree=4,
            mv_layers=6,
            mv_heads=1,
            mv_ffn_ratio=4,
            mv_windows=2,
            downsample=4,
            scale_min=0.5,
            scale_max=15.0,
        )
        base.update(overrides)
        return cls(**base)

    @classmethod
    def preset(cls, name: str, **overrides: Any) -> SeeUConfig:
        presets = {"paper": cls.paper, "cpu_small": cls.cpu_small, "tiny": cls.tiny, "mvsplat": cls.mvsplat}
        if name not in presets:
            raise ValueError(f"unknown preset {name!r}; choose one of {sorted(presets)}")
        return presets[name](**overrides)

    # ---- derived -----------------------------------------------------------------------------
    @property
    def feature_dim(self) -> int:
        return self.backbone_channels[-1]

    @property
    def sh_coeffs(self) -> int:
        return (self.sh_degree + 1) ** 2

    def mvsplat_shape(self):
        """The `MVSplatShape` of ``encoder: "mvsplat"``."""
        from .mvsplat.encoder import MVSplatShape

        return MVSplatShape(
            cnn_channels=tuple(self.mvsplat_cnn_channels),
            feature_dim=self.mvsplat_feature_dim,
            transformer_layers=self.mv_layers,
            ffn_ratio=self.mv_ffn_ratio,
            windows=self.mv_windows,
            downsample=self.downsample,
            num_depth_candidates=self.num_depth_candidates,
            cost_unet_channels=self.mvsplat_cost_unet_channels,
            cost_unet_mult=(1,) * self.mvsplat_cost_unet_levels,
            cost_unet_attention=self.mvsplat_cost_unet_attention,
            depth_unet_channels=self.mvsplat_depth_unet_channels,
            depth_unet_mult=(1,) * self.mvsplat_depth_unet_levels,
            depth_unet_attention=self.mvsplat_depth_unet_attention,
            sh_degree=self.sh_degree,
            scale_min=self.scale_min,
            scale_max=self.scale_max,
        )

    @property
    def needs_semantic(self) -> bool:
        return self.refiner != "none"

    def replace(self, **changes: Any) -> SeeUConfig:
        return replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)
