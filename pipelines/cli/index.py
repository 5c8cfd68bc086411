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

from pipelines.cli.build import add_sampling_arguments, sampling_config
from pipelines.cli.options import add_max_pixels, add_out, max_pixels


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("inputs", nargs="+", help="posed-frames directories")
    add_out(p, "index JSON file to write")
    p.add_argument("--format", choices=["pixelsplat", "latentsplat"], default="pixelsplat")
    p.add_argument("--mode", choices=["interp", "extrap"], default="interp", help="where targets lie")
    add_sampling_arguments(p)
    add_max_pixels(p)
    g = p.add_argument_group("context overlap")
    g.add_argument("--min-overlap", type=float, default=0.0, help="smallest allowed context view overlap (0..1)")
    g.add_argument("--max-overlap", type=float, default=1.0, help="largest allowed context view overlap (0..1)")
    g.add_argument(
        "--overlap-depth", type=float, default=None, help="depth of the overlap test (default sqrt(near*far))"
    )


def run(args: argparse.Namespace) -> int:
    from pipelines.index import IndexFileConfig, write_index
    from seeu_data.build.eval_index import IndexConfig

    cfg = IndexFileConfig(
        inputs=tuple(args.inputs),
        out=args.out,
        format=args.format,
        generation=IndexConfig(
            sampling_config(args, args.mode), args.min_overlap, args.max_overlap, args.overlap_depth
        ),
        seed=args.seed,
        max_pixels=max_pixels(args),
    )
    s = write_index(cfg)
    print(
        f"wrote {args.out}: {s['scenes']} scenes, {s['scenes_with_entries']} with entries "
        f"({s['entries']} entries), {s['scenes'] - s['scenes_with_entries']} null"
    )
    return 0
