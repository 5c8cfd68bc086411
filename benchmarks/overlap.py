"""View choice by overlap on the test scenes with exact cameras: for each of the synthetic 24-view
orbit (in order, and shuffled and renamed) and the 10-view wide-baseline set, the median Sampson
error `seeu check-cameras` finds and the pairs it matched, the context pair `seeu predict
--auto-context` picks, and the context-pair overlaps of a default `seeu build` -- each by the stored
table and by the exact overlap of the scene (`synthetic.true_overlap`); plus the overlap measures
against the exact overlap. These are not timings: any machine gives the same numbers.

    python benchmarks/overlap.py            # 160x120 views, as the tests
    python benchmarks/overlap.py --write    # and the "overlap" section of benchmarks/RESULTS.md
    python benchmarks/overlap.py --timing   # CPU seconds of the cameras measure per scene (50-300 frames): a timing,
                                            # to run on a quiet machine (what every importer adds per scene)
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.results_md import write_section  # noqa: E402
from pipelines.build import BuildConfig, build  # noqa: E402
from pipelines.predict import auto_context_pair  # noqa: E402
from seeu_data.build.triples import TripleShards  # noqa: E402
from seeu_data.camera_check import CameraCheckConfig, check_cameras  # noqa: E402
from seeu_data.overlap import camera_overlap_matrix  # noqa: E402
from seeu_data.store.manifest import provenance  # noqa: E402
from seeu_data.store.posed import PosedDataset, PosedDatasetWriter  # noqa: E402
from seeu_data.synthetic import make_orbit_scene, synthetic_posed_scene, true_overlap, wide_camera_set  # noqa: E402


def scenes(root: Path, h: int, w: int) -> dict:
    """The three posed datasets (exact cameras and tracks) and their exact overlap matrices."""
    orbit = synthetic_posed_scene(24, h, w, scene_id="orbit", world="orbit", tracks=True)
    order = np.random.default_rng(7).permutation(24)
    frame, point = orbit.observations  # type: ignore[misc]
    shuffled = replace(
        orbit,
        images=[orbit.images[i] for i in order],
        cam_to_world=orbit.cam_to_world[order],
        intrinsics_norm=orbit.intrinsics_norm[order],
        source_name=[f"photo_{k}.jpg" for k in range(24)],
        observations=(np.argsort(order)[frame], point),
    )
    wide = synthetic_posed_scene(10, h, w, scene_id="wide", world="orbit", poses=wide_camera_set(10), tracks=True)
    world = make_orbit_scene(0)
    truth = true_overlap(world, orbit.cam_to_world, orbit.intrinsics_norm)
    out = {}
    for name, scene, t in (
        ("orbit (24, in order)", orbit, truth),
        ("orbit shuffled + renamed", shuffled, truth[np.ix_(order, order)]),
        ("wide (10, no path order)", wide, true_overlap(world, wide.cam_to_world, wide.intrinsics_norm)),
    ):
        path = root / scene.scene_id / name.split()[1]
        with PosedDatasetWriter(path, {"benchmark": True}, provenance("benchmarks/overlap.py")) as wr:
            wr.add(scene)
        out[name] = (path, scene.scene_id, t)
    return out


def pair_score(m: np.ndarray, a: int, b: int) -> float:
    return float(min(m[a, b], m[b, a]))


def measure(root: Path, h: int, w: int) -> list[dict]:
    rows = []
    for name, (path, sid, truth) in scenes(root, h, w).items():
        ds = PosedDataset(path)
        stored = ds.overlap(sid).matrix()
        scene = ds.load_scene(sid)
        cams = camera_overlap_matrix(scene.cam_to_world, scene.intrinsics_norm, scene.near, scene.far)
        check = check_cameras(CameraCheckConfig(path=path))["scenes"][0]
        used = [d for d in check["pair_details"] if d["used"]]
        (i, j), _, _ = auto_context_pair(ds.overlap(sid), scene.cam_to_world, scene.intrinsics_norm)
        manifest = build(BuildConfig(inputs=(str(path),), out=root / f"shards_{sid}_{len(rows)}", workers=1))
        ctx = [r.context for r in TripleShards(root / f"shards_{sid}_{len(rows)}").rows()]
        rows.append(
            {
                "scene": name,
                "check_verdict": check["verdict"],
                "median_sampson_px": check["median_error_px"],
                "check_pairs": [
                    (d["frames"], round(d["overlap"], 2), round(pair_score(truth, *d["frames"]), 2)) for d in used
                ],
                "auto_context": ([i, j], round(pair_score(stored, i, j), 2), round(pair_score(truth, i, j), 2)),
                "build_triples": manifest["total_rows"],
                "build_pairs": [(round(pair_score(stored, *c), 2), round(pair_score(truth, *c), 2)) for c in ctx],
                "stored_vs_truth_median": float(np.median(np.abs(stored - truth))),
                "cameras_vs_truth_median": float(np.median(np.abs(cams - truth))),
            }
        )
    return rows


def table(rows: list[dict], h: int, w: int) -> str:
    lines = [
        "## View choice by overlap (test scenes with exact cameras)",
        "",
        f"`python benchmarks/overlap.py --write`: views {w}x{h}; overlaps as stored table / exact (rendered depth).",
        "Median Sampson error of `seeu check-cameras`, the overlaps of the pairs it matched, the pair",
        "`seeu predict --auto-context` picks, and the context pairs of a default `seeu build` (4 triples);",
        "last two columns: median |error| of the stored table (exact tracks) and of the cameras measure.",
        "",
        "| scene | check-cameras | matched pairs (stored / exact) | auto-context | build context pairs | stored err | cameras err |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        pairs = ", ".join(f"{a:.2f}/{b:.2f}" for _, a, b in r["check_pairs"])
        auto = r["auto_context"]
        built = ", ".join(f"{a:.2f}/{b:.2f}" for a, b in r["build_pairs"])
        lines.append(
            f"| {r['scene']} | {r['check_verdict']}, {r['median_sampson_px']:.2f} px | {pairs} | "
            f"{auto[0]}: {auto[1]:.2f}/{auto[2]:.2f} | {built} | {r['stored_vs_truth_median']:.3f} | "
            f"{r['cameras_vs_truth_median']:.3f} |"
        )
    return "\n".join(lines) + "\n"


def timing(repeats: int = 3) -> str:
    """CPU seconds (best of `repeats`) of `overlap_from_cameras` on a walk of 50, 150 and 300 frames
    (RE10K scenes hold about 50-300), and the stored pairs."""
    import time

    from seeu_data.overlap import overlap_from_cameras
    from seeu_data.synthetic import camera_path, default_intrinsics_norm

    lines = ["| frames | CPU s per scene | pairs stored |", "|---|---|---|"]
    for n in (50, 150, 300):
        poses, intr = camera_path(n), np.tile(default_intrinsics_norm(640, 360), (n, 1))
        best, pairs = float("inf"), 0
        for _ in range(repeats):
            t0 = time.process_time()
            pairs = len(overlap_from_cameras(poses, intr, 1.0, 100.0))
            best = min(best, time.process_time() - t0)
        lines.append(f"| {n} | {best:.3f} | {pairs} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="120x160", help="HxW of the views (default 120x160, as the tests)")
    ap.add_argument("--json", action="store_true", help="print the measurements as JSON")
    ap.add_argument("--write", action="store_true", help="write the 'overlap' section of benchmarks/RESULTS.md")
    ap.add_argument("--timing", action="store_true", help="only time the cameras measure (print; a quiet machine's)")
    args = ap.parse_args()
    if args.timing:
        print(timing())
        return
    h, w = (int(v) for v in args.size.split("x"))
    with tempfile.TemporaryDirectory() as tmp:
        rows = measure(Path(tmp), h, w)
    text = table(rows, h, w)
    print(json.dumps(rows, indent=1) if args.json else text)
    if args.write:
        write_section("overlap", text)


if __name__ == "__main__":
    main()
