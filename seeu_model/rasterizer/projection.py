"""EWA projection of 3D Gaussians into pinhole cameras (the 3DGS / gsplat formula).

Per camera: world -> camera with `world_to_cam_from_cam_to_world`, the covariance
`Sigma = R S S^T R^T` rotated into the camera, the affine Jacobian of the perspective map at the
mean (with gsplat's off-screen clamp of x/z and y/z to 1.3x the field of view), 2D covariance
`J Sigma_c J^T + eps2d I` (the 0.3 px^2 low-pass), its inverse (the conic), and in anti-aliased
mode the opacity compensation `sqrt(det(cov) / det(cov + eps2d I))` (Mip-Splatting).

Visibility: `near_plane < z < far_plane` and a positive determinant. The exact pixel extent of a
Gaussian is where `opacity * exp(-power) >= 1/255`, i.e. `power <= log(255 opacity)`; its
bounding box has half-widths `sqrt(2 log(255 o) cov_xx)` and `sqrt(2 log(255 o) cov_yy)`
(`extent`); culling tiles with it never drops a contribution.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from kornia.geometry.conversions import quaternion_to_rotation_matrix

from seeu_data.cameras import intrinsics_pixels, world_to_cam_from_cam_to_world
from seeu_model.gaussians import Gaussians
from seeu_model.rasterizer.sh import sh_to_color

EPS2D = 0.3  # 3DGS low-pass: added to the 2D covariance, in px^2
ALPHA_MIN = 1.0 / 255.0  # contributions below this alpha are skipped
ALPHA_MAX = 0.99  # 3DGS alpha clamp (gsplat's kernel uses 0.999)
T_MIN = 1e-4  # a pixel stops at the Gaussian that would bring its transmittance to <= T_MIN (excluded)


@dataclass
class Projected:
    """Gaussians projected into C = B * V cameras (views flattened scene-major).

    means2d:   (C, N, 2) pixel coordinates, corner-at-origin convention
    conics:    (C, N, 3) inverse 2D covariance (a, b, c) = [[a, b], [b, c]]
    cov2d:     (C, N, 3) 2D covariance (xx, xy, yy) including the low-pass
    depths:    (C, N)    camera z
    opacities: (C, N)    opacity (times the anti-aliasing compensation), 0 where not visible
    colors:    (C, N, 3) view-dependent colour from SH
    valid:     (C, N)    bool, in front of the near plane, before the far plane, positive determinant
    """

    means2d: torch.Tensor
    conics: torch.Tensor
    cov2d: torch.Tensor
    depths: torch.Tensor
    opacities: torch.Tensor
    colors: torch.Tensor
    valid: torch.Tensor

    def extents(self) -> torch.Tensor:
        """Half-widths `(C, N, 2)` (x, y) in px of the region where alpha can reach 1/255 (no grad)."""
        with torch.no_grad():
            o = self.opacities.clamp_min(ALPHA_MIN)
            k = (2.0 * torch.log(o / ALPHA_MIN)).clamp_min(0.0)
            ext = torch.stack([(k * self.cov2d[..., 0]).sqrt(), (k * self.cov2d[..., 2]).sqrt()], -1)
            return torch.where((self.valid & (self.opacities >= ALPHA_MIN))[..., None], ext, torch.zeros_like(ext))


def covariance_3d(scales: torch.Tensor, rotations: torch.Tensor) -> torch.Tensor:
    """World covariance `R diag(s^2) R^T`: scales (..., 3) linear, rotations (..., 4) wxyz -> (..., 3, 3)."""
    rot = quaternion_to_rotation_matrix(rotations)  # kornia: wxyz, normalised first
    m = rot * scales[..., None, :]
    return m @ m.transpose(-1, -2)


def project_gaussians(
    gaussians: Gaussians,
    cam_to_world: torch.Tensor,
    intrinsics: torch.Tensor,
    width: int,
    height: int,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    eps2d: float = EPS2D,
    antialiased: bool = False,
) -> Projected:
    """Project `gaussians` (B, N, ...) into cameras `cam_to_world` (B, V, 4, 4) with normalised
    `intrinsics` (B, V, 3, 3) for a `width` x `height` image. Differentiable in the Gaussians."""
    means, scales, rots, opac, sh = (
        gaussians.means,
        gaussians.scales,
        gaussians.rotations,
        gaussians.opacities,
        gaussians.sh,
    )
    b, n = means.shape[:2]
    v = cam_to_world.shape[1]
    if cam_to_world.shape != (b, v, 4, 4) or intrinsics.shape != (b, v, 3, 3):
        raise ValueError(
            f"cameras must be (B, V, 4, 4) and (B, V, 3, 3) with B={b}, got "
            f"{tuple(cam_to_world.shape)} and {tuple(intrinsics.shape)}"
        )
    dtype = means.dtype
    w2c = world_to_cam_from_cam_to_world(cam_to_world.to(dtype))  # (B, V, 4, 4)
    k_pix = intrinsics_pixels(intrinsics.to(dtype), width, height)  # (B, V, 3, 3)
    rot_c = w2c[:, :, None, :3, :3]  # (B, V, 1, 3, 3)
    means_c = (rot_c @ means[:, None, :, :, None]).squeeze(-1) + w2c[:, :, None, :3, 3]  # (B, V, N, 3)
    cov_c = rot_c @ covariance_3d(scales, rots)[:, None] @ rot_c.transpose(-1, -2)  # (B, V, N, 3, 3)

    fx, fy = k_pix[..., 0, 0, None], k_pix[..., 1, 1, None]  # (B, V, 1)
    cx, cy = k_pix[..., 0, 2, None], k_pix[..., 1, 2, None]
    x, y, z = means_c.unbind(-1)  # (B, V, N)
    valid = (z > near_plane) & (z < far_plane)
    zs = torch.where(valid, z, torch.ones_like(z))  # safe divisor: keeps gradients finite
    tan_x, tan_y = 0.5 * width / fx, 0.5 * height / fy
    lim_x_pos, lim_x_neg = (width - cx) / fx + 0.3 * tan_x, cx / fx + 0.3 * tan_x
    lim_y_pos, lim_y_neg = (height - cy) / fy + 0.3 * tan_y, cy / fy + 0.3 * tan_y
    tx = zs * torch.minimum(torch.maximum(x / zs, -lim_x_neg), lim_x_pos)
    ty = zs * torch.minimum(torch.maximum(y / zs, -lim_y_neg), lim_y_pos)
    zero = torch.zeros_like(zs)
    jac = torch.stack(
        [torch.stack([fx / zs, zero, -fx * tx / zs**2], -1), torch.stack([zero, fy / zs, -fy * ty / zs**2], -1)], -2
    )  # (B, V, N, 2, 3)
    cov2 = jac @ cov_c @ jac.transpose(-1, -2)  # (B, V, N, 2, 2)
    cxx, cxy, cyy = cov2[..., 0, 0], 0.5 * (cov2[..., 0, 1] + cov2[..., 1, 0]), cov2[..., 1, 1]
    det_orig = cxx * cyy - cxy * cxy
    cxx, cyy = cxx + eps2d, cyy + eps2d
    det = cxx * cyy - cxy * cxy
    valid = valid & (det > 0)
    det_s = torch.where(valid, det, torch.ones_like(det))
    conics = torch.stack([cyy / det_s, -cxy / det_s, cxx / det_s], -1)
    means2d = torch.stack([fx * x / zs + cx, fy * y / zs + cy], -1)

    opac_v = opac[:, None, :].expand(b, v, n)
    if antialiased:
        comp = torch.sqrt(torch.clamp(torch.where(valid, det_orig, zero) / det_s, min=0.0))
        opac_v = opac_v * comp
    opac_v = torch.where(valid, opac_v, zero)

    cam_centres = cam_to_world[..., :3, 3].to(dtype)  # (B, V, 3)
    dirs = means[:, None] - cam_centres[:, :, None]  # (B, V, N, 3)
    colors = sh_to_color(sh[:, None].expand(b, v, *sh.shape[1:]), dirs)  # (B, V, N, 3)

    flat = lambda t: t.reshape(b * v, *t.shape[2:])  # noqa: E731
    return Projected(
        means2d=flat(means2d),
        conics=flat(conics),
        cov2d=flat(torch.stack([cxx, cxy, cyy], -1)),
        depths=flat(z),
        opacities=flat(opac_v),
        colors=flat(colors),
        valid=flat(valid),
    )
