"""Loader order and partition (pure functions), in the style of MosaicML Streaming's partition tests.

For world sizes 1-8 and 0-4 DataLoader workers: the union of what all (rank, worker) pairs produce is
the epoch exactly once; every rank yields the same number of batches; the rank's output order does not
depend on the worker count; resuming at any point with another geometry loses and repeats nothing.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from seeu_data.loader.curriculum import GapCurriculum
from seeu_data.loader.order import (
    epoch_order,
    manifest_fingerprint,
    plan_global_batches,
    rank_worker_batches,
    shard_offsets,
)

FILES = [{"path": f"shard-{i}.arrow", "rows": 10, "sha256": f"{i:064x}"} for i in range(3)]


def rank_stream(plan, batch_size: int, rank: int, world_size: int, num_workers: int):
    """What a rank's DataLoader returns: workers' batches taken round-robin, as PyTorch does.

    Returns (list of (global batch index, positions, is_padding)) in output order.
    """
    k = max(1, num_workers)
    per_worker = []
    for w in range(k):
        ids, cols = rank_worker_batches(plan.num_batches, batch_size, rank, world_size, w, num_workers)
        per_worker.append([(int(b), plan.positions[b, cols], plan.is_padding[b, cols]) for b in ids])
    out, active, i = [], list(range(k)), 0
    cursors = [0] * k
    while active:  # DataLoader: cycle over workers still alive, in order
        w = active[i % len(active)]
        if cursors[w] < len(per_worker[w]):
            out.append(per_worker[w][cursors[w]])
            cursors[w] += 1
            i += 1
        else:
            active.remove(w)
            i = active.index(next((a for a in active if a > w), active[0])) if active else 0
    return out


# --------------------------------------------------------------------------------------------- order


def test_fingerprint_depends_on_contents():
    a = manifest_fingerprint(FILES)
    assert a == manifest_fingerprint([dict(f) for f in FILES])
    changed = [dict(f) for f in FILES]
    changed[1]["sha256"] = "f" * 64
    assert manifest_fingerprint(changed) != a
    assert 0 <= a < 2**63


@settings(max_examples=60, deadline=None)
@given(
    rows=st.lists(st.integers(0, 30), min_size=0, max_size=12),
    seed=st.integers(0, 2**40),
    epoch=st.integers(0, 1000),
    block=st.integers(1, 5),
)
def test_epoch_order_is_a_pure_permutation_with_shard_locality(rows, seed, epoch, block):
    fp = 12345
    order = epoch_order(rows, seed, epoch, fp, block_shards=block)
    assert np.array_equal(np.sort(order), np.arange(sum(rows)))
    assert np.array_equal(order, epoch_order(rows, seed, epoch, fp, block_shards=block))
    # Locality: each run of positions belonging to one block touches at most `block` shards, and the
    # blocks are contiguous in the order.
    off = shard_offsets(rows)
    shard_of = np.searchsorted(off, order, side="right") - 1
    seen_blocks, current = [], set()
    for s in shard_of:
        current.add(int(s))
        if len(current) > block:
            seen_blocks.append(current - {int(s)})
            current = {int(s)}
    for b in seen_blocks:
        assert len(b) <= block


def test_epoch_order_changes_with_seed_epoch_and_manifest():
    rows = [10, 10, 10, 10]
    base = epoch_order(rows, 0, 0, 1)
    assert not np.array_equal(base, epoch_order(rows, 1, 0, 1))
    assert not np.array_equal(base, epoch_order(rows, 0, 1, 1))
    assert not np.array_equal(base, epoch_order(rows, 0, 0, 2))
    assert np.array_equal(epoch_order(rows, 0, 0, 1, shuffle=False), np.arange(40))


# ------------------------------------------------------------------------------------------ partition


@settings(max_examples=300, deadline=None)
@given(
    n=st.integers(0, 120),
    batch=st.integers(1, 6),
    world=st.integers(1, 8),
    workers=st.integers(0, 4),
    seen_frac=st.floats(0, 1),
    remainder=st.sampled_from(["pad", "drop"]),
)
def test_partition_exactly_once_equal_batches_worker_independent(n, batch, world, workers, seen_frac, remainder):
    g = batch * world
    seen = int(seen_frac * n)
    plan = plan_global_batches(n, seen, g, remainder)
    got, counts = [], []
    for r in range(world):
        stream = rank_stream(plan, batch, r, world, workers)
        counts.append(len(stream))
        # Output order independent of the worker count, and in global-batch order.
        assert [b for b, _, _ in stream] == list(range(plan.num_batches))
        ref = rank_stream(plan, batch, r, world, 0)
        assert all(np.array_equal(p, q) for (_, p, _), (_, q, _) in zip(stream, ref))
        for _, pos, pad in stream:
            assert len(pos) == batch
            got.extend(pos[~pad].tolist())
    assert len(set(counts)) <= 1  # every rank the same number of batches
    full = (n - seen) // g
    expect = list(range(seen, n)) if remainder == "pad" else list(range(seen, seen + full * g))
    assert sorted(got) == expect  # exactly once
    assert plan.num_batches == (-(-(n - seen) // g) if remainder == "pad" else full)
    if plan.num_batches:
        assert plan.cursor_after[-1] == (n if remainder == "pad" else seen + full * g)
        assert np.all(np.diff(plan.cursor_after) > 0)


@settings(max_examples=200, deadline=None)
@given(
    n=st.integers(1, 150),
    b1=st.integers(1, 5),
    w1=st.integers(1, 8),
    k1=st.integers(0, 4),
    b2=st.integers(1, 5),
    w2=st.integers(1, 8),
    k2=st.integers(0, 4),
    stop_frac=st.floats(0, 1),
    remainder=st.sampled_from(["pad", "drop"]),
)
def test_resume_with_other_geometry_loses_and_repeats_nothing(n, b1, w1, k1, b2, w2, k2, stop_frac, remainder):
    plan1 = plan_global_batches(n, 0, b1 * w1, remainder)
    stop = int(stop_frac * plan1.num_batches)  # batches consumed before the checkpoint
    before = []
    for r in range(w1):
        for _, pos, pad in rank_stream(plan1, b1, r, w1, k1)[:stop]:
            before.extend(pos[~pad].tolist())
    seen = int(plan1.cursor_after[stop - 1]) if stop else 0
    assert sorted(before) == list(range(seen))  # the state is a prefix of the order
    plan2 = plan_global_batches(n, seen, b2 * w2, remainder)
    after = []
    for r in range(w2):
        for _, pos, pad in rank_stream(plan2, b2, r, w2, k2):
            after.extend(pos[~pad].tolist())
    assert not set(before) & set(after)
    union = sorted(before + after)
    assert len(union) == len(set(union))
    if remainder == "pad":
        assert union == list(range(n))
    else:  # only the final partial global batch of the resumed run is dropped
        assert union == list(range(seen + ((n - seen) // (b2 * w2)) * b2 * w2))


@pytest.mark.parametrize("split", [(8, 1), (4, 2), (2, 4), (1, 8)])
def test_global_batches_do_not_depend_on_the_rank_split(split):
    batch, world = split
    plan = plan_global_batches(53, 5, batch * world, "pad")
    ref = plan_global_batches(53, 5, 8, "pad")
    for b in range(plan.num_batches):
        got = np.concatenate(
            [plan.positions[b, rank_worker_batches(plan.num_batches, batch, r, world)[1]] for r in range(world)]
        )
        assert np.array_equal(got, ref.positions[b])


def test_padding_repeats_the_start_of_the_order_and_is_flagged():
    plan = plan_global_batches(10, 0, 4, "pad")
    assert plan.positions.tolist() == [[0, 1, 2, 3], [4, 5, 6, 7], [8, 9, 0, 1]]
    assert plan.is_padding[-1].tolist() == [False, False, True, True]
    tiny = plan_global_batches(2, 0, 7, "pad")  # fewer samples than one global batch: cycle
    assert tiny.positions.tolist() == [[0, 1, 0, 1, 0, 1, 0]]
    assert plan_global_batches(10, 10, 4, "pad").num_batches == 0
    with pytest.raises(ValueError):
        plan_global_batches(10, 11, 4, "pad")
    with pytest.raises(ValueError):
        plan_global_batches(10, 0, 4, "partial")


# ----------------------------------------------------------------------------------------- curriculum


def test_gap_curriculum_ramp():
    c = GapCurriculum(25, 45, 150_000)
    assert c.max_gap(0) == 25 and c.max_gap(75_000) == 35 and c.max_gap(150_000) == 45 and c.max_gap(10**9) == 45
    assert all(c.max_gap(s) <= c.max_gap(s + 1) for s in range(0, 150_000, 997))
    assert GapCurriculum(3, 9, 0).max_gap(0) == 9
    with pytest.raises(ValueError):
        GapCurriculum(10, 5, 100)


@settings(max_examples=150, deadline=None)
@given(
    gaps=st.lists(st.integers(0, 12), min_size=1, max_size=120),
    batch=st.integers(1, 4),
    world=st.integers(1, 4),
    start=st.integers(0, 20),
    warm=st.integers(0, 30),
    stop_frac=st.floats(0, 1),
    world2=st.integers(1, 5),
    remainder=st.sampled_from(["pad", "drop"]),
)
def test_curriculum_plan_filters_deterministically_and_resumes(
    gaps, batch, world, start, warm, stop_frac, world2, remainder
):
    gaps = np.asarray(gaps)
    n, g = len(gaps), batch * world
    cur = GapCurriculum(2, 10, warm)
    plan = plan_global_batches(n, 0, g, remainder, gaps=gaps, max_gap=cur.max_gap, start_step=start)
    used = []
    for b in range(plan.num_batches):
        limit = cur.max_gap(start + b)
        real = plan.positions[b][~plan.is_padding[b]]
        assert np.all(gaps[plan.positions[b]] <= limit)  # padding obeys the curriculum too
        used.extend(real.tolist())
    # Every position is used exactly once or counted as skipped.
    assert sorted(used + plan.skipped.tolist()) == list(range(n))
    assert len(set(used)) == len(used)
    # Resume at a batch boundary with another world size: continuing == re-planning from the cursor.
    stop = int(stop_frac * plan.num_batches)
    seen = int(plan.cursor_after[stop - 1]) if stop else 0
    again = plan_global_batches(n, seen, g, remainder, gaps=gaps, max_gap=cur.max_gap, start_step=start + stop)
    assert np.array_equal(again.positions, plan.positions[stop:])
    other = plan_global_batches(
        n, seen, batch * world2, remainder, gaps=gaps, max_gap=cur.max_gap, start_step=start + stop
    )
    before = [p for b in range(stop) for p in plan.positions[b][~plan.is_padding[b]].tolist()]
    after = [p for b in range(other.num_batches) for p in other.positions[b][~other.is_padding[b]].tolist()]
    skipped_before = plan.skipped[plan.skipped < seen].tolist()
    assert sorted(before + after + skipped_before + other.skipped.tolist()) == list(range(n))


def _plan_rescanning(num_samples, samples_seen, g, remainder, gaps, max_gap, start_step):
    """The curriculum plan as first written (it rescanned the rest of the epoch for every batch): the
    reference the linear plan must equal."""
    rows, pads, cursors, skipped = [], [], [], []
    cur, step = samples_seen, start_step
    while cur < num_samples:
        limit = max_gap(step)
        ok = np.flatnonzero(gaps[cur:] <= limit)
        if len(ok) >= g:
            take = cur + ok[:g]
            end = int(take[-1]) + 1
            skipped.append(np.setdiff1d(np.arange(cur, end, dtype=np.int64), take, assume_unique=True))
            rows.append(take)
            pads.append(np.zeros(g, dtype=bool))
            cursors.append(end)
            cur, step = end, step + 1
            continue
        take = cur + ok
        skipped.append(np.setdiff1d(np.arange(cur, num_samples, dtype=np.int64), take, assume_unique=True))
        if remainder == "pad" and len(take):
            pool = np.flatnonzero(gaps <= limit)
            rows.append(np.concatenate([take, pool[np.arange(g - len(take)) % len(pool)]]))
            pads.append(np.arange(g) >= len(take))
            cursors.append(num_samples)
        elif remainder == "drop":
            skipped.append(take)
        cur = num_samples
    pos = np.stack(rows).astype(np.int64) if rows else np.zeros((0, g), dtype=np.int64)
    pad = np.stack(pads) if pads else np.zeros((0, g), dtype=bool)
    skip = np.sort(np.concatenate(skipped)) if skipped else np.zeros(0, dtype=np.int64)
    return pos, pad, np.asarray(cursors, dtype=np.int64), skip


@settings(max_examples=400, deadline=None)
@given(
    gaps=st.lists(st.integers(0, 12), min_size=1, max_size=300),
    g=st.integers(1, 9),
    seen_frac=st.floats(0, 1),
    start=st.integers(0, 40),
    remainder=st.sampled_from(["pad", "drop"]),
    ramp=st.one_of(
        st.tuples(st.integers(0, 6), st.one_of(st.none(), st.integers(6, 12)), st.integers(0, 60)),
        st.lists(st.integers(-1, 12), min_size=1, max_size=8),  # any limit per step, not monotone
    ),
)
def test_curriculum_plan_equals_the_rescanning_plan(gaps, g, seen_frac, start, remainder, ramp):
    gaps = np.asarray(gaps)
    n = len(gaps)
    if isinstance(ramp, tuple):
        max_gap = GapCurriculum(*ramp).max_gap
    else:
        max_gap = lambda step: float(ramp[(step // 3) % len(ramp)])  # noqa: E731
    seen = int(seen_frac * n)
    plan = plan_global_batches(n, seen, g, remainder, gaps=gaps, max_gap=max_gap, start_step=start)
    expected = _plan_rescanning(n, seen, g, remainder, gaps, max_gap, start)
    for got, want in zip((plan.positions, plan.is_padding, plan.cursor_after, plan.skipped), expected):
        assert got.dtype == want.dtype and np.array_equal(got, want)


def test_curriculum_plan_of_200000_samples_takes_under_a_second():
    """RE10K-size epoch with the peers' ramp (25 -> 45) half way through its warm-up: linear in the samples."""
    import time

    gaps = np.random.default_rng(0).integers(25, 46, size=200_000)
    cur = GapCurriculum(25, 45, 150_000)
    t0 = time.process_time()
    plan = plan_global_batches(len(gaps), 0, 8, "pad", gaps=gaps, max_gap=cur.max_gap, start_step=75_000)
    seconds = time.process_time() - t0
    assert plan.num_batches > 10_000 and len(plan.skipped) > 10_000
    assert seconds < 1.0, seconds
