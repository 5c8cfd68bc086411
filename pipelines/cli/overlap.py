"""Add the view-overlap table to a posed-frames directory made before ingest and import wrote one.

For every scene, how much of each frame's content each other frame sees (from the cameras and the
scene's near/far: docs/formats.md, "View overlap"), stored beside each posed file and listed in the
manifest. Resumable: a re-run keeps the tables already written; --force measures them again.

Example:
  seeu overlap data/posed/old_clip
"""

from __future__ import annotations

import argparse

from pipelines.cli.config_flags import add_config_flags, config_from_args
from pipelines.cli.options import add_force, add_fsync, add_progress, shared_values

SHARED_FLAGS = {"force": "force", "fsync": "fsync", "progress": "progress"}


def add_arguments(p: argparse.ArgumentParser) -> None:
    from pipelines.overlap import OverlapConfig

    add_config_flags(p, OverlapConfig)
    add_force(p, " (measure every table again)")
    add_fsync(p)
    add_progress(p)


def run(args: argparse.Namespace) -> int:
    from pipelines.overlap import OverlapConfig, add_overlap

    cfg = config_from_args(OverlapConfig, args, **shared_values(args, SHARED_FLAGS))
    s = add_overlap(cfg)
    if s["already"]:
        print(f"{cfg.path} already has its overlap tables ({s['scenes']} scenes; --force measures them again)")
    else:
        kept = f", {s['resumed']} kept from an interrupted run" if s["resumed"] else ""
        print(f"added overlap tables to {cfg.path}: {s['computed']} scenes measured{kept}, {s['files']} files")
    return 0
