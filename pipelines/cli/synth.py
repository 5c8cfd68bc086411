"""Render the built-in synthetic clip: a seeded textured corridor with boxes (occlusions, depths from
about 1 to 16 m) seen along a walk-through that translates and turns, ray-cast in numpy.

Writes OUT/clip.mp4 (mp4v) and OUT/clip.json, the exact ground truth per frame: frame number,
timestamp_us, cam_to_world (OpenCV 4x4), intrinsics_norm (fx/W, fy/H, cx/W, cy/H); plus W, H,
fps, path_length and the generator config; with --movers (independently moving boxes) also
OUT/clip.masks.npz, their exact per-frame masks. `seeu ingest OUT/clip.mp4` finds clip.json and adds
pose accuracy against it to its report.

Example:
  seeu synth --out data/synth --frames 90 --size 360x640 --seed 0
  seeu synth --out data/wall --frames 30 --size 180x320 --scene planar
  seeu synth --out data/pan --frames 20 --size 180x320 --scene pan
  seeu synth --out data/box --movers box
"""

from __future__ import annotations

import argparse

from pipelines.cli.config_flags import add_config_flags, config_from_args
from pipelines.cli.options import add_out, add_progress, progress_wanted

# Every flag but these comes from a `setting` of ClipConfig; these say where the clip goes.
OWN_FLAGS = ("out", "name", "progress")


def add_arguments(p: argparse.ArgumentParser) -> None:
    from seeu_data.synthetic import ClipConfig

    add_out(p, "output directory (clip.mp4 + clip.json)")
    add_config_flags(p, ClipConfig)
    p.add_argument("--name", default="clip", help="file stem (default clip)")
    add_progress(p)


def run(args: argparse.Namespace) -> int:
    from seeu_data.synthetic import ClipConfig, write_clip

    cfg = config_from_args(ClipConfig, args)
    video = args.out / f"{args.name}.mp4"
    doc = write_clip(video, cfg, progress=progress_wanted(args))
    print(
        f"wrote {video} ({cfg.n_frames} frames, {cfg.width}x{cfg.height}, path {doc['path_length']:.2f} m) "
        f"and ground truth {video.with_suffix('.json')}"
    )
    return 0
