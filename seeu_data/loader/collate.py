"""Collate transformed samples into the model's batch (docs/ARCHITECTURE.md, "Loader batch").

```
{"context": {"image": (B, Vc, 3, H, W) uint8 RGB (default; or float32 in [0, 1] with image_dtype="float32"),
             "cam_to_world": (B, Vc, 4, 4) float32, "intrinsics": (B, Vc, 3, 3) float32 normalised,
             "near": (B, Vc) float32, "far": (B, Vc) float32, "frame_index": (B, Vc) int64},
 "target": {same keys, Vt views},
 "scene_id": list[str] (B), "sample_id": list[str] (B), "is_padding": (B,) bool}
```
Images leave the loader as uint8 by default (a quarter of the bytes through shared memory, pinned
memory and the host-to-device copy); `batch_to_device` moves a batch and makes them float32 in
[0, 1] on the device -- the training and evaluation loops call it.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from torch.utils.data import get_worker_info

from seeu_data import cameras
from seeu_data.errors import SeeUError
from seeu_data.loader.transforms import ViewsSample
from seeu_data.loader.types import Batch

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
        view = memoryview(array).cast("B")  # type: ignore[arg-type]  # numpy arrays are buffers
        written = 0
        while written < array.nbytes:
            written += os.pwrite(fd, view[written:], written)
        storage = new_shared(fd, array.nbytes)  # dups the fd
    finally:
        os.close(fd)
    dtype = torch.from_numpy(array[:0].reshape(-1)).dtype
    return torch.empty(0, dtype=dtype).set_(storage, 0, array.shape)  # type: ignore[call-overload]


def to_unit_float(images: np.ndarray, out: np.ndarray) -> np.ndarray:
    """uint8 `images` -> `out` (float32, same shape) = images * float32(1/255), in [0, 1].

    A plain cast then an in-place multiply: numpy's mixed-type `multiply(uint8, float32)` goes through
    buffered casting and is ~2.5x slower (identical values).
    """
    np.copyto(out, images, casting="unsafe")
    np.multiply(out, np.float32(1.0 / 255.0), out=out)
    return out


def images_to_tensor(images: np.ndarray, dtype: str = "float32") -> torch.Tensor:
    """(..., 3, H, W) uint8 -> a new float32 tensor in [0, 1] (or a uint8 copy), contiguous.

    Inside a DataLoader worker the result is put in shared memory here (`_shared_tensor_from`), so
    handing the batch to the main process copies nothing more. In the main process it is allocated
    by numpy, whose allocator reuses freed memory (torch's returns fresh pages every time).
    """
    np_dtype = np.uint8 if dtype == "uint8" else np.float32
    in_worker = get_worker_info() is not None
    out_np = _staging(images.shape, np_dtype) if in_worker else np.empty(images.shape, dtype=np_dtype)
    to_unit_float(images, out_np) if dtype != "uint8" else np.copyto(out_np, images)
    if in_worker:
        shared = _shared_tensor_from(out_np)
        if shared is not None:
            return shared
        return torch.from_numpy(out_np.copy()).share_memory_()
    return torch.from_numpy(out_np)


def collate_views(
    samples: Sequence[ViewsSample],
    is_padding: Sequence[bool] | np.ndarray,
    image_dtype: str = "uint8",
    images: np.ndarray | None = None,
    where: str = "",
    ship: bool = False,
    ticket: dict | None = None,
) -> dict:
    """Stack samples into the batch dict. `images`: the (B, V, 3, H, W) uint8 buffer the samples' images live in.

    `ship=True` (DataLoader workers under `StreamingLoader`): the small fields stay numpy (pickled by
    value instead of one shared-memory file each) and the images stay where they are: `ticket` (from
    `ImageRing.ticket`) says which shared buffer holds them, or, without a ticket, they go as a uint8
    shared tensor under "_images". `finish_shipped_batch` in the main process turns either into the
    batch above.
    """
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
    wrap = (lambda a: a) if ship else torch.from_numpy

    def part(sl: slice) -> dict:
        out = {
            "cam_to_world": wrap(np.stack([s.cam_to_world[sl] for s in samples]).astype(np.float32)),
            "intrinsics": wrap(
                cameras.intrinsics_norm_matrix(np.stack([s.intrinsics_norm[sl] for s in samples])).astype(np.float32)
            ),
            "near": wrap(np.stack([s.near[sl] for s in samples])),
            "far": wrap(np.stack([s.far[sl] for s in samples])),
            "frame_index": wrap(np.stack([s.frame_index[sl] for s in samples])),
        }
        if not ship:
            out = {"image": images_to_tensor(images[:, sl], image_dtype), **out}
        return out

    batch = {
        "context": part(slice(0, vc)),
        "target": part(slice(vc, v)),
        "scene_id": [s.scene_id for s in samples],
        "sample_id": [s.sample_id for s in samples],
        "is_padding": wrap(np.asarray(is_padding, dtype=bool)),
    }
    if ship:
        if ticket is None:  # no ring: hand over one uint8 shared tensor
            ticket = {
                "worker": None,
                "seq": None,
                "slot": None,
                "shape": images.shape,
                "buffer": images_to_tensor(images, "uint8").reshape(-1),
            }
        batch["_images"] = {**ticket, "num_context": vc}
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


# ------------------------------------------------------------------------- worker -> main hand-off


class ImageRing:
    """Worker half of the image hand-off: a few batch buffers in shared memory, reused round-robin.

    The worker decodes straight into the buffer of its next batch and sends a small ticket (which
    buffer, which shape); a buffer's shared-memory handle crosses to the main process once, with its
    first ticket. `finish_shipped_batch` copies (or converts) the images out and then sets
    `released[worker]` to the number of this worker's batches it is done with; a buffer is written
    again only after that. The DataLoader keeps at most `prefetch_factor` batches per worker in flight,
    so with `slots = prefetch_factor + 1` the next buffer is always free; if it is not, the batch goes
    in a fresh shared buffer used once -- the worker never waits and never overwrites.

    Compared with a fresh shared tensor per batch this saves the worker a copy and the kernel a page
    allocation per 4 KiB of every batch (about 10 % of the worker's time at 256x256).
    """

    def __init__(self, released: torch.Tensor, worker: int, slots: int):
        self._released = released.numpy()  # (num_workers,) int64 in shared memory, written by the main process
        self.worker, self.slots = int(worker), int(slots)
        self._buffers: list[torch.Tensor | None] = [None] * self.slots
        self._sent = [False] * self.slots
        self._seq = 0  # batches this worker has produced
        self._pending: tuple | None = None  # (slot or None, 1-D uint8 shared tensor, shape)

    def buffer(self, shape: tuple[int, ...]) -> np.ndarray:
        """The (B, V, 3, H, W) uint8 array the next batch's images go into (the same until `ticket()`)."""
        shape = tuple(int(x) for x in shape)
        nbytes = int(np.prod(shape))
        if self._pending is None or self._pending[2] != shape:
            slot = self._seq % self.slots
            if int(self._released[self.worker]) >= self._seq - self.slots + 1:  # its last batch is released
                buf = self._buffers[slot]
                if buf is None or buf.numel() < nbytes:
                    buf = self._buffers[slot] = torch.empty(nbytes, dtype=torch.uint8).share_memory_()
                    self._sent[slot] = False
                self._pending = (slot, buf, shape)
            else:
                self._pending = (None, torch.empty(nbytes, dtype=torch.uint8).share_memory_(), shape)
        return self._pending[1].numpy()[:nbytes].reshape(shape)

    def ticket(self) -> dict:
        """Where the current batch's images are (for `collate_views`); the next `buffer()` is a new batch."""
        if self._pending is None:
            raise RuntimeError("ImageRing.ticket() before buffer()")
        slot, buf, shape = self._pending
        send = slot is None or not self._sent[slot]
        if slot is not None:
            self._sent[slot] = True
        t = {"worker": self.worker, "seq": self._seq, "slot": slot, "shape": shape, "buffer": buf if send else None}
        self._pending = None
        self._seq += 1
        return t


class ImageRingHost:
    """Main-process half of `ImageRing`: the shared `released` counters and the buffers received so far."""

    def __init__(self, num_workers: int, slots: int):
        self.released = torch.zeros(max(1, int(num_workers)), dtype=torch.int64).share_memory_()
        self._released = self.released.numpy()  # writing through numpy: ~50x cheaper than tensor indexing
        self.slots = int(slots)
        self._buffers: dict[tuple[int, int], torch.Tensor] = {}
        self.misses = 0  # batches that came in a one-off buffer (the ring slot was still in use)

    def images(self, ticket: dict) -> np.ndarray:
        """The (B, V, 3, H, W) uint8 images a ticket points at (valid until `release(ticket)`)."""
        buf = ticket["buffer"]
        if ticket["slot"] is not None:
            key = (ticket["worker"], ticket["slot"])
            if buf is not None:
                self._buffers[key] = buf  # keep the mapping: later tickets for this slot send no handle
            else:
                buf = self._buffers[key]
        elif ticket["worker"] is not None:
            self.misses += 1
        shape = tuple(ticket["shape"])
        return buf.numpy()[: int(np.prod(shape))].reshape(shape)

    def release(self, ticket: dict) -> None:
        """Let the worker write the ticket's buffer again (batches of a worker arrive in order)."""
        if ticket["worker"] is not None:
            self._released[ticket["worker"]] = ticket["seq"] + 1


def finish_shipped_batch(
    batch: dict, image_dtype: str = "uint8", ring: ImageRingHost | None = None, pin: bool = False
) -> Batch:
    """Main-process half of `collate_views(..., ship=True)`: the images out of shared memory (uint8 copied,
    or converted to float32 in [0, 1]), numpy -> tensors. `pin`: the images go straight into pinned memory."""
    ticket = batch.pop("_images")
    images = (
        ring.images(ticket)
        if ring is not None
        else ticket["buffer"].numpy()[: int(np.prod(ticket["shape"]))].reshape(ticket["shape"])
    )
    vc = ticket["num_context"]
    np_dtype, torch_dtype = (np.uint8, torch.uint8) if image_dtype == "uint8" else (np.float32, torch.float32)
    for key, sl in (("context", slice(0, vc)), ("target", slice(vc, None))):
        src = images[:, sl]
        if pin:
            out_t = torch.empty(src.shape, dtype=torch_dtype, pin_memory=True)
            out = out_t.numpy()
        else:
            out = np.empty(src.shape, dtype=np_dtype)  # numpy reuses freed memory: no fresh pages
            out_t = torch.from_numpy(out)
        to_unit_float(src, out) if image_dtype != "uint8" else np.copyto(out, src)
        part = batch[key]
        for name, value in part.items():
            part[name] = torch.from_numpy(value)
        batch[key] = {"image": out_t, **part}
    if ring is not None:
        ring.release(ticket)
    batch["is_padding"] = torch.from_numpy(batch["is_padding"])
    return batch  # type: ignore[return-value]  # filled in place into the Batch layout
