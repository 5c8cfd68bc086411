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
    print(
        f"wrote {args.out}: {s['scenes']} scenes, {s['scenes_with_entries']} with entries "
        f"({s['entries']} entries), {s['scenes'] - s['scenes_with_entries']} null"
    )
    return 0
