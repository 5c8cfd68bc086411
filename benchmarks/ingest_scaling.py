"""How `seeu ingest` grows with the frame count: wall time per stage and the growth exponent, per mapper.

For each frame count (default 50, 100, 200, 400) the project's synthetic clip (`seeu synth`: the
corridor, 640x360, seed 0, the same 7.3 m walk sampled more densely) is rendered once and kept under
OUT/clips/; then, for each mapper (`--mapper incremental` and `--mapper global`), one default
`seeu ingest` of it runs from scratch (in this process, --force), one at a time. Per run:

- wall seconds per stage: decode + select, feature extraction, matching, the first mapping run
  (with the keyframe choice), the solution check's further mapping run(s), registering the frames
  that are not keyframes, the final robust bundle adjustment, undistortion, the rest of the SfM child (start-up,
  database reads, model export), chunk planning + writing, and the total; CPU seconds of the whole
  run (this process and the SfM child) and of the child's stages;
- accuracy against the clip's ground truth: % of frames registered, camera-centre RMSE (after a
  similarity alignment) of the largest chunk in % of the path length (targets >= 95 %, <= 0.5 %).

The growth exponent of a stage is the least-squares slope of log(seconds) on log(frames) over the
runs with 100 <= frames <= 400 (`--fit-range`): 1 is linear, 2 quadratic. Wall times depend on the
machine's load (recorded: /proc/loadavg before and after); the CPU-time exponent depends on it less.

Example (about 16 min on a quiet 2-core machine; one ingest at a time):
  .venv/bin/python benchmarks/ingest_scaling.py --frames 50,100,200,400 --mappers incremental,global \\
      --out out/bench_ingest_scaling --write
--write replaces the <!-- ingest-scaling:begin/end --> section of benchmarks/RESULTS.md.
Results also go to OUT/results.json (after every run, so an interrupted benchmark keeps its runs).
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import resource
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.results_md import write_section  # noqa: E402

# (column, label): the stages of one run, in pipeline order; they add up to the total
STAGES = (
    ("decode", "decode+select"),
    ("extract", "extract"),
    ("match", "match"),
    ("map_first", "map (1st run)"),
    ("map_check", "map (check, retries)"),
    ("register", "register"),
    ("final_ba", "final BA"),
    ("undistort", "undistort"),
    ("sfm_other", "SfM other"),
    ("write", "chunks+write"),
)


def growth_exponent(frames: list[int], seconds: list[float], lo: int = 100, hi: int = 400) -> float:
    """Least-squares slope of log(seconds) on log(frames) over the points with lo <= frames <= hi.

    `frames`, `seconds`: (R,) one entry per run. t = c * n**k gives k exactly. NaN when fewer than two
    distinct frame counts lie in the range or a time there is not positive.
    """
    pts = [(n, t) for n, t in zip(frames, seconds) if lo <= n <= hi]
    if len({n for n, _ in pts}) < 2 or any(not (t > 0 and math.isfinite(t)) for _, t in pts):
        return float("nan")
    xs = [math.log(n) for n, _ in pts]
    ys = [math.log(t) for _, t in pts]
    mx, my = sum(xs) / len(xs), sum(ys) / len(ys)
    return sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / sum((x - mx) ** 2 for x in xs)


def stage_seconds(report: dict) -> dict[str, float]:
    """Wall seconds per stage (`STAGES` keys + "total") from an ingest report.json dict.

    The SfM stage is split with the child's own timings (`sfm.timings_s`) and the duration of each
    mapping run (`sfm.mapping_attempts[i].seconds`); "sfm_other" is what the SfM stage spent outside
    them (the child's start-up, database reads, model export)."""
    t = report["timings_s"]
    sfm = report["sfm"].get("timings_s", {})
    attempts = report["sfm"].get("mapping_attempts", [])
    map_all = sfm.get("map_s", float("nan"))
    first = attempts[0].get("seconds", float("nan")) if attempts else float("nan")
    inside = sum(sfm.get(k, 0.0) for k in ("extract_s", "match_s", "map_s", "register_s", "final_ba_s", "undistort_s"))
    return {
        "decode": t.get("decode", 0.0) + t.get("select", 0.0),
        "extract": sfm.get("extract_s", float("nan")),
        "match": sfm.get("match_s", float("nan")),
        "map_first": first,
        "map_check": map_all - first,
        "register": sfm.get("register_s", 0.0),
        "final_ba": sfm.get("final_ba_s", 0.0),
        "undistort": sfm.get("undistort_s", 0.0),
        "sfm_other": t["sfm"] - inside,
        "write": t.get("chunks", 0.0) + t.get("write", 0.0),
        "total": t["total"],
    }


def _cpu_s() -> float:
    """User + system CPU seconds of this process and its waited-for children (the SfM child)."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def _loadavg() -> str:
    try:
        return " ".join(Path("/proc/loadavg").read_text().split()[:3])
    except OSError:
        return "n/a"


def _clip(out: Path, frames: int, width: int, height: int, seed: int) -> Path:
    """The synthetic clip of `frames` frames under OUT/clips/, rendered unless an identical one is there."""
    from seeu_data.synthetic import ClipConfig, ground_truth_path, write_clip

    cfg = ClipConfig(n_frames=frames, size=(height, width), seed=seed)
    video = out / "clips" / f"f{frames}" / "clip.mp4"
    gt = ground_truth_path(video)
    if video.exists() and gt.exists():
        try:
            if json.loads(gt.read_text())["config"] == dict(cfg.__dict__):
                return video
        except (OSError, ValueError, KeyError):
            pass
    t0 = time.perf_counter()
    write_clip(video, cfg)
    print(f"rendered {frames} frames {width}x{height} in {time.perf_counter() - t0:.1f} s -> {video}", flush=True)
    return video


def run_one(video: Path, out_root: Path, mapper: str, keyframe_motion: float | None = None) -> dict:
    """One default `seeu ingest` of `video` with `mapper` (and `keyframe_motion` unless None), from
    scratch; returns the benchmark's row."""
    from pipelines.ingest import IngestConfig, IngestRunConfig, ingest_scene
    from seeu_data.ingest.sfm import SfmConfig
    from seeu_data.ingest.video import discover_sources
    from seeu_data.synthetic import ingest_accuracy

    (source,) = discover_sources([video])
    load_before = _loadavg()
    c0, t0 = _cpu_s(), time.perf_counter()
    sfm = (
        SfmConfig(mapper=mapper)
        if keyframe_motion is None
        else SfmConfig(mapper=mapper, keyframe_motion=keyframe_motion)
    )
    cfg = IngestConfig(out=out_root, inputs=(video,), sfm=sfm, run=IngestRunConfig(force=True))
    report = ingest_scene(source, cfg)
    wall, cpu = time.perf_counter() - t0, _cpu_s() - c0
    acc = ingest_accuracy(report["output"], video, report["registered"], report["frames_selected"])
    best = acc["largest"]
    check = report["sfm"].get("solution_check", {})
    return {
        "frames": report["frames_selected"],
        "mapper": mapper if keyframe_motion is None else f"{mapper}, --keyframe-motion {keyframe_motion:g}",
        "keyframes": report["sfm"].get("keyframes"),
        "mapper_used": (report["sfm"].get("mapper") or {}).get("used", mapper),
        "wall_s": wall,
        "cpu_s": cpu,
        "stages_s": stage_seconds(report),
        "sfm_cpu_s": report["sfm"].get("cpu_timings_s", {}),
        "mapping_runs": len(report["sfm"].get("mapping_attempts", [])),
        "solution_check": check.get("state"),
        "registered_pct": acc["registered_pct"],
        "centre_rmse_pct_path": best["centre_rmse_pct_path"] if best else float("nan"),
        "chunks": len(acc["chunks"]),
        "loadavg_before": load_before,
        "loadavg_after": _loadavg(),
        "summary": report["summary"],
    }


def _keyframes(kf: dict | None) -> str:
    """`count (every s-th)` of a report's sfm.keyframes."""
    return "—" if not kf else f"{kf['count']} (every {kf['stride']})"


def _fmt(v: float) -> str:
    return "—" if not math.isfinite(v) else (f"{v:.1f}" if v < 100 else f"{v:.0f}")


def tables(rows: list[dict], lo: int, hi: int) -> list[str]:
    """Markdown: the stage table (one row per run) and the exponent table (one row per mapper)."""
    head = [
        "mapper",
        "frames",
        "keyframes",
        *(label for _, label in STAGES),
        "total wall",
        "CPU",
        "registered",
        "RMSE % path",
    ]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        s = r["stages_s"]
        lines.append(
            "| "
            + " | ".join(
                [
                    r["mapper"],
                    str(r["frames"]),
                    _keyframes(r.get("keyframes")),
                    *(_fmt(s[k]) for k, _ in STAGES),
                    f"**{_fmt(s['total'])}**",
                    _fmt(r["cpu_s"]),
                    f"{r['registered_pct']:.0f} %",
                    f"{r['centre_rmse_pct_path']:.3f}",
                ]
            )
            + " |"
        )
    lines += ["", f"Growth exponent (log-log slope, {lo} to {hi} frames; 1 = linear):", ""]
    head = ["mapper", "total wall", "total CPU", *(label for _, label in STAGES), "SfM map CPU"]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for mapper in dict.fromkeys(r["mapper"] for r in rows):
        mine = [r for r in rows if r["mapper"] == mapper]
        n = [r["frames"] for r in mine]

        def k(values: list[float]) -> str:
            e = growth_exponent(n, values, lo, hi)
            return "—" if not math.isfinite(e) else f"{e:.2f}"

        lines.append(
            "| "
            + " | ".join(
                [
                    mapper,
                    f"**{k([r['stages_s']['total'] for r in mine])}**",
                    k([r["cpu_s"] for r in mine]),
                    *(k([r["stages_s"][key] for r in mine]) for key, _ in STAGES),
                    k([r["sfm_cpu_s"].get("map_s", float("nan")) for r in mine]),
                ]
            )
            + " |"
        )
    return lines


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", default="50,100,200,400", help="frame counts, comma-separated")
    ap.add_argument("--mappers", default="incremental,global", help="mappers, comma-separated")
    ap.add_argument("--size", default="360x640", help="clip HxW (default 360x640)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--keyframe-motion",
        type=float,
        default=None,
        metavar="PX",
        help="ingest's --keyframe-motion for every run (default: ingest's default; 0 = map every frame, as "
        "before keyframes); the RESULTS.md section is then ingest-scaling-kf<PX>",
    )
    ap.add_argument("--fit-range", default="100,400", help="LO,HI frame counts of the exponent fit")
    ap.add_argument("--out", type=Path, default=Path("out/bench_ingest_scaling"))
    ap.add_argument("--write", action="store_true", help="write the results into benchmarks/RESULTS.md")
    args = ap.parse_args()

    from seeu_data.settings import parse_dims

    frames = [int(v) for v in args.frames.split(",")]
    mappers = [m.strip() for m in args.mappers.split(",")]
    bad = [m for m in mappers if m not in ("incremental", "global", "auto")]
    if bad or any(n < 10 for n in frames):
        ap.error(f"--mappers takes incremental, global, auto (got {bad}); --frames at least 10 each")
    lo, hi = (int(v) for v in args.fit_range.split(","))
    height, width = parse_dims(args.size, "--size", minimum=16)
    load_start, t_start = _loadavg(), time.perf_counter()
    rows: list[dict] = []
    for n in frames:
        video = _clip(args.out, n, width, height, args.seed)
        for mapper in mappers:
            tag = "" if args.keyframe_motion is None else f"_kf{args.keyframe_motion:g}"
            row = run_one(video, args.out / "runs" / f"{mapper}{tag}_{n}", mapper, args.keyframe_motion)
            rows.append(row)
            print(
                f"{mapper:11s} {n:4d} frames: {row['wall_s']:7.1f} s wall, {row['cpu_s']:7.1f} s CPU, "
                + ", ".join(f"{label} {_fmt(row['stages_s'][k])}" for k, label in STAGES)
                + f" | load {row['loadavg_before']} -> {row['loadavg_after']} | {row['summary']}",
                flush=True,
            )
            doc = {"rows": rows, "loadavg_start": load_start, "fit_range": [lo, hi]}
            (args.out / "results.json").write_text(json.dumps(doc, indent=1, default=float))
    load_end, minutes = _loadavg(), (time.perf_counter() - t_start) / 60
    lines = tables(rows, lo, hi)
    print("\n".join(lines))
    print(f"load average (1/5/15 min): {load_start} before, {load_end} after; {minutes:.0f} min in all")
    if args.write:
        text = [
            f"## Ingest scaling (`benchmarks/ingest_scaling.py`): the synthetic clip at {', '.join(map(str, frames))} "
            f"frames, {width}x{height}, "
            + (
                "default `seeu ingest` per mapper"
                if args.keyframe_motion is None
                else f"`seeu ingest --keyframe-motion {args.keyframe_motion:g}` per mapper"
            ),
            "",
            f"Measured {time.strftime('%Y-%m-%d')} on {platform.machine()} with {_cpu_count()} cores, one ingest at a "
            f"time; load average (1/5/15 min) {load_start} before, {load_end} after ({minutes:.0f} min in all). "
            "Wall seconds per stage; CPU: the whole run (all processes and threads). Accuracy against the "
            "clip's ground truth (targets >= 95 % registered, centre RMSE <= 0.5 % of the path).",
            "",
            *lines,
        ]
        section = "ingest-scaling" if args.keyframe_motion is None else f"ingest-scaling-kf{args.keyframe_motion:g}"
        write_section(section, "\n".join(text))
        print("wrote the ingest-scaling section of benchmarks/RESULTS.md")
    print("note: wall times depend on machine load; re-measure on a quiet machine.")
    return 0


def _cpu_count() -> int:
    import os

    return os.cpu_count() or 1


if __name__ == "__main__":
    sys.exit(main())
