"""One end-to-end command timed from two checkouts side by side: A (`--old`, e.g. a `git worktree` of an
earlier commit) and B (this checkout), interleaved A B A B in fresh processes, medians.

The inputs are made once, by this checkout's benchmark scripts, with their defaults:

* build:  `seeu build` (`pipelines.build.build`, local engine, workers 1) of benchmarks/build.py's posed
          data (12 scenes x 120 photo-like 360x640 JPEGs, interp, 100 samples per scene, ~400 MB of shards);
* import: `seeu import pixelsplat` (`write_import`) of benchmarks/import.py's chunks (4 x ~100 MB);
* dl3dv:  `seeu import dl3dv --workers N` (`--workers`) of benchmarks/scale.py's DL3DV 480p stand-ins
          (`--scenes` scenes x 300 PNG frames, 73 MB a scene); its CPU column is the writer's process alone;
* loader: one epoch of `make_loader` (batch 4, 256x256 uint8, `--workers` DataLoader workers) over
          benchmarks/loader.py's 240 triples.

Every run starts after `os.sync()` and after touching and freeing twice the data's size of memory (as
in benchmarks/build.py and import.py). Each run prints its time, its CPU time and the load average;
the machine's other work adds noise to both sides alike, so read the ratio B/A of the medians.
`--fsync` times build and import with `fsync=True`.

Usage: .venv/bin/python benchmarks/ab.py --old /tmp/old build|import|dl3dv|loader [--repeats 5] [--fsync] [--workers 2]
"""

from __future__ import annotations

import argparse
import json
import os
import runpy
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

# Run in a child process with the checkout under test first on the path; prints {"s": wall, "cpu": cpu}.
CHILD = {
    "build": """
from pipelines.build import BuildConfig, build
from seeu_data.build.sampling import SamplingConfig
cfg = BuildConfig(inputs=(DATA,), out=OUT, mode="interp", workers=1, fsync=FSYNC, shard_bytes=64 << 20,
                  sampling=SamplingConfig(mode="interp", gap_min=25, gap_max=45, samples_per_scene=100))
RUN = lambda: build(cfg)
""",
    "import": """
import pyarrow as pa
from seeu_data.importers import ImportReport, write_import
from seeu_data.importers import pixelsplat as ps
pa.array([0])
RUN = lambda: write_import(ps.import_plan(ps.PixelSplatImportConfig(root=Path(DATA), stage="test")), Path(OUT),
                           ImportReport("pixelsplat"), params={}, provenance={}, fsync=FSYNC)
""",
    "dl3dv": """
from pipelines.import_data import ImportConfig, import_dataset
from seeu_data.importers.dl3dv import Dl3dvImportConfig
cfg = ImportConfig(source=Dl3dvImportConfig(root=Path(DATA), resolution="480p"), out=Path(OUT), workers=WORKERS, fsync=FSYNC)
RUN = lambda: import_dataset(cfg)
""",
    "loader": """
import cv2, torch
from seeu_data.loader import make_loader
torch.set_num_threads(1); cv2.setNumThreads(1)
def RUN():
    n = 0
    for b in make_loader(DATA, 4, num_workers=WORKERS, image_hw=(256, 256), seed=0, cache_dir=OUT + "-cache"):
        n += len(b["context"]["image"])
    assert n == 240, n
""",
}

TIMED = """
import json, os, sys, time
from pathlib import Path
DATA, OUT, FSYNC, WORKERS, PREFAULT = sys.argv[1], sys.argv[2], sys.argv[3] == "1", int(sys.argv[4]), int(sys.argv[5])
{setup}
import numpy as np
np.ones(PREFAULT << 20, dtype=np.uint8)
c, t = time.process_time(), time.perf_counter()
RUN()
print(json.dumps({{"s": time.perf_counter() - t, "cpu": time.process_time() - c}}))
"""


def make_inputs(command: str, tmp: Path, scenes: int) -> tuple[Path, int]:
    """The command's input in `tmp` (made by this checkout's benchmark scripts) and its size in MB."""
    sys.path.insert(0, str(ROOT))
    if command == "dl3dv":
        from benchmarks.scale import write_dl3dv

        return tmp / "dl3dv", int(write_dl3dv(tmp / "dl3dv", scenes, 300, "480p") / 1e6)
    if command == "build":
        from benchmarks.build import photo_like_scene
        from seeu_data.store.posed import PosedDatasetWriter

        with PosedDatasetWriter(tmp / "posed", params={}, provenance={}) as w:
            for i in range(12):
                w.add(photo_like_scene(f"scene{i:03d}", 120, i))
        return tmp / "posed", 400
    if command == "import":
        make_dataset = runpy.run_path(str(ROOT / "benchmarks" / "import.py"))["make_dataset"]
        nbytes, _ = make_dataset(tmp / "chunks", 4, 100.0)
        return tmp / "chunks", int(nbytes / 1e6)
    from benchmarks.loader import make_data

    shards, _, _ = make_data(tmp / "loader", 240)
    return shards, 100


def run(tree: Path, command: str, data: Path, out: Path, fsync: bool, workers: int, prefault: int) -> dict:
    shutil.rmtree(out, ignore_errors=True)
    os.sync()  # untimed: no run pays for the previous run's write-back
    code = TIMED.format(setup=CHILD[command])
    argv = [sys.executable, "-c", code, str(data), str(out), str(int(fsync)), str(workers), str(prefault)]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, (str(tree), os.environ.get("PYTHONPATH"))))}
    res = subprocess.run(argv, cwd=tree, env=env, capture_output=True, text=True)
    if res.returncode:
        raise SystemExit(f"{tree}: {res.stderr[-2000:]}")
    shutil.rmtree(out, ignore_errors=True)
    return {**json.loads(res.stdout.strip().splitlines()[-1]), "load": os.getloadavg()[0]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("command", choices=sorted(CHILD))
    ap.add_argument("--old", type=Path, required=True, help="the checkout timed as A")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--fsync", action="store_true")
    ap.add_argument("--workers", type=int, default=2, help="loader: DataLoader workers; dl3dv: import workers")
    ap.add_argument("--scenes", type=int, default=8, help="dl3dv: scenes")
    args = ap.parse_args()
    trees = {"A": args.old.resolve(), "B": ROOT}
    with tempfile.TemporaryDirectory(prefix="seeu-ab-") as tmp:
        data, mb = make_inputs(args.command, Path(tmp), args.scenes)
        runs: dict[str, list[dict]] = {"A": [], "B": []}
        for r in range(-1, args.repeats):  # run -1 warms the page cache and the imports; not counted
            for side in ("A", "B"):
                res = run(trees[side], args.command, data, Path(tmp) / "out", args.fsync, args.workers, 2 * mb)
                print(f"  {side} {res['s']:7.3f} s  CPU {res['cpu']:7.3f} s  load {res['load']:.2f}", flush=True)
                if r >= 0:
                    runs[side].append(res)
    med = {k: statistics.median(x["s"] for x in v) for k, v in runs.items()}
    cpu = {k: statistics.median(x["cpu"] for x in v) for k, v in runs.items()}
    loads = [x["load"] for v in runs.values() for x in v]
    what = (
        args.command
        + (" --fsync" if args.fsync else "")
        + (f" workers {args.workers}" if args.command in ("loader", "dl3dv") else "")
        + (f" {args.scenes} scenes" if args.command == "dl3dv" else "")
    )
    print(
        f"{what}: A {med['A']:.3f} s (CPU {cpu['A']:.3f}), B {med['B']:.3f} s (CPU {cpu['B']:.3f}); "
        f"B/A time {med['B'] / med['A']:.2f}x (CPU {cpu['B'] / cpu['A']:.2f}x); median of {args.repeats} "
        f"A B pairs; load average {min(loads):.1f}-{max(loads):.1f} on {os.cpu_count()} cores"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
