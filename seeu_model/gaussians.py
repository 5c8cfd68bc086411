"""The Gaussian set passed between the model, the rasterizer and the .ply exporter."""

from __future__ import annotations

from dataclasses import dataclass, fields

import torch


@dataclass
class Gaussians:
    """A batch of 3D Gaussians in world space (OpenCV world of the sample's cameras).

    means:      (B, N, 3)
    scales:     (B, N, 3)   linear (not log) standard deviations along the local axes
    rotations:  (B, N, 4)   quaternions (w, x, y, z); normalised by consumers
    opacities:  (B, N)      in [0, 1]
    sh:         (B, N, K, 3) spherical-harmonic colour coefficients, K = (degree + 1)^2;
                SH degree 0 means colour = 0.5 + C0 * sh[..., 0, :] (the 3DGS convention)
    """

    means: torch.Tensor
    scales: torch.Tensor
    rotations: torch.Tensor
    opacities: torch.Tensor
    sh: torch.Tensor

    @property
    def sh_degree(self) -> int:
        return int(round(self.sh.shape[-2] ** 0.5)) - 1

    def __len__(self) -> int:
        return self.means.shape[1]

    def map(self, fn) -> Gaussians:
        """Apply `fn` to every tensor field (e.g. `.detach()`, `.to(device)`, indexing)."""
        return Gaussians(**{f.name: fn(getattr(self, f.name)) for f in fields(self)})
