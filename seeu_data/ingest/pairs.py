"""Which image pairs SfM matches: only those that can overlap.

Frames are numbered 0..n-1 in input order. An image folder of up to `EXHAUSTIVE_MAX_IMAGES` images may be
unordered: every pair (`exhaustive_pairs`), or, above `match_graph.SHORTLIST_ABOVE` images, every pair that shares
enough of the images' most prominent features (`shortlist_pairs`). A larger folder: each image with the
next `UNORDERED_OVERLAP` in name order (`window_pairs`). A video (and `--matcher sequential`) is matched in rounds, each round
chosen from what the ones before found:

1. every frame with the next (`neighbour_pairs`): the image motion between neighbours gives the keyframe
   stride (`seeu_data.ingest.keyframes`);
2. the keyframes (every stride-th frame) with the keyframes 1, 2 and 4 ahead (`NEAR_KEYFRAMES`), in one
   round; then with those 8, 16, ... keyframes ahead, up to 2**(overlap-1), a round each (`keyframe_pairs`):
   the pair d apart only when the pair d/2 apart from the same keyframe had at least `OVERLAP_INLIERS`
   verified inliers, so past the distance where the view stops overlapping no pair is tried (COLMAP's
   sequential matcher tries all of them, and with a stride every frame, not only keyframes, which the
   mapper never reads but the frames between keyframes need only for registration);
3. every other frame with the keyframes before and after it (`other_frame_pairs`): what its registration
   into the keyframes' model reads (with its neighbours of round 1).

    pairs = neighbour_pairs(90)                                # [(0, 1), (1, 2), ...]
    keys = [0, 2, 4, ..., 88, 89]
    near = keyframe_pairs(keys, 2, inliers)                    # all pairs 2 keyframes apart
    ahead = keyframe_pairs(keys, 8, inliers)                   # pairs 8 apart whose pair 4 apart overlapped
    rest = other_frame_pairs(90, keys)                         # (0, 1) is a neighbour: not repeated
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from seeu_data.ingest.match_graph import MIN_INLIERS

# A keyframe pair d keyframes apart is tried only when the pair d/2 apart from the same keyframe had at
# least this many verified inliers (twice what the mapper needs of a pair to use it).
OVERLAP_INLIERS = 2 * MIN_INLIERS
# Keyframes at most this many apart are matched whatever their overlap, in one round: every round reads each
# keyframe's features again (COLMAP's matcher, per call), and 4 keyframes are at most about 4 x
# --keyframe-motion of image motion apart (160 px by default), which a frame the stride was chosen for still
# shares. On the 90-frame orbit of benchmarks/footage.py: the same pairs, two rounds fewer.
NEAR_KEYFRAMES = 4
# The shortlist: each image's this many largest-scale features; a pair is kept when both images find at
# least SHORTLIST_SHARED of theirs in the other (nearest neighbour passing the ratio test), and each image
# keeps its SHORTLIST_KEEP best pairs whatever their count
SHORTLIST_FEATURES = 128
SHORTLIST_SHARED = 8
SHORTLIST_KEEP = 8
RATIO = 0.8  # COLMAP's matching ratio test


def neighbour_pairs(n: int) -> list[tuple[int, int]]:
    """(i, i + 1) for every frame but the last."""
    return [(i, i + 1) for i in range(n - 1)]


def exhaustive_pairs(n: int) -> list[tuple[int, int]]:
    """Every pair (i, j), i < j: n (n - 1) / 2 of them."""
    return [(i, j) for i in range(n) for j in range(i + 1, n)]


def window_pairs(n: int, window: int) -> list[tuple[int, int]]:
    """Each frame with the next `window` frames."""
    return [(i, j) for i in range(n) for j in range(i + 1, min(n, i + 1 + window))]


def keyframe_pairs(keys: list[int], distance: int, inliers: Callable[[int, int], int]) -> list[tuple[int, int]]:
    """Pairs of keyframes `distance` keyframes apart (`keys`: frame numbers, increasing; `distance` a power
    of two): all of them up to `NEAR_KEYFRAMES`, else those whose keyframe pair `distance / 2` apart from the
    same first keyframe had at least `OVERLAP_INLIERS` inliers (`inliers(a, b)`: verified inliers of frames a, b)."""
    out = []
    for j in range(len(keys) - distance):
        if distance <= NEAR_KEYFRAMES or inliers(keys[j], keys[j + distance // 2]) >= OVERLAP_INLIERS:
            out.append((keys[j], keys[j + distance]))
    return out


def keyframe_distances(num_keys: int, overlap: int) -> list[int]:
    """The keyframe distances of round 2: 1, 2, 4, ..., at most 2**(overlap-1), fewer than `num_keys`."""
    return [2**k for k in range(overlap) if 2**k < num_keys]


def keyframe_rounds(distances: list[int]) -> list[list[int]]:
    """`distances` (increasing) in matching rounds: those up to `NEAR_KEYFRAMES` together, then one each."""
    near = [d for d in distances if d <= NEAR_KEYFRAMES]
    return ([near] if near else []) + [[d] for d in distances if d > NEAR_KEYFRAMES]


def other_frame_pairs(n: int, keys: list[int]) -> list[tuple[int, int]]:
    """Each frame that is not a keyframe with the keyframe before it and the one after it, unless that
    keyframe is its neighbour (matched in round 1)."""
    out = []
    is_key = set(keys)
    before = None
    after = {}
    nxt = None
    for i in range(n - 1, -1, -1):
        if i in is_key:
            nxt = i
        else:
            after[i] = nxt
    for i in range(n):
        if i in is_key:
            before = i
            continue
        for k in (before, after[i]):
            if k is not None and abs(k - i) > 1:
                out.append((min(i, k), max(i, k)))
    return out


def shortlist_pairs(descriptors: np.ndarray) -> list[tuple[int, int]]:
    """The pairs of an unordered image set worth matching in full, from a few features of each.

    `descriptors`: `(n, M, 128)` uint8, image i's M most prominent SIFT descriptors (rows of zeros where
    an image has fewer). For each ordered pair (a, b), count the descriptors of a whose nearest neighbour
    in b passes the ratio test (`RATIO`, on the angle between descriptors, as COLMAP); a pair's score is
    the smaller of its two counts. Kept: every pair scoring at least `SHORTLIST_SHARED`, and each image's
    `SHORTLIST_KEEP` best-scoring pairs (score > 0). The dot products are of whole numbers below 2**24,
    exact in float32 whatever the summation order, so the list does not depend on the BLAS threads.
    Returns the pairs (i, j), i < j, sorted.
    """
    n, m, _ = descriptors.shape
    x = descriptors.astype(np.float32)
    norms = np.linalg.norm(x.astype(np.float64), axis=2)  # (n, M)
    inv = np.divide(1.0, norms, out=np.zeros_like(norms), where=norms > 0).astype(np.float32)
    flat = x.reshape(n * m, -1)
    counts = np.zeros((n, n), np.int64)
    for a in range(n):
        # cosines up to a's own norm (the same along a row): element-wise, so exact products stay deterministic
        cos = (x[a] @ flat.T).reshape(m, n, m) * inv[None, :, :]  # (M of a, n, M of b)
        best2 = -np.partition(-cos, 1, axis=2)[:, :, :2].astype(np.float64) * inv[a][:, None, None]
        angle = np.arccos(np.clip(best2, -1.0, 1.0))  # (M, n, 2): best, second best
        passed = (angle[:, :, 0] < RATIO * angle[:, :, 1]) & (norms[a][:, None] > 0)
        counts[a] = passed.sum(0)
    np.fill_diagonal(counts, 0)
    score = np.minimum(counts, counts.T)
    keep = {(min(a, b), max(a, b)) for a, b in zip(*np.nonzero(score >= SHORTLIST_SHARED))}
    for a in range(n):
        order = np.argsort(-score[a], kind="stable")
        keep.update((min(a, int(b)), max(a, int(b))) for b in order[:SHORTLIST_KEEP] if score[a, b] > 0)
    return sorted(keep)
