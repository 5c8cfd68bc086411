"""`seeu view` of a large 3DGS .ply: peak memory against the file's size.

    .venv/bin/python benchmarks/view_ply.py                 # 3 M Gaussians, SH degree 3: a 0.74 GB file
    .venv/bin/python benchmarks/view_ply.py --gaussians 200000 400000 --degree 1   # quick

Each size: a .ply of random Gaussians in the standard 3DGS layout (binary, float32, written in
chunks), then a fresh `seeu view PLY --save scene.viser` process (load, draw the MAX_GAUSSIANS most
opaque, serialise the scene; no server, no browser), its peak RSS (ru_maxrss) and wall seconds.
`seeu view` streams a binary .ply (`seeu_model.ply.load_ply(most=...)`): the peak should not grow
with the file beyond 4 bytes per Gaussian (the opacities the selection ranks).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from seeu_model.ply import ply_property_names  # noqa: E402

_PEAK = (
    "import resource, subprocess, sys; r = subprocess.run(sys.argv[1:]); "
    "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, r.returncode)"
)


def write_random_ply(path: Path, n: int, degree: int, seed: int = 0, chunk: int = 1 << 18) -> int:
    """A 3DGS .ply of `n` random Gaussians (SH `degree`); returns its size in bytes."""
    names = ply_property_names(degree)
    rng = np.random.default_rng(seed)
    header = "ply\nformat binary_little_endian 1.0\n" + f"element vertex {n}\n"
    header += "".join(f"property float {name}\n" for name in names) + "end_header\n"
    with open(path, "wb") as f:
        f.write(header.encode())
        for start in range(0, n, chunk):
            m = min(chunk, n - start)
            rows = rng.normal(scale=0.5, size=(m, len(names))).astype("<f4")
            rows[:, 0:3] = rng.normal(size=(m, 3)) * [1.0, 0.5, 0.5] + [0.0, 0.0, 4.0]
            scale = names.index("scale_0")
            rows[:, scale : scale + 3] = np.log(0.02)
            f.write(rows.tobytes())
    return path.stat().st_size


def measure(ply: Path, out: Path) -> tuple[float, float]:
    """(peak RSS in MB, wall seconds) of `seeu view PLY --save OUT` in a fresh process."""
    t0 = time.perf_counter()
    cmd = [sys.executable, "-c", _PEAK, sys.executable, "-m", "pipelines.cli", "view", str(ply), "--save", str(out)]
    done = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    peak_kb, rc = (int(v) for v in done.stdout.split()[-2:])
    if rc != 0:
        raise SystemExit(f"seeu view failed ({rc}): {done.stderr[-400:]}")
    return peak_kb / 1024, time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--gaussians", type=int, nargs="+", default=[3_000_000])
    ap.add_argument("--degree", type=int, default=3)
    args = ap.parse_args()
    print("| Gaussians | SH degree | .ply | peak RSS of `seeu view --save` | wall |")
    print("|---:|---:|---:|---:|---:|")
    with tempfile.TemporaryDirectory() as tmp:
        for n in args.gaussians:
            ply = Path(tmp) / f"g{n}.ply"
            size = write_random_ply(ply, n, args.degree)
            peak, wall = measure(ply, Path(tmp) / "scene.viser")
            print(f"| {n:,} | {args.degree} | {size / 1e9:.2f} GB | {peak:.0f} MB | {wall:.1f} s |", flush=True)
            ply.unlink()


if __name__ == "__main__":
    main()
