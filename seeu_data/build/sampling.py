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

Context pairs (`pairs`): ``gap`` is the frame-gap sampler above (the peers' protocol for video);
``overlap`` chooses them by the scene's view overlap (`seeu_data.overlap`), for scenes whose frame
numbers mean nothing (photo sets) or are too few for the gaps:

* the pair (a, b) is drawn uniformly among the pairs whose score min(o[a, b], o[b, a]) lies in
  [min_overlap, max_overlap] and that have the targets the mode needs;
* an interpolation target t (not a context) is seen by both contexts at least as well as they see
  each other: min(o[t, a], o[t, b]) >= score(a, b);
* an extrapolation target is any other frame that still shares at least `min_overlap` with one
  context: max(o[t, a], o[t, b]) >= min_overlap (partly outside both, never out of sight);
* V > 2: the other contexts are drawn without replacement among the interpolation targets, and the
  targets among the rest; targets with replacement, as in ``gap``. `extrap_frames` is not used.

The draws run over the frames in `overlap.canonical_order` (sorted by their cameras), so shuffling or
renaming a scene's frames changes no drawn view (up to naming). ``auto`` takes ``gap`` for a scene
whose frame order is a camera path (`overlap.frame_order_is_path`) with frames enough for the gaps,
else ``overlap`` (`pair_rule`).

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
from seeu_data.overlap import OverlapTable, canonical_order, frame_order_is_path
from seeu_data.settings import setting

MODES = ("interp", "extrap")
PAIRS = ("auto", "gap", "overlap")


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
    pairs: str = setting(
        "auto",
        "context pairs by frame gap (the peers' protocol for video), by view overlap, or auto: gap where the "
        "frame order is a camera path with frames enough for the gaps, else overlap",
        choices=PAIRS,
    )
    min_overlap: float = setting(0.3, "overlap pairs: smallest context-pair overlap; a target shares at least this")
    max_overlap: float = setting(0.8, "overlap pairs: largest context-pair overlap")

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
        if self.pairs not in PAIRS:
            raise ValueError(f"pairs must be one of {PAIRS}, got {self.pairs!r}")
        if not 0.0 <= self.min_overlap <= self.max_overlap <= 1.0:
            raise ValueError("need 0 <= min_overlap <= max_overlap <= 1")

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


# ---------------------------------------------------------------------------------------------
# Context pairs by view overlap
# ---------------------------------------------------------------------------------------------


def pair_rule(cfg: SamplingConfig, num_frames: int, cam_to_world: np.ndarray | None) -> str:
    """'gap' or 'overlap' for one scene (see the module docstring); `cam_to_world` (N, 4, 4) is only
    read for ``auto``."""
    if cfg.pairs != "auto":
        return cfg.pairs
    if num_frames < min_scene_length(cfg) or max_gap(cfg, num_frames) < cfg.gap_min:
        return "overlap"
    return "gap" if cam_to_world is not None and frame_order_is_path(cam_to_world) else "overlap"


@dataclass(frozen=True)
class _PairViews:
    """A usable context pair (a, b) in canonical positions, with its interpolation and extrapolation
    targets (canonical positions, ascending)."""

    a: int
    b: int
    interp: np.ndarray
    extrap: np.ndarray


def usable_pairs(cfg: SamplingConfig, m: np.ndarray) -> list[_PairViews]:
    """The context pairs of a directed overlap matrix `m` (N, N) (canonical order) that the overlap
    rule may draw, in (a, b) order."""
    n = len(m)
    score = np.minimum(m, m.T)
    wants_interp = cfg.mode == "interp" or cfg.interp_ratio > 0 or not cfg.wants_outside
    out = []
    for a, b in zip(*np.nonzero(np.triu((score >= cfg.min_overlap) & (score <= cfg.max_overlap), 1))):
        others = np.ones(n, bool)
        others[[a, b]] = False
        inside = others & (np.minimum(m[:, a], m[:, b]) >= score[a, b])
        outside = others & ~inside & (np.maximum(m[:, a], m[:, b]) >= cfg.min_overlap)
        need_inside = cfg.num_context - 2 + (1 if wants_interp else 0)
        if inside.sum() < need_inside or (cfg.wants_outside and not outside.any()):
            continue
        out.append(_PairViews(int(a), int(b), np.flatnonzero(inside), np.flatnonzero(outside)))
    return out


def sample_overlap_scene(
    cfg: SamplingConfig,
    table: OverlapTable,
    cam_to_world: np.ndarray,
    intrinsics_norm: np.ndarray,
    scene_id: str,
    seed: int,
    stream: str | None = None,
) -> list[Sample]:
    """All `cfg.samples_per_scene` samples of one scene by the overlap rule; [] when no pair is usable.
    Shapes: cam_to_world (N, 4, 4), intrinsics_norm (N, 4) (they fix the canonical order). `stream`:
    the random stream's name (default the scene id, as `sample_scene`)."""
    order = canonical_order(cam_to_world, intrinsics_norm)
    m = table.matrix()[np.ix_(order, order)]
    pairs = usable_pairs(cfg, m)
    if not pairs:
        return []
    rng = scene_rng(seed, stream or scene_id)
    out = []
    for k in range(cfg.samples_per_scene):
        p = pairs[int(rng.integers(0, len(pairs)))]
        extra = rng.choice(p.interp, cfg.num_context - 2, replace=False) if cfg.num_context > 2 else np.zeros(0, int)
        inside = np.setdiff1d(p.interp, extra)
        targets = []
        for _ in range(cfg.num_target):
            pool = inside if not cfg.wants_outside or rng.random() < cfg.interp_ratio else p.extrap
            targets.append(int(pool[rng.integers(0, len(pool))]))
        context = sorted(int(order[c]) for c in (p.a, p.b, *extra))
        out.append(make_sample(scene_id, cfg.mode, k, context, sorted(int(order[t]) for t in targets)))
    return out
