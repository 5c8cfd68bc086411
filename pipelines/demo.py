"""Run the toolkit on the built-in synthetic clip and leave results to look at.

Stages (each skipped when its output is already there with the same parameters):
  1. synth   render the synthetic clip with exact ground truth  -> OUT/clip/clip.mp4, clip.json
  2. ingest  pose it with COLMAP SfM into posed chunks          -> OUT/posed/clip/ (report.json,
             trajectory.png, manifest.json; the report compares the poses with the ground truth)
Later stages (triple build, training, evaluation, renders) are added by their issues.

Example:
  seeu demo --out out/demo
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", type=Path, default=Path("out/demo"), help="output directory (default out/demo)")
    p.add_argument("--frames", type=int, default=90, help="frames of the synthetic clip (default 90)")
    p.add_argument("--size", default="640x360", help="clip size WIDTHxHEIGHT (default 640x360)")
    p.add_argument("--seed", type=int, default=0, help="synthetic scene seed (default 0)")
    p.add_argument("--force", action="store_true", help="redo every stage")
    p.add_argument("--progress", action="store_true", help="show progress even when stderr is not a terminal")


def stage_synth(args: argparse.Namespace, progress: bool) -> Path:
    """Render the clip unless OUT/clip holds one made with the same parameters."""
    from pipelines.synth import parse_size
    from seeu_data.synthetic import ClipConfig, ground_truth_path, write_clip

    width, height = parse_size(args.size)
    cfg = ClipConfig(n_frames=args.frames, width=width, height=height, seed=args.seed)
    video = args.out / "clip" / "clip.mp4"
    gt = ground_truth_path(video)
    if not args.force and video.exists() and gt.exists():
        try:
            if json.loads(gt.read_text()).get("config") == dict(cfg.__dict__):
                print(f"[1/2] synth: reusing {video}")
                return video
        except json.JSONDecodeError:
            pass
    print(f"[1/2] synth: rendering {cfg.n_frames} frames at {width}x{height} -> {video}")
    write_clip(video, cfg, progress=progress)
    return video


def stage_ingest(args: argparse.Namespace, video: Path, progress: bool) -> dict:
    from pipelines.ingest import IngestConfig, ingest_scene
    from seeu_data.video import discover_sources

    print("[2/2] ingest: decode -> select -> SfM (pycolmap) -> posed chunks (a re-run resumes)")
    (source,) = discover_sources([video])
    report = ingest_scene(source, args.out / "posed", IngestConfig(), force=args.force, progress=progress)
    print(report["summary"])
    return report


def run(args: argparse.Namespace) -> int:
    progress = args.progress or sys.stderr.isatty()
    args.out.mkdir(parents=True, exist_ok=True)
    video = stage_synth(args, progress)
    report = stage_ingest(args, video, progress)
    out = Path(report["output"])
    rows = [(str(video), f"the synthetic clip (ground truth: {video.with_suffix('.json').name})"),
            (str(out / "trajectory.png"), "camera trajectory of every posed chunk"),
            (str(out / "report.json"), "registration, reprojection error, chunks, dropped frames, accuracy"),
            (f"seeu validate {out}", "check the posed-frames dataset")]
    width = max(len(r[0]) for r in rows)
    print("\nLook at:")
    for path, what in rows:
        print(f"  {path:<{width}}  {what}")
    return 0
