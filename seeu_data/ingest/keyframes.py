"""Keyframes of a video for SfM mapping, and the other frames registered into the mapped model after.

Why: mapping every frame of a dense video costs about the square of the frame count. Frames taken
closer together see the same scene points, so each point's track grows with the frame count, and one
global bundle adjustment costs about the sum of squared track lengths (COLMAP's Schur complement),
which grows as the square; the incremental mapper runs ~40-60 of them (figures: docs/ingest.md,
Keyframes; `benchmarks/ingest_scaling.py`).

So only keyframes are mapped: every `stride`-th frame (and the last), the stride the largest power of
two keeping the median image motion between keyframes <= `target_px` (`keyframe_stride`). The other
frames are then registered into the mapped model one by one, in frame order, with COLMAP's own
incremental-mapper step (`register_frames`: 2D-3D RANSAC + pose refinement against the keyframes'
points, tracks continued; no new points, no bundle adjustment), which costs the same for every frame.

The stride is a power of two because sequential matching with quadratic overlap (`seeu_data.ingest.sfm`)
matches frames 1, 2, 4, ..., 2**(overlap-1) apart: keyframes `stride` apart are then matched to each
other at 1, 2, 4, ... keyframes apart, the same graph the mapper sees on a sparser video.

    motion = consecutive_motion_px(db, names)   # median image motion between consecutive frames, or None
    stride = keyframe_stride(len(names), motion, target_px=40.0, min_keyframes=30, max_stride=512)
    keys = keyframe_names(names, stride)
    added = register_frames(db_path, models, names, keys, seed=0, num_threads=1)
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seeu_data.ingest.match_graph import CHAIN_PCT, MIN_INLIERS


def consecutive_motion_px(db, names: list[str]) -> float | None:
    """Median image motion (pixels) between consecutive frames of `names` (input order) in `db` (an
    open pycolmap.Database): per consecutive pair with >= MIN_INLIERS verified inlier matches, the
    median distance between its matched keypoints; then the median over those pairs. None when fewer
    than CHAIN_PCT % of consecutive frames are matched (not a video: no stride applies)."""
    ids = {img.name: img.image_id for img in db.read_all_images()}
    order = [ids[n] for n in names if n in ids]
    keypoints: dict[int, np.ndarray] = {}

    def xy(image_id: int) -> np.ndarray:
        if image_id not in keypoints:
            keypoints[image_id] = np.asarray(db.read_keypoints(image_id), np.float64)[:, :2]
        return keypoints[image_id]

    per_pair = []
    for a, b in zip(order, order[1:]):
        if not db.exists_two_view_geometry(a, b):
            continue
        matches = np.asarray(db.read_two_view_geometry(a, b).inlier_matches, np.int64).reshape(-1, 2)
        if len(matches) < MIN_INLIERS:
            continue
        per_pair.append(float(np.median(np.linalg.norm(xy(a)[matches[:, 0]] - xy(b)[matches[:, 1]], axis=1))))
    if len(per_pair) < CHAIN_PCT / 100.0 * max(len(names) - 1, 1):
        return None
    return float(np.median(per_pair))


def keyframe_stride(
    num_frames: int, motion_px: float | None, target_px: float, min_keyframes: int, max_stride: int
) -> int:
    """The largest power of two `s` with `s * motion_px <= target_px`, at most `max_stride`, and
    leaving at least `min_keyframes` keyframes (ceil(num_frames / s)); 1 when `target_px` <= 0 or
    there is no motion measurement (`motion_px` None or not positive)."""
    if target_px <= 0 or motion_px is None or not motion_px > 0:
        return 1
    stride = 1
    while (
        2 * stride <= max_stride
        and 2 * stride * motion_px <= target_px
        and -(-num_frames // (2 * stride)) >= min_keyframes
    ):
        stride *= 2
    return stride


def keyframe_names(names: list[str], stride: int) -> list[str]:
    """Every `stride`-th name from the first, and the last one (so the whole video is mapped)."""
    keys = list(names[::stride])
    if names and keys[-1] != names[-1]:
        keys.append(names[-1])
    return keys


def register_frames(
    db_path: str | Path,
    models: dict,
    names: list[str],
    keys: list[str],
    seed: int,
    num_threads: int,
    on_frame=None,
    triangulate: bool = False,
) -> int:
    """Register the frames of `names` that the mapping of `keys` left out into `models` ({index:
    pycolmap.Reconstruction}), in place: the other frames, and keyframes the mapper could not register;
    returns how many were registered.

    Each frame goes into the model holding the nearest registered keyframe before it, else the one
    holding the nearest after it. COLMAP's incremental
    mapper registers it: 2D-3D correspondences through the verified matches to registered frames,
    RANSAC (seeded with `seed`) and pose refinement, its inlier observations appended to the tracks.
    The shared camera is not refined again. `on_frame()` is called after each frame tried. With `triangulate`
    (a trial of frames taken out in a run, `sfm_motion`), the frames nearest a registered keyframe go first and
    each one's new points are triangulated, so that a run's inner frames have points to register against: the
    first 11 keyframes of the 90-frame orbit of benchmarks/footage.py, taken out, were otherwise placed 5 of 11.
    (Registration after mapping does not triangulate: the frames a mover carried, registered again, would
    triangulate the mover and follow it again, as the large mover of benchmarks/dynamic.py did at 640x360.)
    """
    import pycolmap

    # keyframe the mapper registered -> its model; every other frame (keyframes the mapper could not
    # register included) is tried next to the registered keyframes before and after it
    home = {rec.image(i).name: k for k, rec in models.items() for i in rec.reg_image_ids()}
    anchors = set(keys) & set(home)
    following: dict[str, str | None] = {}  # frame -> the registered keyframe after it
    nxt = None
    for n in reversed(names):
        if n in anchors:
            nxt = n
        else:
            following[n] = nxt
    at = {n: k for k, n in enumerate(names)}
    pending, prev = [], None  # (frame, [model indices to try in turn], frames to the nearest anchor)
    for n in names:
        if n in anchors:
            prev = n
        else:
            near = [c for c in (prev, following[n]) if c is not None]
            if near:
                pending.append((n, list(dict.fromkeys(home[c] for c in near)), min(abs(at[n] - at[c]) for c in near)))
    if triangulate:
        pending.sort(key=lambda p: p[2])  # nearest first: a run of frames registers from its ends inwards
    db = pycolmap.Database.open(Path(db_path))
    try:
        cache_options = pycolmap.DatabaseCacheOptions()
        cache_options.min_num_matches = MIN_INLIERS  # as the mapper: pairs with fewer matches are ignored
        cache = pycolmap.DatabaseCache.create(db, cache_options)
    finally:
        db.close()
    options = pycolmap.IncrementalMapperOptions()
    options.random_seed = seed
    options.num_threads = num_threads
    triangulation = pycolmap.IncrementalTriangulatorOptions()
    mapper = pycolmap.IncrementalMapper(cache)
    added = 0
    for attempt in (0, 1):  # the first choice of model, then the second for frames that failed
        by_model: dict = {}
        for n, choices, _ in pending:
            if attempt < len(choices):
                by_model.setdefault(choices[attempt], []).append(n)
        failed = set()
        for k in sorted(by_model):
            rec = models[k]
            mapper.begin_reconstruction(rec)  # adds the database's other frames to it, unregistered
            ids = {img.name: img.image_id for img in rec.images.values()}
            for n in by_model[k]:
                if n in ids and mapper.register_next_image(options, ids[n]):
                    if triangulate:
                        mapper.triangulate_image(triangulation, ids[n])
                    added += 1
                else:
                    failed.add(n)
                if attempt == 0 and on_frame is not None:
                    on_frame()
            mapper.end_reconstruction(False)
        pending = [p for p in pending if p[0] in failed]
    return added


@dataclass(frozen=True)
class Keyframes:
    """The frames mapped: every `stride`-th frame (`names`); `info` is the SfM result's "keyframes"."""

    stride: int
    names: list[str]
    info: dict


def choose_keyframes(
    names: list[str], motion_px: float | None, target_px: float, min_keyframes: int, overlap: int
) -> Keyframes:
    """The frames to map (`keyframe_stride`, `keyframe_names`) of a video matched with quadratic
    overlap `overlap`: keyframes `stride` apart stay matched to each other at 1, 2 and 4 keyframes apart."""
    stride = keyframe_stride(len(names), motion_px, target_px, min_keyframes, 2 ** max(overlap - 3, 0))
    keys = keyframe_names(names, stride)
    return Keyframes(
        stride, keys, {"stride": stride, "count": len(keys), "motion_px": motion_px, "target_px": target_px}
    )
