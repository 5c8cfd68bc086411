"""Pose a video, an image folder, or a folder of videos with COLMAP SfM and write posed chunks.

Stages (each kept under OUT/.work/<scene>/ with a stamp of its inputs and parameters, so re-running
the same command resumes; --force redoes them): decode (--stride, --max-size) -> select frames
(--sharpness-window, --target-frames; every frame keeps its source frame number) -> SfM in a child
process (SIFT, one shared camera of --camera-model, sequential matching with --overlap, loop
detection only with --vocab-tree, a video mapped on keyframes (--keyframe-motion) and its other
frames registered after, --mapper incremental/global/auto, mapping twice from different
seeds for the solution check, a last bundle adjustment with a robust loss (--final-ba-loss),
undistortion to a pinhole camera of the same size when the model has distortion; the same poses
whatever --threads; --size HxW crops/resizes afterwards)
-> posed chunks (contiguous registered runs per model, >= --min-chunk-frames; scale by --scale:
re10k, median-depth or metric, seeu_data/ingest/scale.py) -> OUT/<scene>/ posed-frames dataset
(scenes <scene>_c0, _c1, ...) with report.json and trajectory.png, manifest.json written last.
<scene> is the input's name or --name; OUT/<scene> holding another input's scene is an error
unless --force. Warnings (failed solution check, low parallax) end the summary line.

Example:
  seeu ingest clip.mp4 --out data/posed --target-frames 120
  seeu ingest videos/ photos/ --out data/posed --workers 2 --camera-model OPENCV
  seeu ingest trip2/images --out data/posed --name trip2
  seeu ingest walk.mp4 --out data/posed --scale metric --known-distance 4.2     # first-to-last camera: 4.2 m
  seeu ingest videos/ --out /shared/posed --engine ray --ray-address auto --threads 2   # one scene per Ray task
  seeu validate data/posed/clip
"""

from __future__ import annotations

import argparse
import sys

from pipelines.cli.config_flags import add_config_flags, config_from_args
from pipelines.cli.options import add_force, add_fsync, add_max_pixels, add_out, add_progress, shared_values

# The shared flags (pipelines/cli/options.py) and the IngestConfig fields they set; every other flag
# comes from a `setting` of IngestConfig or its nested configs.
SHARED_FLAGS = {
    "out": "out",
    "force": "run.force",
    "progress": "run.progress",
    "fsync": "run.fsync",
    "max_pixels": "run.max_pixels",
}


def add_arguments(p: argparse.ArgumentParser) -> None:
    from pipelines.ingest import IngestConfig

    add_config_flags(p, IngestConfig)
    add_out(p, "output directory; one dataset per scene: OUT/<scene>/")
    add_force(p, also=", and replace OUT/<scene> even when it holds another input's scene")
    add_progress(p)
    add_fsync(p)
    add_max_pixels(p)


def run(args: argparse.Namespace) -> int:
    from pipelines.ingest import IngestConfig, SceneResult, ingest

    cfg = config_from_args(IngestConfig, args, **shared_values(args, SHARED_FLAGS))

    def show(result: SceneResult) -> None:
        if result.error is not None:
            print(f"seeu ingest: error: {result.error}", file=sys.stderr)
        elif result.report is not None:
            print(result.report["summary"])

    results = ingest(cfg, on_result=show)
    failures = sum(r.error is not None for r in results)
    if len(results) > 1 or cfg.run.engine == "ray":
        print(f"{len(results) - failures}/{len(results)} scenes ingested into {args.out}")
    return 2 if failures else 0
