"""Scale conventions of ingested scenes (`seeu ingest --scale`), recorded in every chunk's meta.

SfM reconstructs a scene up to an unknown scale. Each posed chunk is expressed relative to its first
camera and multiplied by one factor chosen by a convention:

- `re10k` (default): the scale under which the pixelSplat / MVSplat RealEstate10K setup (fixed near
  1, far 100, depth candidates uniform in inverse depth between them) fits the scene: the scene's
  own near estimate (0.4 x the 0.1th percentile of the SfM point depths, the bound the median-depth
  convention records) becomes the peers' near = 1, and near/far are recorded as 1 / 100.
  RealEstate10K's ORB-SLAM scale is arbitrary per clip; what the fixed setup needs is near = 1 below
  every visible surface (a surface nearer than the first depth candidate cannot be placed) and
  far = 100 beyond the farthest. SfM points under-sample the nearest, most foreshortened surfaces
  (floor at the bottom of the frame): on the synthetic corridor (320x180, 36 frames) 1 % of the
  true rendered depths lie below 0.35 x the 5th percentile of the SfM point depths, so a rule such
  as "p5 = 2" would put them in front of near = 1; the 0.4 x p0.1 bound lies below them. The shares of
  points nearer than 1 (`points_nearer_than_near_pct`) and farther than 100
  (`points_farther_than_far_pct`) are recorded, so a scene the peers would clip shows.
- `median-depth`: the median SfM point depth becomes 1; near/far from the depth percentiles
  (`chunks.NEAR_FAR_METHOD`), i.e. the tightest range for this toolkit's own model.
- `metric`: the user gives a real distance D (metres) between two cameras (by default the first and
  the last selected frame): the chunk is in metres; near/far from the depth percentiles.

    s = chunk_scale(ScaleConfig("re10k"), depths, centres)   # -> ScaleChoice(factor, near, far, meta)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seeu_data.errors import SeeUError
from seeu_data.settings import parse_int_pair, setting

SCALES = ("re10k", "median-depth", "metric")
RE10K_NEAR_FAR = (1.0, 100.0)
# near/far from point depths: near = NEAR_MARGIN x the NEAR_PERCENTILE-th percentile, far = FAR_MARGIN x
# the FAR_PERCENTILE-th (SfM triangulates few points on the nearest, most foreshortened surfaces)
NEAR_PERCENTILE, FAR_PERCENTILE = 0.1, 99.9
NEAR_MARGIN, FAR_MARGIN = 0.4, 1.5
# each convention's rule, said once: in the --scale help, in each chunk's meta (`scale_method`) and, word
# for word, in docs/ingest.md (tests/test_scale.py)
SCALE_RULES = {
    "re10k": f"the scene's near bound ({NEAR_MARGIN:g} x percentile {NEAR_PERCENTILE:g} of the SfM point depths) "
    f"becomes 1 and near/far are {RE10K_NEAR_FAR[0]:g}/{RE10K_NEAR_FAR[1]:g}, as in the pixelSplat/MVSplat "
    "RealEstate10K setup",
    "median-depth": f"the median SfM point depth becomes 1; near/far are {NEAR_MARGIN:g} x percentile "
    f"{NEAR_PERCENTILE:g} / {FAR_MARGIN:g} x percentile {FAR_PERCENTILE:g} of the SfM point depths",
    "metric": "metres, from the real distance D (--known-distance) between the cameras of the first and the "
    "last selected frame, or of two source frames named with --distance-frames; near/far as for median-depth",
}


def near_far_from_depths(
    depths: np.ndarray,
    near_percentile: float = NEAR_PERCENTILE,
    far_percentile: float = FAR_PERCENTILE,
    near_margin: float = NEAR_MARGIN,
    far_margin: float = FAR_MARGIN,
) -> tuple[float, float]:
    """(near, far) bounding the positive point depths `depths` (M,): margin x percentile at each end."""
    depths = np.asarray(depths, np.float64)
    return (
        near_margin * float(np.percentile(depths, near_percentile)),
        far_margin * float(np.percentile(depths, far_percentile)),
    )


@dataclass(frozen=True)
class ScaleConfig:
    """`scale`: one of SCALES; `known_distance` (metres, metric only) between the cameras of the
    source frames `distance_frames` (None: the first and the last selected frame)."""

    scale: str = setting(
        "re10k",
        "scale convention, recorded in each chunk's meta: " + "; ".join(f"{k}: {v}" for k, v in SCALE_RULES.items()),
        choices=SCALES,
    )
    known_distance: float | None = setting(
        None,
        "--scale metric: real distance between the cameras of the first and last frame (or of --distance-frames)",
        metavar="METRES",
    )
    distance_frames: tuple[int, int] | None = setting(
        None,
        "--scale metric: the two source frame numbers --known-distance is measured between",
        metavar="A,B",
        parse=parse_int_pair,
    )

    def check(self) -> None:
        if self.scale not in SCALES:
            raise SeeUError(f"--scale must be one of {', '.join(SCALES)}, got {self.scale!r}")
        if self.scale == "metric":
            if self.known_distance is None:
                raise SeeUError("--scale metric needs --known-distance D (metres between two cameras)")
            if not (np.isfinite(self.known_distance) and self.known_distance > 0):
                raise SeeUError(f"--known-distance must be a positive number of metres, got {self.known_distance}")
        elif self.known_distance is not None or self.distance_frames is not None:
            raise SeeUError("--known-distance / --distance-frames only apply with --scale metric")


@dataclass
class ScaleChoice:
    factor: float  # multiply the SfM model's translations by this
    near: float
    far: float
    meta: dict


def chunk_scale(
    cfg: ScaleConfig,
    depths: np.ndarray,
    near_far_unit: tuple[float, float],
    distance_centres: tuple[np.ndarray, np.ndarray] | None = None,
) -> ScaleChoice:
    """The scale factor and near/far of a chunk.

    `depths`: (M,) positive depths of the SfM point observations in the model's cameras (model
    units); `near_far_unit`: near/far from those depths' percentiles (model units, see
    `chunks.NEAR_FAR_METHOD`); `distance_centres`: the two (3,) camera centres (model units) that are
    `cfg.known_distance` metres apart (metric only).
    """
    depths = np.asarray(depths, np.float64)
    if cfg.scale == "median-depth":
        s = 1.0 / float(np.median(depths))
        return ScaleChoice(
            s,
            near_far_unit[0] * s,
            near_far_unit[1] * s,
            {"scale_convention": "median-depth", "scale_method": SCALE_RULES["median-depth"]},
        )
    if cfg.scale == "re10k":
        near, far = RE10K_NEAR_FAR
        s = near / near_far_unit[0]
        return ScaleChoice(
            s,
            near,
            far,
            {
                "scale_convention": "re10k",
                "scale_method": SCALE_RULES["re10k"],
                "points_nearer_than_near_pct": float(100.0 * np.mean(depths * s < near)),
                "points_farther_than_far_pct": float(100.0 * np.mean(depths * s > far)),
                "near_far_method": "fixed 1 / 100 (the pixelSplat / MVSplat RealEstate10K setup)",
                "near_far_from_depths": [near_far_unit[0] * s, near_far_unit[1] * s],
            },
        )
    assert cfg.scale == "metric" and distance_centres is not None and cfg.known_distance is not None
    d = float(np.linalg.norm(np.asarray(distance_centres[0]) - np.asarray(distance_centres[1])))
    if not d > 1e-9 * max(1.0, float(np.median(depths))):
        raise SeeUError(
            "--known-distance: the two cameras are at the same place in the SfM model; "
            "name two frames further apart with --distance-frames"
        )
    s = cfg.known_distance / d
    return ScaleChoice(
        s,
        near_far_unit[0] * s,
        near_far_unit[1] * s,
        {
            "scale_convention": "metric",
            "scale_method": f"metres: the two cameras are {cfg.known_distance:g} m apart (--known-distance)",
        },
    )


def distance_frame_names(frames: list[dict], distance_frames: tuple[int, int] | None, source) -> tuple[str, str] | None:
    """The image names of the selected frames (dicts with "name", "source_frame") whose source frame
    numbers are `distance_frames`; None when not given (the first and the last frame then)."""
    if distance_frames is None:
        return None
    by_source = {int(f["source_frame"]): f["name"] for f in frames}
    for f in distance_frames:
        if f not in by_source:
            raise SeeUError(
                f"--distance-frames: source frame {f} is not among the selected frames "
                f"({len(frames)} kept of the video; see --stride / --target-frames)",
                source,
            )
    return by_source[distance_frames[0]], by_source[distance_frames[1]]
