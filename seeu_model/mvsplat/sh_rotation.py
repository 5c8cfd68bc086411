"""Rotating spherical-harmonic colour coefficients the way MVSplat does.

MVSplat predicts SH coefficients in camera space and rotates them into world space with the Wigner D
matrices of the ``e3nn`` library. Those act on e3nn's real SH basis, whose polar axis is y (the
standard real basis evaluated at the permuted point (z, x, y), with some components' signs flipped),
not on the basis the 3DGS rasteriser evaluates. A model trained with that rotation expects it, so the
MVSplat variant applies the same map. Here it is computed without e3nn: for a rotation R, the matrix
D_l(R) with Y_l(R d) = D_l(R) Y_l(d) for all unit directions d is found by least squares over a fixed
set of directions (exact up to float64 rounding, since the Y_l span an invariant space).
"""

from __future__ import annotations

import math

import torch

# Orthonormal real SH (z-polar), degrees 1..4, as products of (x, y, z); the constants are the standard
# normalisations (the ones the 3DGS rasteriser uses).
_C1 = 0.4886025119029199
_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154, -0.4570457994644658,
       1.445305721320277, -0.5900435899266435)
_C4 = (2.5033429417967046, -1.7701307697799304, 0.9461746957575601, -0.6690465435572892, 0.10578554691520431,
       -0.6690465435572892, 0.47308734787878004, -1.7701307697799304, 0.6258357354491761)

# Sign of each component of e3nn's basis relative to the standard one at the permuted point.
_E3NN_SIGNS = {
    1: (-1, 1, -1),
    2: (1, -1, 1, -1, 1),
    3: (-1, 1, -1, 1, -1, 1, -1),
    4: (1, -1, 1, -1, 1, -1, 1, -1, 1),
}


def _standard_sh(degree: int, d: torch.Tensor) -> torch.Tensor:
    """Unit directions (N, 3) -> standard real SH of one degree (N, 2l+1), z-polar."""
    x, y, z = d.unbind(-1)
    xx, yy, zz = x * x, y * y, z * z
    if degree == 1:
        return torch.stack([-_C1 * y, _C1 * z, -_C1 * x], -1)
    if degree == 2:
        c = _C2
        return torch.stack([c[0] * x * y, c[1] * y * z, c[2] * (2 * zz - xx - yy), c[3] * x * z, c[4] * (xx - yy)], -1)
    if degree == 3:
        c = _C3
        return torch.stack([c[0] * y * (3 * xx - yy), c[1] * x * y * z, c[2] * y * (4 * zz - xx - yy),
                            c[3] * z * (2 * zz - 3 * xx - 3 * yy), c[4] * x * (4 * zz - xx - yy),
                            c[5] * z * (xx - yy), c[6] * x * (xx - 3 * yy)], -1)
    if degree == 4:
        c = _C4
        return torch.stack([c[0] * x * y * (xx - yy), c[1] * y * z * (3 * xx - yy), c[2] * x * y * (7 * zz - 1),
                            c[3] * y * z * (7 * zz - 3), c[4] * (zz * (35 * zz - 30) + 3), c[5] * x * z * (7 * zz - 3),
                            c[6] * (xx - yy) * (7 * zz - 1), c[7] * x * z * (xx - 3 * yy),
                            c[8] * (xx * (xx - 3 * yy) - yy * (3 * xx - yy))], -1)
    raise ValueError(f"SH degree {degree} is not supported (1..4)")


def e3nn_basis(degree: int, d: torch.Tensor) -> torch.Tensor:
    """Unit directions (N, 3) -> e3nn's real SH basis of one degree (N, 2l+1), up to a common factor."""
    signs = torch.tensor(_E3NN_SIGNS[degree], dtype=d.dtype, device=d.device)
    return _standard_sh(degree, d[..., [2, 0, 1]]) * signs


def _fibonacci_directions(n: int) -> torch.Tensor:
    i = torch.arange(n, dtype=torch.float64) + 0.5
    z = 1 - 2 * i / n
    r = (1 - z * z).sqrt()
    phi = i * math.pi * (3 - math.sqrt(5))
    return torch.stack([r * phi.cos(), r * phi.sin(), z], -1)


def wigner_matrices(rotations: torch.Tensor, max_degree: int) -> list[torch.Tensor]:
    """Rotations (..., 3, 3) -> [D_1, ..., D_L], D_l (..., 2l+1, 2l+1) in e3nn's basis, float64."""
    dirs = _fibonacci_directions(64)  # (N, 3)
    r = rotations.to(torch.float64)
    rotated = torch.einsum("...ij,nj->...ni", r, dirs)  # (..., N, 3)
    out = []
    for degree in range(1, max_degree + 1):
        y = e3nn_basis(degree, dirs)  # (N, K)
        y_rot = e3nn_basis(degree, rotated)  # (..., N, K)
        # y_rot = y @ D^T  ->  D^T = pinv(y) @ y_rot
        out.append((torch.linalg.pinv(y) @ y_rot).transpose(-1, -2))
    return out


def rotate_sh(sh: torch.Tensor, rotations: torch.Tensor) -> torch.Tensor:
    """sh (..., 3, K) with K = (L+1)^2 coefficients per colour channel, rotations (..., 3, 3) broadcastable
    to sh's leading dims -> rotated sh (..., 3, K) (degree 0 unchanged)."""
    k = sh.shape[-1]
    max_degree = math.isqrt(k) - 1
    parts = [sh[..., :1]]
    for degree, d in enumerate(wigner_matrices(rotations, max_degree), start=1):
        block = sh[..., degree * degree:(degree + 1) ** 2]
        parts.append(torch.einsum("...ij,...cj->...ci", d.to(sh.dtype), block))
    return torch.cat(parts, -1)
