"""Real spherical harmonics for view-dependent Gaussian colour (the 3DGS / gsplat convention).

Basis order within a degree l is m = -l..l, with the sign convention of the 3DGS CUDA code
(degree 1 is `(-C1 y, C1 z, -C1 x)`): real SH built from the Condon-Shortley complex SH as
`sqrt(2) Im(Y_l^|m|)` for m < 0 and `sqrt(2) Re(Y_l^m)` for m > 0. Degrees 0..4 (K <= 25).
Colour = `clamp_min(0.5 + sum_k sh_k * Y_k(d), 0)` where d is the unit direction from the camera
centre to the Gaussian mean.
"""

from __future__ import annotations

import torch

MAX_SH_DEGREE = 4

C0 = 0.28209479177387814
C1 = 0.4886025119029199
C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
C3 = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)
C4 = (
    2.5033429417967046,
    -1.7701307697799304,
    0.9461746957575601,
    -0.6690465435572892,
    0.10578554691520431,
    -0.6690465435572892,
    0.47308734787878004,
    -1.7701307697799304,
    0.6258357354491761,
)


def num_sh_bases(degree: int) -> int:
    """K = (degree + 1)^2."""
    return (degree + 1) ** 2


def sh_degree_from_bases(k: int) -> int:
    """Inverse of `num_sh_bases`; ValueError when `k` is not a square up to degree 4."""
    deg = int(round(k**0.5)) - 1
    if deg < 0 or (deg + 1) ** 2 != k or deg > MAX_SH_DEGREE:
        raise ValueError(f"SH coefficient count {k} is not (degree + 1)^2 with degree 0..{MAX_SH_DEGREE}")
    return deg


def eval_sh_bases(degree: int, dirs: torch.Tensor) -> torch.Tensor:
    """SH basis values at unit directions `dirs` (..., 3) -> (..., (degree + 1)^2)."""
    if not 0 <= degree <= MAX_SH_DEGREE:
        raise ValueError(f"SH degree must be 0..{MAX_SH_DEGREE}, got {degree}")
    x, y, z = dirs.unbind(-1)
    out = [torch.full_like(x, C0)]
    if degree >= 1:
        out += [-C1 * y, C1 * z, -C1 * x]
    if degree >= 2:
        xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
        out += [C2[0] * xy, C2[1] * yz, C2[2] * (2 * zz - xx - yy), C2[3] * xz, C2[4] * (xx - yy)]
    if degree >= 3:
        out += [
            C3[0] * y * (3 * xx - yy),
            C3[1] * xy * z,
            C3[2] * y * (4 * zz - xx - yy),
            C3[3] * z * (2 * zz - 3 * xx - 3 * yy),
            C3[4] * x * (4 * zz - xx - yy),
            C3[5] * z * (xx - yy),
            C3[6] * x * (xx - 3 * yy),
        ]
    if degree >= 4:
        out += [
            C4[0] * xy * (xx - yy),
            C4[1] * yz * (3 * xx - yy),
            C4[2] * xy * (7 * zz - 1),
            C4[3] * yz * (7 * zz - 3),
            C4[4] * (zz * (35 * zz - 30) + 3),
            C4[5] * xz * (7 * zz - 3),
            C4[6] * (xx - yy) * (7 * zz - 1),
            C4[7] * xz * (xx - 3 * yy),
            C4[8] * (xx * (xx - 3 * yy) - yy * (3 * xx - yy)),
        ]
    return torch.stack(out, dim=-1)


def sh_to_color(sh: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
    """Colour `(..., 3)` from SH coefficients `(..., K, 3)` seen along `dirs` `(..., 3)` (any length).

    `clamp_min(0.5 + sum_k sh[k] * Y_k(dirs / |dirs|), 0)`, as 3DGS and gsplat do.
    """
    degree = sh_degree_from_bases(sh.shape[-2])
    unit = dirs / dirs.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    bases = eval_sh_bases(degree, unit)  # (..., K)
    return torch.clamp_min((bases.unsqueeze(-1) * sh).sum(-2) + 0.5, 0.0)
