"""Streaming loader for triple shards: deterministic, elastic, resumable (see `dataset.py`).

`make_loader(shards, batch_size, ...)` -> `StreamingLoader`; the order/partition maths is in `order.py`.
"""

from seeu_data.loader.collate import batch_to_device
from seeu_data.loader.curriculum import GapCurriculum
from seeu_data.loader.dataset import LoaderConfig, StreamingLoader, TripleStream, make_loader
from seeu_data.loader.order import epoch_order, manifest_fingerprint, plan_global_batches, rank_worker_batches
from seeu_data.loader.source import ShardSource
from seeu_data.loader.types import Batch, Views

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
