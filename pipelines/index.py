"""Evaluation indices for your own posed data (`seeu index`), in the peers' JSON formats.

pixelsplat: {scene: {"context": [l, r], "target": [t1, t2, t3]} | null} (one entry per scene);
latentsplat: {scene: [entry, ...]}. The entries are drawn by `seeu_data.build.eval_index.generate_entries`
(seeded; context pairs redrawn until their frustum overlap is in the window) and read back by
`seeu build --mode eval --index FILE`.

Example:
    from pathlib import Path
    from pipelines.index import IndexFileConfig, write_index
    from seeu_data.build.eval_index import IndexConfig
    from seeu_data.build.sampling import SamplingConfig

    cfg = IndexFileConfig(inputs=("data/posed/clip",), out=Path("data/clip_eval.json"),
                          generation=IndexConfig(SamplingConfig(gap_min=30, gap_max=60), min_overlap=0.3))
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
        g = self.generation
        if not 0.0 <= g.min_overlap <= g.max_overlap <= 1.0:
            raise SeeUError("need 0 <= --min-overlap <= --max-overlap <= 1")
        if g.overlap_depth is not None and not g.overlap_depth > 0:
            raise SeeUError(f"--overlap-depth must be > 0, got {g.overlap_depth}")


def write_index(cfg: IndexFileConfig) -> dict:
    """Draw the entries of every scene of `cfg.inputs` and write `cfg.out` (atomically); returns counts.

    The inputs are checked first (`build.scan_inputs`: `dataset_check.check_dataset`). When no scene
    yields an entry, SeeUError naming the scenes and why (too short for the gap, no pair in the
    overlap window), and nothing is written."""
    import numpy as np

    from pipelines.build import scan_inputs
    from seeu_data.build.eval_index import generate_entries, index_document, no_entry_reason
    from seeu_data.store.arrow_io import atomic_write_text, open_ipc_file

    cfg.check()
    generation = cfg.generation
    if cfg.format == "pixelsplat":
        generation = dataclasses.replace(
            generation, sampling=dataclasses.replace(generation.sampling, samples_per_scene=1)
        )
    scenes = scan_inputs([str(p) for p in cfg.inputs], max_pixels=cfg.max_pixels)
    in_file: dict[str, list[str]] = {}
    for sid in sorted(scenes):
        in_file.setdefault(scenes[sid].path, []).append(sid)
    drawn = {}
    for path, sids in in_file.items():  # one posed file's camera columns mapped at a time
        table = (
            open_ipc_file(path, random_access=True)
            .read_all()
            .select(["cam_to_world", "intrinsics_norm", "near", "far"])
        )
        for sid in sids:
            rows = table.slice(scenes[sid].row_start, scenes[sid].num_frames)
            c2w = rows.column("cam_to_world").combine_chunks().flatten().to_numpy().reshape(-1, 4, 4)
            intr = rows.column("intrinsics_norm").combine_chunks().flatten().to_numpy().reshape(-1, 4)
            near, far = float(rows.column("near")[0].as_py()), float(rows.column("far")[0].as_py())
            drawn[sid] = generate_entries(generation, sid, np.asarray(c2w), np.asarray(intr), near, far, cfg.seed)
        del table
    per_scene = {sid: drawn[sid] for sid in sorted(scenes)}
    empty = [sid for sid, entries in per_scene.items() if not entries]
    if len(empty) == len(per_scene):  # nothing written: the index would be useless
        reasons = "; ".join(no_entry_reason(generation, sid, scenes[sid].num_frames) for sid in empty[:3])
        more = f" (and {len(empty) - 3} more scenes)" if len(empty) > 3 else ""
        raise SeeUError(f"no scene yields an index entry: {reasons}{more}", cfg.inputs[0])
    doc = index_document(per_scene, cfg.format)
    atomic_write_text(cfg.out, json.dumps(doc) + "\n")
    used = sum(1 for v in per_scene.values() if v)
    return {
        "scenes": len(doc),
        "scenes_with_entries": used,
        "entries": sum(len(v) for v in per_scene.values() if v) if cfg.format == "latentsplat" else used,
    }
