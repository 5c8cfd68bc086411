"""Samplers (seeu_data.build.sampling): hypothesis properties, statistics, determinism. (The view
overlap and the overlap rule: tests/test_overlap.py, tests/test_build_pairs.py.)"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from seeu_data.build.sampling import (
    SamplingConfig,
    min_scene_length,
    sample_scene,
    scene_rng,
    target_offsets,
)


@st.composite
def configs(draw):
    mode = draw(st.sampled_from(["interp", "extrap"]))
    v = draw(st.integers(2, 4))
    gap_min = draw(st.integers(v - 1, 40))
    gap_max = draw(st.integers(gap_min, gap_min + 60))
    return SamplingConfig(
        mode=mode,
        num_context=v,
        num_target=draw(st.integers(1, 5)),
        gap_min=gap_min,
        gap_max=gap_max,
        extrap_frames=draw(st.sampled_from([0, 1, 3, 45, 90])),
        interp_ratio=draw(st.sampled_from([0.0, 0.25, 1.0])),
        samples_per_scene=draw(st.integers(1, 6)),
    )


scene_ids = st.text(min_size=1, max_size=12)


@settings(max_examples=300, deadline=None)
@given(cfg=configs(), n=st.integers(1, 250), seed=st.integers(0, 2**40), sid=scene_ids)
def test_sampler_properties(cfg, n, seed, sid):
    samples = sample_scene(cfg, n, sid, seed)
    outside_possible = cfg.mode == "extrap" and cfg.extrap_frames > 0 and cfg.interp_ratio < 1
    needed = cfg.gap_min + 1 + (1 if outside_possible else 0)
    assert min_scene_length(cfg) == needed
    if n < needed:  # too short: skipped, never an index out of range
        assert samples == []
        return
    assert len(samples) == cfg.samples_per_scene
    for k, s in enumerate(samples):
        assert s.k == k and s.scene_id == sid and s.mode == cfg.mode
        assert len(s.context) == cfg.num_context and len(s.target) == cfg.num_target
        assert all(0 <= i < n for i in s.context + s.target)  # every index in range
        assert list(s.context) == sorted(set(s.context))  # distinct, ascending
        left, right = s.context[0], s.context[-1]
        assert s.gap == right - left and cfg.gap_min <= s.gap <= cfg.gap_max
        # offsets recomputed independently
        for t, off in zip(s.target, s.target_offset):
            expect = t - left if t < left else (t - right if t > right else 0)
            assert off == expect
        if cfg.mode == "interp" or not outside_possible:
            assert all(left <= t <= right for t in s.target)  # interp targets inside [left, right]
        else:
            for t in s.target:
                inside = left <= t <= right
                if not inside:  # extrap targets outside and at most N frames away
                    assert (left - cfg.extrap_frames <= t < left) or (right < t <= right + cfg.extrap_frames)
            if cfg.interp_ratio == 0.0:
                assert all(not (left <= t <= right) for t in s.target)
                assert all(1 <= abs(o) <= cfg.extrap_frames for o in s.target_offset)
    # per-seed determinism
    assert sample_scene(cfg, n, sid, seed) == samples


@settings(max_examples=50, deadline=None)
@given(cfg=configs(), seed=st.integers(0, 2**32), ids=st.lists(scene_ids, min_size=2, max_size=6, unique=True))
def test_sampling_independent_of_scene_order(cfg, seed, ids):
    n = cfg.gap_max + 50
    forward = {sid: sample_scene(cfg, n, sid, seed) for sid in ids}
    backward = {sid: sample_scene(cfg, n, sid, seed) for sid in reversed(ids)}
    assert forward == backward
    # different scenes / seeds draw differently (with overwhelming probability for wide ranges)
    if cfg.gap_max - cfg.gap_min >= 10 and cfg.samples_per_scene >= 3:
        assert sample_scene(cfg, n, ids[0], seed) != sample_scene(cfg, n, ids[0], seed + 1)


def test_scene_rng_is_stable_across_processes():
    # sha256-based: a fixed value, unlike Python's salted hash(); pinned so a change is noticed
    a = scene_rng(7, "5aca87f95a9412c6").integers(0, 1 << 30, 3).tolist()
    b = scene_rng(7, "5aca87f95a9412c6").integers(0, 1 << 30, 3).tolist()
    assert a == b
    import subprocess
    import sys

    code = "from seeu_data.build.sampling import scene_rng; print(scene_rng(7, '5aca87f95a9412c6').integers(0, 1 << 30, 3).tolist())"
    out = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        env={"PYTHONHASHSEED": "123"},
        cwd=str(__import__("pathlib").Path(__file__).resolve().parent.parent),
    )
    assert out.stdout.strip() == str(a)


def test_extrap_statistics_mix_and_range():
    """Mix ratio and offset range, checked against binomial / uniform expectations."""
    cfg = SamplingConfig(
        mode="extrap", gap_min=30, gap_max=30, extrap_frames=10, interp_ratio=0.3, samples_per_scene=4000, num_target=1
    )
    samples = sample_scene(cfg, 200, "stats", 0)
    offs = np.array([s.target_offset[0] for s in samples])
    frac_inside = (offs == 0).mean()
    sigma = np.sqrt(0.3 * 0.7 / len(offs))
    assert abs(frac_inside - 0.3) < 5 * sigma
    outside = offs[offs != 0]
    # with both sides fully available (left placed away from the edges) offsets are uniform on +-1..10
    central = np.array(
        [s.target_offset[0] for s in samples if 10 <= s.context[0] and s.context[1] <= 189 and s.target_offset[0]]
    )
    vals, counts = np.unique(central, return_counts=True)
    assert set(vals.tolist()) == set(range(-10, 0)) | set(range(1, 11))
    expected = len(central) / 20
    chi2 = ((counts - expected) ** 2 / expected).sum()
    assert chi2 < 50  # 19 dof: p ~ 1e-4
    assert outside.min() >= -10 and outside.max() <= 10


def test_extrap_clipped_at_scene_edges():
    # scene of gap + 2 frames: exactly one outside frame per placement, never out of range
    cfg = SamplingConfig(mode="extrap", gap_min=20, gap_max=40, extrap_frames=45, samples_per_scene=200)
    for s in sample_scene(cfg, 22, "edge", 3):
        assert s.gap == 20
        assert all(t in (0, 21) for t in s.target) and all(o in (-1, 1) for o in s.target_offset)


def test_interp_endpoints_and_v_greater_than_two():
    cfg = SamplingConfig(mode="interp", num_context=4, gap_min=3, gap_max=3, num_target=3, samples_per_scene=500)
    samples = sample_scene(cfg, 10, "v4", 1)
    for s in samples:
        assert s.context[0] + 3 == s.context[-1] and len(set(s.context)) == 4
    targets = np.array([[t - s.context[0] for t in s.target] for s in samples])
    assert set(np.unique(targets).tolist()) == {0, 1, 2, 3}  # endpoints included


def test_ablation_zero_extrap_frames_is_interpolation():
    cfg = SamplingConfig(mode="extrap", gap_min=5, gap_max=8, extrap_frames=0, samples_per_scene=50)
    assert min_scene_length(cfg) == 6
    assert all(o == 0 for s in sample_scene(cfg, 6, "a", 0) for o in s.target_offset)


def test_target_offsets_closed_form():
    assert target_offsets((33, 31), (32, 24, 44)) == (0, -7, 11)
    assert target_offsets((10, 20, 15), (9, 10, 20, 21)) == (-1, 0, 0, 1)


def test_invalid_config_is_refused():
    with pytest.raises(ValueError):
        SamplingConfig(gap_min=10, gap_max=5)
    with pytest.raises(ValueError):
        SamplingConfig(num_context=3, gap_min=1)
    with pytest.raises(ValueError):
        SamplingConfig(mode="extrap", interp_ratio=1.5)
