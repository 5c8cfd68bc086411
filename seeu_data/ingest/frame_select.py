"""Frame selection after decoding: sharpness filter and target count (the stride is applied while
decoding). Pure functions on per-frame metadata, so the choice is cheap to recompute and test.

    keep, dropped = select_frames(sharpness=[...], source_frames=[...], config=SelectConfig(...))
    # keep: positions into the candidate list; dropped: [{"source_frame", "reason"}]
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seeu_data.limits import MAX_FRAMES, check_range
from seeu_data.settings import setting


@dataclass(frozen=True)
class SelectConfig:
    """stride: keep every stride-th decoded frame (applied while decoding);
    sharpness_window: in each consecutive window of this many candidates, drop the blurriest
    (0 or 1 = off); target_frames: then keep this many, evenly spaced (None = all)."""

    stride: int = setting(1, "keep every N-th decoded frame")
    sharpness_window: int = setting(0, "drop the blurriest frame in each window of N candidates (0 = off)")
    target_frames: int | None = setting(None, "then keep this many frames, evenly spaced (default: all)")

    def check(self) -> None:
        check_range(self.stride, "--stride", 1, MAX_FRAMES)
        check_range(self.sharpness_window, "--sharpness-window", 0, MAX_FRAMES)
        if self.target_frames is not None:
            check_range(self.target_frames, "--target-frames", 2, MAX_FRAMES)


def drop_blurriest_per_window(sharpness: np.ndarray, window: int) -> tuple[np.ndarray, np.ndarray]:
    """Split `(N,)` sharpness scores into consecutive windows of `window`; drop the lowest of each.

    A trailing window shorter than `window` is kept whole. Returns (kept, dropped) positions, sorted.
    """
    sharpness = np.asarray(sharpness, np.float64)
    n = len(sharpness)
    if window < 2 or n == 0:
        return np.arange(n), np.zeros(0, np.int64)
    dropped = [start + int(np.argmin(sharpness[start : start + window])) for start in range(0, n - window + 1, window)]
    mask = np.ones(n, bool)
    mask[dropped] = False
    return np.nonzero(mask)[0], np.asarray(dropped, np.int64)


def evenly_spaced(n: int, target: int | None) -> np.ndarray:
    """`target` positions out of `n`, evenly spaced and including the first and last (all if n <= target)."""
    if target is None or n <= target:
        return np.arange(n)
    return np.unique(np.round(np.linspace(0, n - 1, target)).astype(np.int64))


def select_frames(
    sharpness: list[float] | np.ndarray, source_frames: list[int] | np.ndarray, config: SelectConfig
) -> tuple[np.ndarray, list[dict]]:
    """Apply the sharpness filter then the target count to the decoded candidates.

    Returns positions into the candidate list (increasing) and the dropped frames with the reason.
    """
    config.check()
    source_frames = np.asarray(source_frames, np.int64)
    kept, blurry = drop_blurriest_per_window(np.asarray(sharpness), config.sharpness_window)
    dropped = [{"source_frame": int(source_frames[i]), "reason": "blurriest in its sharpness window"} for i in blurry]
    pick = evenly_spaced(len(kept), config.target_frames)
    not_picked = np.setdiff1d(np.arange(len(kept)), pick)
    dropped += [
        {"source_frame": int(source_frames[kept[i]]), "reason": "thinned to --target-frames"} for i in not_picked
    ]
    dropped.sort(key=lambda d: int(d["source_frame"]))  # type: ignore[call-overload]
    return kept[pick], dropped
