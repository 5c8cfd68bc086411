"""Generate an evaluation index for your own posed data (seeded), in the peers' formats.

pixelsplat: {scene: {"context": [l, r], "target": [t1, t2, t3]} | null}  (one entry per scene)
latentsplat: {scene: [entry, ...]}  (--samples-per-scene entries per scene)
Scenes too short for the gaps get null. With --min-overlap / --max-overlap the context pair is
redrawn until the two views' frustum overlap (a pixel grid unprojected at --overlap-depth, default
sqrt(near * far), seen by the other camera; the smaller of both directions) falls in the window.
The index is read back by `seeu build --mode eval --index FILE`.

Examples:
  seeu index data/posed/clip --out data/clip_eval.json --gap-min 30 --gap-max 60 --seed 0
  seeu index data/posed/clip --out data/clip_extra.json --format latentsplat --mode extrap \\
      --extrap-frames 45 --samples-per-scene 3 --min-overlap 0.3 --max-overlap 0.9
"""

from __future__ import annotations

import argparse
import json

from seeu_data.errors import SeeUError


def add_arguments(p: argparse.ArgumentParser) -> None:
    from pipelines.build import add_sampling_arguments

    p.add_argument("inputs", nargs="+", help="posed-frames directories")
    p.add_argument("--out", required=True, help="index JSON file to write")
    p.add_argument("--format", choices=["pixelsplat", "latentsplat"], default="pixelsplat")
    p.add_argument("--mode", choices=["interp", "extrap"], default="interp", help="where targets lie")
    add_sampling_arguments(p)
    g = p.add_argument_group("context overlap")
    g.add_argument("--min-overlap", type=float, default=0.0, help="smallest allowed context view overlap (0..1)")
    g.add_argument("--max-overlap", type=float, default=1.0, help="largest allowed context view overlap (0..1)")
    g.add_argument(
        "--overlap-depth", type=float, default=None, help="depth of the overlap test (default sqrt(near*far))"
    )


def run(args: argparse.Namespace) -> int:
    import dataclasses

    import numpy as np

    from pipelines.build import sampling_config
    from seeu_data.arrow_io import atomic_write_text, open_ipc_file
    from seeu_data.build import scan_inputs
    from seeu_data.eval_index import IndexConfig, generate_entries, index_document

    if not 0.0 <= args.min_overlap <= args.max_overlap <= 1.0:
        raise SeeUError("need 0 <= --min-overlap <= --max-overlap <= 1")
    sampling = sampling_config(args, args.mode)
    if args.format == "pixelsplat":
        sampling = dataclasses.replace(sampling, samples_per_scene=1)
    cfg = IndexConfig(sampling, args.min_overlap, args.max_overlap, args.overlap_depth)
    scenes = scan_inputs(args.inputs)
    tables: dict = {}
    per_scene = {}
    for sid in sorted(scenes):
        src = scenes[sid]
        if src.path not in tables:
            tables[src.path] = (
                open_ipc_file(src.path).read_all().select(["cam_to_world", "intrinsics_norm", "near", "far"])
            )
        rows = tables[src.path].slice(src.row_start, src.num_frames)
        c2w = rows.column("cam_to_world").combine_chunks().flatten().to_numpy().reshape(-1, 4, 4)
        intr = rows.column("intrinsics_norm").combine_chunks().flatten().to_numpy().reshape(-1, 4)
        near, far = float(rows.column("near")[0].as_py()), float(rows.column("far")[0].as_py())
        per_scene[sid] = generate_entries(cfg, sid, np.asarray(c2w), np.asarray(intr), near, far, args.seed)
    doc = index_document(per_scene, args.format)
    atomic_write_text(args.out, json.dumps(doc) + "\n")
    used = sum(1 for v in per_scene.values() if v)
    entries = sum(len(v) for v in per_scene.values() if v)
    print(
        f"wrote {args.out}: {len(doc)} scenes, {used} with entries "
        f"({entries if args.format == 'latentsplat' else used} entries), {len(doc) - used} null"
    )
    return 0
