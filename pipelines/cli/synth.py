"""Render the built-in synthetic clip: a seeded textured corridor with boxes (occlusions, depths from
about 1 to 16 m) seen along a walk-through that translates and turns, ray-cast in numpy.

Writes OUT/clip.mp4 (mp4v) and OUT/clip.json, the exact ground truth per frame: frame number,
timestamp_us, cam_to_world (OpenCV 4x4), intrinsics_norm (fx/W, fy/H, cx/W, cy/H); plus W, H,
fps, path_length and the generator config. `seeu ingest OUT/clip.mp4` finds clip.json and adds
pose accuracy against it to its report.

Example:
  seeu synth --out data/synth --frames 90 --size 640x360 --seed 0
  seeu synth --out data/wall --frames 30 --size 320x180 --scene planar
  seeu synth --out data/pan --frames 20 --size 320x180 --scene pan
"""

from __future__ import annotations

import argparse

from pipelines.cli.options import add_out, add_progress, progress_wanted
from seeu_data.limits import MAX_VIDEO_FRAMES, MAX_VIDEO_SIDE
from seeu_data.settings import parse_dims


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_out(p, "output directory (clip.mp4 + clip.json)")
    p.add_argument("--frames", type=int, default=90, help=f"number of frames (default 90, at most {MAX_VIDEO_FRAMES})")
    p.add_argument(
        "--size",
        default="640x360",
        metavar="WxH",
        help=f"frame size WIDTHxHEIGHT (default 640x360; sides 16..{MAX_VIDEO_SIDE})",
    )
    p.add_argument("--seed", type=int, default=0, help="scene seed: textures and box layout (default 0)")
    p.add_argument(
        "--scene",
        choices=["corridor", "planar", "pan"],  # seeu_data.synthetic.SCENES (not imported here: cv2)
        default="corridor",
        help="corridor (default); planar: one large textured wall with three small boxes, seen by "
        "a camera walking along it at 4 m (a scene dominated by one plane); pan: the corridor seen by a "
        "camera turning 60 deg on a tripod (little parallax)",
    )
    p.add_argument("--fps", type=float, default=30.0, help="frame rate written to the video (default 30)")
    p.add_argument("--name", default="clip", help="file stem (default clip)")
    add_progress(p)


def run(args: argparse.Namespace) -> int:
    from seeu_data.synthetic import ClipConfig, write_clip

    width, height = parse_dims(
        args.size, "--size", minimum=16, maximum=MAX_VIDEO_SIDE
    )  # WIDTHxHEIGHT, as video sizes are written
    cfg = ClipConfig(n_frames=args.frames, width=width, height=height, seed=args.seed, fps=args.fps, scene=args.scene)
    video = args.out / f"{args.name}.mp4"
    doc = write_clip(video, cfg, progress=progress_wanted(args))
    print(
        f"wrote {video} ({cfg.n_frames} frames, {width}x{height}, path {doc['path_length']:.2f} m) "
        f"and ground truth {video.with_suffix('.json')}"
    )
    return 0
