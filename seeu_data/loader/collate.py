"""Collate transformed samples into the model's batch (docs/ARCHITECTURE.md, "Loader batch").

```
{"context": {"image": (B, Vc, 3, H, W) uint8 RGB (default; or float32 in [0, 1] with image_dtype="float32"),
             "cam_to_world": (B, Vc, 4, 4) float32, "intrinsics": (B, Vc, 3, 3) float32 normalised,
             "near": (B, Vc) float32, "far": (B, Vc) float32, "frame_index": (B, Vc) int64,
             "mask": (B, Vc, H, W) bool, True = excluded pixel -- only in batches where a view has a mask},
 "target": {same keys, Vt views},
 "scene_id": list[str] (B), "sample_id": list[str] (B), "is_padding": (B,) bool}
```
Images leave the loader as uint8 by default (a quarter of the bytes through shared memory, pinned
memory and the host-to-device copy); `batch_to_device` moves a batch and makes them float32 in
[0, 1] on the device -- the training and evaluation loops call it.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from torch.utils.data import get_worker_info

from seeu_data import cameras
from seeu_data.errors import SeeUError
from seeu_data.loader.transforms import ViewsSample


def to_unit_float(images: np.ndarray, out: np.ndarray) -> np.ndarray:
    """uint8 `images` -> `out` (float32, same shape) = images * float32(1/255), in [0, 1].

    A plain cast then an in-place multiply: numpy's mixed-type `multiply(uint8, float32)` goes through
    buffered casting and is ~2.5x slower (identical values).
    """
    np.copyto(out, images, casting="unsafe")
    np.multiply(out, np.float32(1.0 / 255.0), out=out)
    return out


def images_to_tensor(images: np.ndarray, dtype: str = "float32") -> torch.Tensor:
    """(..., 3, H, W) uint8 -> a new float32 tensor in [0, 1] (or a uint8 copy), contiguous. In a
    DataLoader worker it is made in shared memory, as torch's default collate does, so the DataLoader
    hands it to the main process without another copy."""
    out = torch.empty(images.shape, dtype=torch.uint8 if dtype == "uint8" else torch.float32)
    if get_worker_info() is not None:
        out.share_memory_()
    to_unit_float(images, out.numpy()) if dtype != "uint8" else np.copyto(out.numpy(), images)
    return out


def collate_views(
    samples: Sequence[ViewsSample],
    is_padding: Sequence[bool] | np.ndarray,
    image_dtype: str = "uint8",
    images: np.ndarray | None = None,
    where: str = "",
) -> dict:
    """Stack samples into the batch dict, the images as tensors and the other fields as numpy arrays
    (`StreamingLoader` makes them tensors in the main process). `images`: the (B, V, 3, H, W) uint8
    buffer the samples' images live in (copied out: the buffer is reused)."""
    if not samples:
        raise ValueError("empty batch")
    vc, v = samples[0].num_context, len(samples[0].frame_index)
    for s in samples:
        if (s.num_context, len(s.frame_index)) != (vc, v):
            raise SeeUError(
                f"sample {s.sample_id} has {s.num_context} context / {len(s.frame_index)} views, "
                f"the batch has {vc} / {v}: batches need equal view counts",
                where,
            )
    if images is None:
        images = np.stack([s.images for s in samples])
    masks = None
    if any(s.masks is not None for s in samples):
        masks = np.zeros(images.shape[:2] + images.shape[3:], dtype=bool)  # (B, V, H, W)
        for k, s in enumerate(samples):
            if s.masks is not None:
                masks[k] = s.masks

    def part(sl: slice) -> dict:
        views = {
            "image": images_to_tensor(images[:, sl], image_dtype),
            "cam_to_world": np.stack([s.cam_to_world[sl] for s in samples]).astype(np.float32),
            "intrinsics": cameras.intrinsics_norm_matrix(np.stack([s.intrinsics_norm[sl] for s in samples])).astype(
                np.float32
            ),
            "near": np.stack([s.near[sl] for s in samples]),
            "far": np.stack([s.far[sl] for s in samples]),
            "frame_index": np.stack([s.frame_index[sl] for s in samples]),
        }
        if masks is not None:
            views["mask"] = masks[:, sl]
        return views

    batch = {
        "context": part(slice(0, vc)),
        "target": part(slice(vc, v)),
        "scene_id": [s.scene_id for s in samples],
        "sample_id": [s.sample_id for s in samples],
        "is_padding": np.asarray(is_padding, dtype=bool),
    }
    return batch


def image_to_float(image: torch.Tensor) -> torch.Tensor:
    """A loader image tensor as float32 in [0, 1]: uint8 -> float32 * float32(1/255) (the same values the
    loader's float32 output has, on any device); float tensors are returned as they are."""
    if image.dtype != torch.uint8:
        return image
    return image.to(torch.float32).mul_(1.0 / 255.0)


def batch_to_device(batch: Any, device: torch.device | str, non_blocking: bool = True) -> Any:
    """Move every tensor of a (nested) loader batch to `device`; uint8 images become float32 in [0, 1] there.

    The loader's default uint8 images thus cost a quarter of the bytes up to the device and are converted
    there (a GPU does it for free); float32 batches just move. The training and evaluation loops call this.
    """
    if isinstance(batch, torch.Tensor):
        return batch.to(device, non_blocking=non_blocking)
    if isinstance(batch, dict):
        return {
            k: image_to_float(v.to(device, non_blocking=non_blocking))
            if k == "image" and isinstance(v, torch.Tensor)
            else batch_to_device(v, device, non_blocking)
            for k, v in batch.items()
        }
    if isinstance(batch, (list, tuple)) and batch and isinstance(batch[0], torch.Tensor):
        return type(batch)(batch_to_device(v, device, non_blocking) for v in batch)
    return batch
