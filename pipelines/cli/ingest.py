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
from pathlib import Path

from pipelines.cli.options import add_force, add_fsync, add_out, add_progress, add_workers, parse_dims, progress_wanted
from seeu_data.ingest.scale import SCALES
from seeu_data.ingest.sfm import CAMERA_MODELS, FEATURES, FINAL_BA_LOSSES, MAPPERS


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("inputs", nargs="+", metavar="INPUT", help="video file, folder of images, or folder of videos")
    add_out(p, "output directory; one dataset per scene: OUT/<scene>/")
    p.add_argument(
        "--name",
        default=None,
        help="scene name for a single input (default: the file's or folder's name; inputs sharing a "
        "name get their parent folder's name in front: a/images, b/images -> a-images, b-images)",
    )
    p.add_argument("--stride", type=int, default=1, help="keep every N-th decoded frame (default 1)")
    p.add_argument(
        "--target-frames", type=int, default=None, help="then keep this many frames, evenly spaced (default: all)"
    )
    p.add_argument(
        "--sharpness-window",
        type=int,
        default=0,
        help="drop the blurriest frame in each window of N candidates (0 = off)",
    )
    p.add_argument("--max-size", type=int, default=None, help="downscale so the longer side is at most N pixels")
    p.add_argument(
        "--size",
        default=None,
        metavar="HxW",
        help="make the posed frames exactly HxW: resize to cover + centre crop after SfM (intrinsics "
        "updated), e.g. 360x640 for the peers' RE10K loaders; default: the (undistorted) frame size",
    )
    p.add_argument(
        "--camera-model",
        default="SIMPLE_RADIAL",
        choices=CAMERA_MODELS,
        help="shared camera model; models with distortion are undistorted (default SIMPLE_RADIAL)",
    )
    p.add_argument("--overlap", type=int, default=10, help="sequential matching overlap in frames (default 10)")
    p.add_argument(
        "--vocab-tree", type=Path, default=None, help="vocabulary-tree file: enables loop detection (off without one)"
    )
    p.add_argument(
        "--mapper",
        choices=MAPPERS,
        default="incremental",
        help="COLMAP incremental mapping (default), GLOMAP global mapping, or auto: incremental when "
        ">= 90%% of consecutive frames match (a video), else global (recorded in report.json)",
    )
    p.add_argument(
        "--features",
        choices=list(FEATURES),
        default="sift",
        help="feature type (default sift; aliked needs a pycolmap built with ONNX, checked up front)",
    )
    p.add_argument(
        "--keyframe-motion",
        type=float,
        default=20.0,
        metavar="PX",
        help="map a video on keyframes every 2, 4, 8, ... frames, as far apart as keeps the median image "
        "motion between keyframes <= PX pixels (at least 30 keyframes), then register the other frames "
        "into the model; mapping time then grows with the frame count, not its square (default 20; 0 = "
        "map every frame)",
    )
    p.add_argument("--min-chunk-frames", type=int, default=10, help="shortest posed chunk kept (default 10)")
    p.add_argument(
        "--scale",
        choices=SCALES,
        default="re10k",
        help="scale convention, recorded in each chunk's meta: re10k (default; 5th-percentile point depth "
        "= 2, near/far 1/100 as the pixelSplat/MVSplat RealEstate10K setup), median-depth (median "
        "point depth = 1, near/far from the points), metric (metres, needs --known-distance)",
    )
    p.add_argument(
        "--known-distance",
        type=float,
        default=None,
        metavar="METRES",
        help="--scale metric: real distance between the cameras of the first and last frame (or of --distance-frames)",
    )
    p.add_argument(
        "--distance-frames",
        type=frame_pair,
        default=None,
        metavar="A,B",
        help="--scale metric: the two source frame numbers --known-distance is measured between",
    )
    p.add_argument("--max-features", type=int, default=8192, help="SIFT features per frame (default 8192)")
    p.add_argument(
        "--final-ba-loss",
        choices=FINAL_BA_LOSSES,
        default="soft_l1",
        help="a last global bundle adjustment of each model after mapping (a video: of its keyframes), with this robust "
        "loss, so that the few large SIFT residuals pull the camera less (default soft_l1; none = off)",
    )
    p.add_argument(
        "--final-ba-loss-scale",
        type=float,
        default=0.5,
        metavar="PX",
        help="scale of --final-ba-loss in pixels (default 0.5)",
    )
    p.add_argument(
        "--sfm-attempts",
        type=int,
        default=3,
        help="re-run incremental mapping with the next seed while it registers < 80%% of the frames, "
        "keeping the run that registers most (default 3 runs at most)",
    )
    p.add_argument(
        "--no-sfm-check",
        action="store_true",
        help="skip the solution check (a second mapping from the next seed whose camera centres must "
        "agree within 1%% of the path; mapping takes about twice as long with it)",
    )
    add_workers(p, "local engine: scenes processed in parallel (default 1)", default=1)
    p.add_argument(
        "--engine",
        choices=["local", "ray"],
        default="local",
        help="local processes (default) or Ray: one scene per task, as many at once as the cluster's "
        "CPUs allow; the same posed files",
    )
    p.add_argument(
        "--ray-address",
        default=None,
        help="--engine ray: a running cluster (host:port, or auto); default: start a local instance",
    )
    p.add_argument(
        "--threads",
        type=int,
        default=-1,
        help="COLMAP threads per scene for feature extraction (default: all cores / workers; 1 with "
        "--engine ray, where each task reserves max(--threads, --map-threads) CPUs); results do not depend on it",
    )
    p.add_argument(
        "--map-threads",
        type=int,
        default=1,
        help="threads for matching and mapping (default 1: poses identical run after run; more speeds up "
        "them on large inputs, but results then depend on thread timing; -1 = all cores)",
    )
    add_force(p, also=", and replace OUT/<scene> even when it holds another input's scene")
    p.add_argument(
        "--heartbeat",
        type=float,
        default=None,
        metavar="SECONDS",
        help="while no progress bars show (no terminal, or --no-progress), print a status line every SECONDS "
        "(default 10, or $SEEU_HEARTBEAT_S; 0 = off)",
    )
    p.add_argument(
        "--strict",
        action="store_true",
        help="refuse an image folder holding an entry with an image name that cannot be read as an image "
        "(a FIFO, a directory, no read permission, other bytes); default: skip it and name it in the summary",
    )
    add_progress(p)
    add_fsync(p)


def frame_pair(text: str) -> tuple[int, int]:
    """`--distance-frames A,B` -> (A, B)."""
    try:
        a, b = (int(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"not two frame numbers A,B: {text!r}") from None
    return a, b


def run(args: argparse.Namespace) -> int:
    from pipelines.ingest import IngestConfig, SceneResult, ingest

    cfg = IngestConfig(
        inputs=tuple(args.inputs),
        out=args.out,
        name=args.name,
        stride=args.stride,
        target_frames=args.target_frames,
        sharpness_window=args.sharpness_window,
        max_size=args.max_size,
        size=parse_dims(args.size, "--size") if args.size else None,
        camera_model=args.camera_model,
        overlap=args.overlap,
        vocab_tree=None if args.vocab_tree is None else str(args.vocab_tree),
        mapper=args.mapper,
        features=args.features,
        min_chunk_frames=args.min_chunk_frames,
        scale=args.scale,
        known_distance=args.known_distance,
        distance_frames=args.distance_frames,
        max_features=args.max_features,
        sfm_attempts=args.sfm_attempts,
        sfm_check=not args.no_sfm_check,
        engine=args.engine,
        ray_address=args.ray_address,
        workers=args.workers,
        threads=args.threads,
        map_threads=args.map_threads,
        keyframe_motion=args.keyframe_motion,
        final_ba_loss=args.final_ba_loss,
        final_ba_loss_scale=args.final_ba_loss_scale,
        force=args.force,
        heartbeat_s=args.heartbeat,
        progress=progress_wanted(args),
        fsync=args.fsync,
        strict=args.strict,
    )

    def show(result: SceneResult) -> None:
        if result.error is not None:
            print(f"seeu ingest: error: {result.error}", file=sys.stderr)
        elif result.report is not None:
            print(result.report["summary"])

    results = ingest(cfg, on_result=show)
    failures = sum(r.error is not None for r in results)
    if len(results) > 1 or cfg.engine == "ray":
        print(f"{len(results) - failures}/{len(results)} scenes ingested into {args.out}")
    return 2 if failures else 0
