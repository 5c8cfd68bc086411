"""The streaming loader against MosaicML Streaming (`mosaicml-streaming`) on the same triples, local disk.

The companion of `benchmarks/peers.py` (LitData), with its data, decode and measurements: the same
`--samples` rows of 2 context + 3 target views (photo-like 360x640 JPEGs), written twice --

* seeu:   Arrow triple shards + manifest (60 rows per shard), read by `seeu_data.loader.make_loader`;
* mosaic: `streaming.MDSWriter` (no compression, shards of about 60 rows), each sample
          `{"index", "img0".."img4": bytes, "intrinsics_norm", "cam_to_world", "near", "far"}` with the
          JPEGs stored as bytes, read by `streaming.StreamingDataset(shuffle=True, shuffle_seed=0)` +
          `StreamingDataLoader`, each sample through the seeu loader's own decode + resize
          (`peers.lit_transform` -> `transform_sample`) and the default collate.

Both give uint8 (4, 5, 3, 256, 256) batches at 0/1/2 workers, measured interleaved, each pass in a
fresh forked process (`peers.in_child`, `peers.one_pass`): samples/s, CPU ms per sample of the process
tree, time to first batch. Resume: stop after `--stop-after` batches, `state_dict()` through JSON, a
new loader with other workers resumes; duplicates, losses, and the order against an uninterrupted epoch.

`mosaicml-streaming` pins numpy < 2.2 and transformers < 5, which our pins do not allow, so it is not
a dependency: run this in a separate virtualenv that sees ours, e.g.

    python -m venv /tmp/venv-mosaic
    .venv/bin/python -c "import site; print(site.getsitepackages()[0])" \\
        > /tmp/venv-mosaic/lib/python3.11/site-packages/seeu_venv.pth
    /tmp/venv-mosaic/bin/pip install --no-deps mosaicml-streaming brotli python-snappy cramjam zstd xxhash catalogue
    /tmp/venv-mosaic/bin/python benchmarks/peers_mosaic.py [--samples 240] [--repeats 3] [--workers 0 1 2]

(the package's own code runs as shipped, with numpy 2.4; the cloud clients it declares are not needed
for local disk).
"""

from __future__ import annotations

import os
import statistics
import sys
import tempfile
import time
import warnings
from pathlib import Path

import cv2
import numpy as np
import torch

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from benchmarks import peers  # noqa: E402
from benchmarks.loader import VIEWS, make_triples, write_seeu_shards  # noqa: E402

SHARD_ROWS = peers.SHARD_ROWS


def build_mosaic(out: Path, triples: list[list[bytes]]) -> None:
    from streaming import MDSWriter

    columns = {"index": "int", **{f"img{v}": "bytes" for v in range(VIEWS)}}
    columns.update({"intrinsics_norm": "ndarray", "cam_to_world": "ndarray", "near": "ndarray", "far": "ndarray"})
    row_bytes = int(np.mean([sum(len(b) for b in t) for t in triples])) + 1024
    item = peers.LitItem(triples)
    with MDSWriter(out=str(out), columns=columns, compression=None, size_limit=SHARD_ROWS * row_bytes) as writer:
        for i in range(len(triples)):
            writer.write(item(i))


def mosaic_loader(local: str, workers: int, batch: int):
    from streaming import StreamingDataLoader, StreamingDataset

    class Triples(StreamingDataset):
        def __getitem__(self, idx: int) -> dict:
            return peers.lit_transform(super().__getitem__(idx))

    dataset = Triples(local=local, shuffle=True, shuffle_seed=0, batch_size=batch)
    return StreamingDataLoader(dataset, batch_size=batch, num_workers=workers, persistent_workers=False)


def make(name: str, where: dict, workers: int, batch: int, cache: Path):
    if name == "seeu":
        return peers.make(name, where, workers, batch, cache)
    return mosaic_loader(where["mosaic"], workers, batch)


def main() -> int:
    args = peers.common_args(__doc__).parse_args()
    import streaming

    # MDS hands ndarray columns over read-only; lit_transform's torch.from_numpy warns on each
    warnings.filterwarnings("ignore", message="The given NumPy array is not writable")
    torch.set_num_threads(1)
    cv2.setNumThreads(1)
    print(f"load average before: {peers.loadavg()}; mosaicml-streaming {streaming.__version__}, numpy {np.__version__}")
    with tempfile.TemporaryDirectory(prefix="seeu-peers-mosaic-") as tmp:
        root = Path(tmp)
        triples = make_triples(args.samples)
        write_seeu_shards(root / "warm-seeu", triples[:2], SHARD_ROWS)  # imports paid before the timed builds
        build_mosaic(root / "warm-mosaic", triples[:2])
        build, disk = {}, {}
        for name, fn in (
            ("seeu", lambda p: write_seeu_shards(p, triples, SHARD_ROWS)),
            ("mosaic", lambda p: build_mosaic(p, triples)),
        ):
            t = time.perf_counter()
            fn(root / name)
            build[name] = time.perf_counter() - t
            disk[name] = peers.du(root / name)
        print(
            f"build: seeu {build['seeu']:.2f} s, {disk['seeu'] / 1e6:.2f} MB | mosaic {build['mosaic']:.2f} s, "
            f"{disk['mosaic'] / 1e6:.2f} MB; {args.samples} triples, batch {args.batch}, median of {args.repeats}"
        )
        where = {"seeu": str(root / "seeu"), "mosaic": str(root / "mosaic")}
        cache = root / "cache"
        for name in ("seeu", "mosaic"):  # page cache and sha256 stamps, for both
            peers.in_child(peers.one_pass, name, where, 0, 16, cache, args.samples, maker=make)
        runs: dict[tuple, list[dict]] = {}
        for r in range(args.repeats):
            for workers in args.workers:
                for name in ("seeu", "mosaic") if r % 2 == 0 else ("mosaic", "seeu"):
                    res = peers.in_child(
                        peers.one_pass, name, where, workers, args.batch, cache, args.samples, maker=make
                    )
                    runs.setdefault((workers, name), []).append(res)
        print(
            "| workers | seeu samples/s | mosaic samples/s | seeu/mosaic | CPU ms/sample (seeu / mosaic) | first batch s (seeu / mosaic) |"
        )
        print("|---|---|---|---|---|---|")
        for workers in args.workers:
            s, m = runs[(workers, "seeu")], runs[(workers, "mosaic")]
            ratio = statistics.median(a["samples_s"] / b["samples_s"] for a, b in zip(s, m))

            def med(v: list[dict], key: str) -> float:
                return statistics.median(x[key] for x in v)

            print(
                f"| {workers} | {med(s, 'samples_s'):.1f} | {med(m, 'samples_s'):.1f} | {ratio:.2f}x | "
                f"{med(s, 'cpu_ms'):.1f} / {med(m, 'cpu_ms'):.1f} | {med(s, 'first_s'):.2f} / {med(m, 'first_s'):.2f} |"
            )
        print(
            "| loader | stop after k batches | workers before -> after | samples before + after | duplicates | losses | order = uninterrupted epoch's |"
        )
        print("|---|---|---|---|---|---|---|")
        for stop in args.stop_after:
            for before, after in ((2, 1), (1, 2), (0, 2)):
                for name in ("seeu", "mosaic"):
                    try:
                        c = peers.in_child(
                            peers.resume_counts,
                            name,
                            where,
                            args.batch,
                            cache,
                            args.samples,
                            stop,
                            before,
                            after,
                            maker=make,
                        )
                        print(
                            f"| {name} | {stop} | {before} -> {after} | {c['before']} + {c['after']} | {c['duplicates']} | "
                            f"{c['losses']} | {'yes' if c['same_order'] else 'no'} |"
                        )
                    except Exception as exc:  # noqa: BLE001 - a peer's failure is a result to record
                        print(f"| {name} | {stop} | {before} -> {after} | error: {str(exc).splitlines()[0]} | | | |")
    print(f"load average after: {peers.loadavg()}; {os.cpu_count()} CPUs")
    return 0


if __name__ == "__main__":
    sys.exit(main())
