"""Context-target view sampling: pure functions from (scene length, config, seed) to index plans.

No images are touched here; a plan is a handful of integers per sample, so the whole build plan is
computed on the driver before any shard is written (that is what makes local and Ray builds
byte-identical).

Modes (frame indices are the posed frames' `frame_index`, 0 .. N-1):

* ``interp`` -- the peers' bounded sampler: context gap g uniform in [gap_min, gap_max] (clipped to
  the scene), left context uniform in [0, N-1-g], right = left + g, targets drawn uniformly *with
  replacement* inside [left, right] (endpoints included), then sorted.
* ``extrap`` -- SeeU / pixelSplat-curriculum extrapolation: every target is, with probability
  `interp_ratio`, an interpolation target (inside [left, right]); otherwise it is drawn uniformly from
  the frames *outside* the pair and at most `extrap_frames` away, clipped to the scene:
  [left - E, left - 1] U [right + 1, right + E]. The gap is clipped to N - 2 so every placement leaves
  at least one outside frame. With `extrap_frames == 0` (the "no extrapolation" ablation) all targets
  are interpolation targets.

With V > 2 context views, left/right are placed by the gap and the other V - 2 contexts are drawn
without replacement strictly inside (left, right). Contexts are listed in ascending order.

`target_offset` of a target t: 0 when min(ctx) <= t <= max(ctx), t - min(ctx) (< 0) before,
t - max(ctx) (> 0) after.

Randomness: one numpy Generator per (seed, scene_id), seeded from the sha256 of the scene id (never
Python's `hash()`), so a scene's samples do not depend on processing order, worker count or engine.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field

import numpy as np

from seeu_data.limits import MAX_CONTEXT_VIEWS, MAX_FRAMES, MAX_SAMPLES, MAX_TARGET_VIEWS, check_range
from seeu_data.settings import setting

MODES = ("interp", "extrap")


@dataclass(frozen=True)
class SamplingConfig:
    """Parameters of the interp / extrap samplers (see the module docstring)."""

    mode: str = setting("interp", "where targets lie", choices=MODES)
    num_context: int = setting(2, "context views per example", aliases=("-V",))
    num_target: int = setting(3, "target views per example", aliases=("-T",))
    gap_min: int = setting(25, "smallest context gap in frames")
    gap_max: int = setting(45, "largest context gap in frames")
    extrap_frames: int = setting(45, "extrap: targets at most this many frames before/after the pair")
    interp_ratio: float = setting(0.0, "extrap: probability that a target is drawn inside the pair instead")
    samples_per_scene: int = setting(4, "examples drawn per scene")

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {self.mode!r}")
        # each count in its range (SeeUError naming the `seeu build` flag): a huge count would plan forever
        check_range(self.num_context, "--num-context", 2, MAX_CONTEXT_VIEWS)
        check_range(self.num_target, "--num-target", 1, MAX_TARGET_VIEWS)
        check_range(self.samples_per_scene, "--samples-per-scene", 1, MAX_SAMPLES)
        check_range(self.gap_min, "--gap-min", 1, MAX_FRAMES)
        check_range(self.gap_max, "--gap-max", 1, MAX_FRAMES)
        check_range(self.extrap_frames, "--extrap-frames", 0, MAX_FRAMES)
        if self.gap_min < self.num_context - 1:
            raise ValueError(f"gap_min must be >= num_context - 1 = {self.num_context - 1}")
        if self.gap_max < self.gap_min:
            raise ValueError("gap_max must be >= gap_min")
        if not 0.0 <= self.interp_ratio <= 1.0:
            raise ValueError("interp_ratio must be in [0, 1]")

    @property
    def wants_outside(self) -> bool:
        """True when extrapolation targets outside the pair can be drawn."""
        return self.mode == "extrap" and self.extrap_frames > 0 and self.interp_ratio < 1.0


@dataclass(frozen=True)
class Sample:
    """One planned example: frame indices only. `context` (V,), `target` (T,), `target_offset` (T,)."""

    scene_id: str
    mode: str
    k: int  # ordinal of the sample within its scene (and mode)
    context: tuple[int, ...]
    target: tuple[int, ...]
    target_offset: tuple[int, ...] = field(default=())

    @property
    def sample_id(self) -> str:
        return f"{self.scene_id}/{self.mode}/{self.k}"

    @property
    def gap(self) -> int:
        return int(max(self.context) - min(self.context))

    @property
    def views(self) -> tuple[int, ...]:
        """Contexts first, then targets: the order of the per-view columns."""
        return self.context + self.target

    def as_dict(self) -> dict:
        return {
            "scene_id": self.scene_id,
            "mode": self.mode,
            "k": self.k,
            "context": list(self.context),
            "target": list(self.target),
        }


def target_offsets(context, target) -> tuple[int, ...]:
    """Signed offset of every target from the context range (0 inside)."""
    lo, hi = min(context), max(context)
    return tuple(int(t - lo) if t < lo else int(t - hi) if t > hi else 0 for t in target)


def make_sample(scene_id: str, mode: str, k: int, context, target) -> Sample:
    context = tuple(int(c) for c in context)
    target = tuple(int(t) for t in target)
    return Sample(scene_id, mode, k, context, target, target_offsets(context, target))


def scene_rng(seed: int, scene_id: str) -> np.random.Generator:
    """Generator seeded by (seed, sha256(scene_id)): independent of order, workers and engine."""
    digest = hashlib.sha256(scene_id.encode("utf-8")).digest()
    words = [int.from_bytes(digest[i : i + 4], "little") for i in range(0, 16, 4)]
    return np.random.default_rng(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, int(seed) >> 32 & 0xFFFFFFFF, *words]))


def min_scene_length(cfg: SamplingConfig) -> int:
    """Fewest frames a scene needs for `cfg` (gap_min + 1, plus one outside frame for extrap)."""
    return cfg.gap_min + 1 + (1 if cfg.wants_outside else 0)


def max_gap(cfg: SamplingConfig, num_frames: int) -> int:
    """Largest usable gap in a scene of `num_frames` frames (may be < gap_min: scene too short)."""
    limit = num_frames - 1 - (1 if cfg.wants_outside else 0)
    return min(cfg.gap_max, limit)


def sample_one(rng: np.random.Generator, cfg: SamplingConfig, num_frames: int, scene_id: str, k: int) -> Sample:
    """Draw one sample from a scene of `num_frames` frames (caller checked the length)."""
    hi_gap = max_gap(cfg, num_frames)
    if hi_gap < cfg.gap_min:
        raise ValueError(f"scene of {num_frames} frames is too short for gap_min {cfg.gap_min}")
    gap = int(rng.integers(cfg.gap_min, hi_gap + 1))
    left = int(rng.integers(0, num_frames - gap))
    right = left + gap
    inner: tuple[int, ...] = ()
    if cfg.num_context > 2:
        inner = tuple(int(x) for x in rng.choice(np.arange(left + 1, right), cfg.num_context - 2, replace=False))
    context = tuple(sorted((left, right) + inner))

    targets = []
    if cfg.wants_outside:
        before = np.arange(max(0, left - cfg.extrap_frames), left)
        after = np.arange(right + 1, min(num_frames, right + cfg.extrap_frames + 1))
        outside = np.concatenate([before, after])
    for _ in range(cfg.num_target):
        if cfg.wants_outside and rng.random() >= cfg.interp_ratio:
            targets.append(int(outside[rng.integers(0, len(outside))]))
        else:
            targets.append(int(rng.integers(left, right + 1)))
    return make_sample(scene_id, cfg.mode, k, context, sorted(targets))


def sample_scene(cfg: SamplingConfig, num_frames: int, scene_id: str, seed: int) -> list[Sample]:
    """All `cfg.samples_per_scene` samples of one scene; [] when the scene is too short."""
    if num_frames < min_scene_length(cfg):
        return []
    rng = scene_rng(seed, scene_id)
    return [sample_one(rng, cfg, num_frames, scene_id, k) for k in range(cfg.samples_per_scene)]


def frustum_overlap(
    cam_to_world_a: np.ndarray,
    intrinsics_a: np.ndarray,
    cam_to_world_b: np.ndarray,
    intrinsics_b: np.ndarray,
    depth: float,
    grid: int = 16,
) -> float:
    """Fraction of camera A's view (a grid of pixels unprojected at `depth`) that camera B sees.

    Shapes: cam_to_world (4, 4), intrinsics_norm (4,). Computed on a normalised 1x1 image (the
    intrinsics are normalised), so the result does not depend on the resolution. Symmetrise with
    min(overlap(a, b), overlap(b, a)) for a pair score.
    """
    from seeu_data.cameras import project_points, unproject_pixels

    ticks = (np.arange(grid) + 0.5) / grid
    uv = np.stack(np.meshgrid(ticks, ticks, indexing="xy"), -1).reshape(-1, 2)
    pts = unproject_pixels(
        uv, np.full(len(uv), float(depth)), np.asarray(cam_to_world_a, float), np.asarray(intrinsics_a, float), 1, 1
    )
    uv_b, z_b = project_points(pts, np.asarray(cam_to_world_b, float), np.asarray(intrinsics_b, float), 1, 1)
    seen = (z_b > 0) & (uv_b >= 0).all(-1) & (uv_b <= 1).all(-1)
    return float(seen.mean())
