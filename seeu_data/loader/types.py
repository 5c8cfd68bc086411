"""The loader's batch, typed (what `StreamingLoader` yields and `batch_to_device` moves).

B samples, V context views, T target views, H x W the loader's output size. Cameras follow
`seeu_data.cameras`: OpenCV axes, camera-to-world, intrinsics normalised by the image size.
"""

from __future__ import annotations

from typing import NotRequired, TypedDict

import torch


class Views(TypedDict):
    """The context (N = V) or target (N = T) views of a batch."""

    image: torch.Tensor  # (B, N, 3, H, W) uint8 (default), or float32 in [0, 1] (`batch_to_device`)
    cam_to_world: torch.Tensor  # (B, N, 4, 4) float32
    intrinsics: torch.Tensor  # (B, N, 3, 3) float32, row 0 divided by W, row 1 by H
    near: torch.Tensor  # (B, N) float32
    far: torch.Tensor  # (B, N) float32
    frame_index: torch.Tensor  # (B, N) int64, the frames' indices in their scene
    mask: NotRequired[torch.Tensor]  # (B, N, H, W) bool, True = excluded pixel; only when a view has a mask


class Batch(TypedDict):
    """One loader batch."""

    context: Views
    target: Views
    scene_id: list[str]  # (B,)
    sample_id: list[str]  # (B,)
    is_padding: torch.Tensor  # (B,) bool: filler samples that keep ranks' batch counts equal
