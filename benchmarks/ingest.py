"""Benchmark `seeu ingest` (defaults: every trust feature on) against bare pycolmap on the same frames.

1. Renders the project's synthetic clip (default 90 frames, 640x360, seed 0) with exact ground truth.
2. Runs, in turn (A B A B ..., `--pairs` pairs, >= 3 for a median):
   A: `seeu ingest` in-process with its defaults (--force: decode, select, SfM child with keyframes,
      the solution check's two mappings and the final robust bundle adjustment, chunks, Arrow write,
      report);
   B: what a user writes with pycolmap alone on the frames A decoded: extract_features,
      match_sequential, incremental_mapping, all defaults.
3. Prints the median wall and CPU seconds of each, the ratio seeu / bare (goal <= 1.0 on a quiet
   machine), the load average before and after (os.getloadavg: on a shared machine the ratio means
   little), both accuracies against the ground truth (registered %, models, camera-centre RMSE after a
   similarity alignment in % of the path, mean frame-to-frame rotation error, focal error) and
   whether seeu's poses were identical in every run. Writes <out>/result.json.

Example (quiet 2-core machine, the figure in RESULTS.md):
  .venv/bin/python benchmarks/ingest.py --frames 90 --size 360x640 --pairs 3 --out out/bench_ingest
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def bare_pycolmap(image_dir: Path, work: Path) -> tuple[dict, dict]:
    """extract -> match -> map with pycolmap's defaults; returns ({index: Reconstruction}, per-call seconds)."""
    import pycolmap

    pycolmap.logging.minloglevel = 2  # COLMAP's INFO and WARNING lines off (errors still shown)
    if work.exists():
        shutil.rmtree(work)
    (work / "sparse").mkdir(parents=True)
    db = work / "database.db"
    t: dict[str, float] = {}
    t0 = time.perf_counter()
    pycolmap.extract_features(db, image_dir)
    t["extract"] = time.perf_counter() - t0
    t1 = time.perf_counter()
    pycolmap.match_sequential(db)
    t["match"] = time.perf_counter() - t1
    t2 = time.perf_counter()
    recs = pycolmap.incremental_mapping(db, image_dir, work / "sparse")
    t["map"] = time.perf_counter() - t2
    return recs, t


def bare_accuracy(recs: dict, truth: dict, num_frames: int) -> dict:
    """The largest bare model against the ground truth (frame files are named <source frame>.jpg)."""
    import numpy as np

    from seeu_data.ingest.pose_eval import pose_accuracy

    registered = {recs[k].image(i).name for k in recs for i in recs[k].reg_image_ids()}
    out: dict = {"registered_pct": 100.0 * len(registered) / max(num_frames, 1), "models": len(recs), "largest": None}
    if not recs:
        return out
    rec = max(recs.values(), key=lambda r: r.num_reg_images())
    index = {int(f): i for i, f in enumerate(truth["frame"])}
    est, rows, intr = [], [], []
    for i in sorted(rec.reg_image_ids(), key=lambda i: rec.image(i).name):
        img = rec.image(i)
        w2c = np.eye(4)
        w2c[:3] = np.asarray(img.cam_from_world().matrix())
        est.append(np.linalg.inv(w2c))
        rows.append(index[int(Path(img.name).stem)])
        cam = rec.cameras[img.camera_id]
        K = cam.calibration_matrix()
        intr.append([K[0, 0] / cam.width, K[1, 1] / cam.height, K[0, 2] / cam.width, K[1, 2] / cam.height])
    if len(est) >= 3:
        acc = pose_accuracy(np.stack(est), truth["cam_to_world"][rows], np.array(intr), truth["intrinsics_norm"][rows])
        out["largest"] = acc.as_dict()
    return out


def _cpu_s() -> float:
    """User + system CPU seconds of this process and its waited-for children (the SfM child)."""
    import resource

    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def _load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def _accuracy_line(name: str, registered_pct: float, models: int, best: dict | None) -> str:
    if best is None:
        return f"  {name:14s} {registered_pct:5.1f} % registered, {models} model(s), no model to compare"
    return (
        f"  {name:14s} {registered_pct:5.1f} % registered, {models} model(s); largest {best['num_frames']} frames: "
        f"centre RMSE {best['centre_rmse_pct_path']:.3f} % of path, rel. rotation {best['rel_rot_err_mean_deg']:.3f} deg, "
        f"focal {best['focal_err_pct']:.2f} %"
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=90)
    ap.add_argument("--size", default="360x640", help="H x W of the rendered clip")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=Path("out/bench_ingest"))
    ap.add_argument("--pairs", type=int, default=3, help="seeu / bare pairs run in turn; medians reported")
    args = ap.parse_args()

    from pipelines.ingest import IngestConfig, IngestRunConfig, ingest_scene
    from seeu_data.ingest.video import discover_sources
    from seeu_data.settings import parse_dims
    from seeu_data.synthetic import ClipConfig, ingest_accuracy, load_ground_truth, write_clip

    height, width = parse_dims(args.size, "--size", minimum=16)
    video = args.out / "clip" / "clip.mp4"
    t0 = time.perf_counter()
    write_clip(video, ClipConfig(n_frames=args.frames, size=(height, width), seed=args.seed))
    print(f"rendered {args.frames} frames {width}x{height} in {time.perf_counter() - t0:.1f} s -> {video}", flush=True)
    truth = load_ground_truth(video)

    cfg = IngestConfig(out=args.out / "posed", inputs=(video,), run=IngestRunConfig(force=True))  # the defaults
    (source,) = discover_sources([video])
    work = args.out / "posed" / ".work" / source.name
    frames_dir = work / "decode" / "frames"
    seeu_wall, seeu_cpu, bare_wall, bare_cpu, poses = [], [], [], [], []
    report: dict = {}
    bare: dict = {}
    load_before = _load()
    for pair in range(args.pairs):
        c0, t0 = _cpu_s(), time.perf_counter()
        report = ingest_scene(source, cfg)
        seeu_wall.append(time.perf_counter() - t0)
        seeu_cpu.append(_cpu_s() - c0)
        sfm = json.loads((work / "sfm" / "result.json").read_text())
        poses.append([(im["name"], im["world_to_cam"]) for m in sfm["models"] for im in m["images"]])
        print(f"pair {pair + 1} seeu: {seeu_wall[-1]:.1f} s wall, {seeu_cpu[-1]:.1f} s CPU, load {_load()}", flush=True)
        c0 = _cpu_s()
        recs, calls = bare_pycolmap(frames_dir, args.out / "bare")
        bare_wall.append(sum(calls.values()))
        bare_cpu.append(_cpu_s() - c0)
        bare = {"calls_s": calls, **bare_accuracy(recs, truth, report["frames_selected"])}
        print(f"pair {pair + 1} bare: {bare_wall[-1]:.1f} s wall, {bare_cpu[-1]:.1f} s CPU, load {_load()}", flush=True)
    load_after = _load()

    med = statistics.median
    ratio = med(seeu_wall) / med(bare_wall)
    n = report["frames_selected"]
    acc = ingest_accuracy(report["output"], video, report["registered"], report["frames_selected"])
    identical = all(p == poses[0] for p in poses[1:])
    print()
    print(f"{n} frames selected of {report['frames_decoded']}; medians of {args.pairs} pair(s) run in turn")
    print(
        f"seeu ingest   : {med(seeu_wall):7.1f} s wall, CPU {med(seeu_cpu):6.1f} s (last run, sfm child: "
        + ", ".join(f"{k} {v:.1f}" for k, v in report["sfm"]["timings_s"].items())
        + ")"
    )
    calls = bare["calls_s"]
    print(
        f"bare pycolmap : {med(bare_wall):7.1f} s wall, CPU {med(bare_cpu):6.1f} s (last run: extract "
        f"{calls['extract']:.1f}, match {calls['match']:.1f}, map {calls['map']:.1f})"
    )
    print(
        f"ratio seeu / bare (wall): {ratio:.3f} (goal <= 1.0 on a quiet machine); CPU {med(seeu_cpu) / med(bare_cpu):.3f}"
    )
    print(f"load average (1, 5, 15 min): before {load_before}, after {load_after}; {os.cpu_count()} CPUs")
    print("accuracy vs ground truth:")
    print(_accuracy_line("seeu ingest", acc["registered_pct"], len(acc["chunks"]), acc["largest"]))
    print(_accuracy_line("bare pycolmap", bare["registered_pct"], bare["models"], bare["largest"]))
    check = report["sfm"].get("solution_check", {})
    print(f"seeu: solution check {check.get('state')}, poses identical in all {args.pairs} runs: {identical}")
    (args.out / "result.json").write_text(
        json.dumps(
            {
                "frames": n,
                "pairs": args.pairs,
                "ratio_wall": ratio,
                "seeu_wall_s": seeu_wall,
                "bare_wall_s": bare_wall,
                "seeu_cpu_s": seeu_cpu,
                "bare_cpu_s": bare_cpu,
                "load_before": load_before,
                "load_after": load_after,
                "sfm_timings_s": report["sfm"]["timings_s"],
                "seeu_accuracy": acc,
                "bare": bare,
                "poses_identical": identical,
                "solution_check": check,
            },
            indent=1,
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
