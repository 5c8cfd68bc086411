"""The SeeU model (paper §3): multi-view encoder -> coarse matching -> latent Gaussians -> CEA-conditioned
residual refinement -> upsampling decoder -> rasterised target views.

    context images (B, V, 3, H, W)
      ResNetBackbone                 -> (B, V, C, h, w)           h, w = H/s, W/s
      MultiViewTransformer           -> F (B, V, C, h, w)
      plane_sweep_cost               -> cost (B, V, D, h, w) -> P, coarse depth (B, V, h, w), entropy (B, V, h, w)
      CoarseGaussianHead             -> Θ_l (B, V, h, w, C_l)      latent Gaussian tokens
      ConditionEncoder (frozen ViT)  -> E (B, L, condition_dim)   CEA / CLS / CLIP / BLIP-2
      refiner (CGT | UNet | none)    -> Θ^_l = Θ_l + f(Θ_l, E)
      UpsamplingDecoder              -> Gaussians, N = V*H*W (refined) and the same for Θ_l (coarse)
      rasterize                      -> target renders (B, T, 3, H, W)

With ``encoder: "mvsplat"`` the coarse stage is MVSplat's encoder exactly (seeu_model/mvsplat/), one
Gaussian per pixel and view; without a refiner it is "SeeU w/o refinement" (what MVSplat renders), with
one the refiner's zero-initialised residual corrects MVSplat's raw parameters (`_encode_mvsplat`).

`SeeU.encode(context)` returns the refined Gaussians only (timed separately from rendering by the
evaluator); `SeeU.encode_all(context)` returns every intermediate; `SeeU.forward(batch)` encodes and
renders the batch's target views. The frozen semantic encoder stays in eval mode, has no gradients,
and is left out of `trainable_state_dict()`.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch
import torch.nn.functional as F
from torch import nn

from seeu_data.errors import SeeUError

from .backbone import ResNetBackbone
from .cgt import ConditionalGaussianTransformer
from .condition import ConditionEncoder
from .config import SeeUConfig
from .cost_volume import depth_candidates, depth_posterior, expected_depth, matching_entropy, plane_sweep_cost
from .decoder import UpsamplingDecoder
from .gaussian_heads import CoarseGaussianHead, LatentLayout, gaussians_from_params
from .gaussians import Gaussians
from .multiview_transformer import MultiViewTransformer
from .semantic import FrozenModule
from .unet_refiner import UNetRefiner

if TYPE_CHECKING:
    from .rasterizer import RenderOutput


@dataclass
class SeeUEncoding:
    """Everything `encode_all` computes for the context views.

    gaussians:         refined Gaussians, N = V*H*W (view-major, row-major pixels)
    coarse_gaussians:  the unrefined latent tokens decoded the same way ("w/o refinement"), N = V*H*W
                       (None when not asked for: `encode`, `forward` without ``render_coarse``)
    latent_gaussians:  the coarse Gaussians on the latent grid (pixel-aligned centres at the matched depth), N = V*h*w
    depth:             (B, V, H, W) depth of the refined Gaussians
    coarse_depth:      (B, V, h, w) softmax-expected plane-sweep depth
    entropy:           (B, V, h, w) normalised matching entropy in [0, 1]
    cost:              (B, V, D, h, w) plane-sweep correlation volume
    depth_candidates:  (B, V, D)
    latent:            (B, V, h, w, C_l) coarse latent Gaussian tokens Θ_l
    residual:          (B, V, h, w, C_l) refiner output (zeros when refiner == "none")
    condition:         (B, L, condition_dim) condition tokens, or None without a refiner
    """

    gaussians: Gaussians
    coarse_gaussians: Gaussians | None
    latent_gaussians: Gaussians
    depth: torch.Tensor
    coarse_depth: torch.Tensor
    entropy: torch.Tensor
    cost: torch.Tensor
    depth_candidates: torch.Tensor
    latent: torch.Tensor
    residual: torch.Tensor
    condition: torch.Tensor | None


@dataclass
class SeeUOutput:
    """`forward` output: the encoding plus the target renders (RenderOutput: color (B, T, 3, H, W),
    depth (B, T, 1, H, W), alpha (B, T, 1, H, W)); `coarse_render` when asked for."""

    encoding: SeeUEncoding
    render: RenderOutput | None
    coarse_render: RenderOutput | None = None

    @property
    def gaussians(self) -> Gaussians:
        return self.encoding.gaussians

    @property
    def coarse_gaussians(self) -> Gaussians | None:
        return self.encoding.coarse_gaussians

    @property
    def depth(self) -> torch.Tensor:
        return self.encoding.depth

    @property
    def entropy(self) -> torch.Tensor:
        return self.encoding.entropy


class SeeU(nn.Module):
    def __init__(self, cfg: SeeUConfig | None = None):
        super().__init__()
        cfg = cfg or SeeUConfig()
        self.cfg = cfg
        self.condition: ConditionEncoder | None = None
        self.refiner: nn.Module | None = None
        if cfg.encoder == "mvsplat":
            from .mvsplat.encoder import MVSplatEncoder

            self.mvsplat = MVSplatEncoder(cfg.mvsplat_shape())
            if cfg.refiner != "none":  # on MVSplat's latent tokens: pooled raw parameters + matched features
                self._build_refiner(cfg, self.mvsplat.raw_channels + cfg.mvsplat_feature_dim)
            return
        c = cfg.feature_dim
        self.layout = LatentLayout(cfg.sh_coeffs, cfg.latent_feature_dim)
        self.backbone = ResNetBackbone(cfg.backbone_channels, cfg.downsample)
        self.transformer = MultiViewTransformer(c, cfg.mv_layers, cfg.mv_heads, cfg.mv_ffn_ratio, cfg.mv_windows)
        # Decoded (full-resolution) Gaussians start near 1.5 pixel footprints: raw = logit((1.5 - min) / (max - min)).
        unit = (1.5 - cfg.scale_min) / (cfg.scale_max - cfg.scale_min)
        init_scale = float(torch.logit(torch.tensor(unit).clamp(1e-3, 1 - 1e-3)))
        self.heads = CoarseGaussianHead(c, cfg.num_depth_candidates, self.layout, cfg.head_hidden, init_scale)
        if cfg.refiner != "none":
            self._build_refiner(cfg, self.layout.channels)
        self.decoder = UpsamplingDecoder(self.layout, cfg.decoder_hidden, cfg.scale_min, cfg.scale_max)

    def _build_refiner(self, cfg: SeeUConfig, channels: int) -> None:
        self.condition = ConditionEncoder(cfg)
        if cfg.refiner == "transformer":
            self.refiner = ConditionalGaussianTransformer(
                channels, cfg.condition_dim, cfg.cgt_hidden, cfg.cgt_layers, cfg.cgt_heads, cfg.cgt_mlp_ratio
            )
        else:
            self.refiner = UNetRefiner(channels, cfg.condition_dim, cfg.unet_channels, cfg.cgt_heads)

    # ------------------------------------------------------------------------------------------
    # Frozen parts
    # ------------------------------------------------------------------------------------------
    def frozen_prefixes(self) -> list[str]:
        """State-dict prefixes of frozen modules (the semantic encoder)."""
        return [name + "." for name, m in self.named_modules() if isinstance(m, FrozenModule) and name]

    def train(self, mode: bool = True) -> SeeU:
        super().train(mode)
        for m in self.modules():  # frozen encoders stay in eval mode
            if isinstance(m, FrozenModule):
                nn.Module.train(m, False)
        return self

    def trainable_state_dict(self) -> OrderedDict[str, torch.Tensor]:
        """The state dict without the frozen semantic encoder (what checkpoints store)."""
        prefixes = tuple(self.frozen_prefixes())
        return OrderedDict((k, v) for k, v in self.state_dict().items() if not k.startswith(prefixes))

    def load_trainable_state_dict(self, state: dict[str, torch.Tensor], strict: bool = True) -> None:
        """Load a `trainable_state_dict()`; the frozen encoder keeps its (pretrained) weights."""
        prefixes = tuple(self.frozen_prefixes())
        frozen = [k for k in state if k.startswith(prefixes)] if prefixes else []
        if frozen:
            state = {k: v for k, v in state.items() if k not in frozen}
        try:
            missing, unexpected = self.load_state_dict(state, strict=False)
        except RuntimeError as exc:  # shape mismatches
            raise SeeUError(
                f"checkpoint does not match the model configuration: {str(exc).splitlines()[-1].strip()}"
            ) from exc
        missing = [k for k in missing if not k.startswith(prefixes)] if prefixes else list(missing)
        if strict and (missing or unexpected):
            raise SeeUError(
                f"checkpoint does not match the model configuration: missing {missing[:5]}"
                f"{'...' if len(missing) > 5 else ''}, unexpected {list(unexpected)[:5]}"
                f"{'...' if len(unexpected) > 5 else ''}"
            )

    def trainable_parameters(self) -> list[nn.Parameter]:
        return [p for p in self.parameters() if p.requires_grad]

    # ------------------------------------------------------------------------------------------
    # Encoding
    # ------------------------------------------------------------------------------------------
    def _check_context(self, context: dict) -> None:
        img = context["image"]
        if img.dim() != 5 or img.shape[2] != 3:
            raise ValueError(f"context image must be (B, V, 3, H, W), got {tuple(img.shape)}")
        b, v, _, h, w = img.shape
        if v < 2:
            raise ValueError("SeeU needs at least two context views (plane-sweep matching)")
        unit = self.size_unit
        if h % unit or w % unit:
            raise ValueError(
                f"context images must have H and W divisible by {unit} "
                f"(s={self.cfg.downsample}, {self.cfg.mv_windows} shifted windows"
                f"{', UNet levels' if self.cfg.refiner == 'unet' else ''}); got {h}x{w}"
            )

    @property
    def size_unit(self) -> int:
        """Image H and W must be multiples of this: s x 2 x windows per side (shifted windows on the
        latent grid), and s x 2^(levels - 1) for the UNet refiner."""
        unit = self.cfg.downsample * self.cfg.mv_windows * 2
        if self.cfg.refiner == "unet":
            unit = math.lcm(unit, self.cfg.downsample * 2 ** (len(self.cfg.unet_channels) - 1))
        return unit

    def encode_all(self, context: dict, decode_coarse: bool = True) -> SeeUEncoding:
        """context: image (B, V, 3, H, W) in [0, 1], cam_to_world (B, V, 4, 4), intrinsics (B, V, 3, 3)
        normalised, near/far (B, V)  ->  SeeUEncoding. With ``decode_coarse=False`` the unrefined tokens
        are not decoded (``coarse_gaussians`` is then None; `encode` uses this)."""
        self._check_context(context)
        if self.cfg.encoder == "mvsplat":
            return self._encode_mvsplat(context, decode_coarse)
        images = context["image"]
        c2w, intr = context["cam_to_world"], context["intrinsics"]
        near, far = context["near"].to(images.dtype), context["far"].to(images.dtype)
        b, v, _, hh, ww = images.shape

        feats = self.transformer(self.backbone(images))  # (B, V, C, h, w)
        h, w = feats.shape[-2:]
        depths = depth_candidates(near.float(), far.float(), self.cfg.num_depth_candidates)  # (B, V, D)
        cost = plane_sweep_cost(feats, c2w, intr, depths)  # (B, V, D, h, w)
        post = depth_posterior(cost)
        coarse_depth = expected_depth(post, depths)  # (B, V, h, w)
        entropy = matching_entropy(post)
        low = F.adaptive_avg_pool2d(images.reshape(b * v, 3, hh, ww), (h, w)).reshape(b, v, 3, h, w)
        latent = self.heads(feats, post, coarse_depth, low, near, far)  # (B, V, h, w, C_l)

        condition = None
        if self.refiner is not None and self.condition is not None:  # built together (`_build_refiner`)
            condition = self.condition(images, entropy)
            residual = self.refiner(latent, condition)
        else:
            residual = torch.zeros_like(latent)
        refined = latent + residual

        gaussians, depth = self.decoder(refined, images, c2w, intr, near, far)
        coarse_gaussians = None
        if self.refiner is None:
            coarse_gaussians = gaussians
        elif decode_coarse:
            coarse_gaussians, _ = self.decoder(latent, images, c2w, intr, near, far)
        latent_gaussians, _ = gaussians_from_params(
            latent.permute(0, 1, 4, 2, 3), c2w, intr, near, far, self.layout, self.cfg.scale_min, self.cfg.scale_max
        )
        return SeeUEncoding(
            gaussians,
            coarse_gaussians,
            latent_gaussians,
            depth,
            coarse_depth,
            entropy,
            cost,
            depths,
            latent,
            residual,
            condition,
        )

    def _encode_mvsplat(self, context: dict, decode_coarse: bool) -> SeeUEncoding:
        """MVSplat's encoder, with SeeU's refiner (when configured) on its latent tokens.

        Latent token Θ_l (B, V, h, w, R + C): MVSplat's raw per-pixel parameters (R: offset, scale, rotation,
        SH, disparity residual, opacity logit) averaged over each s x s cell, and its matched features F.
        The refiner's residual on the first R channels is upsampled bilinearly and added to the raw
        parameters before MVSplat's activations, so a zero residual (the refiner at initialisation)
        gives exactly MVSplat's Gaussians. ``cost`` holds MVSplat's depth probabilities (B, V, D, h, w)."""
        images = context["image"]
        c2w, intr = context["cam_to_world"], context["intrinsics"]
        near, far = context["near"].to(images.dtype), context["far"].to(images.dtype)
        enc = self.mvsplat
        pred = enc.predict(images, c2w, intr, near, far)
        raw = pred["raw"]  # (B, V, R, H, W)
        b, v, r, hh, ww = raw.shape
        h, w = pred["features"].shape[-2:]
        s = self.cfg.downsample
        pooled = F.avg_pool2d(raw.reshape(b * v, r, hh, ww), s).reshape(b, v, r, h, w)
        latent = torch.cat([pooled, pred["features"]], 2).permute(0, 1, 3, 4, 2)  # (B, V, h, w, R + C)
        entropy = matching_entropy(pred["probabilities"])
        condition = None
        coarse = None
        if self.refiner is not None and self.condition is not None:  # built together (`_build_refiner`)
            condition = self.condition(images, entropy)
            residual = self.refiner(latent, condition)
            delta = F.interpolate(
                residual[..., :r].permute(0, 1, 4, 2, 3).reshape(b * v, r, h, w),
                size=(hh, ww),
                mode="bilinear",
                align_corners=False,
            ).reshape(b, v, r, hh, ww)
            out = enc.adapt(dict(pred, raw=raw + delta), c2w, intr, near, far)
            if decode_coarse:
                coarse = enc.adapt(pred, c2w, intr, near, far)
        else:
            residual = torch.zeros_like(latent)
            out = enc.adapt(pred, c2w, intr, near, far)

        def gaussians(o) -> Gaussians:
            return Gaussians(means=o.means, scales=o.scales, rotations=o.rotations, opacities=o.opacities, sh=o.sh)

        g = gaussians(out)
        coarse_g = g if self.refiner is None else (gaussians(coarse) if coarse is not None else None)
        return SeeUEncoding(
            g,
            coarse_g,
            coarse_g if coarse_g is not None else g,
            out.depth,
            1.0 / pred["coarse_disparity"],
            entropy,
            pred["probabilities"],
            1.0 / pred["disparities"],
            latent,
            residual,
            condition,
        )

    def encode(self, context: dict) -> Gaussians:
        """context (as in `encode_all`) -> refined Gaussians (B, V*H*W, ...)."""
        return self.encode_all(context, decode_coarse=False).gaussians

    # ------------------------------------------------------------------------------------------
    # Prediction from a checkpoint (Python API of `seeu predict`)
    # ------------------------------------------------------------------------------------------
    @classmethod
    def from_checkpoint(cls, path, device: torch.device | str | None = None) -> SeeU:
        """The model of a `seeu train` checkpoint (a ckpt-*.pt file, or a directory: its newest; a
        `seeu convert-checkpoint` MVSplat checkpoint the same way), in eval mode on `device` (None:
        cuda when available). The same loading as `seeu render` / `seeu predict`. SeeUError (one line)
        for a file that is not a valid checkpoint."""
        from .training.checkpoint import load_checkpoint

        return cls.from_checkpoint_dict(
            load_checkpoint(path), device or ("cuda" if torch.cuda.is_available() else "cpu")
        )

    @classmethod
    def from_checkpoint_dict(cls, ckpt: dict, device: torch.device | str = "cpu", **model_overrides) -> SeeU:
        """The model of a loaded checkpoint (`training.checkpoint.load_checkpoint`): rebuilt from its
        model config (frozen pretrained parts loaded from their own weights, as in training), its
        trained state loaded (`load_model_state`), in eval mode on `device`."""
        from .training.checkpoint import load_model_state

        if not isinstance(ckpt.get("model_config") or {}, dict):
            raise SeeUError("checkpoint model_config is not a mapping", ckpt.get("path"))
        cfg_dict = dict(ckpt.get("model_config") or {})
        cfg_dict.update(model_overrides)
        try:
            model = cls(SeeUConfig(**cfg_dict))
        except (TypeError, ValueError, KeyError, AttributeError) as exc:
            msg = str(exc).splitlines()[0][:200] if str(exc) else type(exc).__name__
            raise SeeUError(f"checkpoint model config is not valid for this toolkit: {msg}", ckpt.get("path")) from None
        load_model_state(model, ckpt["model"], ckpt.get("path"))
        return model.to(device).eval()

    @torch.no_grad()
    def predict(self, images, intrinsics, cam_to_world, near, far) -> Gaussians:
        """3D Gaussians from V >= 2 posed context views of one scene (what `seeu predict` computes).

        images: (V, 3, H, W) float RGB in [0, 1] (H, W: multiples of `size_unit`, e.g. the training
            size; `pipelines.render.context_from_views` resizes and crops decoded images to it);
        intrinsics: (V, 3, 3) normalised (first row / W, second row / H: fx/W, fy/H, cx/W, cy/H, pixel
            corner at 0, centres at +0.5), as everywhere in the toolkit (`seeu_data.cameras`);
        cam_to_world: (V, 4, 4) OpenCV camera-to-world (x right, y down, z forward);
        near, far: the scene's depth range in the cameras' units (floats, or (V,) per view).
        Tensors or arrays; moved to the model's device as float32.
        Returns Gaussians with B = 1: means (1, N, 3), scales (1, N, 3), rotations (1, N, 4), opacities
        (1, N), sh (1, N, K, 3), N = V*H*W, in the cameras' world frame.
        """
        dev = next(self.parameters()).device
        img = torch.as_tensor(images, dtype=torch.float32, device=dev)
        v = img.shape[0]

        def per_view(x) -> torch.Tensor:
            return torch.as_tensor(x, dtype=torch.float32, device=dev).expand(v)[None].clone()

        context = {
            "image": img[None],
            "intrinsics": torch.as_tensor(intrinsics, dtype=torch.float32, device=dev)[None],
            "cam_to_world": torch.as_tensor(cam_to_world, dtype=torch.float32, device=dev)[None],
            "near": per_view(near),
            "far": per_view(far),
        }
        return self.encode(context)

    # ------------------------------------------------------------------------------------------
    # Rendering
    # ------------------------------------------------------------------------------------------
    @staticmethod
    def render(gaussians: Gaussians, cameras: dict, size: tuple[int, int], background=None, backend: str = "auto"):
        """Render Gaussians into cameras: cam_to_world (B, T, 4, 4), intrinsics (B, T, 3, 3) normalised,
        size (H, W) -> RenderOutput (color (B, T, 3, H, W), depth/alpha (B, T, 1, H, W)). Always float32."""
        from .rasterizer import rasterize

        h, w = size
        device_type = gaussians.means.device.type
        with torch.autocast(device_type=device_type, enabled=False):  # rasterise in float32, also under autocast
            g = gaussians.map(lambda t: t.float())
            return rasterize(
                g,
                cameras["cam_to_world"].float(),
                cameras["intrinsics"].float(),
                w,
                h,
                background=background,
                backend=backend,
            )

    def forward(self, batch: dict, render_coarse: bool = False, background=None, backend: str = "auto") -> SeeUOutput:
        """batch: the loader layout ("context" and optionally "target" dicts) -> SeeUOutput with the
        target views rendered at the target images' size (context size when no target image is given)."""
        enc = self.encode_all(batch["context"], decode_coarse=render_coarse)
        target = batch.get("target")
        render = coarse = None
        if target is not None:
            size = (
                tuple(target["image"].shape[-2:]) if "image" in target else tuple(batch["context"]["image"].shape[-2:])
            )
            render = self.render(enc.gaussians, target, size, background, backend)
            if render_coarse and enc.coarse_gaussians is not None:  # decoded when render_coarse
                coarse = self.render(enc.coarse_gaussians, target, size, background, backend)
        return SeeUOutput(enc, render, coarse)


def build_model(cfg: SeeUConfig | None = None) -> SeeU:
    """Build SeeU from a config (the paper's defaults when None)."""
    return SeeU(cfg or SeeUConfig())


def parameter_counts(model: SeeU) -> OrderedDict[str, tuple[int, int]]:
    """Per top-level module (the semantic encoder split out): name -> (trainable, frozen) parameter counts."""
    counts: OrderedDict[str, tuple[int, int]] = OrderedDict()
    for name, module in model.named_children():
        for sub_name, sub in [(name, module)] if name != "condition" else list(module.named_children()):
            key = name if sub is module else f"{name}.{sub_name}"
            trainable = sum(p.numel() for p in sub.parameters() if p.requires_grad)
            frozen = sum(p.numel() for p in sub.parameters() if not p.requires_grad)
            if trainable or frozen:
                counts[key] = (trainable, frozen)
    return counts
