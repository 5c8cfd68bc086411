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

import os
from typing import Sequence

import numpy as np
import torch
from torch.utils.data import get_worker_info

from ..errors import SeeUError
from .transforms import ViewsSample


_STAGING: dict[tuple, np.ndarray] = {}  # per-process reusable staging buffers (shape, dtype) -> array


def _staging(shape: tuple, dtype) -> np.ndarray:
    key = (tuple(shape), np.dtype(dtype).str)
    buf = _STAGING.get(key)
    if buf is None:
        if len(_STAGING) >= 8:
            _STAGING.pop(next(iter(_STAGING)))
        buf = _STAGING[key] = np.empty(shape, dtype=dtype)
    return buf


def _shared_tensor_from(array: np.ndarray) -> torch.Tensor | None:
    """A tensor in a new shared-memory file holding a copy of `array`, written with one pwrite().

    Filling fresh shared memory through a mapping costs a page fault per 4 KiB page, more than the
    arithmetic that produced the data; writing the file (memfd) lets the kernel allocate in bulk.
    The storage is what PyTorch's "file_descriptor" sharing sends as is. None if not available here.
    """
    if not hasattr(os, "memfd_create") or torch.multiprocessing.get_sharing_strategy() != "file_descriptor":
        return None
    new_shared = getattr(torch.UntypedStorage, "_new_shared_fd_cpu", None)
    if new_shared is None:
        return None
    fd = os.memfd_create("seeu-batch", os.MFD_CLOEXEC)
    try:
        view = memoryview(array).cast("B")
        written = 0
        while written < array.nbytes:
            written += os.pwrite(fd, view[written:], written)
        storage = new_shared(fd, array.nbytes)  # dups the fd
    finally:
        os.close(fd)
    dtype = torch.from_numpy(array[:0].reshape(-1)).dtype
    return torch.empty(0, dtype=dtype).set_(storage, 0, array.shape)


def images_to_tensor(images: np.ndarray, dtype: str = "float32") -> torch.Tensor:
    """(..., 3, H, W) uint8 -> a new float32 tensor in [0, 1] (or a uint8 copy), contiguous.

    Inside a DataLoader worker the result is put in shared memory here (`_shared_tensor_from`), so
    handing the batch to the main process copies nothing more. In the main process it is allocated
    by numpy, whose allocator reuses freed memory (torch's returns fresh pages every time).
    """
    np_dtype = np.uint8 if dtype == "uint8" else np.float32
    in_worker = get_worker_info() is not None
    out_np = _staging(images.shape, np_dtype) if in_worker else np.empty(images.shape, dtype=np_dtype)
    if dtype == "uint8":
        np.copyto(out_np, images)
    else:
        np.multiply(images, np.float32(1.0 / 255.0), out=out_np, dtype=np.float32)
    if in_worker:
        shared = _shared_tensor_from(out_np)
        if shared is not None:
            return shared
        return torch.from_numpy(out_np.copy()).share_memory_()
    return torch.from_numpy(out_np)


def collate_views(samples: Sequence[ViewsSample], is_padding: Sequence[bool], image_dtype: str = "float32",
                  images: np.ndarray | None = None, where: str = "", ship: bool = False) -> dict:
    """Stack samples into the batch dict. `images`: the (B, V, 3, H, W) uint8 buffer the samples' images live in.

    `ship=True` (DataLoader workers under `StreamingLoader`): images stay uint8 (a quarter of the bytes
    to hand over) and the small fields stay numpy (pickled by value instead of one shared-memory file
    each); `finish_shipped_batch` in the main process turns that into the batch above.
    """
    if not samples:
        raise ValueError("empty batch")
    vc, v = samples[0].num_context, len(samples[0].frame_index)
    for s in samples:
        if (s.num_context, len(s.frame_index)) != (vc, v):
            raise SeeUError(f"sample {s.sample_id} has {s.num_context} context / {len(s.frame_index)} views, "
                            f"the batch has {vc} / {v}: batches need equal view counts", where)
    if images is None:
        images = np.stack([s.images for s in samples])
    wrap = (lambda a: a) if ship else torch.from_numpy

    def part(sl: slice) -> dict:
        return {
            "image": images_to_tensor(images[:, sl], "uint8" if ship else image_dtype),
            "cam_to_world": wrap(np.stack([s.cam_to_world[sl] for s in samples])),
            "intrinsics": wrap(np.stack([s.intrinsics[sl] for s in samples])),
            "near": wrap(np.stack([s.near[sl] for s in samples])),
            "far": wrap(np.stack([s.far[sl] for s in samples])),
            "frame_index": wrap(np.stack([s.frame_index[sl] for s in samples])),
        }

    return {
        "context": part(slice(0, vc)),
        "target": part(slice(vc, v)),
        "scene_id": [s.scene_id for s in samples],
        "sample_id": [s.sample_id for s in samples],
        "is_padding": wrap(np.asarray(is_padding, dtype=bool)),
    }


def finish_shipped_batch(batch: dict, image_dtype: str = "float32") -> dict:
    """Main-process half of `collate_views(..., ship=True)`: numpy -> tensors, uint8 -> float32 in [0, 1]."""
    for key in ("context", "target"):
        part = batch[key]
        for name, value in part.items():
            if name == "image":
                if image_dtype == "float32":
                    out = np.empty(value.shape, dtype=np.float32)  # numpy reuses freed memory: no fresh pages
                    np.multiply(value.numpy(), np.float32(1.0 / 255.0), out=out, dtype=np.float32)
                    part[name] = torch.from_numpy(out)
            else:
                part[name] = torch.from_numpy(value)
    batch["is_padding"] = torch.from_numpy(batch["is_padding"])
    return batch
