"""Rotating spherical-harmonic colour coefficients the way MVSplat does.

MVSplat predicts SH coefficients in camera space and rotates them into world space with the Wigner D
matrices of the ``e3nn`` library. Those act on e3nn's real SH basis, whose polar axis is y (the
standard real basis of `seeu_model.rasterizer.sh` evaluated at the permuted point (z, x, y), with some
components' signs flipped),
not on the basis the 3DGS rasteriser evaluates. A model trained with that rotation expects it, so the
MVSplat variant applies the same map. Here it is computed without e3nn: for a rotation R, the matrix
D_l(R) with Y_l(R d) = D_l(R) Y_l(d) for all unit directions d is found by least squares over a fixed
set of directions (exact up to float64 rounding, since the Y_l span an invariant space).
"""

from __future__ import annotations

import math

import torch

from seeu_model.rasterizer.sh import eval_sh_bases

# Sign of each component of e3nn's basis relative to the standard one at the permuted point.
_E3NN_SIGNS = {
    1: (-1, 1, -1),
    2: (1, -1, 1, -1, 1),
    3: (-1, 1, -1, 1, -1, 1, -1),
    4: (1, -1, 1, -1, 1, -1, 1, -1, 1),
}


def e3nn_basis(degree: int, d: torch.Tensor) -> torch.Tensor:
    """Unit directions (N, 3) -> e3nn's real SH basis of one degree (N, 2l+1), up to a common factor."""
    signs = torch.tensor(_E3NN_SIGNS[degree], dtype=d.dtype, device=d.device)
    return eval_sh_bases(degree, d[..., [2, 0, 1]])[..., degree * degree :] * signs


def _fibonacci_directions(n: int) -> torch.Tensor:
    i = torch.arange(n, dtype=torch.float64) + 0.5
    z = 1 - 2 * i / n
    r = (1 - z * z).sqrt()
    phi = i * math.pi * (3 - math.sqrt(5))
    return torch.stack([r * phi.cos(), r * phi.sin(), z], -1)


def wigner_matrices(rotations: torch.Tensor, max_degree: int) -> list[torch.Tensor]:
    """Rotations (..., 3, 3) -> [D_1, ..., D_L], D_l (..., 2l+1, 2l+1) in e3nn's basis, float64."""
    dirs = _fibonacci_directions(64).to(rotations.device)  # (N, 3)
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
        block = sh[..., degree * degree : (degree + 1) ** 2]
        parts.append(torch.einsum("...ij,...cj->...ci", d.to(sh.dtype), block))
    return torch.cat(parts, -1)
