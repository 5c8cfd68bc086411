"""Benchmark `seeu ingest --dynamic` on synthetic clips with moving objects against their exact masks.

1. Renders the corridor walk (default 90 frames, 640x360, seed 0) without movers and with each mover
   preset of `seeu synth --movers` (box: one box of about a tenth of the frame swinging side to side
   ahead of the camera; large: one crossing the room, up to more than half of the frame; slow: at most
   0.3 m/s; several: three of other sizes, speeds and paths; far: one crossing far ahead), each with its
   exact per-frame masks.
2. Ingests every clip with `--dynamic mask` and with `--dynamic off` (in-process, --force, the other
   settings at their defaults), in turn.
3. Prints per clip and mode: wall and CPU seconds (and the ratio to the clip without movers in the same
   mode: the goal is at most 1.5 with masking), camera centres against the ground truth (RMSE after a
   similarity alignment, % of the path: the goal is within 0.5 % with masking), the solution check's
   state and the warnings (with masking off, a clip with movers must end in a warning, not a pass),
   and with masking the masks against the truth (`seeu_data.synthetic.mask_accuracy`: pooled IoU, the
   goal >= 0.7 on the box; recall; false positives, % of all pixels, mean and worst frame: on the clip
   without movers every masked pixel is one), and whether the try mapped first without the matches on moving
   content was kept (else it was mapped again with its focal length held, then with every match). Writes
   <out>/result.json.
   With --exact-masks each clip with movers gets its exact masks as the user's own (`seeu ingest --masks`,
   which keeps SfM's features out of them).
4. With --footage KINDS: static clips of `benchmarks/footage.py` (another renderer: a street walk, an orbit, a
   tripod pan; sky, smooth walls, other textures) ingested with --dynamic mask, where every masked pixel is a
   false positive (`mask_accuracy` against a truth without movers): the mean share of the pixels, the worst
   frame, the frames with any.

Example (quiet 2-core machine, the figures in RESULTS.md):
  .venv/bin/python benchmarks/dynamic.py --out out/bench_dynamic
  .venv/bin/python benchmarks/dynamic.py --quick --out out/bench_dynamic_quick   # 30 frames 320x180, box only
  .venv/bin/python benchmarks/dynamic.py --movers "" --modes mask --footage walk,orbit,pan   # false positives only
  .venv/bin/python benchmarks/dynamic.py --movers unseen --modes mask --size 180x320   # movers never tuned on
  .venv/bin/python benchmarks/dynamic.py --movers unseen --modes mask --size 180x320 --exact-masks   # as --masks
  .venv/bin/python benchmarks/dynamic.py --movers dominant --modes mask,off --size 180x320   # filling the view
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

MODES = ("mask", "off")
# Movers the presets of `seeu synth --movers` (and the tuning of ingest) never saw, for `--movers unseen`: other
# sizes, depths, speeds and paths (seeu_data.synthetic.Mover). Each is rendered under its name here.
UNSEEN = {
    "close_big": ((1.0, 1.0, 1.0), dict(distance=1.8, amplitude=0.5, period=60)),
    "mid_cross": ((1.0, 1.2, 0.4), dict(distance=5.0, amplitude=1.5, period=70, path="crossing", y0=0.0)),
    "small_fast": ((0.3, 0.3, 0.3), dict(distance=2.0, amplitude=1.0, period=20)),
    "wall_far": ((2.2, 1.8, 0.3), dict(distance=9.0, amplitude=1.4, period=100, path="crossing", y0=0.0, phase=1.0)),
    "circler": ((0.7, 0.7, 0.7), dict(distance=3.0, amplitude=1.2, period=45, path="circle")),
    "person_x": ((0.5, 1.7, 0.3), dict(distance=4.0, amplitude=1.5, period=120, path="crossing", y0=0.1)),
    "follow": ((0.5, 1.7, 0.3), dict(distance=3.0, amplitude=0.2, period=200, y0=0.1)),
}
# Movers filling much of the view for long stretches, for `--movers dominant` (found after the rest was built).
DOMINANT = {
    "wall_follow": ((1.8, 1.6, 0.3), dict(distance=2.2, amplitude=0.5, period=150, y0=0.0)),  # ahead, half the view
    "train": ((6.0, 1.6, 0.3), dict(distance=4.0, amplitude=2.5, period=360, path="crossing", y0=0.0)),  # then all
    "near_fast": ((0.7, 0.7, 0.7), dict(distance=1.5, amplitude=0.6, period=24)),  # close, swinging fast
}
SETS = {"unseen": UNSEEN, "dominant": DOMINANT}


def presets(set_name: str) -> dict:
    """The movers of SETS[set_name] as `seeu_data.synthetic.MOVER_PRESETS` entries {name: (Mover,)}."""
    from seeu_data.synthetic import Mover

    return {name: (Mover(size, **where),) for name, (size, where) in SETS[set_name].items()}


def _cpu_s() -> float:
    """User + system CPU seconds of this process and its waited-for children (the SfM child)."""
    import resource

    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def exact_masks(video: Path, folder: Path) -> Path | None:
    """The clip's exact mover masks as a user's mask folder (`seeu ingest --masks`: <frame>.png, nonzero =
    excluded); None for a clip without movers."""
    import cv2
    import numpy as np

    from seeu_data.synthetic import load_ground_truth

    truth = load_ground_truth(video)
    if "mask" not in truth:
        return None
    folder.mkdir(parents=True, exist_ok=True)
    for frame, mask in zip(truth["frame"], truth["mask"]):
        cv2.imwrite(str(folder / f"{int(frame):06d}.png"), mask.astype(np.uint8) * 255)
    return folder


def run_clip(video: Path, out: Path, mode: str, masks: Path | None = None, focal: float | None = None) -> dict:
    """One ingest of `video` with --dynamic `mode` (and `--masks masks`, `--focal focal`) into `out`: times,
    accuracy, check, warnings, masks, the first try without the matches on moving content (report.json's
    motion.static_first), the focal length of each model over the image's longer side, how firmly the footage holds
    it (`mapping.focal_hold`) and the fitted pincushion at the corners (`solution_check.corner_pincushion_pct`)."""
    from pipelines.ingest import IngestConfig, IngestRunConfig, ingest_scene
    from seeu_data.ingest.sfm import SfmConfig
    from seeu_data.ingest.video import discover_sources
    from seeu_data.synthetic import ingest_accuracy, mask_accuracy

    cfg = IngestConfig(
        out=out,
        inputs=(video,),
        sfm=SfmConfig(dynamic=mode, focal=focal),
        run=IngestRunConfig(force=True),
        masks=None if masks is None else str(masks),
    )
    (source,) = discover_sources([video])
    c0, t0 = _cpu_s(), time.perf_counter()
    report = ingest_scene(source, cfg)
    wall, cpu = time.perf_counter() - t0, _cpu_s() - c0
    acc = ingest_accuracy(report["output"], video, report["registered"], report["frames_selected"])
    best = acc["largest"] or {}
    motion = report.get("motion") or {}
    check = report["sfm"]["solution_check"]
    return {
        "wall_s": wall,
        "cpu_s": cpu,
        "sfm_timings_s": report["sfm"]["timings_s"],
        "registered_pct": acc["registered_pct"],
        "centre_rmse_pct_path": best.get("centre_rmse_pct_path"),
        "check": check.get("state"),
        "focal_hold": check.get("focal_hold"),
        "corner_pincushion_pct": check.get("corner_pincushion_pct"),
        "warnings": report["warnings"],
        "mean_masked_pct": motion.get("mean_masked_pct"),
        "frames_masked": motion.get("frames_masked", 0),
        "masks": mask_accuracy(report["output"], video) if mode == "mask" else None,
        "static_first": motion.get("static_first"),
        "focal": [
            m["camera"]["fx"] / max(m["camera"]["width"], m["camera"]["height"]) for m in report["sfm"]["models"]
        ],
    }


def line(name: str, mode: str, r: dict, base: dict | None) -> str:
    """One row of the table."""
    if "error" in r:  # ingest ended in an error (one line, as a user sees it)
        return f"{name:8s} {mode:4s} error: {r['error']}"
    ratio = f"{r['wall_s'] / base['wall_s']:.2f}x" if base else "-"
    centre = r["centre_rmse_pct_path"]
    hold, pincushion = r.get("focal_hold"), r.get("corner_pincushion_pct")
    out = (
        f"{name:8s} {mode:4s} {r['wall_s']:7.1f} s ({ratio:>6s}) CPU {r['cpu_s']:7.1f} s  "
        f"centres {'-' if centre is None else f'{centre:.3f}'} % path  check {r['check']}  "
        f"focal {', '.join(f'{f:.3f}' for f in r['focal'])}"
        f"{'' if hold is None else f' held {hold:.3f}'}{'' if pincushion is None else f' pincushion {pincushion:+.1f} %'}"
        f"{'  WARNING' if r['warnings'] else ''}"
    )
    first = r.get("static_first") or {}
    static, held = first.get("kept"), (first.get("held") or {}).get("kept")
    if static is not None:  # mapped first without the matches on moving content
        out += (
            "  without the mover's matches"
            if static
            else "  focal length held (a second try)"
            if held
            else f"  with every match (a {'third' if 'held' in first else 'second'} try)"
        )
    m = r["masks"]
    if m:
        out += (
            f"  masks: IoU {m['iou']:.3f} recall {m['recall']:.3f} false positives {m['false_positive_pct']:.3f} % "
            f"(worst frame {m['false_positive_max_pct']:.2f} %), {r['frames_masked']} frames with any"
        )
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=90)
    ap.add_argument("--size", default="360x640", help="H x W of the rendered clips")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--movers",
        default="box,large,slow,several,far",
        help="mover presets, besides the clip without; 'unseen' or 'dominant': the movers of UNSEEN or DOMINANT",
    )
    ap.add_argument("--modes", default="mask,off", help="--dynamic modes to run, in turn")
    ap.add_argument("--quick", action="store_true", help="30 frames 180x320, the box only (a check that it runs)")
    ap.add_argument("--footage", default="", help="static kinds of benchmarks/footage.py (walk, orbit, pan) to ingest")
    ap.add_argument(
        "--exact-masks",
        action="store_true",
        help="give each clip with movers its exact masks as the user's own (seeu ingest --masks)",
    )
    ap.add_argument(
        "--known-focal",
        action="store_true",
        help="give ingest the renderer's own focal length, as a user who knows the lens (seeu ingest --focal)",
    )
    ap.add_argument("--out", type=Path, default=Path("out/bench_dynamic"))
    args = ap.parse_args()
    if args.quick:
        args.frames, args.size, args.movers = 30, "180x320", "box"

    from benchmarks.footage import render_kind
    from seeu_data.errors import SeeUError
    from seeu_data.settings import parse_dims
    from seeu_data.synthetic import ClipConfig, load_ground_truth, write_clip

    height, width = parse_dims(args.size, "--size", minimum=16)
    if args.movers in SETS:
        from seeu_data.synthetic import MOVER_PRESETS

        MOVER_PRESETS.update(presets(args.movers))
        args.movers = ",".join(SETS[args.movers])
    clips = ["none", *[m for m in args.movers.split(",") if m]]
    modes = [m for m in args.modes.split(",") if m in MODES]
    results: dict = {}
    load_before = os.getloadavg()
    for name in clips:
        video = args.out / "clips" / f"{name}.mp4"
        t0 = time.perf_counter()
        write_clip(video, ClipConfig(n_frames=args.frames, size=(height, width), seed=args.seed, movers=name))
        print(f"rendered {name}: {args.frames} frames {width}x{height} in {time.perf_counter() - t0:.1f} s", flush=True)
        masks = exact_masks(video, args.out / "exact_masks" / name) if args.exact_masks else None
        focal = None
        if args.known_focal:  # the renderer's fx is over the width
            focal = float(load_ground_truth(video)["intrinsics_norm"][0][0]) * width / max(width, height)
        for mode in modes:
            try:
                r = run_clip(video, args.out / "posed" / mode, mode, masks, focal)
            except SeeUError as e:
                r = {"error": str(e)}
            results.setdefault(name, {})[mode] = r
            print(line(name, mode, r, results["none"][mode] if name != "none" else None), flush=True)
    footage = [k for k in args.footage.split(",") if k]
    for kind in footage:
        video = render_kind(kind, args.frames, (height, width), args.out / "footage" / kind)
        results[kind] = {"mask": run_clip(video, args.out / "posed" / "footage", "mask")}
        print(line(kind, "mask", results[kind]["mask"], None), flush=True)
    print(f"\nload average before {load_before}, after {os.getloadavg()}; {os.cpu_count()} CPUs")
    print("table:")
    for name in clips:
        for mode in modes:
            print(line(name, mode, results[name][mode], results["none"][mode] if name != "none" else None))
    for kind in footage:
        print(line(kind, "mask", results[kind]["mask"], None))
    doc = {"frames": args.frames, "size": [height, width], "seed": args.seed, "results": results}
    doc["load_before"], doc["load_after"] = load_before, os.getloadavg()
    (args.out / "result.json").write_text(json.dumps(doc, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
