"""The streaming dataset (a PyTorch IterableDataset) and `StreamingLoader`, its resumable DataLoader.

```
loader = make_loader("s3://bucket/re10k-triples", batch_size=14, num_workers=4, seed=0, flip_p=0.5)
for epoch in range(start_epoch, epochs):
    loader.set_epoch(epoch)
    for batch in loader:          # docs/ARCHITECTURE.md "Loader batch" (+ "is_padding"); images uint8
        batch = batch_to_device(batch, "cuda")   # images -> float32 in [0, 1] on the GPU
        ...
        ckpt["loader"] = loader.state_dict()   # {"epoch", "samples_seen", "step", ...} integers
loader.load_state_dict(ckpt["loader"])           # also with other num_workers / world_size / batch size
```

Order and partition: `seeu_data.loader.order`. The plan of the current epoch is computed in the
main process when iteration starts (every rank computes the same one) and handed to the workers,
which read, decode and collate whole batches; batch j of a rank comes from worker j % num_workers,
and the DataLoader returns batches round-robin, so the output order does not depend on the worker
count. Each batch carries the global `samples_seen` after it, which the loader records when it hands
the batch out: a checkpoint taken between two batches resumes exactly.
"""

from __future__ import annotations

import os
import time
import warnings
from collections import OrderedDict
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.data import DataLoader, IterableDataset, get_worker_info

from seeu_data.errors import SeeUError
from seeu_data.image_ops import single_threaded_cv2
from seeu_data.limits import MAX_PIXELS
from seeu_data.loader.collate import collate_views
from seeu_data.loader.curriculum import GapCurriculum
from seeu_data.loader.formats import BATCH_FORMATS, to_pixelsplat
from seeu_data.loader.order import (
    GlobalPlan,
    epoch_order,
    manifest_fingerprint,
    plan_global_batches,
    rank_worker_batches,
    shard_offsets,
)
from seeu_data.loader.shard_reader import ShardChanged, ShardReader
from seeu_data.loader.source import DEFAULT_CACHE_LIMIT, ShardSource
from seeu_data.loader.transforms import ViewsSample, transform_sample
from seeu_data.loader.types import Batch
from seeu_data.store.triple_row import TripleRow


@dataclass(frozen=True)
class LoaderConfig:
    """Everything that shapes the stream besides the data and the (rank, world size, workers) geometry."""

    batch_size: int = 1  # per rank
    image_hw: tuple[int, int] = (256, 256)
    seed: int = 0
    shuffle: bool = True
    block_shards: int = 4  # shuffle rows within blocks of this many (shuffled) shards
    remainder: str = "pad"  # last partial global batch: "pad" (flagged is_padding) or "drop"
    flip_p: float = 0.0  # probability of mirroring a sample (deterministic per (seed, epoch, position))
    interpolation: str = "linear"  # "linear" (crop-only warp, fast) | "area" (anti-aliased) | "lanczos" | "cubic"
    image_dtype: str = "uint8"  # "uint8" (convert on the device: collate.batch_to_device) or "float32" in [0, 1]
    on_error: str = "raise"  # unreadable shard / image: "raise" a SeeUError, or "skip" (warn, count, replace)
    verify: str = "sha256"  # local shards: "sha256" on first read, or "size" only
    cache_dir: str | None = None  # object-storage download cache and verification stamps
    cache_limit_bytes: int = DEFAULT_CACHE_LIMIT
    curriculum: GapCurriculum | None = None
    max_open_shards: int = 16  # per worker
    max_pixels: int = MAX_PIXELS  # largest image (width x height) read, `--max-pixels` (`dataset_check`)
    batch_format: str = "seeu"  # "seeu" (`types.Batch`) or "pixelsplat" (the peers' layout: `formats.py`)

    def __post_init__(self) -> None:
        object.__setattr__(self, "image_hw", tuple(int(x) for x in self.image_hw))
        if self.batch_size < 1:
            raise ValueError("batch_size must be >= 1")
        if self.on_error not in ("raise", "skip"):
            raise ValueError("on_error must be 'raise' or 'skip'")
        if self.image_dtype not in ("float32", "uint8"):
            raise ValueError("image_dtype must be 'float32' or 'uint8'")
        if not 0.0 <= self.flip_p <= 1.0:
            raise ValueError("flip_p must be in [0, 1]")
        if self.batch_format not in BATCH_FORMATS:
            raise ValueError(f"batch_format must be one of {', '.join(BATCH_FORMATS)}")


def resolve_rank(rank: int | None, world_size: int | None) -> tuple[int, int]:
    """(rank, world size): the arguments, else torch.distributed, else $RANK / $WORLD_SIZE, else (0, 1)."""
    if rank is not None and world_size is not None:
        return int(rank), int(world_size)
    if torch.distributed.is_available() and torch.distributed.is_initialized():
        return torch.distributed.get_rank(), torch.distributed.get_world_size()
    return int(os.environ.get("RANK", 0)), int(os.environ.get("WORLD_SIZE", 1))


def flip_decisions(seed: int, epoch: int, positions: np.ndarray, p: float) -> np.ndarray:
    """`(n,) bool`: whether to mirror the sample at each epoch position (splitmix64 hash, pure)."""
    if p <= 0.0:
        return np.zeros(len(positions), dtype=bool)
    with np.errstate(over="ignore"):
        x = np.asarray(positions, dtype=np.uint64) + np.uint64((seed * 0x9E3779B1 + epoch * 0x85EBCA77) & (2**64 - 1))
        x = x + np.uint64(0x9E3779B97F4A7C15)
        x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        x = x ^ (x >> np.uint64(31))
    return (x >> np.uint64(11)).astype(np.float64) / float(1 << 53) < p


@dataclass
class _Position:
    epoch: int = 0
    samples_seen: int = 0
    step: int = 0


class TripleStream(IterableDataset):
    """Batches of context-target triples from a triples dataset (local dir or object-storage URL).

    Yields collated batches (`batch_size` samples of this rank), so wrap it in a DataLoader with
    `batch_size=None` -- or use `StreamingLoader` / `make_loader`, which also keep the resume state.
    Extra keys: `"is_padding"` (B,) bool; private `"_cursor"` (samples_seen after the batch) and
    `"_skipped"` (samples replaced because they could not be read), removed by `StreamingLoader`.
    """

    def __init__(
        self,
        source: str | Path | ShardSource,
        config: LoaderConfig = LoaderConfig(),
        rank: int | None = None,
        world_size: int | None = None,
        filesystem=None,
    ):
        self.config = config
        self.source = (
            source
            if isinstance(source, ShardSource)
            else ShardSource(
                source,
                cache_dir=config.cache_dir,
                cache_limit_bytes=config.cache_limit_bytes,
                verify=config.verify,
                filesystem=filesystem,
            )
        )
        self.rank, self.world_size = resolve_rank(rank, world_size)
        if not 0 <= self.rank < self.world_size:
            raise ValueError(f"rank {self.rank} outside [0, {self.world_size})")
        self.shard_rows = [s.rows for s in self.source.shards]
        self.offsets = shard_offsets(self.shard_rows)
        self.num_samples = int(self.offsets[-1])
        self.fingerprint = manifest_fingerprint(self.source.manifest["files"])
        self.position = _Position()
        self._orders: dict[int, np.ndarray] = {}
        self._plan_key: tuple | None = None
        self._plan: GlobalPlan | None = None
        self._gaps: np.ndarray | None = None
        self._readers: OrderedDict[int, ShardReader] = OrderedDict()
        self._bad_shards: dict[int, str] = {}
        self._scratch: np.ndarray | None = None  # (B, V, 3, H, W) uint8 images of the current batch (reused)

    # ------------------------------------------------------------------ plan
    @property
    def global_batch_size(self) -> int:
        return self.config.batch_size * self.world_size

    def order(self, epoch: int) -> np.ndarray:
        """`(N,) int64` row ids of the epoch in order (pure function of seed, epoch, manifest)."""
        if epoch not in self._orders:
            self._orders = {
                epoch: epoch_order(
                    self.shard_rows,
                    self.config.seed,
                    epoch,
                    self.fingerprint,
                    self.config.shuffle,
                    self.config.block_shards,
                )
            }
        return self._orders[epoch]

    def row_gaps(self) -> np.ndarray:
        """`(N,) int64` context gap per row id (read once; needed by the curriculum)."""
        if self._gaps is None:
            self._gaps = (
                np.concatenate([self._reader(k).gaps() for k in range(len(self.shard_rows))])
                if self.shard_rows
                else np.zeros(0, np.int64)
            )
        return self._gaps

    def plan(self) -> GlobalPlan:
        """The remaining global batches of the current epoch from the current position."""
        p, c = self.position, self.config
        key = (p.epoch, p.samples_seen, p.step, self.global_batch_size, c)
        if self._plan_key != key:
            order = self.order(p.epoch)
            if c.curriculum is None:
                plan = plan_global_batches(self.num_samples, p.samples_seen, self.global_batch_size, c.remainder)
            else:
                plan = plan_global_batches(
                    self.num_samples,
                    p.samples_seen,
                    self.global_batch_size,
                    c.remainder,
                    gaps=self.row_gaps()[order],
                    max_gap=c.curriculum.max_gap,
                    start_step=p.step,
                )
            self._plan_key, self._plan = key, plan
        assert self._plan is not None
        return self._plan

    def num_batches(self) -> int:
        """Batches this rank still yields in the current epoch (the same on every rank)."""
        return self.plan().num_batches

    # ------------------------------------------------------------------ reading
    def _reader(self, k: int) -> ShardReader:
        reader = self._readers.get(k)
        if reader is not None:
            self._readers.move_to_end(k)
            return reader
        if k in self._bad_shards:
            raise SeeUError(self._bad_shards[k], self.source.name(k))
        try:
            path = self.source.local_path(k)
            reader = ShardReader(path, self.source.name(k), self.source.shards[k].rows, self.config.max_pixels)
        except SeeUError as exc:
            self._bad_shards[k] = str(exc)
            raise
        self._readers[k] = reader
        while len(self._readers) > self.config.max_open_shards:
            self._readers.popitem(last=False)
        return reader

    def read_row(self, row_id: int) -> TripleRow:
        """The stored sample with global row id `row_id`."""
        k = int(np.searchsorted(self.offsets, row_id, side="right") - 1)
        return self._reader(k).sample(int(row_id - self.offsets[k]))

    def _load(self, row_id: int, flip: bool, slot: int, batch_size: int) -> ViewsSample:
        """Read and transform one sample into row `slot` of the batch image buffer."""
        k = int(np.searchsorted(self.offsets, row_id, side="right") - 1)
        raw = self._reader(k).sample(int(row_id - self.offsets[k]))
        shape = (batch_size, len(raw.images), 3) + tuple(self.config.image_hw)
        if slot == 0:  # a new batch (or its first sample again, replaced)
            if self._scratch is None or self._scratch.shape != shape:
                self._scratch = np.empty(shape, dtype=np.uint8)
        elif self._scratch is None or self._scratch.shape != shape:
            have = "?" if self._scratch is None else self._scratch.shape[1]
            raise SeeUError(
                f"sample {raw.sample_id} has {len(raw.images)} views, the batch {have}: batches need equal view counts",
                self.source.name(k),
            )
        return transform_sample(
            raw,
            self.config.image_hw,
            flip,
            self.config.interpolation,
            where=self.source.name(k),
            out=self._scratch[slot],
            max_pixels=self.config.max_pixels,
        )

    def make_batch(self, positions: np.ndarray, is_padding: np.ndarray, epoch: int) -> dict:
        """Read, transform and collate the samples at these epoch positions, `(B,)` each."""
        c = self.config
        order = self.order(epoch)
        flips = flip_decisions(c.seed, epoch, positions, c.flip_p)
        pad = np.asarray(is_padding, dtype=bool).copy()
        size = len(positions)
        samples: list[ViewsSample] = []
        skipped = 0
        fill = 0  # next epoch position tried as a replacement for an unreadable sample
        for i, pos in enumerate(positions):
            try:
                samples.append(self._load(int(order[pos]), bool(flips[i]), i, size))
                continue
            except SeeUError as exc:
                if c.on_error == "raise" or isinstance(exc, ShardChanged):  # data changed under the run: stop
                    raise
                warnings.warn(f"seeu loader: skipping unreadable sample: {exc}", stacklevel=2)
                skipped += 1
            while True:  # replace it with the first readable sample from the start of the order
                if fill >= len(order):
                    raise SeeUError(
                        "no readable sample left to fill a batch (every shard unreadable?)", self.source.url
                    )
                try:
                    samples.append(self._load(int(order[fill]), False, i, size))
                    pad[i] = True
                    fill += 1
                    break
                except ShardChanged:
                    raise
                except SeeUError:
                    fill += 1
        batch = collate_views(samples, pad, c.image_dtype, images=self._scratch, where=self.source.url)
        batch["_skipped"] = skipped
        return batch

    def __iter__(self) -> Iterator[dict]:
        info = get_worker_info()
        worker, num_workers = (info.id, info.num_workers) if info is not None else (0, 0)
        plan = self.plan()
        epoch = self.position.epoch
        ids, cols = rank_worker_batches(
            plan.num_batches, self.config.batch_size, self.rank, self.world_size, worker, num_workers
        )
        for b in ids:
            try:
                batch = self.make_batch(plan.positions[b, cols], plan.is_padding[b, cols], epoch)
            except SeeUError as exc:
                if info is None:
                    raise
                # In a worker: hand the error to the main process as data, so it is raised there as the
                # same one-line SeeUError (a DataLoader re-raise would carry the worker's traceback).
                yield {"_error": _error_parts(exc)}
                return
            batch["_cursor"] = int(plan.cursor_after[b])
            yield batch


def _naming_dead_workers(batches: Iterator) -> Iterator:
    """`batches` (a DataLoader iterator). A worker killed while it hands a batch over can surface first as
    a ConnectionError or EOFError (the batch's tensors cannot be fetched from the dead process), before
    PyTorch's SIGCHLD handler names it: PyTorch is then asked which worker died, so the error is its
    "DataLoader worker (pid N) is killed by signal" (`interrupts.worker_death`'s one line). A killed process's
    sockets close before it can be waited for, so PyTorch is asked for up to a second: asked once, a test that
    kills a worker got "[Errno 104] Connection reset by peer" in 2 of 6 runs."""
    while True:
        try:
            batch = next(batches)
        except StopIteration:
            return
        except (ConnectionError, EOFError):
            deadline = time.monotonic() + 1.0
            while time.monotonic() < deadline:
                torch._C._error_if_any_worker_fails()  # PyTorch's own check: raises the named death of a worker gone
                time.sleep(0.02)
            raise
        yield batch


def _error_parts(exc: SeeUError) -> tuple[str, str | None]:
    """(message, path) of a SeeUError, so it can be rebuilt in another process."""
    text = str(exc)
    if exc.path is not None and text.startswith(exc.path + ": "):
        return text[len(exc.path) + 2 :], exc.path
    return text, None


def _as_is(batch: Any) -> Any:
    """The DataLoader's per-item collate: batches are collated already (keep numpy as numpy)."""
    return batch


class StreamingLoader:
    """A DataLoader over a `TripleStream` that knows where it is: `state_dict()` / `load_state_dict()`.

    State: `epoch`, `samples_seen` (global samples of the epoch consumed, all ranks together), `step`
    (global batches consumed since the start of training; drives the curriculum), plus the seed and
    the dataset fingerprint to refuse a checkpoint of another dataset. A finished epoch advances
    `epoch` by itself, and so does iterating from a state taken after an epoch's last batch
    (`samples_seen` == the epoch size); `set_epoch(e)` jumps to the start of epoch e (no-op if already in e).
    Batches: `types.Batch`, or with `batch_format="pixelsplat"` the peers' layout (`formats.to_pixelsplat`).
    """

    def __init__(
        self,
        dataset: TripleStream,
        num_workers: int = 0,
        pin_memory: bool = False,
        prefetch_factor: int | None = 2,
        multiprocessing_context: str | None = None,
        timeout: float = 0,
    ):
        self.dataset = dataset
        self.num_workers = int(num_workers)
        self.pin_memory = pin_memory
        self.prefetch_factor = prefetch_factor if num_workers > 0 else None
        self.multiprocessing_context = multiprocessing_context
        self.timeout = timeout
        self.stats = {"skipped_corrupt": 0, "skipped_curriculum": 0, "padding": 0}

    # ------------------------------------------------------------------ state
    @property
    def epoch(self) -> int:
        return self.dataset.position.epoch

    @property
    def samples_seen(self) -> int:
        return self.dataset.position.samples_seen

    @property
    def step(self) -> int:
        return self.dataset.position.step

    def set_epoch(self, epoch: int) -> None:
        if epoch != self.dataset.position.epoch:
            self.dataset.position = _Position(int(epoch), 0, self.dataset.position.step)

    def state_dict(self) -> dict:
        p = self.dataset.position
        return {
            "epoch": p.epoch,
            "samples_seen": p.samples_seen,
            "step": p.step,
            "seed": self.dataset.config.seed,
            "num_samples": self.dataset.num_samples,
            "fingerprint": self.dataset.fingerprint,
        }

    def load_state_dict(self, state: dict) -> None:
        ds = self.dataset
        if "fingerprint" in state and int(state["fingerprint"]) != ds.fingerprint:
            raise SeeUError(
                "loader checkpoint belongs to a different dataset (manifest fingerprint differs)", ds.source.url
            )
        if not 0 <= int(state["samples_seen"]) <= ds.num_samples:
            raise SeeUError(
                f"loader checkpoint has samples_seen {state['samples_seen']} outside [0, {ds.num_samples}]",
                ds.source.url,
            )
        if "seed" in state and int(state["seed"]) != ds.config.seed:
            ds.config = replace(ds.config, seed=int(state["seed"]))  # the order must be the checkpoint's
        ds.position = _Position(int(state["epoch"]), int(state["samples_seen"]), int(state.get("step", 0)))

    def __len__(self) -> int:
        """Batches this rank yields when iterated now: from the current position to the end of the epoch,
        or the whole next epoch when the position is an epoch's end (a Lightning checkpoint taken there)."""
        self._roll_over()
        return self.dataset.num_batches()

    def _roll_over(self) -> None:
        ds = self.dataset
        if ds.position.samples_seen > 0 and ds.num_batches() == 0:
            # a state saved after the last batch of an epoch (samples_seen == epoch size, or only a
            # dropped remainder left) means the start of the next epoch
            ds.position = _Position(ds.position.epoch + 1, 0, ds.position.step)

    # ------------------------------------------------------------------ iteration
    def __iter__(self) -> Iterator[Batch]:
        ds = self.dataset
        self._roll_over()
        plan = ds.plan()  # computed here once; forked workers inherit it
        loader = DataLoader(
            ds,
            batch_size=None,
            collate_fn=_as_is,
            num_workers=self.num_workers,
            pin_memory=self.pin_memory and torch.cuda.is_available(),
            prefetch_factor=self.prefetch_factor,
            persistent_workers=False,
            multiprocessing_context=self.multiprocessing_context if self.num_workers else None,
            timeout=self.timeout,
        )
        skipped = plan.skipped
        if self.num_workers:
            with single_threaded_cv2():
                batches = iter(loader)  # forks the workers
        else:
            batches = iter(loader)
        for batch in _naming_dead_workers(batches):
            if "_error" in batch:
                raise SeeUError(*batch["_error"])
            # The small fields cross from the workers as numpy (pickled by value): as tensors, each is a
            # shared-memory file of its own, which made an epoch 1.2-1.4x slower (benchmarks/RESULTS.md).
            for key in ("context", "target"):
                batch[key] = {k: torch.as_tensor(v) for k, v in batch[key].items()}
            batch["is_padding"] = torch.as_tensor(batch["is_padding"])
            cursor = batch.pop("_cursor")
            self.stats["skipped_corrupt"] += batch.pop("_skipped")
            self.stats["padding"] += int(batch["is_padding"].numpy().sum())
            before = ds.position.samples_seen
            self.stats["skipped_curriculum"] += int(np.searchsorted(skipped, cursor) - np.searchsorted(skipped, before))
            ds.position = _Position(ds.position.epoch, cursor, ds.position.step + 1)
            yield to_pixelsplat(batch) if ds.config.batch_format == "pixelsplat" else batch  # type: ignore[misc]
        ds.position = _Position(ds.position.epoch + 1, 0, ds.position.step)


def make_loader(
    shards: str | Path,
    batch_size: int,
    *,
    num_workers: int = 0,
    rank: int | None = None,
    world_size: int | None = None,
    seed: int = 0,
    pin_memory: bool = False,
    filesystem=None,
    multiprocessing_context: str | None = None,
    timeout: float = 0,
    **config,
) -> StreamingLoader:
    """A `StreamingLoader` over the triples dataset at `shards` (directory or object-storage URL).

    `config` takes the other `LoaderConfig` fields (image_hw, flip_p, remainder, curriculum, ...).
    """
    cfg = LoaderConfig(batch_size=batch_size, seed=seed, **config)
    ds = TripleStream(shards, cfg, rank=rank, world_size=world_size, filesystem=filesystem)
    return StreamingLoader(
        ds,
        num_workers=num_workers,
        pin_memory=pin_memory,
        multiprocessing_context=multiprocessing_context,
        timeout=timeout,
    )
