"""Which image pairs SfM matches (`seeu_data.ingest.pairs`): closed-form counts and cases, and the
shortlist of an unordered set against groups of images built to share features."""

from __future__ import annotations

import numpy as np

from seeu_data.ingest.pairs import (
    OVERLAP_INLIERS,
    exhaustive_pairs,
    keyframe_distances,
    keyframe_pairs,
    keyframe_rounds,
    neighbour_pairs,
    other_frame_pairs,
    shortlist_pairs,
    window_pairs,
)


def test_pair_lists_have_their_closed_form_counts():
    assert neighbour_pairs(5) == [(0, 1), (1, 2), (2, 3), (3, 4)]
    assert len(exhaustive_pairs(11)) == 55 and len(set(exhaustive_pairs(11))) == 55
    assert len(window_pairs(10, 3)) == 3 * 7 + 2 + 1  # the last three frames have fewer ahead
    assert keyframe_distances(51, 10) == [1, 2, 4, 8, 16, 32]
    assert keyframe_distances(400, 3) == [1, 2, 4]


def test_keyframe_pairs_stop_where_the_view_stopped_overlapping():
    keys = list(range(0, 44, 4))  # 11 keyframes
    assert keyframe_pairs(keys, 1, lambda a, b: 0) == [(k, k + 4) for k in keys[:-1]]
    # up to NEAR_KEYFRAMES apart: every pair, whatever the pairs nearer found
    assert keyframe_pairs(keys, 4, lambda a, b: 0) == [(k, k + 16) for k in keys[:-4]]
    # 8 keyframes apart only from keyframes whose pair 4 apart overlapped well: from 0, not from 4
    strong = {(0, 16): OVERLAP_INLIERS, (4, 20): OVERLAP_INLIERS - 1, (8, 24): 100}
    assert keyframe_pairs(keys, 8, lambda a, b: strong.get((a, b), 0)) == [(0, 32), (8, 40)]
    assert keyframe_rounds([1, 2, 4, 8, 16]) == [[1, 2, 4], [8], [16]]
    assert keyframe_rounds([2, 4, 8]) == [[2, 4], [8]] and keyframe_rounds([]) == []


def test_other_frames_are_paired_with_the_keyframes_around_them_but_not_twice_with_a_neighbour():
    # keyframes 0, 4, 8 and the last frame 9
    pairs = other_frame_pairs(10, [0, 4, 8, 9])
    assert pairs == [(1, 4), (0, 2), (2, 4), (0, 3), (5, 8), (4, 6), (6, 8), (4, 7)]


def test_shortlist_keeps_the_pairs_that_share_features_and_only_those():
    """12 images in 3 groups of 4: the images of a group share 40 of their 64 descriptors (with a little
    noise), the rest are random. Every pair within a group is kept, none across groups (their
    nearest neighbours fail the ratio test); the list follows the images when they are reordered."""
    rng = np.random.default_rng(0)
    groups = [rng.integers(0, 120, (40, 128)) for _ in range(3)]
    images = []
    for g in range(3):
        for _ in range(4):
            own = rng.integers(0, 120, (24, 128))
            shared = np.clip(groups[g] + rng.integers(-3, 4, groups[g].shape), 0, 255)
            images.append(np.concatenate([shared, own]))
    desc = np.stack(images).astype(np.uint8)  # (12, 64, 128)
    within = [(a, b) for a in range(12) for b in range(a + 1, 12) if a // 4 == b // 4]
    assert shortlist_pairs(desc) == within
    order = rng.permutation(12)
    back = {int(new): int(old) for new, old in enumerate(order)}
    shuffled = shortlist_pairs(desc[order])
    assert sorted((min(back[a], back[b]), max(back[a], back[b])) for a, b in shuffled) == within
    # an image with fewer features (rows of zeros) still finds its group
    desc[0, 48:] = 0
    assert shortlist_pairs(desc) == within
