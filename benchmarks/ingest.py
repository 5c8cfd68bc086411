"""Benchmark `seeu ingest` (its defaults: every check on) against plain pycolmap, over several kinds of footage.

Footage (`--kinds`, each rendered once and kept under OUT/footage/; `benchmarks/footage.py`, a renderer
of its own, not the tests' `seeu_data.synthetic`, except `corridor`):

    walk      a 12 m forward walk down a street of photo-textured facades (video)
    orbit     a full circle around boxes in a walled yard, looking at the centre (video)
    pan       a tripod pan of 70 deg, 5 cm off the axis (video)
    photos    an unordered photo set around the yard, names in no order (image folder)
    walk720   the walk at 1280x720 (video)
    corridor  the project's own synthetic clip (`seeu synth`), for the figures measured before

For each kind and frame count (`--frames 90,400`: the same path sampled more densely) the two run in
turn, A B A B ... (`--pairs`), each in a process of its own (so its peak memory is its own):

    A  `seeu ingest` with its defaults, --force (decode, select, SfM child with its checks, chunks, write);
    B  what a user writes with pycolmap alone on the frames A decoded: extract_features, then
       match_sequential (a video) or match_exhaustive (photos), then incremental_mapping, all defaults.

Per run: wall seconds, CPU seconds (every process and thread), the peak of the summed resident memory
of the run's processes (sampled every 0.1 s), the stages (A: decode+select, extract, match, map (every
mapping run), final BA, register, everything after SfM; B: extract, match, map), and the accuracy against
the ground truth (registered %, camera-centre RMSE after a similarity alignment in % of the path, mean
frame-to-frame rotation error; the largest model/chunk). Printed per row: medians, the ratio A / B of the
wall medians (and of CPU), whether A's poses were identical in every run, and, for a kind run at several
frame counts, the growth exponent of the wall medians (log-log slope over every count given). Wall times
mean little on a loaded machine (load average printed before and after): CPU seconds mean more. A run
still going after `--cap` seconds (default 900) is stopped, and its time is shown as more than the cap.

Examples (quiet machine, the figures in RESULTS.md; `--write` puts the table there):
  .venv/bin/python benchmarks/ingest.py --kinds walk,orbit,pan,photos,walk720 --frames 90 --pairs 2 --write
  .venv/bin/python benchmarks/ingest.py --kinds walk --frames 50,400 --pairs 2 --write
  .venv/bin/python benchmarks/ingest.py --kinds photos --frames 11 --size 2048x3072 --pairs 2 --write
  .venv/bin/python benchmarks/ingest.py --quick            # a few minutes: does everything run?
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import signal
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.ingest_scaling import growth_exponent  # noqa: E402
from benchmarks.results_md import write_section  # noqa: E402

KINDS = ("walk", "orbit", "pan", "photos", "walk720", "corridor")
DEFAULT_SIZE = {"walk720": (720, 1280)}  # (H, W); every other kind 360x640


def footage(kind: str, frames: int, size: tuple[int, int], out: Path) -> Path:
    """The video (or photo folder) of `kind`, rendered unless already there; its ground truth beside it."""
    from benchmarks.footage import render_kind

    where = out / "footage" / f"{kind}-{frames}-{size[1]}x{size[0]}"
    if kind == "corridor":
        from seeu_data.synthetic import ClipConfig, write_clip

        video = where / "clip.mp4"
        if not video.exists():
            write_clip(video, ClipConfig(n_frames=frames, size=size, seed=0))
        return video
    return render_kind("walk" if kind == "walk720" else kind, frames, size, where)


# ------------------------------------------------------------------------------------------------
# One side of a pair, in its own process (`--one seeu|bare`): prints one JSON line
# ------------------------------------------------------------------------------------------------


def _cpu_self() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def frames_dir_of(target: Path, out: Path) -> Path:
    """Where `seeu ingest --out OUT/posed` keeps `target`'s decoded frames (bare pycolmap maps the same files)."""
    from seeu_data.ingest.video import discover_sources

    (source,) = discover_sources([target])
    return out / "posed" / ".work" / source.name / "decode" / "frames"


def run_seeu(target: Path, out: Path) -> dict:
    """A default `seeu ingest` of `target` from scratch: stages (wall; CPU of the SfM child's), accuracy, poses."""
    import hashlib

    from pipelines.ingest import IngestConfig, IngestRunConfig, ingest_scene
    from seeu_data.errors import SeeUError
    from seeu_data.ingest.video import discover_sources
    from seeu_data.synthetic import ingest_accuracy

    (source,) = discover_sources([target])
    cfg = IngestConfig(out=out / "posed", inputs=(target,), run=IngestRunConfig(force=True, heartbeat_s=0))
    try:
        report = ingest_scene(source, cfg)
    except SeeUError as exc:  # e.g. no model: a result of the benchmark too
        failed = {"stages": {}, "stages_cpu": {}, "registered_pct": 0.0, "largest": None, "poses_sha256": None}
        return {**failed, "error": str(exc)}
    t, sfm, cpu = report["timings_s"], report["sfm"]["timings_s"], report["sfm"]["cpu_timings_s"]
    in_sfm = ("extract_s", "match_s", "map_s", "final_ba_s", "register_s")
    stages = {
        "decode": t.get("decode", 0.0) + t.get("select", 0.0),
        "extract": sfm.get("extract_s", 0.0),
        "match": sfm.get("match_s", 0.0),
        "map": sfm.get("map_s", 0.0),
        "final_ba": sfm.get("final_ba_s", 0.0),
        "register": sfm.get("register_s", 0.0),
        "after_sfm": t["total"] - t.get("decode", 0.0) - t.get("select", 0.0) - sum(sfm.get(k, 0.0) for k in in_sfm),
    }
    stages_cpu = {k[:-2]: v for k, v in cpu.items()}
    result = json.loads((out / "posed" / ".work" / source.name / "sfm" / "result.json").read_text())
    poses = [(im["name"], im["world_to_cam"]) for m in result["models"] for im in m["images"]]
    acc = ingest_accuracy(report["output"], target, report["registered"], report["frames_selected"])
    return {
        "stages": stages,
        "stages_cpu": stages_cpu,
        "frames": report["frames_selected"],
        "registered_pct": acc["registered_pct"],
        "models": len(result["models"]),
        "largest": acc["largest"],
        "poses_sha256": hashlib.sha256(json.dumps(poses).encode()).hexdigest(),
        "solution_check": report["sfm"]["solution_check"].get("state"),
        "keyframes": report["sfm"].get("keyframes"),
        "matcher": report["sfm"].get("matcher"),
    }


def run_bare(frames_dir: Path, work: Path, exhaustive: bool, target: Path) -> dict:
    """extract -> sequential or exhaustive matching -> incremental mapping, pycolmap's defaults."""
    import pycolmap

    pycolmap.logging.minloglevel = 2  # COLMAP's INFO and WARNING lines off (errors still shown)
    shutil.rmtree(work, ignore_errors=True)
    (work / "sparse").mkdir(parents=True)
    db = work / "database.db"
    stages, stages_cpu = {}, {}
    for name, call in (
        ("extract", lambda: pycolmap.extract_features(db, frames_dir)),
        ("match", lambda: pycolmap.match_exhaustive(db) if exhaustive else pycolmap.match_sequential(db)),
        ("map", lambda: pycolmap.incremental_mapping(db, frames_dir, work / "sparse")),
    ):
        t0, c0 = time.perf_counter(), _cpu_self()
        recs = call()
        stages[name], stages_cpu[name] = time.perf_counter() - t0, _cpu_self() - c0
    return {"stages": stages, "stages_cpu": stages_cpu, **bare_accuracy(recs, target, len(list(frames_dir.iterdir())))}


def bare_accuracy(recs: dict, target: Path, num_frames: int) -> dict:
    """The largest model against the ground truth (frame files are named <source frame>.jpg)."""
    import numpy as np

    from seeu_data.ingest.pose_eval import pose_accuracy
    from seeu_data.synthetic import load_ground_truth

    truth = load_ground_truth(target)
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


# ------------------------------------------------------------------------------------------------
# The parent: runs the sides in turn, measures them from outside
# ------------------------------------------------------------------------------------------------


def _tree_rss_mb(pid: int) -> float:
    """Summed resident memory (MB) of `pid` and its descendants (/proc/PID/task/*/children, VmRSS)."""
    total = 0.0
    try:
        status = Path(f"/proc/{pid}/status").read_text()
        total = next((int(x.split()[1]) for x in status.splitlines() if x.startswith("VmRSS:")), 0) / 1024.0
        for task in Path(f"/proc/{pid}/task").iterdir():
            for child in (task / "children").read_text().split():
                total += _tree_rss_mb(int(child))
    except (OSError, ValueError):
        pass  # the process ended meanwhile
    return total


def measure(argv: list[str], cap_s: float) -> dict:
    """Run `argv` (one side) in a process of its own: its JSON line, wall and CPU seconds, peak memory. A run
    still going after `cap_s` seconds is stopped (its process group killed) and recorded as {"capped": cap_s}."""
    kids0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.Popen(
        [sys.executable, __file__, *argv], stdout=subprocess.PIPE, text=True, cwd=ROOT, start_new_session=True
    )
    peak = [0.0]

    def sample() -> None:
        while proc.poll() is None:
            peak[0] = max(peak[0], _tree_rss_mb(proc.pid))
            time.sleep(0.1)

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    try:
        out, _ = proc.communicate(timeout=cap_s)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        sampler.join()
        return {"capped": cap_s, "wall_s": cap_s, "cpu_s": float("nan"), "peak_mb": peak[0], "stages": {}}
    wall = time.perf_counter() - t0
    sampler.join()
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(argv)} failed (exit {proc.returncode})")
    row = json.loads(out.strip().splitlines()[-1])
    cpu = kids.ru_utime + kids.ru_stime - kids0.ru_utime - kids0.ru_stime
    return {**row, "wall_s": wall, "cpu_s": cpu, "peak_mb": peak[0]}


def _acc(side: dict) -> str:
    if side.get("capped"):
        return f"stopped after {side['capped']:.0f} s"
    if side.get("error"):
        return f"failed: {side['error'].split(': ', 1)[-1][:70]}"
    best = side.get("largest")
    if best is None:
        return f"{side['registered_pct']:.0f} %, no model"
    return f"{side['registered_pct']:.0f} %, {best['centre_rmse_pct_path']:.3f} %, {best['rel_rot_err_mean_deg']:.3f}°"


def _stages(runs: list[dict], key: str = "stages") -> str:
    med = statistics.median
    done = [r for r in runs if r.get(key)]
    if not done:
        return "stopped" if any(r.get("capped") for r in runs) else "failed"
    return ", ".join(f"{k} {med(r[key][k] for r in done):.1f}" for k in done[0][key])


def _identical(runs: list[dict]) -> str:
    """Whether the finished runs wrote identical poses ("-" when none finished)."""
    done = {x["poses_sha256"] for x in runs if not x.get("capped")}
    return str(len(done) == 1) if done else "-"


def table(rows: list[dict]) -> str:
    """RESULTS.md's table: one line per kind and frame count, then the stage breakdowns."""
    med = statistics.median
    lines = [
        "| kind | frames | size | seeu wall s | bare wall s | ratio | CPU s seeu / bare | peak MB seeu / bare "
        "| seeu: registered, centre RMSE % path, rotation | bare: same | seeu poses identical |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        a, b = r["seeu"], r["bare"]
        wa, wb = med(x["wall_s"] for x in a), med(x["wall_s"] for x in b)
        # a capped side's median is a bound: more than the cap (and the ratio a bound the other way)
        more_a, more_b = any(x.get("capped") for x in a), any(x.get("capped") for x in b)
        ratio = f"{'>' if more_a else '<' if more_b else ''}{wa / wb:.2f}×" if not (more_a and more_b) else "?"
        lines.append(
            f"| {r['kind']} | {r['frames']} | {r['size'][1]}x{r['size'][0]} | {'>' * more_a}{wa:.1f} "
            f"| {'>' * more_b}{wb:.1f} | **{ratio}** "
            f"| {med(x['cpu_s'] for x in a):.0f} / {med(x['cpu_s'] for x in b):.0f} "
            f"| {max(x['peak_mb'] for x in a):.0f} / {max(x['peak_mb'] for x in b):.0f} "
            f"| {_acc(a[-1])} | {_acc(b[-1])} | {_identical(a)} |"
        )
    lines.append("")
    lines.append("Stages, medians (wall s; seeu's SfM child also in CPU s):")
    for r in rows:
        lines.append(
            f"- {r['kind']} {r['frames']}: seeu {_stages(r['seeu'])} (CPU: {_stages(r['seeu'], 'stages_cpu')}); "
            f"bare {_stages(r['bare'])} (CPU: {_stages(r['bare'], 'stages_cpu')})"
        )
    by_kind: dict[str, list[dict]] = {}
    for r in rows:
        by_kind.setdefault(r["kind"], []).append(r)
    for kind, rs in by_kind.items():
        if len({r["frames"] for r in rs}) > 1:
            n = [r["frames"] for r in rs]
            ga = growth_exponent(n, [med(x["wall_s"] for x in r["seeu"]) for r in rs], min(n), max(n))
            gb = growth_exponent(n, [med(x["wall_s"] for x in r["bare"]) for r in rs], min(n), max(n))
            lines.append(f"- growth exponent ({kind}, {min(n)} to {max(n)} frames, wall): seeu {ga:.2f}, bare {gb:.2f}")
    return "\n".join(lines)


def _load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--kinds", default="walk,orbit,pan,photos,walk720", help=f"comma-separated, of {', '.join(KINDS)}")
    ap.add_argument("--frames", default="90", help="comma-separated frame counts")
    ap.add_argument("--size", default=None, help="HxW for every kind (default 360x640; walk720 720x1280)")
    ap.add_argument("--pairs", type=int, default=2, help="A B pairs run in turn; medians reported")
    ap.add_argument("--out", type=Path, default=Path("out/bench_ingest"))
    ap.add_argument(
        "--cap",
        type=float,
        default=900.0,
        help="stop a run still going after this many seconds (its time recorded as more than that)",
    )
    ap.add_argument("--quick", action="store_true", help="walk and photos, 30 frames 270x480, one pair")
    ap.add_argument("--write", action="store_true", help="put the table in benchmarks/RESULTS.md")
    ap.add_argument("--one", choices=("seeu", "bare"), help=argparse.SUPPRESS)
    ap.add_argument("--target", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--frames-dir", type=Path, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one == "seeu":
        print(json.dumps(run_seeu(args.target, args.out)))
        return 0
    if args.one == "bare":
        exhaustive = args.target.is_dir()
        print(json.dumps(run_bare(args.frames_dir, args.out / "bare", exhaustive, args.target)))
        return 0

    from seeu_data.settings import parse_dims

    kinds = ["walk", "photos"] if args.quick else args.kinds.split(",")
    counts = [30] if args.quick else [int(n) for n in args.frames.split(",")]
    pairs = 1 if args.quick else args.pairs
    for k in kinds:
        if k not in KINDS:
            raise SystemExit(f"--kinds: unknown kind {k!r}; one of {', '.join(KINDS)}")
    rows = []
    load_before = _load()
    for kind in kinds:
        for n in counts:
            size = (270, 480) if args.quick else DEFAULT_SIZE.get(kind, (360, 640))
            if args.size:
                size = parse_dims(args.size, "--size", minimum=16)
            t0 = time.perf_counter()
            target = footage(kind, n, size, args.out)
            print(f"{kind} {n} frames {size[1]}x{size[0]}: {target} ({time.perf_counter() - t0:.0f} s)", flush=True)
            work = args.out / "runs" / f"{kind}-{n}"
            row: dict = {"kind": kind, "frames": n, "size": size, "seeu": [], "bare": []}
            for p in range(pairs):
                a = measure(["--one", "seeu", "--target", str(target), "--out", str(work)], args.cap)
                row["seeu"].append(a)
                frames_dir = frames_dir_of(target, work)
                b = measure(
                    ["--one", "bare", "--target", str(target), "--frames-dir", str(frames_dir), "--out", str(work)],
                    args.cap,
                )
                row["bare"].append(b)
                print(
                    f"  pair {p + 1}: seeu {a['wall_s']:.1f} s ({a['cpu_s']:.0f} CPU-s, {a['peak_mb']:.0f} MB; "
                    f"{_acc(a)}), bare {b['wall_s']:.1f} s ({b['cpu_s']:.0f} CPU-s, {b['peak_mb']:.0f} MB; "
                    f"{_acc(b)}); load {_load()}",
                    flush=True,
                )
            rows.append(row)
            (args.out / "result.json").write_text(json.dumps(rows, indent=1))
    text = table(rows)
    header = (
        f"Measured {time.strftime('%Y-%m-%d')} on {os.cpu_count()} cores; load average (1/5/15 min) {load_before} "
        f"before, {_load()} after; `benchmarks/ingest.py --kinds {','.join(kinds)} --frames "
        f"{','.join(map(str, counts))} --pairs {pairs}`."
    )
    print()
    print(header)
    print(text)
    if args.write:
        name = "ingest-" + "-".join(kinds) + "-" + "-".join(map(str, counts))
        write_section(name, header + "\n\n" + text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
