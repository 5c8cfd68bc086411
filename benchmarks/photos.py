"""`seeu ingest` on a folder of photos against bare pycolmap's exhaustive matching (issue #31 item 3).

For a folder of photos (e.g. MASt3R's assets/NLE_tower: 7 phone photos, 6 portrait 1000x1334 and one
landscape 1334x1000), runs once each:
   A: `seeu ingest FOLDER` in-process with its defaults (`--matcher auto`: exhaustive for an image
      folder; one camera per frame size) and `--min-chunk-frames` as given;
   B: pycolmap alone on the same photos: extract_features (camera mode AUTO: a camera per size),
      match_exhaustive, incremental_mapping, all defaults.
Prints, for each, the posed (registered) photos, the verified image pairs, the models and the wall
and CPU seconds, with the load average (os.getloadavg) before and after.

Example (the figures in RESULTS.md):
  .venv/bin/python benchmarks/photos.py /tmp/NLE_tower --min-chunk-frames 3 --out out/bench_photos
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def bare_pycolmap(image_dir: Path, work: Path) -> dict:
    """extract -> exhaustive matching -> incremental mapping with pycolmap's defaults."""
    import pycolmap

    pycolmap.logging.minloglevel = 2
    if work.exists():
        shutil.rmtree(work)
    (work / "sparse").mkdir(parents=True)
    db = work / "database.db"
    pycolmap.extract_features(db, image_dir, camera_mode=pycolmap.CameraMode.AUTO)
    pycolmap.match_exhaustive(db)
    recs = pycolmap.incremental_mapping(db, image_dir, work / "sparse")
    database = pycolmap.Database.open(db)
    pairs = int(database.num_verified_image_pairs())
    cameras = int(database.num_cameras())
    database.close()
    names = {r.image(i).name for r in recs.values() for i in r.reg_image_ids()}
    print("pycolmap: not posed:", sorted({p.name for p in image_dir.iterdir()} - names))
    posed = len(names)
    return {"posed": posed, "pairs": pairs, "models": len(recs), "cameras": cameras}


def main() -> int:
    from pipelines.ingest import IngestConfig, IngestRunConfig, ingest
    from seeu_data.ingest.chunks import ChunkConfig

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folder", type=Path)
    ap.add_argument("--out", type=Path, default=Path("out/bench_photos"))
    ap.add_argument("--min-chunk-frames", type=int, default=3)
    args = ap.parse_args()
    n = len([p for p in args.folder.iterdir() if p.suffix.lower() in (".jpg", ".jpeg", ".png")])
    print(f"{args.folder}: {n} photos; load before {os.getloadavg()[0]:.1f}")
    rows = []
    t0, c0 = time.perf_counter(), time.process_time() + _children_cpu()
    cfg = IngestConfig(
        out=args.out / "seeu",
        inputs=(args.folder,),
        chunks=ChunkConfig(min_chunk_frames=args.min_chunk_frames),
        run=IngestRunConfig(force=True),  # every stage redone: no stage reused from an earlier run
    )
    (res,) = ingest(cfg)
    wall, cpu = time.perf_counter() - t0, time.process_time() + _children_cpu() - c0
    rep = res.report
    rows.append(
        ("seeu ingest", rep["registered"], rep["sfm"]["num_verified_pairs"], len(rep["sfm"]["models"]), wall, cpu)
    )
    print(rep["summary"], "| matcher:", rep["sfm"]["matcher"]["used"], "| mapper:", rep["sfm"]["mapper"]["used"])
    print("not posed:", [d for d in rep["dropped_frames"]])
    t0, c0 = time.perf_counter(), time.process_time() + _children_cpu()
    bare = bare_pycolmap(args.folder, args.out / "bare")
    wall, cpu = time.perf_counter() - t0, time.process_time() + _children_cpu() - c0
    rows.append(("pycolmap exhaustive", bare["posed"], bare["pairs"], bare["models"], wall, cpu))
    print(f"load after {os.getloadavg()[0]:.1f}")
    print("| run | posed | verified pairs | models | wall s | CPU s |\n|---|---|---|---|---|---|")
    for name, posed, pairs, models, w, c in rows:
        print(f"| {name} | {posed}/{n} | {pairs} | {models} | {w:.1f} | {c:.1f} |")
    return 0


def _children_cpu() -> float:
    import resource

    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


if __name__ == "__main__":
    sys.exit(main())
