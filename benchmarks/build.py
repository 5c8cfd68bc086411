"""`seeu build` throughput against the bare cost: reading the same posed images and writing them with
pyarrow alone.

Creates a posed-frames dataset in a temporary directory (`--scenes` scenes x `--frames` photo-like
360x640 JPEGs, ~40-60 KB each), plans an interp build (2 context + 3 target views,
`--samples-per-scene`, ~400 MB of shards by default), then measures side by side, interleaved, `--repeats` times, one process each:

* seeu: `pipelines.build.build` with the local engine, workers 1, `seeu build`'s default on up to 4
        cores (plan, shard specs, rows with cameras and metadata, atomic IPC writes, sha256 per shard,
        manifest);
* bare: for the very same sample plan, memory-map the posed Arrow files, take the five views'
        encoded images and write them as a `list<binary>` column with `pyarrow.ipc.new_file`,
        cut into the same number of files -- no cameras, no hashing, no manifest, no atomic rename.

* seeu+fsync: the same build with `--fsync` (`BuildConfig.fsync`: every shard fsynced before its rename);
* bare+fsync: the bare copy with an fsync per file (the baseline for seeu+fsync).

Prints triples/s and MB/s (median run), the process CPU time, and the ratios seeu/bare (target
>= 0.8; seeu's default policy: atomic renames, no fsync) and seeu+fsync/bare+fsync. seeu also
hashes every shard once it is written (sha256 for the manifest, read back from the page cache), so the
ratio is bounded by about bare / (bare + sha256). With
`--resize 256x256` the seeu build decodes, resizes, crops and re-encodes (reported for information;
the bare baseline stays the copy). On a shared machine, re-measure when it is quiet.

Fresh memory on a VM (as in `benchmarks/import.py`): where the balloon driver reports free pages to
the host, writing 400 MB into page-cache pages the hypervisor took back costs ~2.5 ms per MB more, in
whichever run happens to get them (runs of the same build then vary 0.2-0.8 s). Every run therefore
starts after `os.sync()` and after touching and freeing twice the shards' size of memory (untimed);
`--prefault-mb 0` turns that off.

Usage: .venv/bin/python benchmarks/build.py [--scenes 12] [--frames 120] [--samples-per-scene 100]
                                            [--repeats 3] [--workers 1] [--resize 256x256] [--posed DIR]
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pyarrow as pa

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from pipelines.build import BuildConfig, build, plan_sampled, scan_inputs, shard_specs  # noqa: E402
from seeu_data.build.sampling import SamplingConfig  # noqa: E402
from seeu_data.build.triples import ImageOptions, ShardSpec  # noqa: E402
from seeu_data.settings import parse_dims  # noqa: E402
from seeu_data.store.posed import PosedDatasetWriter, PosedScene  # noqa: E402

H, W = 360, 640


def photo_like_scene(scene_id: str, n: int, seed: int) -> PosedScene:
    """A scene panning over a smooth textured panorama: photo-like JPEG sizes (~40-60 KB)."""
    rng = np.random.default_rng(seed)
    pano_w = W + 4 * n
    low = cv2.resize(rng.uniform(40, 215, (8, 24, 3)).astype(np.float32), (pano_w, H), interpolation=cv2.INTER_CUBIC)
    mid = cv2.resize(
        rng.normal(0, 25, (60, 180 + n, 3)).astype(np.float32), (pano_w, H), interpolation=cv2.INTER_LINEAR
    )
    pano = low + mid
    images, poses = [], []
    for i in range(n):
        frame = pano[:, 4 * i : 4 * i + W] + rng.normal(0, 4, (H, W, 3))
        ok, buf = cv2.imencode(".jpg", np.clip(frame, 0, 255).astype(np.uint8), [cv2.IMWRITE_JPEG_QUALITY, 90])
        images.append(buf.tobytes())
        pose = np.eye(4)
        pose[0, 3] = 0.02 * i
        poses.append(pose)
    return PosedScene(
        scene_id,
        images,
        "jpeg",
        np.full(n, W),
        np.full(n, H),
        np.tile([0.8, 1.4, 0.5, 0.5], (n, 1)),
        np.stack(poses),
        1.0,
        100.0,
        np.arange(n, dtype=np.int64),
        np.arange(n, dtype=np.int64) * 33_333,
    )


def bare_copy(specs: list[ShardSpec], out: Path, fsync: bool = False) -> None:
    """The bare cost: same views taken from the mmapped posed files, written as list<binary> IPC files."""
    out.mkdir(parents=True, exist_ok=True)
    tables: dict[str, pa.Table] = {}
    for spec in specs:
        parts, base = [], {}
        for sid, src in spec.sources.items():
            if src.path not in tables:
                tables[src.path] = pa.ipc.open_file(pa.memory_map(src.path, "r")).read_all()
            base[sid] = sum(p.num_rows for p in parts)
            parts.append(tables[src.path].slice(src.row_start, src.num_frames).select(["image"]))
        posed = pa.concat_tables(parts)
        flat = [base[s.scene_id] + v for s in spec.samples for v in s.views]
        images = posed.column("image").take(pa.array(flat)).combine_chunks()
        counts = [len(s.views) for s in spec.samples]
        offsets = pa.array(np.concatenate([[0], np.cumsum(counts)]).astype(np.int32))
        table = pa.table({"image": pa.ListArray.from_arrays(offsets, images)})
        with pa.OSFile(str(out / spec.file), "wb") as sink, pa.ipc.new_file(sink, table.schema) as writer:
            writer.write_table(table, max_chunksize=spec.rows_per_batch)
        if fsync:  # the same durability as seeu's writes: data on disk before the file counts as written
            with open(out / spec.file, "rb") as fh:
                os.fsync(fh.fileno())


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenes", type=int, default=12)
    p.add_argument("--frames", type=int, default=120)
    p.add_argument("--samples-per-scene", type=int, default=100)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--shard-size", type=int, default=64 << 20)
    p.add_argument("--resize", default=None, help="HxW, e.g. 256x256")
    p.add_argument("--tmp", default=None, help="working directory (default: a temporary one)")
    p.add_argument("--posed", default=None, help="keep / reuse the generated posed data in this directory")
    p.add_argument("--workers", type=int, default=1, help="seeu local engine workers (default 1: in-process)")
    p.add_argument(
        "--prefault-mb",
        type=int,
        default=None,
        help="MB of memory touched and freed before each run (default: 2x the shards' size; 0: off)",
    )
    args = p.parse_args()

    tmp = Path(tempfile.mkdtemp(prefix="seeu-bench-build-", dir=args.tmp))
    try:
        t0 = time.perf_counter()
        posed = Path(args.posed) if args.posed else tmp / "posed"
        if not (posed / "manifest.json").exists():
            with PosedDatasetWriter(posed, params={}, provenance={}) as w:
                for i in range(args.scenes):
                    w.add(photo_like_scene(f"scene{i:03d}", args.frames, i))
        posed_mb = sum(f.stat().st_size for f in posed.glob("*.arrow")) / 1e6
        print(
            f"posed data: {args.scenes} scenes x {args.frames} frames {W}x{H}, {posed_mb:.0f} MB "
            f"(made in {time.perf_counter() - t0:.1f} s)"
        )
        resize = parse_dims(args.resize, "--resize") if args.resize else None
        cfg = BuildConfig(
            inputs=(str(posed),),
            out=str(tmp / "seeu"),
            mode="interp",
            sampling=SamplingConfig(mode="interp", gap_min=25, gap_max=45, samples_per_scene=args.samples_per_scene),
            image=ImageOptions(resize=resize),
            shard_bytes=args.shard_size,
            workers=args.workers,
        )
        scenes = scan_inputs(cfg.inputs)
        specs = list(shard_specs(cfg, plan_sampled(cfg, scenes), scenes))
        n = sum(len(s.samples) for s in specs)
        est_mb = n * 5 * posed_mb / (args.scenes * args.frames)  # the shards: 5 views per triple
        prefault_mb = int(2 * est_mb) if args.prefault_mb is None else args.prefault_mb
        print(
            f"each run starts after touching and freeing {prefault_mb} MB"
            if prefault_mb
            else "no prefault: runs pay the hypervisor's cost of fresh memory"
        )
        names = ("bare", "seeu", "bare+fsync", "seeu+fsync")
        times: dict[str, list[float]] = {k: [] for k in names}
        cpu: dict[str, list[float]] = {k: [] for k in names}
        sizes: dict[str, float] = {}
        for r in range(-1, args.repeats):  # run -1 warms the page cache and imports; not timed
            for name in names if r % 2 == 0 else names[::-1]:
                out = tmp / name
                shutil.rmtree(out, ignore_errors=True)
                os.sync()  # untimed: no run pays for the previous run's write-back
                if prefault_mb:  # untimed: hot free memory for every run (see the module docstring)
                    np.ones(prefault_mb << 20, dtype=np.uint8)
                t, c = time.perf_counter(), time.process_time()
                if name.startswith("seeu"):
                    build(replace(cfg, out=str(out), fsync=name == "seeu+fsync"))
                else:
                    bare_copy(specs, out, fsync=name == "bare+fsync")
                if r >= 0:
                    times[name].append(time.perf_counter() - t)
                    cpu[name].append(time.process_time() - c)
                sizes[name] = sum(f.stat().st_size for f in out.glob("*.arrow")) / 1e6
        import hashlib

        hash_times = []
        for _ in range(3):  # the manifest's sha256 alone, over the shards seeu wrote (page cache)
            t = time.perf_counter()
            for f in sorted((tmp / "seeu").glob("*.arrow")):
                digest = hashlib.sha256()
                with open(f, "rb") as fh:
                    while block := fh.read(4 << 20):
                        digest.update(block)
            hash_times.append(time.perf_counter() - t)
        med = {k: statistics.median(v) for k, v in times.items()}
        print(
            f"{n} triples (5 views each) in {len(specs)} shards; median of {args.repeats} interleaved runs; "
            f"seeu workers {args.workers}" + (f"; seeu resizes to {args.resize}" if resize else "")
        )
        for name in names:
            print(
                f"  {name:10s} {n / med[name]:8.0f} triples/s  {sizes[name] / med[name]:8.1f} MB/s written "
                f"({sizes[name]:.0f} MB, {med[name]:.2f} s, CPU {statistics.median(cpu[name]):.2f} s; "
                f"runs {', '.join(f'{t:.2f}' for t in times[name])})"
            )
        best = {k: min(v) for k, v in times.items()}
        ratio = med["bare"] / med["seeu"]
        print(
            f"ratio seeu/bare (throughput) = {ratio:.2f} median, {best['bare'] / best['seeu']:.2f} best-of-runs  "
            f"(target >= 0.8{', copy path only' if resize else ''})"
        )
        print(
            f"ratio seeu+fsync/bare+fsync = {med['bare+fsync'] / med['seeu+fsync']:.2f} median, "
            f"{best['bare+fsync'] / best['seeu+fsync']:.2f} best-of-runs  (both fsync every file; for reference)"
        )
        print(
            f"sha256 of seeu's shards alone (read from the page cache and hashed): {min(hash_times):.2f} s "
            f"({sizes['seeu'] / 1e3 / min(hash_times):.2f} GB/s) -- the bare copy does not hash; "
            f"ratio seeu / (bare copy then sha256 of its output) = {(med['bare'] + min(hash_times)) / med['seeu']:.2f}"
        )
        print(f"machine load average: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
