"""Split SfM models into posed chunks, normalise their scale and pick near/far.

A posed chunk is a contiguous run of selected frames registered in one SfM model: a frame that is
not registered breaks the run, and a model split by COLMAP gives separate chunks. Frames matched out
of order (an image folder matched exhaustively, or each image with its next neighbours:
result.json's "matcher" with "quadratic" false) are photos whose name order means nothing: there a
chunk is every frame a model registered, in name order. A frame registered
in several overlapping models belongs to the largest one only. Runs shorter than
`min_chunk_frames` are dropped (and reported); for photos, models shorter than `shortest_chunk`: at most
80 % of the set, COLMAP's own rule for keeping a model (9 of 11 photos is a scene).

Scale and frame of each chunk (recorded in the chunk's meta): poses are expressed relative to the
chunk's first camera (identity) and scaled by the convention `config.scale` (`seeu_data.ingest.scale`:
re10k, median-depth, metric); near/far (median-depth, metric) are the 0.1th / 99.9th percentiles of
the depths of the SfM points seen by the model's cameras times 0.4 / 1.5 (SfM triangulates few
points on the nearest, most foreshortened surfaces, hence the margins); re10k records the peers' 1 / 100.

    chunks, dropped = plan_chunks(scene_name, frames, sfm_result, sfm_dir, ChunkConfig(min_chunk_frames=10))
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from seeu_data.cameras import cam_to_world_from_world_to_cam, homogeneous_from_3x4, invert_rigid
from seeu_data.errors import SeeUError
from seeu_data.ingest.scale import (
    FAR_MARGIN,
    FAR_PERCENTILE,
    NEAR_MARGIN,
    NEAR_PERCENTILE,
    ScaleConfig,
    chunk_scale,
    near_far_from_depths,
)
from seeu_data.limits import MAX_FRAMES, check_range
from seeu_data.settings import setting

NEAR_FAR_METHOD = (
    "sfm_point_depth_percentiles: near = 0.4 * p0.1, far = 1.5 * p99.9 of the depths of SfM point "
    "observations in the model's cameras"
)
FRAME_METHOD = "world frame = first camera of the chunk"


@dataclass(frozen=True)
class ChunkConfig:
    min_chunk_frames: int = setting(
        10, "shortest posed chunk kept (an image folder: at most 80% of its images, as SfM keeps a model)"
    )
    near_percentile: float = NEAR_PERCENTILE
    far_percentile: float = FAR_PERCENTILE
    near_margin: float = NEAR_MARGIN
    far_margin: float = FAR_MARGIN
    scale: ScaleConfig = field(default_factory=ScaleConfig)

    def check(self) -> None:
        check_range(self.min_chunk_frames, "--min-chunk-frames", 2, MAX_FRAMES)
        self.scale.check()


@dataclass
class Chunk:
    """One posed chunk. N = frames. cam_to_world: (N, 4, 4) normalised; intrinsics_norm: (N, 4), width and
    height: (N,) per frame (frames of different sizes, e.g. portrait and landscape photos, have their own camera)."""

    scene_id: str
    model_index: int
    frame_positions: list[int]  # positions into the selected-frame list
    image_paths: list[Path]
    cam_to_world: np.ndarray
    intrinsics_norm: np.ndarray
    width: np.ndarray
    height: np.ndarray
    near: float
    far: float
    meta: dict = field(default_factory=dict)


def _runs(flags: np.ndarray) -> list[tuple[int, int]]:
    """Maximal runs of True in a boolean `(N,)` array as [start, end) pairs."""
    runs, start = [], None
    for i, f in enumerate(list(flags) + [False]):
        if f and start is None:
            start = i
        elif not f and start is not None:
            runs.append((start, i))
            start = None
    return runs


def colmap_smallest(min_size: int, num_frames: int) -> int:
    """COLMAP's rule for the smallest model it keeps: `min_size` frames, or 80 % of the `num_frames` frames
    mapped if fewer (9 of 11 photos is a model, as bare pycolmap keeps it)."""
    return min(min_size, int(0.8 * num_frames))


def shortest_chunk(config: ChunkConfig, ordered: bool, num_frames: int) -> int:
    """The fewest frames of a kept chunk: `min_chunk_frames`; of photos matched out of order, the models
    SfM keeps (`colmap_smallest`), at least 2."""
    return config.min_chunk_frames if ordered else max(2, colmap_smallest(config.min_chunk_frames, num_frames))


def plan_chunks(
    scene_name: str,
    frame_names: list[str],
    sfm_result: dict,
    sfm_dir: str | Path,
    config: ChunkConfig,
    distance_names: tuple[str, str] | None = None,
) -> tuple[list[Chunk], list[dict]]:
    """Turn SfM models into chunks. `frame_names`: the selected frames' image names, in order;
    `distance_names`: the two frames `config.scale.known_distance` apart (metric scale; default the
    first and the last frame).

    Returns the chunks (ordered by first frame) and dropped frames as
    {"position", "reason"} (position into `frame_names`).
    """
    config.check()
    ordered = (sfm_result.get("matcher") or {}).get("quadratic", True)  # frames matched in their order
    sfm_dir = Path(sfm_dir)
    pos_of = {n: i for i, n in enumerate(frame_names)}
    registered_anywhere = np.zeros(len(frame_names), bool)
    raw: list[tuple[list[int], dict, dict[int, np.ndarray]]] = []  # (positions, model, world-to-camera by position)
    dropped: list[dict] = []
    claimed = np.zeros(len(frame_names), bool)
    # COLMAP may register a frame in several (overlapping) models: the largest model claims it, so
    # no frame appears in two chunks.
    for model in sorted(sfm_result["models"], key=lambda m: -len(m["images"])):
        w2c = {
            pos_of[im["name"]]: homogeneous_from_3x4(np.asarray(im["world_to_cam"], np.float64))
            for im in model["images"]
            if im["name"] in pos_of
        }
        model.setdefault("cameras", [model["camera"]])  # results before per-size cameras: one shared camera
        flags = np.zeros(len(frame_names), bool)
        flags[list(w2c)] = True
        registered_anywhere |= flags
        flags &= ~claimed
        claimed |= flags
        if ordered:
            raw += [(list(range(start, end)), model, w2c) for start, end in _runs(flags)]
        elif flags.any():
            raw.append(([int(p) for p in np.nonzero(flags)[0]], model, w2c))
    kept = []
    least = shortest_chunk(config, ordered, len(frame_names))
    for positions, model, w2c in sorted(raw, key=lambda r: (r[0][0], -len(r[0]))):
        if len(positions) < least:
            what = "a registered run" if ordered else "an SfM model"
            bound = f"--min-chunk-frames {least}" if least == config.min_chunk_frames else f"{least}, 80% of the photos"
            dropped += [
                {"position": p, "reason": f"in {what} of {len(positions)} frames (< {bound})"} for p in positions
            ]
            continue
        kept.append((positions, model, w2c))
    dropped += [{"position": int(p), "reason": "not registered by SfM"} for p in np.nonzero(~registered_anywhere)[0]]
    # a frame dropped from a short run may still be in a kept chunk of another model
    in_chunks = {p for positions, _, _ in kept for p in positions}
    dropped = sorted((d for d in dropped if d["position"] not in in_chunks), key=lambda d: d["position"])
    chunks = []
    for j, (positions, model, w2c) in enumerate(kept):
        cam = model["camera"]
        im_cam = {pos_of[im["name"]]: im.get("camera", 0) for im in model["images"] if im["name"] in pos_of}
        depths = np.load(sfm_dir / f"points_depth_{model['index']}.npy")
        depths = depths[np.isfinite(depths) & (depths > 0)]
        if len(depths) < 10:
            raise SeeUError(f"SfM model {model['index']} has only {len(depths)} usable 3D points")
        near_far_unit = near_far_from_depths(
            depths, config.near_percentile, config.far_percentile, config.near_margin, config.far_margin
        )
        centres = None
        if config.scale.scale == "metric":
            names = distance_names or (frame_names[0], frame_names[-1])
            missing = [n for n in names if pos_of.get(n) not in w2c]
            if missing:
                raise SeeUError(
                    f"--scale metric: frame {missing[0]} is not registered in SfM model {model['index']}, "
                    "so its distance is unknown (name registered frames with --distance-frames)"
                )
            centres = tuple(invert_rigid(w2c[pos_of[n]])[:3, 3] for n in names)
        choice = chunk_scale(config.scale, depths, near_far_unit, centres)
        scale, near, far = choice.factor, choice.near, choice.far
        c2w = cam_to_world_from_world_to_cam(np.stack([w2c[p] for p in positions]))
        first_w2c = invert_rigid(c2w[0])
        c2w = first_w2c @ c2w  # first camera of the chunk = identity
        c2w[:, :3, 3] *= scale
        sfm_to_chunk = np.diag([scale, scale, scale, 1.0]) @ first_w2c  # SfM world point -> chunk frame
        cams = [model["cameras"][im_cam[p]] for p in positions]
        w = np.array([int(c["width"]) for c in cams], np.int64)
        h = np.array([int(c["height"]) for c in cams], np.int64)
        intr = np.array(
            [[c["fx"] / c["width"], c["fy"] / c["height"], c["cx"] / c["width"], c["cy"] / c["height"]] for c in cams]
        )
        chunks.append(
            Chunk(
                scene_id=f"{scene_name}_c{j}",
                model_index=int(model["index"]),
                frame_positions=positions,
                image_paths=[Path(model["image_dir"]) / frame_names[p] for p in positions],
                cam_to_world=c2w,
                intrinsics_norm=intr,
                width=w,
                height=h,
                near=near,
                far=far,
                meta={
                    "sfm_model": int(model["index"]),
                    "camera_model": cam["model"],
                    "camera_params": cam["params"],
                    "undistorted": bool(model["undistorted"]),
                    "distortion_max_px": model.get("distortion_max_px"),
                    "camera_as_mapped": model.get("camera_distorted", cam),
                    "scale_factor": scale,
                    **choice.meta,
                    "sfm_to_chunk": sfm_to_chunk.tolist(),
                    "frame_method": FRAME_METHOD,
                    "near_far_method": choice.meta.get("near_far_method", NEAR_FAR_METHOD),
                    "mean_reprojection_error_px": model["mean_reprojection_error"],
                },
            )
        )
    return chunks, dropped
