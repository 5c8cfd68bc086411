"""The MVSplat encoder (Chen et al., "MVSplat: Efficient 3D Gaussian Splatting from Sparse Multi-View
Images", ECCV 2024), written for SeeU to reproduce its forward pass exactly, so that MVSplat's released
checkpoints run in SeeU after `seeu convert-checkpoint mvsplat` (parity: tests/test_mvsplat_parity.py).

    images (B, V, 3, H, W) in [0, 1], c2w (B, V, 4, 4), normalised intrinsics (B, V, 3, 3), near/far (B, V)
      MVSplatBackbone          -> features F, CNN features (B, V, C, h, w), h = H/4
      plane sweep              -> correlation with every other view at D disparities uniform in [1/far, 1/near]
                                  (mean over the other views) (B, V, D, h, w), concatenated with F
      cost UNet + 1x1 skip     -> refined cost (B, V, D, h, w) -> depth head -> softmax P over D
      coarse disparity         =  sum_d P_d * disparity_d; its maximum probability = matching confidence
      upsampled features, depth UNet on [image, features, disparity, confidence] (full resolution)
      disparity head           -> residual disparity (clamped to [1/far, 1/near]) and opacity (sigmoid)
      Gaussian head            -> per pixel: sub-pixel offset (2), scale (3), rotation (4), SH (3K)
      Gaussian adapter         -> Gaussians, one per pixel and view (N = V*H*W, view-major, row-major)

Conventions of MVSplat kept as they are: the Gaussian centre lies at distance ``depth`` along the unit
pixel ray (the ray length, not z); scales are ``depth * 0.1 * (pixel size in normalised camera units)``
times a sigmoid in [scale_min, scale_max]; SH degrees >= 1 are damped by 0.1 * 0.25^degree and rotated
to world space with e3nn's Wigner matrices (`sh_rotation`).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from seeu_data.cameras import rotmat_from_quat_xyzw

from .backbone import MVSplatBackbone
from .sh_rotation import rotate_sh
from .unet import RefineUNet


@dataclass(frozen=True)
class MVSplatShape:
    """The structure of an MVSplat encoder (MVSplat's RE10K / ACID release by default)."""

    cnn_channels: tuple[int, int, int] = (64, 96, 128)
    feature_dim: int = 128
    transformer_layers: int = 6
    ffn_ratio: int = 4
    windows: int = 2
    downsample: int = 4
    num_depth_candidates: int = 128
    cost_unet_channels: int = 128
    cost_unet_mult: tuple[int, ...] = (1, 1, 1)
    cost_unet_attention: tuple[int, ...] = (4,)
    depth_unet_channels: int = 32
    depth_unet_mult: tuple[int, ...] = (1, 1, 1, 1, 1)
    depth_unet_attention: tuple[int, ...] = (16,)
    sh_degree: int = 4
    scale_min: float = 0.5
    scale_max: float = 15.0


@dataclass
class MVSplatOutput:
    """Per-pixel results (N = V*H*W, view-major then row-major pixels).

    means (B, N, 3); scales (B, N, 3) camera-space std devs; rotations (B, N, 4) unit quaternions (w, x, y, z)
    in world space; covariances (B, N, 3, 3) world space; opacities (B, N); sh (B, N, K, 3) world space;
    depth (B, V, H, W); coarse_disparity (B, V, h, w); probabilities (B, V, D, h, w) softmax over the
    disparity candidates; disparities (B, V, D).
    """

    means: torch.Tensor
    scales: torch.Tensor
    rotations: torch.Tensor
    covariances: torch.Tensor
    opacities: torch.Tensor
    sh: torch.Tensor
    depth: torch.Tensor
    coarse_disparity: torch.Tensor
    probabilities: torch.Tensor
    disparities: torch.Tensor


def matrix_to_quaternion_wxyz(r: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) rotation -> (..., 4) unit quaternion (w, x, y, z), w >= 0 (branch on the largest term)."""
    m = r.reshape(-1, 3, 3)
    tr = m[:, 0, 0] + m[:, 1, 1] + m[:, 2, 2]
    cand = torch.stack(
        [
            torch.stack([1 + tr, m[:, 2, 1] - m[:, 1, 2], m[:, 0, 2] - m[:, 2, 0], m[:, 1, 0] - m[:, 0, 1]], -1),
            torch.stack(
                [
                    m[:, 2, 1] - m[:, 1, 2],
                    1 + m[:, 0, 0] - m[:, 1, 1] - m[:, 2, 2],
                    m[:, 0, 1] + m[:, 1, 0],
                    m[:, 0, 2] + m[:, 2, 0],
                ],
                -1,
            ),
            torch.stack(
                [
                    m[:, 0, 2] - m[:, 2, 0],
                    m[:, 0, 1] + m[:, 1, 0],
                    1 - m[:, 0, 0] + m[:, 1, 1] - m[:, 2, 2],
                    m[:, 1, 2] + m[:, 2, 1],
                ],
                -1,
            ),
            torch.stack(
                [
                    m[:, 1, 0] - m[:, 0, 1],
                    m[:, 0, 2] + m[:, 2, 0],
                    m[:, 1, 2] + m[:, 2, 1],
                    1 - m[:, 0, 0] - m[:, 1, 1] + m[:, 2, 2],
                ],
                -1,
            ),
        ],
        1,
    )  # (M, 4 candidates, 4): each is 4 * q * q_i for i = w, x, y, z
    diag = torch.stack(
        [
            1 + tr,
            1 + m[:, 0, 0] - m[:, 1, 1] - m[:, 2, 2],
            1 - m[:, 0, 0] + m[:, 1, 1] - m[:, 2, 2],
            1 - m[:, 0, 0] - m[:, 1, 1] + m[:, 2, 2],
        ],
        -1,
    )
    best = diag.argmax(-1)
    q = cand[torch.arange(m.shape[0], device=m.device), best]
    q = q / q.norm(dim=-1, keepdim=True)
    q = torch.where(q[:, :1] < 0, -q, q)
    return q.reshape(*r.shape[:-2], 4)


class MVSplatEncoder(nn.Module):
    def __init__(self, shape: MVSplatShape):
        super().__init__()
        self.shape = shape
        s = shape
        c, d = s.feature_dim, s.num_depth_candidates
        self.backbone = MVSplatBackbone(s.cnn_channels, c, s.transformer_layers, s.ffn_ratio, s.windows)
        # cost volume refinement
        cc = s.cost_unet_channels
        self.cost_in = nn.Conv2d(d + c, cc, 3, 1, 1)
        self.cost_in_norm = nn.GroupNorm(8, cc)
        self.cost_unet = RefineUNet(cc, s.cost_unet_mult, s.cost_unet_attention)
        self.cost_out = nn.Conv2d(cc, d, 3, 1, 1)
        self.cost_skip = nn.Conv2d(d + c, d, 1)
        self.depth_head = nn.Sequential(nn.Conv2d(d, 2 * d, 3, 1, 1), nn.GELU(), nn.Conv2d(2 * d, d, 3, 1, 1))
        # full-resolution features and depth refinement
        self.upsample_conv = nn.Conv2d(2 * c, c, 3, 1, 1)
        dc = s.depth_unet_channels
        self.feature_proj = nn.Conv2d(c, dc, 3, 1, 1)
        self.refine_in = nn.Conv2d(3 + dc + 2, dc, 3, 1, 1)
        self.refine_in_norm = nn.GroupNorm(4, dc)
        self.refine_unet = RefineUNet(dc, s.depth_unet_mult, s.depth_unet_attention)
        # heads
        self.sh_coeffs = (s.sh_degree + 1) ** 2
        raw = 2 + 7 + 3 * self.sh_coeffs
        self.gaussian_head = nn.Sequential(
            nn.Conv2d(dc + 3 + c, 2 * raw, 3, 1, 1), nn.GELU(), nn.Conv2d(2 * raw, raw, 3, 1, 1)
        )
        self.disparity_head = nn.Sequential(nn.Conv2d(dc, 2 * dc, 3, 1, 1), nn.GELU(), nn.Conv2d(2 * dc, 2, 3, 1, 1))
        mask = torch.ones(self.sh_coeffs)
        for degree in range(1, s.sh_degree + 1):
            mask[degree * degree : (degree + 1) ** 2] = 0.1 * 0.25**degree
        self.register_buffer("sh_damping", mask, persistent=False)

    # ------------------------------------------------------------------------------------------
    def _cost_volume(self, feats, c2w, intr, near, far):
        """feats (B, V, C, h, w) -> correlation (B, V, D, h, w), disparity candidates (B, V, D)."""
        b, v, c, h, w = feats.shape
        d = self.shape.num_depth_candidates
        t = torch.linspace(0.0, 1.0, d, device=feats.device)
        dmin, dmax = 1.0 / far, 1.0 / near  # (B, V)
        disp = (dmin[..., None] + t * (dmax - dmin)[..., None]).to(feats.dtype)  # (B, V, D)
        k = intr[..., :3, :3].clone()
        k[..., 0, :] *= float(w)
        k[..., 1, :] *= float(h)  # pixel units of the feature grid
        ys, xs = torch.meshgrid(
            torch.arange(h, device=feats.device), torch.arange(w, device=feats.device), indexing="ij"
        )
        pix = torch.stack([xs, ys, torch.ones_like(xs)], 0).float().reshape(3, h * w)
        if v == 2:  # as MVSplat: one relative pose and its inverse
            rel = torch.linalg.inv(c2w[:, 1]) @ c2w[:, 0]
            pairs = [[rel, torch.linalg.inv(rel)]]  # per shift: pose of each reference view into its source
        else:
            pairs = [[torch.linalg.inv(c2w[:, (r + s) % v]) @ c2w[:, r] for r in range(v)] for s in range(1, v)]
        corr_sum = []
        depth = (1.0 / disp).reshape(b * v, d, 1)  # (BV, D, 1)
        for s, poses in enumerate(pairs, start=1):
            src = feats[:, [(r + s) % v for r in range(v)]]  # (B, V, C, h, w)
            pose = torch.stack(poses, 1).reshape(b * v, 4, 4)
            kk = k.reshape(b * v, 3, 3)
            with torch.no_grad():
                rays = torch.linalg.inv(kk) @ pix  # (BV, 3, hw)
                pts = (pose[:, :3, :3] @ rays)[:, :, None, :] * depth[:, None]  # (BV, 3, D, hw)
                pts = pts + pose[:, :3, 3:, None]
                proj = (kk @ pts.reshape(b * v, 3, -1)).reshape(b * v, 3, d, h * w)
                xy = proj[:, :2] / proj[:, 2:].clamp(min=1e-3)
                grid = torch.stack([2 * xy[:, 0] / (w - 1) - 1, 2 * xy[:, 1] / (h - 1) - 1], -1)  # (BV, D, hw, 2)
            warped = F.grid_sample(
                src.reshape(b * v, c, h, w),
                grid.reshape(b * v, d * h, w, 2),
                mode="bilinear",
                padding_mode="zeros",
                align_corners=True,
            ).reshape(b * v, c, d, h, w)
            ref = feats.reshape(b * v, c, 1, h, w)
            corr_sum.append((ref * warped).sum(1) / c**0.5)  # (BV, D, h, w)
        corr = torch.stack(corr_sum, 0).mean(0)
        return corr.reshape(b, v, d, h, w), disp

    @property
    def raw_channels(self) -> int:
        """Per-pixel raw parameters: sub-pixel offset (2), scale (3), rotation (4), SH (3K), disparity residual
        (1), opacity logit (1)."""
        return 2 + 7 + 3 * self.sh_coeffs + 2

    def predict(
        self, images: torch.Tensor, c2w: torch.Tensor, intr: torch.Tensor, near: torch.Tensor, far: torch.Tensor
    ) -> dict:
        """Everything before the Gaussian adapter. images (B, V, 3, H, W) in [0, 1]; c2w (B, V, 4, 4);
        intrinsics (B, V, 3, 3) normalised; near/far (B, V) -> dict: raw (B, V, raw_channels, H, W),
        coarse_disparity_full (B, V, 1, H, W), coarse_disparity (B, V, h, w), probabilities (B, V, D, h, w),
        disparities (B, V, D), features (B, V, C, h, w)."""
        s = self.shape
        b, v, _, hh, ww = images.shape
        feats, cnn = self.backbone(images)
        _, _, c, h, w = feats.shape
        corr, disp = self._cost_volume(feats, c2w, intr, near, far)
        bv = b * v
        x = torch.cat([corr, feats], 2).reshape(bv, -1, h, w)
        cost = self.cost_out(self.cost_unet(F.gelu(self.cost_in_norm(self.cost_in(x))), v)) + self.cost_skip(x)
        prob = torch.softmax(self.depth_head(cost), 1)  # (BV, D, h, w)
        disp_flat = disp.reshape(bv, -1, 1, 1)
        coarse = (disp_flat * prob).sum(1, keepdim=True)  # (BV, 1, h, w)
        conf = F.interpolate(prob.max(1, keepdim=True)[0], scale_factor=s.downsample)  # nearest
        coarse_full = F.interpolate(coarse, scale_factor=s.downsample, mode="bilinear", align_corners=True)

        up = F.interpolate(
            self.upsample_conv(torch.cat([feats, cnn], 2).reshape(bv, 2 * c, h, w)),
            scale_factor=s.downsample,
            mode="bilinear",
            align_corners=True,
        )
        up = F.gelu(up)  # (BV, C, H, W)
        img = images.reshape(bv, 3, hh, ww)
        refine = torch.cat([img, self.feature_proj(up), coarse_full, conf], 1)
        refined = self.refine_unet(F.gelu(self.refine_in_norm(self.refine_in(refine))), v)
        raw = torch.cat([self.gaussian_head(torch.cat([refined, img, up], 1)), self.disparity_head(refined)], 1)
        return {
            "raw": raw.reshape(b, v, -1, hh, ww),
            "coarse_disparity_full": coarse_full.reshape(b, v, 1, hh, ww),
            "coarse_disparity": coarse.reshape(b, v, h, w),
            "probabilities": prob.reshape(b, v, -1, h, w),
            "disparities": disp,
            "features": feats,
        }

    def adapt(
        self, pred: dict, c2w: torch.Tensor, intr: torch.Tensor, near: torch.Tensor, far: torch.Tensor
    ) -> MVSplatOutput:
        """`predict`'s output (its ``raw`` possibly refined) -> Gaussians, MVSplat's activations."""
        s = self.shape
        raw_all = pred["raw"]
        b, v, _, hh, ww = raw_all.shape
        bv = b * v
        raw, delta, density = raw_all.reshape(bv, -1, hh, ww).split((self.raw_channels - 2, 1, 1), 1)
        coarse_full = pred["coarse_disparity_full"].reshape(bv, 1, hh, ww)
        lo = (1.0 / far).reshape(bv, 1, 1, 1)
        hi = (1.0 / near).reshape(bv, 1, 1, 1)
        depth = 1.0 / (coarse_full + delta).clamp(lo, hi)  # (BV, 1, H, W)
        p = torch.sigmoid(density)
        opacity = 0.5 * (1 - (1 - p) + p)  # MVSplat's pdf -> opacity map with exponent 1

        # Gaussian adapter, per pixel (flattened row-major)
        n = hh * ww
        raw = raw.reshape(b, v, -1, n).transpose(2, 3)  # (B, V, HW, R)
        depth_px = depth.reshape(b, v, n)
        k3 = intr[..., :3, :3]
        ys, xs = torch.meshgrid(
            torch.arange(hh, device=raw_all.device), torch.arange(ww, device=raw_all.device), indexing="ij"
        )
        pixel = torch.tensor((1 / ww, 1 / hh), dtype=torch.float32, device=raw_all.device)
        xy = torch.stack([(xs + 0.5) / ww, (ys + 0.5) / hh], -1).reshape(n, 2)
        xy = xy + (raw[..., :2].sigmoid() - 0.5) * pixel  # (B, V, HW, 2)
        scale_raw, quat, sh = raw[..., 2:].split((3, 4, 3 * self.sh_coeffs), -1)
        scales = s.scale_min + (s.scale_max - s.scale_min) * scale_raw.sigmoid()
        footprint = 0.1 * (torch.linalg.inv(k3[..., :2, :2]) @ pixel).sum(-1)  # (B, V)
        scales = scales * depth_px[..., None] * footprint[:, :, None, None]
        quat = quat / (quat.norm(dim=-1, keepdim=True) + 1e-8)  # (x, y, z, w), camera space
        rot_cam = rotmat_from_quat_xyzw(quat)
        r_c2w = c2w[..., :3, :3][:, :, None]  # (B, V, 1, 3, 3)
        cov_cam = rot_cam @ torch.diag_embed(scales) @ torch.diag_embed(scales) @ rot_cam.transpose(-1, -2)
        cov = r_c2w @ cov_cam @ r_c2w.transpose(-1, -2)
        dirs = torch.cat([xy, torch.ones_like(xy[..., :1])], -1)  # (B, V, HW, 3)
        dirs = (torch.linalg.inv(k3)[:, :, None] @ dirs[..., None])[..., 0]
        dirs = dirs / dirs.norm(dim=-1, keepdim=True)
        dirs = (r_c2w @ dirs[..., None])[..., 0]
        means = c2w[..., None, :3, 3] + dirs * depth_px[..., None]
        sh = sh.reshape(b, v, n, 3, self.sh_coeffs) * self.sh_damping
        sh = rotate_sh(sh, c2w[..., :3, :3][:, :, None])  # (B, V, HW, 3, K)
        rotations = matrix_to_quaternion_wxyz(r_c2w @ rot_cam)

        def flat(t: torch.Tensor) -> torch.Tensor:
            return t.reshape(b, v * n, *t.shape[3:])

        return MVSplatOutput(
            means=flat(means),
            scales=flat(scales),
            rotations=flat(rotations),
            covariances=flat(cov),
            opacities=opacity.reshape(b, v * n),
            sh=flat(sh).transpose(-1, -2),
            depth=depth.reshape(b, v, hh, ww),
            coarse_disparity=pred["coarse_disparity"],
            probabilities=pred["probabilities"],
            disparities=pred["disparities"],
        )

    def forward(
        self, images: torch.Tensor, c2w: torch.Tensor, intr: torch.Tensor, near: torch.Tensor, far: torch.Tensor
    ) -> MVSplatOutput:
        """images (B, V, 3, H, W) in [0, 1]; c2w (B, V, 4, 4); intrinsics (B, V, 3, 3) normalised; near/far (B, V)."""
        return self.adapt(self.predict(images, c2w, intr, near, far), c2w, intr, near, far)
