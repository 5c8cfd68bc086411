"""Process-group set-up for torchrun (single node or multi-node) and plain single-process runs.

``torchrun --nproc_per_node=G [--nnodes=N --node_rank=R --rdzv_endpoint=HOST:PORT] -m pipelines.cli train ...``
sets RANK / WORLD_SIZE / LOCAL_RANK / MASTER_ADDR / MASTER_PORT; `setup_distributed` reads them and
joins the group with NCCL on CUDA, gloo on CPU. Without them it is a no-op (world size 1).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from datetime import timedelta

import torch
import torch.distributed as dist


@dataclass
class DistInfo:
    rank: int = 0
    world_size: int = 1
    local_rank: int = 0
    device: torch.device = torch.device("cpu")
    initialized_here: bool = False

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    @property
    def enabled(self) -> bool:
        return self.world_size > 1


def pick_device(local_rank: int = 0, device: str | None = None) -> torch.device:
    """`device` if given ("cpu", "cuda", "cuda:1"), else this process's GPU, else the CPU."""
    if device:
        return torch.device(device)
    if torch.cuda.is_available():
        return torch.device("cuda", local_rank % torch.cuda.device_count())
    return torch.device("cpu")


def setup_distributed(device: str | None = None, backend: str | None = None, timeout_s: float = 1800.0) -> DistInfo:
    """Join the process group described by the torchrun environment (or the one already initialised)."""
    if dist.is_available() and dist.is_initialized():
        local = int(os.environ.get("LOCAL_RANK", dist.get_rank()))
        return DistInfo(dist.get_rank(), dist.get_world_size(), local, pick_device(local, device), False)
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return DistInfo(device=pick_device(0, device))
    rank = int(os.environ["RANK"])
    local = int(os.environ.get("LOCAL_RANK", rank))
    dev = pick_device(local, device)
    if dev.type == "cuda":
        torch.cuda.set_device(dev)
    backend = backend or ("nccl" if dev.type == "cuda" else "gloo")
    dist.init_process_group(backend, rank=rank, world_size=world, timeout=timedelta(seconds=timeout_s))
    return DistInfo(rank, world, local, dev, True)


def cleanup_distributed(info: DistInfo) -> None:
    if info.initialized_here and dist.is_initialized():
        dist.destroy_process_group()


def all_gather_objects(obj, info: DistInfo) -> list:
    """[obj of rank 0, obj of rank 1, ...] (a one-element list without a process group)."""
    if not info.enabled:
        return [obj]
    out = [None] * info.world_size
    dist.all_gather_object(out, obj)
    return out


def barrier(info: DistInfo) -> None:
    if info.enabled:
        dist.barrier()


def _all_reduce(value: float, dtype: torch.dtype, op, info: DistInfo) -> torch.Tensor:
    """`value` reduced with `op` over the ranks, as a one-element tensor on the CPU or the NCCL device."""
    t = torch.tensor([value], dtype=dtype)
    if dist.get_backend() == "nccl":
        t = t.to(info.device)
    dist.all_reduce(t, op=op)
    return t


def mean_across(value: float, info: DistInfo) -> float:
    """Average a Python float over the ranks (for logging)."""
    if not info.enabled:
        return value
    return float(_all_reduce(value, torch.float64, dist.ReduceOp.SUM, info).item()) / info.world_size


def max_across(value: int, info: DistInfo) -> int:
    """The largest of an integer over the ranks (a decision every rank must take alike)."""
    if not info.enabled:
        return value
    return int(_all_reduce(value, torch.int64, dist.ReduceOp.MAX, info).item())
