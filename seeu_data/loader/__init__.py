"""Streaming loader for triple shards: deterministic, elastic, resumable (see `dataset.py`).

`make_loader(shards, batch_size, ...)` -> `StreamingLoader`; the order/partition maths is in `order.py`.
"""

from .collate import batch_to_device
from .curriculum import GapCurriculum
from .dataset import LoaderConfig, StreamingLoader, TripleStream, make_loader
from .order import epoch_order, manifest_fingerprint, plan_global_batches, rank_worker_batches
from .source import ShardSource
from .types import Batch, Views

__all__ = [
    "Batch",
    "Views",
    "batch_to_device",
    "GapCurriculum",
    "LoaderConfig",
    "StreamingLoader",
    "TripleStream",
    "make_loader",
    "epoch_order",
    "manifest_fingerprint",
    "plan_global_batches",
    "rank_worker_batches",
    "ShardSource",
]
