"""Counts and statistics of a triples directory, and a contact sheet of sample triples.

Reports rows, shards, bytes, scenes, modes, views per example, the context gap distribution, the
target offsets (inside the pair / before / after, range), image sizes and bytes per view, and the
build report (skipped scenes, evaluation-index problems). --sheet draws N examples (evenly spaced
over the dataset): one row per example, contexts then targets, each labelled with its frame index
and offset, the row with mode, scene and gap.

Examples:
  seeu inspect data/shards/extrap
  seeu inspect data/shards/extrap --json
  seeu inspect data/shards/eval --sheet eval_sheet.png --sheet-rows 8
"""

from __future__ import annotations

import argparse
import json

from pipelines.cli.config_flags import add_config_flags, config_from_args

# Every flag but --json (how the statistics are printed) comes from a `setting` of InspectConfig.
OWN_FLAGS = ("json",)


def add_arguments(p: argparse.ArgumentParser) -> None:
    from pipelines.inspect_triples import InspectConfig

    add_config_flags(p, InspectConfig)
    p.add_argument("--json", action="store_true", help="print the statistics as JSON")


def print_text(s: dict) -> None:
    """The statistics of `triple_statistics` as lines of text."""
    print(f"{s['path']}: {s['rows']} triples, {s['shards']} shards, {s['bytes'] / 1e6:.1f} MB, {s['scenes']} scenes")
    print("modes: " + ", ".join(f"{m} {c}" for m, c in s["modes"].items()))
    print(f"views: context {s['num_context']}, target {s['num_target']}")
    g = s["gap"]
    if g["count"]:
        print(f"context gap: min {g['min']}, median {g['median']:g}, mean {g['mean']:g}, max {g['max']}")
    t = s["target_offset"]
    line = f"targets: {t['inside']} inside the pair, {t['before']} before, {t['after']} after"
    if t["outside"]["count"]:
        line += f" (offsets {t['outside']['min']}..{t['outside']['max']})"
    print(line)
    print(
        "image sizes (WxH: views): "
        + ", ".join(f"{k}: {v}" for k, v in s["image_sizes"].items())
        + f"; {s['image_bytes_per_view_mean'] / 1e3:.1f} kB per view"
    )
    rep = s["report"]
    if rep.get("scenes_skipped_too_short"):
        print(
            f"build skipped {rep['scenes_skipped_too_short']} scenes shorter than {rep.get('min_scene_frames')} frames"
        )
    if "index_entries" in rep:
        print(
            f"eval index: {rep['index_entries']} entries, {rep['index_null_skipped']} null skipped, "
            f"{rep['not_written']} not written"
        )


def run(args: argparse.Namespace) -> int:
    from pipelines.inspect_triples import InspectConfig, inspect_triples

    cfg = config_from_args(InspectConfig, args)
    stats = inspect_triples(cfg)
    if args.json:
        print(json.dumps(stats, indent=1))
    else:
        print_text(stats)
        if cfg.sheet:
            print(f"contact sheet: {cfg.sheet} ({len(stats['sheet']['samples'])} examples)")
    return 0
