"""Evaluation indices: read the peers' three formats as they are, and generate one for own data.

Formats (frame indices are posed `frame_index` values, contexts and targets in the listed order):

* ``pixelsplat`` (pixelSplat, MVSplat, DepthSplat, HiSplat, TranSplat ``evaluation_index_*.json``):
  ``{scene: {"context": [l, r], "target": [t1, t2, t3]} | null}``; null entries are skipped and counted.
* ``latentsplat`` (latentSplat ``re10k_extra.json``): ``{scene: [entry, entry, ...]}``, a list per scene
  of such entries (null items skipped).
* ``dl3dv`` (DepthSplat ``assets/dl3dv_*.json``, 2/4/6/12 context views): the pixelsplat layout keyed by
  DL3DV scene hashes (64 hex digits); the scene is ``dl3dv_<hash>`` (the DL3DV importer's scene key).
* NoPoSplat's indices are the pixelsplat layout with an ``"overlap"`` per entry (the context pair's
  overlap, or a bin name ``small`` / ``medium`` / ``large``), kept as `IndexEntry.overlap`; `seeu index`
  writes it too.
* ``dtu`` (MVSplat DTU protocol, ``evaluation_index_dtu_nctx2.json``): keys ``scanN_train_0K`` whose
  scene is ``scanN`` (the DTU importer's scene id) and whose view ids are frame indices.

`read_index` returns the entries in file order; `entry.k` numbers a scene's entries 0, 1, ... in that
order (the sample id of the written row is ``{scene}/eval/{k}``).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from seeu_data.build.sampling import (
    Sample,
    SamplingConfig,
    max_gap,
    min_scene_length,
    pair_rule,
    sample_one,
    sample_overlap_scene,
    scene_rng,
)
from seeu_data.errors import SeeUError
from seeu_data.overlap import BINS, OverlapTable, context_overlap
from seeu_data.settings import parse_names, setting
from seeu_data.store.json_file import read_json

FORMATS = ("pixelsplat", "latentsplat", "dtu", "dl3dv")
_DTU_KEY = re.compile(r"^(scan\d+)_train_(\d+)$")
_DL3DV_KEY = re.compile(r"^[0-9a-f]{64}$")
DL3DV_SCENE_PREFIX = "dl3dv_"  # as seeu_data.importers.dl3dv.SCENE_PREFIX


@dataclass(frozen=True)
class IndexEntry:
    """One evaluation example as the index lists it."""

    key: str  # the index key (scene id, or e.g. 'scan1_train_00')
    scene_id: str
    k: int  # ordinal of the entry among its scene's entries, in file order
    context: tuple[int, ...]
    target: tuple[int, ...]
    overlap: float | str | None = None  # the entry's "overlap" (NoPoSplat: a value or a bin name), if any


@dataclass
class EvalIndex:
    path: str
    format: str
    entries: list[IndexEntry]
    num_keys: int
    num_null: int


def detect_format(doc: dict) -> str:
    """Guess the format of a parsed index (see the module docstring)."""
    values = [v for v in doc.values() if v is not None]
    if values and all(isinstance(v, list) for v in values):
        return "latentsplat"
    if doc and all(_DTU_KEY.match(k) for k in doc):
        return "dtu"
    if doc and all(_DL3DV_KEY.match(k) for k in doc):
        return "dl3dv"
    return "pixelsplat"


def _entry(raw, key: str, where: Path) -> tuple[tuple[int, ...], tuple[int, ...]]:
    if not isinstance(raw, dict) or "context" not in raw or "target" not in raw:
        raise SeeUError(f"entry {key!r} is not {{'context': [...], 'target': [...]}}", where)
    try:
        ctx = tuple(int(x) for x in raw["context"])
        tgt = tuple(int(x) for x in raw["target"])
    except (TypeError, ValueError):
        raise SeeUError(f"entry {key!r} holds non-integer frame indices", where) from None
    if not ctx or not tgt:
        raise SeeUError(f"entry {key!r} has no context or no target frames", where)
    return ctx, tgt


def read_index(path: str | Path, fmt: str = "auto") -> EvalIndex:
    """Parse an evaluation index file in one of FORMATS (or 'auto')."""
    path = Path(path)
    if not path.exists():
        raise SeeUError("evaluation index not found", path)
    doc = read_json(path, "evaluation index")
    if not isinstance(doc, dict):
        raise SeeUError("evaluation index must be a JSON object {scene: entry}", path)
    if fmt == "auto":
        fmt = detect_format(doc)
    if fmt not in FORMATS:
        raise SeeUError(f"unknown index format {fmt!r} (known: {', '.join(FORMATS)})", path)
    entries: list[IndexEntry] = []
    per_scene: dict[str, int] = {}
    nulls = 0
    for key, value in doc.items():
        items = value if fmt == "latentsplat" else [value]
        if fmt == "latentsplat" and value is not None and not isinstance(value, list):
            raise SeeUError(f"entry {key!r}: the latentSplat format holds a list per scene", path)
        if value is None:
            nulls += 1
            continue
        scene = key
        if fmt == "dtu":
            m = _DTU_KEY.match(key)
            if not m:
                raise SeeUError(f"DTU index key {key!r} is not 'scanN_train_K'", path)
            scene = m.group(1)
        elif fmt == "dl3dv":
            if not _DL3DV_KEY.match(key):
                raise SeeUError(f"DL3DV index key {key!r:.80} is not a scene hash (64 hex digits)", path)
            scene = DL3DV_SCENE_PREFIX + key
        for j, raw in enumerate(items):
            if raw is None:
                nulls += 1
                continue
            ctx, tgt = _entry(raw, key if fmt != "latentsplat" else f"{key}[{j}]", path)
            k = per_scene.get(scene, 0)
            per_scene[scene] = k + 1
            overlap = raw.get("overlap")
            entries.append(
                IndexEntry(key, scene, k, ctx, tgt, overlap if isinstance(overlap, (int, float, str)) else None)
            )
    return EvalIndex(str(path), fmt, entries, len(doc), nulls)


# ---------------------------------------------------------------------------------------------
# Generation for own data (`seeu index`)
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class IndexConfig:
    """What `seeu index` draws per scene: a SamplingConfig (its context pairs by frame gap or by view
    overlap, `sampling.pair_rule`), or with `bins` contexts by overlap bin."""

    sampling: SamplingConfig
    bins: tuple[str, ...] | None = setting(
        None,
        "draw the context pairs by overlap bin, the entries spread evenly over them: small (0.05-0.3), "
        "medium (0.3-0.55), large (0.55-0.8), NoPoSplat's (default: by --pairs)",
        parse=parse_names,
        metavar="BIN,...",
    )


def _index_entry(sample: Sample, m: np.ndarray) -> dict:
    return {
        "context": list(sample.context),
        "target": list(sample.target),
        "overlap": round(context_overlap(m, sample.context), 4),
    }


def generate_entries(
    cfg: IndexConfig,
    scene_id: str,
    table: OverlapTable,
    cam_to_world: np.ndarray,
    intrinsics_norm: np.ndarray,
    seed: int,
    ordinal: int = 0,
) -> list[dict] | None:
    """Up to `samples_per_scene` entries {"context", "target", "overlap"} for one scene, or None (scene
    unusable). "overlap" is the contexts' overlap (`overlap.context_overlap`; NoPoSplat's index field).

    Shapes: cam_to_world (N, 4, 4), intrinsics_norm (N, 4); `table` the scene's overlap. With `bins`,
    entry k of the scene of `ordinal` (its position among the scenes) is drawn in bin
    (ordinal + k) mod len(bins), else in the next bin that has a pair.
    """
    s = cfg.sampling
    n = len(cam_to_world)
    m = table.matrix()
    # streams of their own: an index drawn with the same seed and options as a training build does
    # not repeat that build's samples
    stream = f"seeu-index/{scene_id}"
    if cfg.bins:
        out = []
        for k in range(s.samples_per_scene):
            for j in range(len(cfg.bins)):
                lo, hi = BINS[cfg.bins[(ordinal + k + j) % len(cfg.bins)]]
                one = replace(s, pairs="overlap", min_overlap=lo, max_overlap=hi, samples_per_scene=1)
                got = sample_overlap_scene(one, table, cam_to_world, intrinsics_norm, scene_id, seed, f"{stream}/{k}")
                if got:
                    out.append(_index_entry(replace(got[0], k=k), m))
                    break
        return out or None
    if pair_rule(s, n, cam_to_world) == "overlap":
        samples = sample_overlap_scene(s, table, cam_to_world, intrinsics_norm, scene_id, seed, stream)
    else:
        if n < min_scene_length(s) or max_gap(s, n) < s.gap_min:
            return None
        rng = scene_rng(seed, stream)
        samples = [sample_one(rng, s, n, scene_id, k) for k in range(s.samples_per_scene)]
    return [_index_entry(x, m) for x in samples] or None


def no_entry_reason(cfg: IndexConfig, scene_id: str, num_frames: int, rule: str) -> str:
    """Why `generate_entries` gave a scene of `num_frames` frames no entry, in words (`rule`: its pair rule)."""
    s = cfg.sampling
    if cfg.bins:
        return f"scene {scene_id!r}: no context pair in the overlap bins {', '.join(cfg.bins)}"
    if rule == "overlap":
        return f"scene {scene_id!r}: no context pair with overlap in [{s.min_overlap:g}, {s.max_overlap:g}] and targets"
    outside = " and one frame outside the pair" if s.wants_outside else ""
    return f"scene {scene_id!r} has {num_frames} frames, a gap of {s.gap_min}{outside} needs {min_scene_length(s)}"


def index_document(per_scene: dict[str, list[dict] | None], fmt: str) -> dict:
    """Assemble the JSON document: pixelsplat keeps the first entry per scene (null if none)."""
    if fmt == "latentsplat":
        return {sid: entries for sid, entries in per_scene.items()}
    if fmt == "pixelsplat":
        return {sid: (entries[0] if entries else None) for sid, entries in per_scene.items()}
    raise SeeUError(f"cannot write index format {fmt!r} (use pixelsplat or latentsplat)")
