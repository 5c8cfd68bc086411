"""Evaluation indices for your own posed data (`seeu index`), in the peers' JSON formats.

pixelsplat: {scene: {"context": [l, r], "target": [t1, t2, t3]} | null} (one entry per scene);
latentsplat: {scene: [entry, ...]}. The entries are drawn by `seeu_data.build.eval_index.generate_entries`
(seeded; context pairs by frame gap or by view overlap as `seeu build` chooses them, or by overlap
bin with `bins`), each with its contexts' "overlap" (NoPoSplat's field), and read back by
`seeu build --mode eval --index FILE`.

Example:
    from pathlib import Path
    from pipelines.index import IndexFileConfig, write_index
    from seeu_data.build.eval_index import IndexConfig
    from seeu_data.build.sampling import SamplingConfig

    cfg = IndexFileConfig(inputs=("data/posed/clip",), out=Path("data/clip_eval.json"),
                          generation=IndexConfig(SamplingConfig(gap_min=30, gap_max=60), bins=("small", "large")))
    summary = write_index(cfg)      # {"scenes": ..., "scenes_with_entries": ..., "entries": ...}
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path

from seeu_data.build.eval_index import IndexConfig
from seeu_data.errors import SeeUError
from seeu_data.limits import MAX_PIXELS
from seeu_data.overlap import BINS
from seeu_data.settings import setting

FORMATS = ("pixelsplat", "latentsplat")


@dataclass(frozen=True, kw_only=True)
class IndexFileConfig:
    """inputs: posed-frames directories; out: the JSON file; format: pixelsplat (one entry per scene)
    or latentsplat (`generation.sampling.samples_per_scene` per scene); seed: the draw's seed."""

    inputs: tuple[str | Path, ...] = setting(help="posed-frames directories", positional=True, many=True)
    out: Path
    generation: IndexConfig
    format: str = setting(
        "pixelsplat", "pixelsplat: one entry per scene; latentsplat: a list per scene", choices=FORMATS
    )
    seed: int = setting(0, "random seed")
    max_pixels: int = MAX_PIXELS  # largest input image, `--max-pixels` (the inputs are checked)

    def check(self) -> None:
        if self.format not in FORMATS:
            raise SeeUError(f"--format must be one of {', '.join(FORMATS)}, got {self.format!r}")
        unknown = [b for b in self.generation.bins or () if b not in BINS]
        if unknown:
            raise SeeUError(f"--bins: unknown bin {unknown[0]!r} (known: {', '.join(BINS)})")


def write_index(cfg: IndexFileConfig) -> dict:
    """Draw the entries of every scene of `cfg.inputs` and write `cfg.out` (atomically); returns counts
    (scenes, scenes_with_entries, entries, and entries per overlap bin).

    The inputs are checked first (`build.scan_inputs`: `dataset_check.check_dataset`). Each scene's
    overlap is its stored table (measured from the cameras when the data has none). When no scene
    yields an entry, SeeUError naming the scenes and why (too short for the gap, no pair in the
    overlap range or bins), and nothing is written."""
    from pipelines.build import InputScenes, scan_inputs
    from seeu_data.build.eval_index import generate_entries, index_document, no_entry_reason
    from seeu_data.build.sampling import pair_rule
    from seeu_data.overlap import overlap_bin
    from seeu_data.store.arrow_io import atomic_write_text

    cfg.check()
    generation = cfg.generation
    if cfg.format == "pixelsplat":
        generation = dataclasses.replace(
            generation, sampling=dataclasses.replace(generation.sampling, samples_per_scene=1)
        )
    scenes = scan_inputs([str(p) for p in cfg.inputs], max_pixels=cfg.max_pixels)
    views = InputScenes([str(p) for p in cfg.inputs])
    per_scene = {}
    for ordinal, sid in enumerate(sorted(scenes)):
        c2w, intr, _, _ = views.cameras(sid)
        per_scene[sid] = generate_entries(generation, sid, views.overlap(sid), c2w, intr, cfg.seed, ordinal)
    empty = [sid for sid, entries in per_scene.items() if not entries]
    if len(empty) == len(per_scene):  # nothing written: the index would be useless
        reasons = "; ".join(
            no_entry_reason(
                generation,
                sid,
                scenes[sid].num_frames,
                pair_rule(generation.sampling, scenes[sid].num_frames, views.cameras(sid)[0]),
            )
            for sid in empty[:3]
        )
        more = f" (and {len(empty) - 3} more scenes)" if len(empty) > 3 else ""
        raise SeeUError(f"no scene yields an index entry: {reasons}{more}", cfg.inputs[0])
    doc = index_document(per_scene, cfg.format)
    atomic_write_text(cfg.out, json.dumps(doc) + "\n")
    written = [e for v in doc.values() if v for e in (v if cfg.format == "latentsplat" else [v])]
    bins: dict[str, int] = {}
    for e in written:
        name = overlap_bin(e["overlap"]) or "outside the bins"
        bins[name] = bins.get(name, 0) + 1
    return {
        "scenes": len(doc),
        "scenes_with_entries": sum(1 for v in per_scene.values() if v),
        "entries": len(written),
        "bins": bins,
    }
