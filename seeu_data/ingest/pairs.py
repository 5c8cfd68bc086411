"""Which image pairs SfM matches: only those that can overlap.

Frames are numbered 0..n-1 in input order. An image folder of up to `EXHAUSTIVE_MAX_IMAGES` images may be
unordered: every pair (`exhaustive_pairs`). A larger folder: each image with the next `UNORDERED_OVERLAP`
in name order (`window_pairs`). A video (and `--matcher sequential`) is matched in rounds, each round
chosen from what the ones before found:

1. every frame with the next (`neighbour_pairs`): the image motion between neighbours gives the keyframe
   stride (`seeu_data.ingest.keyframes`);
2. the keyframes (every stride-th frame) with the keyframes 1, 2, 4, ... keyframes ahead, up to
   2**(overlap-1) (`keyframe_pairs`); the pair d apart only when the pair d/2 apart from the same keyframe
   had at least `OVERLAP_INLIERS` verified inliers: past the distance where the view stops overlapping,
   no pair is tried (COLMAP's sequential matcher tries all of them, and with a stride every frame, not
   only keyframes, which the mapper never reads but the frames between keyframes need only for
   registration);
3. every other frame with the keyframes before and after it (`other_frame_pairs`): what its registration
   into the keyframes' model reads (with its neighbours of round 1).

    pairs = neighbour_pairs(90)                                # [(0, 1), (1, 2), ...]
    keys = [0, 2, 4, ..., 88, 89]
    ahead = keyframe_pairs(keys, 2, inliers)                   # pairs 2 keyframes apart worth trying
    rest = other_frame_pairs(90, keys)                         # (0, 1) is a neighbour: not repeated
"""

from __future__ import annotations

from collections.abc import Callable

from seeu_data.ingest.match_graph import MIN_INLIERS

# A keyframe pair d keyframes apart is tried only when the pair d/2 apart from the same keyframe had at
# least this many verified inliers (twice what the mapper needs of a pair to use it).
OVERLAP_INLIERS = 2 * MIN_INLIERS


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
    of two): all of them for distance 1, else those whose keyframe pair `distance / 2` apart from the same
    first keyframe had at least `OVERLAP_INLIERS` inliers (`inliers(a, b)`: verified inliers of frames a, b)."""
    out = []
    for j in range(len(keys) - distance):
        if distance == 1 or inliers(keys[j], keys[j + distance // 2]) >= OVERLAP_INLIERS:
            out.append((keys[j], keys[j + distance]))
    return out


def keyframe_distances(num_keys: int, overlap: int) -> list[int]:
    """The keyframe distances of round 2: 1, 2, 4, ..., at most 2**(overlap-1), fewer than `num_keys`."""
    return [2**k for k in range(overlap) if 2**k < num_keys]


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
