"""Pose a video, an image folder, or a folder of videos with COLMAP SfM and write posed chunks.

Stages (each kept under OUT/.work/<scene>/ with a stamp of its inputs and parameters, so re-running
the same command resumes; --force redoes them): decode (--stride, --max-size) -> select frames
(--sharpness-window, --target-frames; every frame keeps its source frame number) -> SfM in a child
process (SIFT, one shared camera of --camera-model, sequential matching with --overlap, loop
detection only with --vocab-tree, --mapper incremental/global/auto, mapping twice from different
seeds for the solution check, undistortion to a pinhole camera of the same size when the model has
distortion; the same poses whatever --threads; --size HxW crops/resizes afterwards)
-> posed chunks (contiguous registered runs per model, >= --min-chunk-frames; scale by --scale:
re10k, median-depth or metric, seeu_data/scale.py) -> OUT/<scene>/ posed-frames dataset
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
import json
import os
import re
import sys
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from pipelines.options import parse_dims


# Bump when a stage's output layout changes, so old work directories are redone rather than misread.
DECODE_STAGE_FORMAT = 2
SFM_STAGE_FORMAT = 6


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("inputs", nargs="+", metavar="INPUT", help="video file, folder of images, or folder of videos")
    p.add_argument("--out", required=True, type=Path, help="output directory; one dataset per scene: OUT/<scene>/")
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
        choices=["PINHOLE", "SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV"],
        help="shared camera model; models with distortion are undistorted (default SIMPLE_RADIAL)",
    )
    p.add_argument("--overlap", type=int, default=10, help="sequential matching overlap in frames (default 10)")
    p.add_argument(
        "--vocab-tree", type=Path, default=None, help="vocabulary-tree file: enables loop detection (off without one)"
    )
    p.add_argument(
        "--mapper",
        choices=["incremental", "global", "auto"],
        default="incremental",
        help="COLMAP incremental mapping (default), GLOMAP global mapping, or auto: incremental when "
        ">= 90%% of consecutive frames match (a video), else global (recorded in report.json)",
    )
    p.add_argument(
        "--features",
        choices=["sift", "aliked"],
        default="sift",
        help="feature type (default sift; aliked needs a pycolmap built with ONNX, checked up front)",
    )
    p.add_argument("--min-chunk-frames", type=int, default=10, help="shortest posed chunk kept (default 10)")
    p.add_argument(
        "--scale",
        choices=["re10k", "median-depth", "metric"],
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
        type=_frame_pair,
        default=None,
        metavar="A,B",
        help="--scale metric: the two source frame numbers --known-distance is measured between",
    )
    p.add_argument("--max-features", type=int, default=8192, help="SIFT features per frame (default 8192)")
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
    p.add_argument("--workers", type=int, default=1, help="local engine: scenes processed in parallel (default 1)")
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
    p.add_argument(
        "--force",
        action="store_true",
        help="redo every stage instead of resuming, and replace OUT/<scene> even when it holds another input's scene",
    )
    p.add_argument(
        "--heartbeat",
        type=float,
        default=None,
        metavar="SECONDS",
        help="when stderr is not a terminal, print a status line every SECONDS (default 10; 0 = off)",
    )
    p.add_argument("--progress", action="store_true", help="show progress bars even when stderr is not a terminal")
    p.add_argument(
        "--fsync",
        action="store_true",
        help="fsync every output file before its rename (durable across a power loss; slower). "
        "Default: atomic renames only, a torn file is caught by the manifest sha256; also SEEU_FSYNC=1",
    )


def _frame_pair(text: str) -> tuple[int, int]:
    try:
        a, b = (int(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"not two frame numbers A,B: {text!r}") from None
    return a, b


@dataclass(frozen=True)
class IngestConfig:
    """All parameters of one ingest run (recorded in each manifest's params)."""

    stride: int = 1
    target_frames: int | None = None
    sharpness_window: int = 0
    max_size: int | None = None
    camera_model: str = "SIMPLE_RADIAL"
    overlap: int = 10
    vocab_tree: str | None = None
    min_chunk_frames: int = 10
    max_features: int = 8192
    threads: int = -1
    sfm_attempts: int = 3
    sfm_check: bool = True
    map_threads: int = 1
    jpeg_quality: int = 95
    scale: str = "re10k"
    mapper: str = "incremental"
    features: str = "sift"
    known_distance: float | None = None
    distance_frames: tuple[int, int] | None = None
    size: tuple[int, int] | None = None
    extra: dict = field(default_factory=dict)


def _encode_jpeg(rgb, quality: int) -> bytes:
    import cv2

    from seeu_data.errors import SeeUError

    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:  # pragma: no cover
        raise SeeUError("JPEG encoding failed")
    return buf.tobytes()


def _decode_stage(source, cfg: IngestConfig, prog):
    """Stage function: decode every stride-th frame, resize, write JPEGs + per-frame metadata."""

    from seeu_data.arrow_io import atomic_write_bytes
    from seeu_data.errors import SeeUError
    from seeu_data.video import iter_frames, probe_video, resize_max_side, sharpness

    def fn(d: Path) -> dict:
        frames_dir = d / "frames"
        frames_dir.mkdir()
        in_source = probe_video(source.path).frame_count if source.kind == "video" else len(source.image_files)
        total = -(-in_source // cfg.stride)
        frames, size = [], None
        prog.stage("decode", total)
        for fr in iter_frames(source, cfg.stride):
            prog.advance()
            rgb = resize_max_side(fr.rgb, cfg.max_size)
            if size is None:
                size = rgb.shape[:2]
            elif rgb.shape[:2] != size:
                where = source.path / fr.source_name if fr.source_name else source.path
                raise SeeUError(
                    f"frame size {rgb.shape[1]}x{rgb.shape[0]} differs from the first frame's "
                    f"{size[1]}x{size[0]} (one shared camera needs one size)",
                    where,
                )
            name = f"{fr.source_frame:06d}.jpg"
            atomic_write_bytes(frames_dir / name, _encode_jpeg(rgb, cfg.jpeg_quality))  # OS errors name the file
            frames.append(
                {
                    "name": name,
                    "source_frame": fr.source_frame,
                    "timestamp_us": fr.timestamp_us,
                    "source_name": fr.source_name,
                    "sharpness": sharpness(rgb),
                }
            )
        if not frames:
            raise SeeUError("no frames decoded", source.path)
        return {"frames": frames, "width": int(size[1]), "height": int(size[0]), "frames_in_source": int(in_source)}

    return fn


def _ground_truth_accuracy(source, frames: list[dict], chunks, registered: int, selected: int) -> dict | None:
    """Accuracy against a synthetic clip's ground-truth JSON lying beside the video, if there is one."""
    import numpy as np

    from seeu_data.errors import SeeUError
    from seeu_data.pose_eval import pose_accuracy
    from seeu_data.synthetic import ground_truth_path, load_ground_truth

    if source.kind != "video" or not ground_truth_path(source.path).exists():
        return None
    try:
        gt = load_ground_truth(source.path)
    except (SeeUError, ValueError, KeyError):
        return None
    index = {int(f): i for i, f in enumerate(gt["frame"])}
    out = {
        "file": str(ground_truth_path(source.path)),
        "registered_pct": 100.0 * registered / max(selected, 1),
        "chunks": [],
    }
    for ch in chunks:
        src = [frames[p]["source_frame"] for p in ch.frame_positions]
        if len(src) < 3 or any(s not in index for s in src):
            continue
        rows = [index[s] for s in src]
        # Normalised focal lengths survive --max-size; undistortion may crop the image by a few pixels
        # without resampling, so compare the camera as mapped (on the decoded frames) with the truth.
        mapped = ch.meta["camera_as_mapped"]
        intr = np.array(
            [
                mapped["fx"] / mapped["width"],
                mapped["fy"] / mapped["height"],
                mapped["cx"] / mapped["width"],
                mapped["cy"] / mapped["height"],
            ]
        )
        acc = pose_accuracy(ch.cam_to_world, gt["cam_to_world"][rows], [intr] * len(rows), gt["intrinsics_norm"][rows])
        out["chunks"].append({"scene_id": ch.scene_id, **acc.as_dict()})
    return out


def input_identity(source) -> dict:
    """What makes an input the same input: its resolved path and its content fingerprint."""
    return {"path": str(source.path.resolve()), "fingerprint": source.fingerprint()}


def check_scene_owner(out_dir: Path, identity: dict, force: bool) -> None:
    """Refuse to overwrite OUT/<scene> when it holds another input's scene (unless `force`).

    The same input: the same resolved path, or the same content fingerprint (a moved folder); the
    identity is read from the scene's report.json (`input_identity`, or `input` for older reports).
    A dataset without an ingest report counts as another input's.
    """
    from seeu_data.errors import SeeUError

    if force or not out_dir.exists():
        return
    report_path = out_dir / "report.json"
    recorded = None
    if report_path.exists():
        try:
            doc = json.loads(report_path.read_text())
            recorded = doc.get("input_identity") or {"path": str(Path(doc["input"]).resolve())}
        except (OSError, ValueError, KeyError, TypeError):
            recorded = None
    elif not (out_dir / "manifest.json").exists():
        return  # nothing finished there (an interrupted run): nothing to lose
    if recorded and (
        recorded.get("path") == identity["path"] or recorded.get("fingerprint") == identity["fingerprint"]
    ):
        return
    what = f"scene of another input ({recorded['path']})" if recorded else "dataset not written by seeu ingest"
    raise SeeUError(f"already holds a {what}; choose another --name or --out, or --force to replace it", out_dir)


def ingest_scene(
    source, out_root: Path, cfg: IngestConfig, force: bool = False, progress: bool = False, heartbeat_s: float = 0.0
) -> dict:
    """Run every stage for one scene; returns its report (also written to OUT/<scene>/report.json).

    `progress`: tqdm bars; `heartbeat_s` > 0: a status line on stderr that often (`StageProgress`).
    Raises SeeUError when OUT/<scene> holds another input's scene and not `force`.
    """
    from seeu_data.progress import StageProgress

    out_dir = out_root / source.name
    identity = input_identity(source)
    check_scene_owner(out_dir, identity, force)
    with StageProgress(f"seeu ingest: {source.name}", bar=progress, heartbeat_s=heartbeat_s) as prog:
        return _ingest_scene(source, out_root, cfg, force, prog, identity)


def _ingest_scene(source, out_root: Path, cfg: IngestConfig, force: bool, prog, identity: dict) -> dict:
    import numpy as np

    from seeu_data.chunks import ChunkConfig, plan_chunks
    from seeu_data.errors import SeeUError
    from seeu_data.frame_select import SelectConfig, select_frames
    from seeu_data.ingest_report import (
        baseline_over_depth,
        mean_reprojection_error,
        plot_trajectory,
        scene_warnings,
        summary_line,
        write_report,
    )
    from seeu_data.manifest import MANIFEST_NAME, provenance
    from seeu_data.points import POINTS_DIR, write_chunk_points
    from seeu_data.posed import POSED_FILES, PosedDatasetWriter, PosedScene
    from seeu_data.resize import resize_scene
    from seeu_data.scale import ScaleConfig, distance_frame_names
    from seeu_data.sfm import SfmConfig, run_sfm
    from seeu_data.resume import StageCache, stamp_of, sweep

    t_start = time.perf_counter()
    out_dir = out_root / source.name
    (out_dir / MANIFEST_NAME).unlink(missing_ok=True)  # being redone: must not look complete meanwhile
    select_cfg = SelectConfig(cfg.stride, cfg.sharpness_window, cfg.target_frames)
    select_cfg.check()
    chunk_cfg = ChunkConfig(
        min_chunk_frames=cfg.min_chunk_frames, scale=ScaleConfig(cfg.scale, cfg.known_distance, cfg.distance_frames)
    )
    chunk_cfg.check()
    sfm_cfg = SfmConfig(
        camera_model=cfg.camera_model,
        overlap=cfg.overlap,
        vocab_tree=None if cfg.vocab_tree is None else str(Path(cfg.vocab_tree).resolve()),
        min_model_size=max(3, min(cfg.min_chunk_frames, 10)),
        max_num_features=cfg.max_features,
        num_threads=cfg.threads,
        mapping_attempts=cfg.sfm_attempts,
        mapper=cfg.mapper,
        features=cfg.features,
        solution_check=cfg.sfm_check,
        mapping_threads=cfg.map_threads,
    )
    sfm_cfg.check()
    cache = StageCache(out_root / ".work" / source.name, force=force)

    decode_key = {
        "input": identity["path"],
        "fingerprint": identity["fingerprint"],
        "kind": source.kind,
        "stride": cfg.stride,
        "max_size": cfg.max_size,
        "jpeg_quality": cfg.jpeg_quality,
        "format": DECODE_STAGE_FORMAT,
    }
    decode_dir = cache.stage_dir("decode")
    decoded, _ = cache.run("decode", decode_key, lambda: _decode_stage(source, cfg, prog)(decode_dir), decode_dir)
    frames_all = decoded["frames"]

    t0 = time.perf_counter()
    keep, dropped_sel = select_frames(
        [f["sharpness"] for f in frames_all], [f["source_frame"] for f in frames_all], select_cfg
    )
    frames = [frames_all[i] for i in keep]
    cache.timings["select"] = time.perf_counter() - t0
    need = max(3, cfg.min_chunk_frames)
    if len(frames) < need:
        raise SeeUError(
            f"only {len(frames)} usable frame(s) after selection; SfM and --min-chunk-frames need at least {need}",
            source.path,
        )

    names = [f["name"] for f in frames]
    # the thread count does not change the results (image ids and RANSAC seeds are fixed by the frames)
    sfm_params = {k: v for k, v in asdict(sfm_cfg).items() if k != "num_threads"}
    sfm_key = {"decode": stamp_of(decode_key), "names": names, "sfm": sfm_params, "format": SFM_STAGE_FORMAT}
    sfm_dir = cache.stage_dir("sfm")
    sfm_result, _ = cache.run(
        "sfm", sfm_key, lambda: run_sfm(decode_dir / "frames", names, sfm_dir, sfm_cfg, source.path, prog), sfm_dir
    )
    prog.stage("write")

    t0 = time.perf_counter()
    chunks, dropped_chunk = plan_chunks(
        source.name,
        names,
        sfm_result,
        cache.stage_dir("sfm"),
        chunk_cfg,
        distance_frame_names(frames, cfg.distance_frames, source.path),
    )
    registered = len({im["name"] for m in sfm_result["models"] for im in m["images"]})
    if not chunks:
        raise SeeUError(
            f"SfM registered {registered}/{len(frames)} frames but no contiguous run reaches "
            f"--min-chunk-frames {cfg.min_chunk_frames}",
            source.path,
        )
    cache.timings["chunks"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    dropped = dropped_sel + [
        {"source_frame": frames[d["position"]]["source_frame"], "reason": d["reason"]} for d in dropped_chunk
    ]
    dropped.sort(key=lambda d: d["source_frame"])
    check = sfm_result.get("solution_check", {})
    check_state = "not run" if not check.get("ran") else ("passed" if check.get("passed") else "failed")
    for c in chunks:
        c.meta["baseline_over_depth"] = baseline_over_depth(c.cam_to_world)
        c.meta["sfm_solution_check"] = check_state
    params = {**asdict(cfg), "inputs": [str(source.path)], "sfm": asdict(sfm_cfg)}
    prov = provenance("seeu ingest", [str(source.path)], input_fingerprint=identity["fingerprint"])
    report = {
        "scene": source.name,
        "input": str(source.path),
        "input_kind": source.kind,
        "input_identity": identity,
        "frames_decoded": decoded["frames_in_source"],
        "frames_candidates": len(frames_all),
        "frames_selected": len(frames),
        "registered": registered,
        "registration_rate": registered / len(frames),
        "frames_in_chunks": sum(len(c.frame_positions) for c in chunks),
        "mean_reprojection_error_px": mean_reprojection_error(sfm_result["models"]),
        "sfm": {
            "num_keypoints": sfm_result.get("num_keypoints"),
            "num_verified_pairs": sfm_result.get("num_verified_pairs"),
            "timings_s": sfm_result.get("timings", {}),
            "models": [
                {
                    "index": m["index"],
                    "registered": len(m["images"]),
                    "points3D": m["num_points3D"],
                    "mean_reprojection_error_px": m["mean_reprojection_error"],
                    "camera": m["camera"],
                    "undistorted": m["undistorted"],
                    "distortion_max_px": m.get("distortion_max_px"),
                }
                for m in sfm_result["models"]
            ],
            "discarded_models": sfm_result.get("discarded_models", []),
            "mapping_attempts": sfm_result.get("mapping_attempts", []),
            "mapper": sfm_result.get("mapper"),
            "solution_check": {**check, "state": check_state},
        },
        "chunks": [
            {
                "scene_id": c.scene_id,
                "num_frames": len(c.frame_positions),
                "source_frames": [
                    frames[c.frame_positions[0]]["source_frame"],
                    frames[c.frame_positions[-1]]["source_frame"],
                ],
                "near": c.near,
                "far": c.far,
                "sfm_model": c.model_index,
                "baseline_over_depth": c.meta["baseline_over_depth"],
            }
            for c in chunks
        ],
        "dropped_frames": dropped,
        "output": str(out_dir),
    }
    report["warnings"] = scene_warnings(report)
    gt = _ground_truth_accuracy(source, frames, chunks, registered, len(frames))
    if gt is not None:
        report["ground_truth"] = gt

    sweep(out_dir, POSED_FILES, keep=())  # an earlier run's files: this run writes its own
    sweep(out_dir / POINTS_DIR, "*.ply", keep=())
    with PosedDatasetWriter(out_dir, params=params, provenance=prov) as writer:
        for c in chunks:
            imgs = []
            for path in c.image_paths:
                if not path.exists():
                    raise SeeUError("SfM image missing from the work directory (re-run with --force)", path)
                imgs.append(path.read_bytes())
            fr = [frames[p] for p in c.frame_positions]
            n = len(fr)
            scene = PosedScene(
                scene_id=c.scene_id,
                images=imgs,
                image_format="jpeg",
                width=np.full(n, c.width),
                height=np.full(n, c.height),
                intrinsics_norm=np.tile(c.intrinsics_norm, (n, 1)),
                cam_to_world=c.cam_to_world,
                near=c.near,
                far=c.far,
                source_frame=np.array([f["source_frame"] for f in fr], np.int64),
                timestamp_us=np.array([f["timestamp_us"] for f in fr], np.int64),
                source_name=[f["source_name"] for f in fr],
                meta={
                    **c.meta,
                    "source": str(source.path),
                    **write_chunk_points(
                        cache.stage_dir("sfm"), c.model_index, c.meta["sfm_to_chunk"], out_dir, c.scene_id
                    ),
                },
            )
            writer.add(scene if cfg.size is None else resize_scene(scene, cfg.size, cfg.jpeg_quality))
        cache.timings["write"] = time.perf_counter() - t0
        report["timings_s"] = {**cache.timings, "total": time.perf_counter() - t_start}
        report["reused"] = dict(cache.reused)
        writer.report = {
            k: report[k]
            for k in (
                "frames_selected",
                "registered",
                "registration_rate",
                "frames_in_chunks",
                "mean_reprojection_error_px",
            )
        }
        writer.report["dropped_frames"] = len(dropped)
        writer.report["warnings"] = report["warnings"]
        write_report(out_dir / "report.json", report)
        plot_trajectory(
            out_dir / "trajectory.png",
            chunks,
            f"{source.name}: {registered}/{len(frames)} registered, {len(chunks)} chunk(s)",
        )
    report["summary"] = summary_line(report)
    return report


def _scene_worker(payload: tuple) -> tuple[str, dict | None, str | None]:
    """Process-pool entry: (name, report, error line)."""
    from seeu_data.errors import SeeUError

    source, out_root, cfg, force, heartbeat_s = payload
    try:
        return source.name, ingest_scene(source, out_root, cfg, force=force, heartbeat_s=heartbeat_s), None
    except SeeUError as exc:
        return source.name, None, str(exc)


def run(args: argparse.Namespace) -> int:
    from seeu_data.arrow_io import fsync_policy

    with fsync_policy(True if args.fsync else None):
        return _run(args)


def _run(args: argparse.Namespace) -> int:
    from concurrent.futures import ProcessPoolExecutor
    import multiprocessing

    from tqdm import tqdm

    from seeu_data.errors import SeeUError
    from seeu_data.scale import ScaleConfig
    from seeu_data.sfm import SfmConfig
    from seeu_data.video import discover_sources

    if args.workers < 1:
        raise SeeUError(f"--workers must be >= 1, got {args.workers}")
    if args.engine == "ray" and args.workers != 1:
        raise SeeUError("--workers is for the local engine; on Ray each scene is a task that takes --threads CPUs")
    if args.engine == "local" and args.ray_address is not None:
        raise SeeUError("--ray-address needs --engine ray")
    ScaleConfig(args.scale, args.known_distance, args.distance_frames).check()  # before any scene starts
    SfmConfig(mapper=args.mapper, features=args.features).check()  # e.g. ALIKED without ONNX: one line, now
    sources = discover_sources(args.inputs)
    if args.name is not None:
        if len(sources) != 1:
            raise SeeUError(f"--name names one scene, but the inputs hold {len(sources)}")
        if not re.fullmatch(r"[A-Za-z0-9_-][A-Za-z0-9_.-]*", args.name):
            raise SeeUError(f"--name must be letters, digits, '_', '-', '.' (not first), got {args.name!r}")
        sources = [replace(sources[0], name=args.name)]
    progress = args.progress or sys.stderr.isatty()
    # a status line every few seconds when no terminal shows bars (CI, logs); SEEU_HEARTBEAT_S sets the default
    heartbeat = args.heartbeat if args.heartbeat is not None else float(os.environ.get("SEEU_HEARTBEAT_S", "10"))
    heartbeat = 0.0 if progress else heartbeat
    workers = min(args.workers, len(sources))
    if args.threads != -1:
        threads = args.threads
    else:
        threads = 1 if args.engine == "ray" else max(1, (os.cpu_count() or 1) // workers)
    cfg = IngestConfig(
        stride=args.stride,
        target_frames=args.target_frames,
        sharpness_window=args.sharpness_window,
        max_size=args.max_size,
        camera_model=args.camera_model,
        overlap=args.overlap,
        vocab_tree=None if args.vocab_tree is None else str(args.vocab_tree),
        min_chunk_frames=args.min_chunk_frames,
        max_features=args.max_features,
        threads=threads,
        sfm_attempts=args.sfm_attempts,
        scale=args.scale,
        known_distance=args.known_distance,
        distance_frames=args.distance_frames,
        size=parse_dims(args.size, "--size") if args.size else None,
        mapper=args.mapper,
        features=args.features,
        sfm_check=not args.no_sfm_check,
        map_threads=args.map_threads,
    )
    if args.engine == "ray":
        from pipelines.ingest_ray import ingest_on_ray

        results = ingest_on_ray(
            sources,
            args.out,
            cfg,
            scene_fn=ingest_scene,
            address=args.ray_address,
            force=args.force,
            on_result=lambda r: _print_result(r.name, r.report, r.error),
            progress=progress,
        )
        failures = sum(r.error is not None for r in results)
        print(f"{len(sources) - failures}/{len(sources)} scenes ingested into {args.out}")
        return 2 if failures else 0
    args.out.mkdir(parents=True, exist_ok=True)
    if len(sources) == 1:
        report = ingest_scene(sources[0], args.out, cfg, force=args.force, progress=progress, heartbeat_s=heartbeat)
        print(report["summary"])
        return 0
    failures = 0
    if workers == 1:
        results: list[tuple[str, dict | None, str | None]] = []
        for s in sources:
            try:
                results.append(
                    (
                        s.name,
                        ingest_scene(s, args.out, cfg, force=args.force, progress=progress, heartbeat_s=heartbeat),
                        None,
                    )
                )
            except SeeUError as exc:
                results.append((s.name, None, str(exc)))
            _print_result(*results[-1])
            failures += results[-1][2] is not None
    else:
        ctx = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(workers, mp_context=ctx) as pool:
            futures = pool.map(_scene_worker, [(s, args.out, cfg, args.force, heartbeat) for s in sources])
            for name, report, err in tqdm(futures, total=len(sources), desc="scenes", disable=not progress):
                _print_result(name, report, err)
                failures += err is not None
    print(f"{len(sources) - failures}/{len(sources)} scenes ingested into {args.out}")
    return 2 if failures else 0


def _print_result(name: str, report: dict | None, err: str | None) -> None:
    if err is not None:
        print(f"seeu ingest: error: {err}", file=sys.stderr)
    elif report is not None:
        print(report["summary"])
