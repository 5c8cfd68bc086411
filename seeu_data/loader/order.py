"""Epoch order and partition: pure functions of (seed, epoch, manifest) and the run's geometry.

Vocabulary (all integers, no hidden state):

* **row id** -- a sample's index in the dataset: shard k's row j has id `shard_offset[k] + j`.
* **order** -- `epoch_order(...)`, a permutation of all row ids, `(N,) int64`; a pure function of
  (seed, epoch, manifest fingerprint). Shards are shuffled, then rows are shuffled inside blocks of
  `block_shards` consecutive shards (locality: a stretch of the epoch touches a few shards).
* **position** -- an index into the order. `samples_seen` is a position: everything before it has been
  consumed (globally, across all ranks), everything from it on has not.
* **global batch** -- `G = batch_size * world_size` consecutive positions; rank r takes the
  contiguous slice `[r * batch_size, (r + 1) * batch_size)` of every global batch. The samples of a
  global batch therefore do not depend on how G is split into ranks.
* **workers** -- inside a rank, batch j goes to DataLoader worker `j % num_workers`. PyTorch's
  DataLoader takes batches from its workers round-robin, so the rank's output order is the same for
  any number of workers (0 = the main process, same as 1).
* **remainder** -- the last, partial global batch is either dropped (`"drop"`) or padded (`"pad"`) with
  positions from the start of the order, flagged `is_padding`. Either way every rank yields the same
  number of batches, so DDP never waits on a rank that ran out.

Resuming at `samples_seen = s` with another world size / batch size / worker count simply plans the
positions `[s, N)` with the new geometry: nothing before s is repeated, nothing from s on is lost.

With a gap curriculum (`curriculum.GapCurriculum`) the global batches are formed by walking the
order from `samples_seen` and skipping positions whose context gap exceeds the curriculum's maximum
at that batch's training step (`plan_global_batches(..., gaps=..., max_gap=...)`). Skipped samples are
counted and not revisited in this epoch; the walk is deterministic, so it resumes exactly too.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

REMAINDER_MODES = ("pad", "drop")


def manifest_fingerprint(files: Sequence[dict]) -> int:
    """63-bit fingerprint of a manifest's file list (paths, row counts, sha256): the order's dataset key."""
    digest = hashlib.sha256()
    for entry in files:
        digest.update(f"{entry['path']}\0{int(entry['rows'])}\0{entry['sha256']}\n".encode())
    return int.from_bytes(digest.digest()[:8], "little") >> 1


def shard_offsets(shard_rows: Sequence[int]) -> np.ndarray:
    """`(S + 1,) int64` cumulative row counts: shard k holds row ids `[off[k], off[k + 1])`."""
    return np.concatenate([[0], np.cumsum(np.asarray(shard_rows, dtype=np.int64))]).astype(np.int64)


def epoch_order(
    shard_rows: Sequence[int], seed: int, epoch: int, fingerprint: int, shuffle: bool = True, block_shards: int = 4
) -> np.ndarray:
    """The epoch's sample order: a permutation of the row ids `0 .. N-1`, `(N,) int64`.

    A pure function of its arguments. `shuffle=False` gives shard order, row order (evaluation).
    """
    offsets = shard_offsets(shard_rows)
    total = int(offsets[-1])
    if not shuffle:
        return np.arange(total, dtype=np.int64)
    if block_shards < 1:
        raise ValueError("block_shards must be >= 1")
    rng = np.random.default_rng(
        [int(seed) & 0xFFFFFFFF, int(seed) >> 32, int(epoch), fingerprint & 0xFFFFFFFF, fingerprint >> 32]
    )
    shards = rng.permutation(len(shard_rows))
    parts = []
    for start in range(0, len(shards), block_shards):
        block = np.concatenate(
            [np.arange(offsets[k], offsets[k + 1], dtype=np.int64) for k in shards[start : start + block_shards]]
        )
        parts.append(rng.permutation(block))
    return np.concatenate(parts) if parts else np.zeros(0, dtype=np.int64)


@dataclass(frozen=True)
class GlobalPlan:
    """The global batches still to come in an epoch.

    positions: `(nb, G) int64` positions into the epoch order; is_padding: `(nb, G) bool`;
    cursor_after: `(nb,) int64` the `samples_seen` value once batch b has been consumed;
    skipped: `(K,) int64` positions passed over by the curriculum (ascending).
    """

    positions: np.ndarray
    is_padding: np.ndarray
    cursor_after: np.ndarray
    skipped: np.ndarray

    @property
    def num_batches(self) -> int:
        return int(self.positions.shape[0])


def _pad_positions(count: int, pool: np.ndarray) -> np.ndarray:
    """`count` padding positions taken cyclically from `pool` (positions from the start of the order)."""
    if count == 0:
        return np.zeros(0, dtype=np.int64)
    if len(pool) == 0:
        raise ValueError("cannot pad: no sample is eligible")
    return pool[np.arange(count) % len(pool)].astype(np.int64)


def plan_global_batches(
    num_samples: int,
    samples_seen: int,
    global_batch: int,
    remainder: str = "pad",
    gaps: np.ndarray | None = None,
    max_gap: Callable[[int], float] | None = None,
    start_step: int = 0,
) -> GlobalPlan:
    """Global batches of the positions `[samples_seen, num_samples)` of an epoch order.

    Without a curriculum: consecutive runs of `global_batch` positions. With one, `gaps` is the
    `(N,)` context gap *of each position* (i.e. `gap[order]`) and `max_gap(step)` the largest gap
    allowed at training step `step`; global batch b (trained at step `start_step + b`) takes the next
    positions whose gap is allowed, skipping the others.
    """
    if remainder not in REMAINDER_MODES:
        raise ValueError(f"remainder must be one of {REMAINDER_MODES}, got {remainder!r}")
    if global_batch < 1:
        raise ValueError("global batch size must be >= 1")
    if not 0 <= samples_seen <= num_samples:
        raise ValueError(f"samples_seen {samples_seen} outside [0, {num_samples}]")
    g = global_batch
    empty = np.zeros(0, dtype=np.int64)
    if max_gap is None:
        rest = num_samples - samples_seen
        full, part = divmod(rest, g)
        pos = np.arange(samples_seen, samples_seen + full * g, dtype=np.int64).reshape(full, g)
        pad = np.zeros((full, g), dtype=bool)
        cursor = samples_seen + g * np.arange(1, full + 1, dtype=np.int64)
        if part and remainder == "pad":
            tail = np.arange(samples_seen + full * g, num_samples, dtype=np.int64)
            fill = _pad_positions(g - part, np.arange(num_samples, dtype=np.int64))
            pos = np.concatenate([pos, np.concatenate([tail, fill])[None]])
            pad = np.concatenate([pad, (np.arange(g) >= part)[None]])
            cursor = np.concatenate([cursor, [num_samples]])
        return GlobalPlan(pos, pad, cursor.astype(np.int64), empty)

    gaps = np.asarray(gaps)
    if gaps.shape != (num_samples,):
        raise ValueError("gaps must hold one gap per position")
    rows, pads, cursors, skipped = [], [], [], []
    cur, step = samples_seen, start_step
    while cur < num_samples:
        # The run of steps from `step` on that share its limit (at most the batches that can remain)
        # takes the next run * g allowed positions at once: work in proportion to the positions passed.
        limit = max_gap(step)
        run, most = 1, -(-(num_samples - cur) // g)
        while run < most and max_gap(step + run) == limit:
            run += 1
        take = _allowed_from(gaps, cur, run * g, limit)
        full = len(take) // g
        if full:
            end = int(take[full * g - 1]) + 1
            skipped.append(_passed_over(cur, end, take[: full * g]))
            rows.append(take[: full * g].reshape(full, g))
            pads.append(np.zeros((full, g), dtype=bool))
            cursors.append(take[g - 1 : full * g : g] + 1)
            cur, step = end, step + full
        if full == run:
            continue
        # The epoch ends inside batch `step`, whose limit is still `limit` (full < run).
        last = take[full * g :]
        skipped.append(_passed_over(cur, num_samples, last))
        if remainder == "pad" and len(last):
            pool = np.flatnonzero(gaps <= limit)
            rows.append(np.concatenate([last, _pad_positions(g - len(last), pool)])[None])
            pads.append((np.arange(g) >= len(last))[None])
            cursors.append(np.array([num_samples], dtype=np.int64))
        elif remainder == "drop":
            skipped.append(last)  # never trained on: counted with the skipped ones
        cur = num_samples
    if rows:
        pos, pad = np.concatenate(rows).astype(np.int64), np.concatenate(pads)
    else:
        pos, pad = np.zeros((0, g), dtype=np.int64), np.zeros((0, g), dtype=bool)
    skip = np.sort(np.concatenate(skipped)) if skipped else empty
    cursor_after = np.concatenate(cursors).astype(np.int64) if cursors else empty
    return GlobalPlan(pos, pad, cursor_after, skip.astype(np.int64))


def _allowed_from(gaps: np.ndarray, start: int, count: int, limit: float) -> np.ndarray:
    """The first `count` positions from `start` on whose gap is at most `limit` (all of them when fewer
    remain), ascending `(<= count,) int64`. The window looked at doubles until it holds them, so the
    work is at most about four times the positions passed over."""
    window = count
    while True:
        ok = np.flatnonzero(gaps[start : start + window] <= limit)
        if len(ok) >= count or start + window >= len(gaps):
            return (start + ok[:count]).astype(np.int64)
        window *= 2


def _passed_over(start: int, end: int, taken: np.ndarray) -> np.ndarray:
    """The positions of `[start, end)` not in `taken` (a subset of them), ascending."""
    mask = np.ones(end - start, dtype=bool)
    mask[taken - start] = False
    return start + np.flatnonzero(mask).astype(np.int64)


def rank_worker_batches(
    num_global_batches: int, batch_size: int, rank: int, world_size: int, worker: int = 0, num_workers: int = 0
) -> tuple[np.ndarray, slice]:
    """Which global batches a (rank, worker) pair produces and which columns of them it takes.

    Returns `(batch_indices (nb_w,), columns)`: the worker produces global batches
    `worker, worker + num_workers, ...` (all of them for `num_workers` 0 or 1) and takes the rank's
    contiguous columns `[rank * batch_size, (rank + 1) * batch_size)` of each.
    """
    if not 0 <= rank < world_size:
        raise ValueError(f"rank {rank} outside [0, {world_size})")
    k = max(1, num_workers)
    if not 0 <= worker < k:
        raise ValueError(f"worker {worker} outside [0, {k})")
    return (np.arange(worker, num_global_batches, k, dtype=np.int64), slice(rank * batch_size, (rank + 1) * batch_size))
