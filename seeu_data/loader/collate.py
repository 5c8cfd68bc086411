"""Collate transformed samples into the model's batch (docs/ARCHITECTURE.md, "Loader batch").

```
{"context": {"image": (B, Vc, 3, H, W) float32 in [0, 1] (or uint8 with image_dtype="uint8"),
             "cam_to_world": (B, Vc, 4, 4) float32, "intrinsics": (B, Vc, 3, 3) float32 normalised,
             "near": (B, Vc) float32, "far": (B, Vc) float32, "frame_index": (B, Vc) int64},
 "target": {same keys, Vt views},
 "scene_id": list[str] (B), "sample_id": list[str] (B), "is_padding": (B,) bool}
```
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import torch
from torch.utils.data import get_worker_info

from ..errors import SeeUError
from .transforms import ViewsSample


def images_to_tensor(images: np.ndarray, dtype: str = "float32") -> torch.Tensor:
    """(..., 3, H, W) uint8 -> float32 in [0, 1] (or the uint8 itself), contiguous.

    Inside a DataLoader worker the result is allocated in shared memory up front, so handing the batch
    to the main process does not copy it again (what PyTorch's default collate does too).
    """
    u8 = torch.from_numpy(np.ascontiguousarray(images))
    if dtype == "uint8":
        return u8.clone() if get_worker_info() is None else u8.clone().share_memory_()
    out = torch.empty(u8.shape, dtype=torch.float32)
    if get_worker_info() is not None:
        out.share_memory_()
    torch.mul(u8, 1.0 / 255.0, out=out)
    return out


def collate_views(samples: Sequence[ViewsSample], is_padding: Sequence[bool], image_dtype: str = "float32",
                  images: np.ndarray | None = None, where: str = "") -> dict:
    """Stack samples into the batch dict. `images` (B, V, 3, H, W) uint8 if the samples already live in it."""
    if not samples:
        raise ValueError("empty batch")
    vc, v = samples[0].num_context, len(samples[0].frame_index)
    for s in samples:
        if (s.num_context, len(s.frame_index)) != (vc, v):
            raise SeeUError(f"sample {s.sample_id} has {s.num_context} context / {len(s.frame_index)} views, "
                            f"the batch has {vc} / {v}: batches need equal view counts", where)
    if images is None:
        images = np.stack([s.images for s in samples])

    def part(sl: slice) -> dict:
        return {
            "image": images_to_tensor(images[:, sl], image_dtype),
            "cam_to_world": torch.from_numpy(np.stack([s.cam_to_world[sl] for s in samples])),
            "intrinsics": torch.from_numpy(np.stack([s.intrinsics[sl] for s in samples])),
            "near": torch.from_numpy(np.stack([s.near[sl] for s in samples])),
            "far": torch.from_numpy(np.stack([s.far[sl] for s in samples])),
            "frame_index": torch.from_numpy(np.stack([s.frame_index[sl] for s in samples])),
        }

    return {
        "context": part(slice(0, vc)),
        "target": part(slice(vc, v)),
        "scene_id": [s.scene_id for s in samples],
        "sample_id": [s.sample_id for s in samples],
        "is_padding": torch.as_tensor(np.asarray(is_padding, dtype=bool)),
    }
