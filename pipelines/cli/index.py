"""Generate an evaluation index for your own posed data (seeded), in the peers' formats.

pixelsplat: {scene: {"context": [l, r], "target": [t1, t2, t3], "overlap": o} | null}  (one entry per scene)
latentsplat: {scene: [entry, ...]}  (--samples-per-scene entries per scene)
Context pairs as `seeu build` chooses them (--pairs: by frame gap on camera paths, by view overlap in
[--min-overlap, --max-overlap] elsewhere), or with --bins by NoPoSplat's overlap bins (small
0.05-0.3, medium 0.3-0.55, large 0.55-0.8), the entries spread evenly over the bins named. Every
entry records its contexts' overlap ("overlap", from the posed data's overlap table), so
`seeu eval` reports metrics per bin. Scenes without a usable pair get null. The index is read back by
`seeu build --mode eval --index FILE`.

Examples:
  seeu index data/posed/clip --out data/clip_eval.json --gap-min 30 --gap-max 60 --seed 0
  seeu index data/posed/photos --out data/photos_eval.json --bins small,medium,large
  seeu index data/posed/clip --out data/clip_extra.json --format latentsplat --mode extrap \\
      --extrap-frames 45 --samples-per-scene 3
"""

from __future__ import annotations

import argparse

from pipelines.cli.build import config_with_sampling
from pipelines.cli.config_flags import add_config_flags
from pipelines.cli.options import add_max_pixels, add_out, shared_values

# The shared flags (pipelines/cli/options.py) and the IndexFileConfig fields they set; every other flag
# comes from a `setting` of IndexFileConfig or its nested configs (IndexConfig, SamplingConfig).
SHARED_FLAGS = {"out": "out", "max_pixels": "max_pixels"}


def add_arguments(p: argparse.ArgumentParser) -> None:
    from pipelines.index import IndexFileConfig

    add_config_flags(p, IndexFileConfig)
    add_out(p, "index JSON file to write")
    add_max_pixels(p)


def run(args: argparse.Namespace) -> int:
    from pipelines.index import IndexFileConfig, write_index

    cfg = config_with_sampling(IndexFileConfig, args, **shared_values(args, SHARED_FLAGS))
    s = write_index(cfg)
    bins = ", ".join(f"{n} {k}" for k, n in s["bins"].items())
    print(
        f"wrote {args.out}: {s['scenes']} scenes, {s['scenes_with_entries']} with entries "
        f"({s['entries']} entries; overlap: {bins}), {s['scenes'] - s['scenes_with_entries']} null"
    )
    return 0
