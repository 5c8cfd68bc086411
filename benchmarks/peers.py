"""The streaming loader against LitData (Lightning's `litdata`) on the same triples.

One data set, written twice in a temporary directory -- `--samples` rows of 2 context + 3 target
views, photo-like 360x640 JPEGs (`benchmarks/loader.py`'s generator), the same JPEG bytes:

* seeu:    Arrow triple shards + manifest (`benchmarks/loader.py`'s writer: 60 rows per shard, what
           `seeu build` writes), read by `seeu_data.loader.make_loader`;
* litdata: `litdata.optimize()` (1 worker, chunks of 60 rows), each item
           `{"index", "img0".."img4": bytes, "intrinsics_norm": (5, 4), "cam_to_world": (5, 4, 4),
           "near", "far": (5,)}` -- the JPEGs stored as bytes (not re-encoded), read by
           `litdata.StreamingDataset(shuffle=True)` + `StreamingDataLoader`, with a `transform`
           that runs the loader's own decode + resize (`seeu_data.loader.transforms.transform_sample`:
           OpenCV decode, bilinear cover resize + centre crop, intrinsics updated) and the default collate.

Both give uint8 (4, 5, 3, 256, 256) image batches, shuffled with seed 0, at 0/1/2 workers, measured
interleaved by this one script (alternating which goes first; each pass in a fresh forked process):
samples/s of one full pass (from making the loader to the last batch), CPU time per sample (the
process tree's user + system time: less sensitive to the machine's load than samples/s), time to
first batch, peak memory of the process tree (the sum of RSS, and of PSS, which counts pages shared
by forked workers once; sampled every 50 ms in a separate pass, as the sampling itself costs CPU),
build time and bytes on disk. Local disk (page cache warm, a pass of each beforehand) and a local
moto S3 server (`moto_server` in a subprocess) with a cold cache (an empty cache directory for every
pass). LitData reaches moto through `storage_options={"endpoint_url": ...}` plus one patch for plain
http (`allow_plain_http_in_litdata`); ours through `s3://bucket/prefix?endpoint_override=host:port&scheme=http`.

Resume: each loader is stopped after `--stop-after` batches, its state saved (`state_dict()`), and a
new loader with another number of workers resumes the epoch from it; the script counts the samples
seen twice (duplicates) and never (losses) over that epoch, and checks the order against an
uninterrupted epoch.

Prints the medians of `--repeats` and the ratios seeu/litdata (targets: >= 1.5 from local disk and
>= 1.0 from S3, 2 workers); `--write` records them as the
`peers` section of benchmarks/RESULTS.md. The machine may be shared: the ratios come from runs
interleaved under the same load; the load average is printed before and after.

Needs the optional extra `peers` (`pip install -e .[peers]`: litdata) and moto (for S3).

Usage: .venv/bin/python benchmarks/peers.py [--samples 240] [--repeats 3] [--workers 0 1 2] [--no-s3]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import torch

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from benchmarks.loader import CONTEXT, INTRINSICS, OUT, VIEWS, H, W, camera_poses, make_triples, write_seeu_shards  # noqa: E402
from benchmarks.results_md import write_section  # noqa: E402
from seeu_data.loader import make_loader  # noqa: E402
from seeu_data.loader.transforms import transform_sample  # noqa: E402
from seeu_data.store.triple_row import TripleRow  # noqa: E402

SHARD_ROWS = 60
S3_ENV = {
    "AWS_ACCESS_KEY_ID": "testing",
    "AWS_SECRET_ACCESS_KEY": "testing",
    "AWS_DEFAULT_REGION": "us-east-1",
    "AWS_EC2_METADATA_DISABLED": "true",
}


# ------------------------------------------------------------------------------------ litdata side


class LitItem:
    """`optimize()`'s fn: one row of the data set as a LitData item (a picklable callable)."""

    def __init__(self, triples: list[list[bytes]]):
        self.triples = triples
        self.c2w = np.stack(camera_poses()).astype(np.float64)  # (V, 4, 4)
        self.intr = np.array([INTRINSICS] * VIEWS, dtype=np.float64)  # (V, 4)

    def __call__(self, i: int) -> dict:
        return {
            "index": i,
            **{f"img{v}": b for v, b in enumerate(self.triples[i])},
            "intrinsics_norm": self.intr,
            "cam_to_world": self.c2w,
            "near": np.ones(VIEWS, np.float32),
            "far": np.full(VIEWS, 100.0, np.float32),
        }


def lit_transform(item: dict) -> dict:
    """A LitData item -> images (V, 3, 256, 256) uint8 + cameras, by the seeu loader's own decode/resize."""
    raw = TripleRow(
        sample_id=str(item["index"]),
        scene_id="",
        mode="interp",
        num_context=CONTEXT,
        frame_index=np.arange(VIEWS),
        source_frame=np.arange(VIEWS),
        images=[memoryview(item[f"img{v}"]) for v in range(VIEWS)],
        image_format="jpeg",
        width=np.full(VIEWS, W, np.int32),
        height=np.full(VIEWS, H, np.int32),
        intrinsics_norm=item["intrinsics_norm"],
        cam_to_world=item["cam_to_world"],
        near=item["near"],
        far=item["far"],
        gap=VIEWS - 1,
        target_offset=np.zeros(VIEWS - CONTEXT, np.int64),
    )
    s = transform_sample(raw, OUT, where="litdata")
    return {
        "index": item["index"],
        "images": torch.from_numpy(s.images),
        "intrinsics_norm": torch.from_numpy(s.intrinsics_norm),
        "cam_to_world": torch.from_numpy(s.cam_to_world),
        "near": torch.from_numpy(s.near),
        "far": torch.from_numpy(s.far),
    }


def build_litdata(out: Path, triples: list[list[bytes]]) -> None:
    from litdata import optimize

    # optimize() stages chunks under $TMPDIR/chunks unless told otherwise: keep its scratch beside `out`.
    scratch = out.parent / f".{out.name}-scratch"
    env = {
        "DATA_OPTIMIZER_CACHE_FOLDER": str(scratch / "chunks"),
        "DATA_OPTIMIZER_DATA_CACHE_FOLDER": str(scratch / "data"),
    }
    saved = {k: os.environ.get(k) for k in env}
    os.environ.update(env)
    try:
        optimize(
            fn=LitItem(triples),
            inputs=list(range(len(triples))),
            output_dir=str(out),
            chunk_size=SHARD_ROWS,
            num_workers=1,
            start_method="fork",
            verbose=False,
        )
    finally:
        for k, v in saved.items():
            os.environ.pop(k) if v is None else os.environ.__setitem__(k, v)
        shutil.rmtree(scratch, ignore_errors=True)


def allow_plain_http_in_litdata() -> None:
    """Let LitData's chunk downloads reach an http:// endpoint (the local moto server).

    LitData 0.2.76 downloads chunks with obstore, built from the boto3 client's endpoint and region
    but with fixed client options (`litdata.streaming.downloader._OBSTORE_CLIENT_OPTIONS`); obstore
    refuses plain http unless the client option `allow_http` is set, and neither `storage_options`
    nor an environment variable reaches it, so every chunk GET fails ("HTTP error: builder error",
    reqwest BadScheme). Real object stores are https; this only adds `allow_http` to that dict.
    """
    from litdata.streaming import downloader

    downloader._OBSTORE_CLIENT_OPTIONS["allow_http"] = "true"


def lit_loader(url: str, workers: int, batch: int, cache: Path, storage_options: dict | None = None):
    from litdata import StreamingDataLoader, StreamingDataset

    if storage_options and storage_options.get("endpoint_url", "").startswith("http://"):
        allow_plain_http_in_litdata()
    ds = StreamingDataset(
        url, cache_dir=str(cache), shuffle=True, seed=0, transform=lit_transform, storage_options=storage_options or {}
    )
    return StreamingDataLoader(ds, batch_size=batch, num_workers=workers)


# ------------------------------------------------------------------------------------ measuring


def _tree(pid: int) -> list[int]:
    """pid and its descendants (from /proc/<pid>/task/*/children)."""
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        try:
            for task in os.listdir(f"/proc/{p}/task"):
                with open(f"/proc/{p}/task/{task}/children") as fh:
                    todo.extend(int(c) for c in fh.read().split())
        except OSError:
            pass
    return out


def _rss_pss(pids: list[int]) -> tuple[int, int]:
    rss = pss = 0
    for p in pids:
        try:
            with open(f"/proc/{p}/smaps_rollup") as fh:
                for line in fh:
                    if line.startswith("Rss:"):
                        rss += int(line.split()[1]) << 10
                    elif line.startswith("Pss:"):
                        pss += int(line.split()[1]) << 10
        except OSError:
            pass
    return rss, pss


class PeakMemory:
    """Peak RSS and PSS (bytes) of this process and its children while active, `exclude`d pids left out."""

    def __init__(self, exclude: set[int], interval: float = 0.05):
        self.exclude, self.interval = exclude, interval
        self.rss = self.pss = 0
        self._stop = threading.Event()

    def _run(self) -> None:
        while not self._stop.is_set():
            rss, pss = _rss_pss([p for p in _tree(os.getpid()) if p not in self.exclude])
            self.rss, self.pss = max(self.rss, rss), max(self.pss, pss)
            self._stop.wait(self.interval)

    def __enter__(self) -> PeakMemory:
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()


def ids_of(name: str, batch: dict) -> list[int]:
    """The row numbers of the samples of a batch (padding left out)."""
    if name == "seeu":
        return [
            int(s.removeprefix("scene").split("/")[0]) for s, p in zip(batch["sample_id"], batch["is_padding"]) if not p
        ]
    return [int(i) for i in batch["index"]]


def images_of(name: str, batch: dict) -> torch.Tensor:
    """(B, V, 3, H, W) uint8."""
    if name == "seeu":
        return torch.cat([batch["context"]["image"], batch["target"]["image"]], dim=1)
    return batch["images"]


def make(name: str, where: dict, workers: int, batch: int, cache: Path):
    if name == "seeu":
        return make_loader(where["seeu"], batch, num_workers=workers, image_hw=OUT, seed=0, cache_dir=str(cache))
    return lit_loader(where["litdata"], workers, batch, cache, where.get("storage_options"))


class _NoSampling:
    rss = pss = 0

    def __enter__(self) -> _NoSampling:
        return self

    def __exit__(self, *exc) -> None:
        pass


def cpu_seconds() -> float:
    """User + system CPU time of this process and its reaped children (the loader workers)."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def one_pass(
    name: str,
    where: dict,
    workers: int,
    batch: int,
    cache: Path,
    samples: int,
    memory: set[int] | None = None,
    maker=make,
) -> dict:
    """A full epoch: samples/s, time to first batch, CPU ms per sample of the process tree; checks that
    every sample came exactly once. `memory`: sample the peak memory, these pids left out (costly:
    reading smaps_rollup about doubles the CPU per sample, so throughput passes run without it).
    `maker(name, where, workers, batch, cache)` makes the loader (`make`: seeu or litdata)."""
    seen: list[int] = []
    with PeakMemory(memory) if memory is not None else _NoSampling() as mem:
        c0 = cpu_seconds()
        t0 = time.perf_counter()
        first = None
        for b in maker(name, where, workers, batch, cache):
            if first is None:
                first = time.perf_counter() - t0
                assert images_of(name, b).shape[1:] == (VIEWS, 3) + OUT and images_of(name, b).dtype == torch.uint8
            seen += ids_of(name, b)
        dt = time.perf_counter() - t0
        cpu = cpu_seconds() - c0
    assert sorted(seen) == list(range(samples)), (name, workers, len(seen), len(set(seen)))
    return {"samples_s": samples / dt, "first_s": first, "cpu_ms": 1000 * cpu / samples, "rss": mem.rss, "pss": mem.pss}


def in_child(fn, *args, **kwargs):
    """`fn(*args, **kwargs)` run in a forked child process, its result returned: every pass starts from
    the same state (nothing carries over from the passes before it: heap, open shards, and LitData's
    obstore runtime, which its forked workers cannot use once the parent has started it)."""
    import multiprocessing as mp

    ctx = mp.get_context("fork")
    recv, send = ctx.Pipe(duplex=False)

    def run() -> None:
        try:
            send.send(("ok", fn(*args, **kwargs)))
        except BaseException as exc:  # noqa: BLE001 - reported to the parent
            send.send(("error", f"{type(exc).__name__}: {exc}"))

    proc = ctx.Process(target=run)
    proc.start()
    send.close()
    status, value = recv.recv()
    proc.join()
    if status != "ok":
        raise RuntimeError(value)
    return value


def resume_counts(
    name: str,
    where: dict,
    batch: int,
    cache: Path,
    samples: int,
    stop_after: int,
    workers_before: int,
    workers_after: int,
    edit_state=None,
    maker=make,
) -> dict:
    """Stop after `stop_after` batches, save the state, resume with other workers: duplicates and losses,
    and whether the epoch came in the order of an uninterrupted one (with `workers_before`).

    `edit_state(state) -> state`, if given, alters the saved state (the tests use it to check the counting);
    `maker` makes the loaders, as for `one_pass`."""
    loader = maker(name, where, workers_before, batch, cache)
    seen: list[int] = []
    for k, b in enumerate(loader):
        seen += ids_of(name, b)
        if k + 1 == stop_after:
            state = loader.state_dict()
            break
    del loader
    state = json.loads(json.dumps(state))  # as a checkpoint would carry it
    if edit_state is not None:
        state = edit_state(state)
    resumed = maker(name, where, workers_after, batch, cache)
    resumed.load_state_dict(state)
    after = [i for b in resumed for i in ids_of(name, b)]
    got = seen + after
    uninterrupted = [i for b in maker(name, where, workers_before, batch, cache) for i in ids_of(name, b)]
    return {
        "before": len(seen),
        "after": len(after),
        "duplicates": len(got) - len(set(got)),
        "losses": samples - len(set(got) & set(range(samples))),
        "same_order": got == uninterrupted,
    }


# ------------------------------------------------------------------------------------ S3 (moto)


def start_moto() -> tuple[subprocess.Popen, str]:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    exe = Path(sys.executable).with_name("moto_server")
    proc = subprocess.Popen(
        [str(exe), "-H", "127.0.0.1", "-p", str(port)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    endpoint = f"http://127.0.0.1:{port}"
    import boto3

    client = boto3.client("s3", endpoint_url=endpoint, region_name="us-east-1")
    for _ in range(200):
        try:
            client.list_buckets()
            return proc, endpoint
        except Exception:  # noqa: BLE001 - not up yet
            time.sleep(0.1)
    proc.kill()
    raise RuntimeError("moto_server did not start")


def upload(endpoint: str, local: Path, bucket: str, prefix: str) -> None:
    import boto3

    client = boto3.client("s3", endpoint_url=endpoint, region_name="us-east-1")
    try:
        client.create_bucket(Bucket=bucket)
    except client.exceptions.BucketAlreadyOwnedByYou:
        pass
    for f in sorted(p for p in local.rglob("*") if p.is_file()):
        client.upload_file(str(f), bucket, f"{prefix}/{f.relative_to(local)}")


# ------------------------------------------------------------------------------------ main


def du(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


def loadavg() -> str:
    return Path("/proc/loadavg").read_text().split()[:3].__str__().replace("'", "")


def common_args(doc: str) -> argparse.ArgumentParser:
    """The options this script shares with `benchmarks/peers_mosaic.py`."""
    ap = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--samples", type=int, default=240)
    ap.add_argument("--batch", type=int, default=4)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--workers", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument(
        "--stop-after",
        type=int,
        nargs="+",
        default=[7, 37],
        help="resume test: batches before the stop (one test each)",
    )
    return ap


def main() -> int:
    ap = common_args(__doc__)
    ap.add_argument("--no-s3", action="store_true", help="local disk only")
    ap.add_argument("--json", type=Path, default=None, help="also write the results here")
    ap.add_argument("--write", action="store_true", help="write the peers section of benchmarks/RESULTS.md")
    args = ap.parse_args()
    import litdata

    torch.set_num_threads(1)
    cv2.setNumThreads(1)  # one decode per worker process for both (as benchmarks/loader.py)
    os.environ.update(S3_ENV)
    load_before = loadavg()
    print(f"load average before: {load_before}")
    moto = None
    with tempfile.TemporaryDirectory(prefix="seeu-peers-bench-") as tmp:
        root = Path(tmp)
        triples = make_triples(args.samples)
        kb = np.mean([len(b) for t in triples for b in t]) / 1024
        print(
            f"data: {args.samples} triples x {VIEWS} views of {H}x{W} JPEG (mean {kb:.0f} KB) -> {OUT[0]}x{OUT[1]}, "
            f"batch {args.batch}; {args.repeats} interleaved repeats, median"
        )
        write_seeu_shards(root / "warm-seeu", triples[:2], SHARD_ROWS)  # imports (pyarrow's pandas, ...) paid
        build_litdata(root / "warm-litdata", triples[:2])  # before the timed builds
        t = time.perf_counter()
        write_seeu_shards(root / "seeu", triples, SHARD_ROWS)
        build = {"seeu": time.perf_counter() - t}
        t = time.perf_counter()
        build_litdata(root / "litdata", triples)
        build["litdata"] = time.perf_counter() - t
        disk = {"seeu": du(root / "seeu"), "litdata": du(root / "litdata")}
        raw = sum(len(b) for tr in triples for b in tr)
        print(
            f"build: seeu {build['seeu']:.2f} s, {disk['seeu'] / 1e6:.2f} MB | litdata {build['litdata']:.2f} s, "
            f"{disk['litdata'] / 1e6:.2f} MB (JPEG bytes {raw / 1e6:.2f} MB)"
        )
        storages = {"local": {"seeu": str(root / "seeu"), "litdata": str(root / "litdata")}}
        exclude: set[int] = set()
        if not args.no_s3:
            moto, endpoint = start_moto()
            exclude.add(moto.pid)
            upload(endpoint, root / "seeu", "bench", "seeu")
            upload(endpoint, root / "litdata", "bench", "litdata")
            host = endpoint.split("://")[1]
            storages["s3"] = {
                "seeu": f"s3://bench/seeu?endpoint_override={host}&scheme=http&region=us-east-1",
                "litdata": "s3://bench/litdata",
                "storage_options": {"endpoint_url": endpoint, "region_name": "us-east-1"},
            }
        try:
            warm = root / "cache-warm"  # local: sha256 stamps + page cache, for both
            for name in ("seeu", "litdata"):
                one_pass(name, storages["local"], 0, 16, warm, args.samples)
            runs: dict[tuple, list[dict]] = {}
            for r in range(args.repeats):
                for storage, where in storages.items():
                    for workers in args.workers:
                        for name in ("seeu", "litdata") if r % 2 == 0 else ("litdata", "seeu"):
                            cache = warm if storage == "local" else root / f"cache-{name}-{storage}-{workers}-{r}"
                            res = in_child(one_pass, name, where, workers, args.batch, cache, args.samples)
                            runs.setdefault((storage, workers, name), []).append(res)
                            if storage != "local":
                                shutil.rmtree(cache, ignore_errors=True)
                print(f"repeat {r + 1}/{args.repeats} done, load {loadavg()}", flush=True)
            peak = {}  # one pass each with the memory sampler
            for storage, where in storages.items():
                for workers in args.workers:
                    for name in ("seeu", "litdata"):
                        cache = warm if storage == "local" else root / f"cache-{name}-{storage}-{workers}-mem"
                        peak[(storage, workers, name)] = in_child(
                            one_pass, name, where, workers, args.batch, cache, args.samples, memory=exclude
                        )
                        if storage != "local":
                            shutil.rmtree(cache, ignore_errors=True)
            resume = {}
            for stop in args.stop_after:
                for before, after in ((2, 1), (1, 2), (0, 2)):
                    for name in ("seeu", "litdata"):
                        try:
                            resume[(name, stop, before, after)] = resume_counts(
                                name, storages["local"], args.batch, warm, args.samples, stop, before, after
                            )
                        except Exception as exc:  # noqa: BLE001 - a peer's failure is a result to record
                            resume[(name, stop, before, after)] = {
                                "error": f"{type(exc).__name__}: {exc}".splitlines()[0]
                            }
        finally:
            if moto is not None:
                moto.terminate()
                moto.wait()
    load_after = loadavg()

    med = {k: {m: statistics.median(x[m] for x in v) for m in v[0]} for k, v in runs.items()}
    for k, v in med.items():
        v["rss"], v["pss"] = peak[k]["rss"], peak[k]["pss"]
    lines = [
        f"## Streaming loader vs LitData (`benchmarks/peers.py --repeats {args.repeats}`): the same "
        f"{args.samples} triples x {VIEWS} views, 360x640 JPEG ({kb:.0f} KB) -> 256x256, batch {args.batch}",
        "",
        f"- {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, machine: {os.cpu_count()} CPUs ({platform.processor() or platform.machine()}), "
        f"torch {torch.__version__}, OpenCV {cv2.__version__}, litdata {litdata.__version__}; "
        f"load average (1/5/15 min) {load_before} before, {load_after} after "
        "(a shared machine: compare the ratios, measured interleaved under the same load)",
        f"- both: shuffled (seed 0), the same decode + bilinear cover resize/crop (`transform_sample`), uint8 out; "
        f"samples/s of one full pass (median of {args.repeats}; the ratio is the median of the ratios of the "
        "pairs run back to back; each pass in a fresh forked process), CPU time per sample of the process "
        "tree (user + system), time to first batch, peak memory of the process tree in a separate pass "
        "(sum of RSS; PSS counts pages shared by forked workers once); S3 = a local moto server on the "
        "same machine, cold cache (an empty cache directory per pass)",
        f"- build: seeu {build['seeu']:.2f} s, {disk['seeu'] / 1e6:.2f} MB on disk; litdata `optimize()` "
        f"(1 worker) {build['litdata']:.2f} s, {disk['litdata'] / 1e6:.2f} MB (the JPEGs: {raw / 1e6:.2f} MB)",
        "",
        "| storage | workers | seeu samples/s | litdata samples/s | seeu/litdata (paired) | CPU ms/sample (seeu / litdata) "
        "| first batch s (seeu / litdata) | peak RSS MB (seeu / litdata) | peak PSS MB (seeu / litdata) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    print(
        f"\n{'storage':8} {'workers':>7} {'seeu/s':>8} {'lit/s':>8} {'ratio':>6} {'first(s/l)':>12} "
        f"{'RSS MB (s/l)':>14} {'PSS MB (s/l)':>14} {'CPU ms/sample (s/l)':>20}"
    )
    ratios = {}
    for storage in storages:
        for workers in args.workers:
            s, li = med[(storage, workers, "seeu")], med[(storage, workers, "litdata")]
            # the median of the ratios of the pairs run back to back (the load drifts between repeats)
            ratio = statistics.median(
                a["samples_s"] / b["samples_s"]
                for a, b in zip(runs[(storage, workers, "seeu")], runs[(storage, workers, "litdata")])
            )
            ratios[(storage, workers)] = ratio
            print(
                f"{storage:8} {workers:7d} {s['samples_s']:8.1f} {li['samples_s']:8.1f} {ratio:5.2f}x "
                f"{s['first_s']:5.2f}/{li['first_s']:5.2f} {s['rss'] / 2**20:6.0f}/{li['rss'] / 2**20:6.0f} "
                f"{s['pss'] / 2**20:6.0f}/{li['pss'] / 2**20:6.0f} {s['cpu_ms']:9.1f}/{li['cpu_ms']:5.1f}"
            )
            lines.append(
                f"| {storage} | {workers} | {s['samples_s']:.1f} | {li['samples_s']:.1f} | {ratio:.2f}x | "
                f"{s['cpu_ms']:.1f} / {li['cpu_ms']:.1f} | "
                f"{s['first_s']:.2f} / {li['first_s']:.2f} | {s['rss'] / 2**20:.0f} / {li['rss'] / 2**20:.0f} | "
                f"{s['pss'] / 2**20:.0f} / {li['pss'] / 2**20:.0f} |"
            )
    targets = []
    if ("local", 2) in ratios:
        targets.append(f"local, 2 workers: {ratios[('local', 2)]:.2f}x (target >= 1.5)")
    if ("s3", 2) in ratios:
        targets.append(f"S3, 2 workers: {ratios[('s3', 2)]:.2f}x (target >= 1.0)")
    print("seeu/litdata samples/s: " + "; ".join(targets))
    lines.insert(
        next(i for i, x in enumerate(lines) if x.startswith("- build")) + 1,
        "- seeu/litdata samples/s: " + "; ".join(targets),
    )
    lines += [
        "",
        "Resume (local disk): stop after k batches, `state_dict()` through JSON, a new loader with another "
        "number of workers resumes the epoch; samples seen twice (duplicates) and never (losses):",
        "",
    ]
    lines += [
        "| loader | stop after k batches | workers before -> after | samples before + after | duplicates | losses "
        "| order = uninterrupted epoch's |",
        "|---|---|---|---|---|---|---|",
    ]
    print("\nresume (stop, save, resume with other workers): samples before + after, duplicates, losses, same order")
    for (name, stop, before, after), r in resume.items():
        text = (
            f"{r['before']} + {r['after']} | {r['duplicates']} | {r['losses']} | {'yes' if r['same_order'] else 'no'}"
            if "error" not in r
            else f"fails: {r['error']} | - | - | -"
        )
        print(f"  {name:8} k={stop} {before} -> {after} workers: " + text.replace(" | ", ", "))
        lines.append(f"| {name} | {stop} | {before} -> {after} | {text} |")
    print(f"load average after: {load_after}")
    if args.write:
        write_section("peers", "\n".join(lines))
    if args.json:
        args.json.write_text(
            json.dumps(
                {
                    "build_s": build,
                    "disk_bytes": disk,
                    "load": [load_before, load_after],
                    "runs": {"/".join(map(str, k)): v for k, v in runs.items()},
                    "peak_memory": {"/".join(map(str, k)): v for k, v in peak.items()},
                    "resume": {"/".join(map(str, k)): v for k, v in resume.items()},
                },
                indent=1,
            )
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
