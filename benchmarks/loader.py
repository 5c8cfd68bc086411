"""Streaming-loader throughput against a pixelSplat-style loader and the raw JPEG-decode limit.

Builds one data set twice in a temporary directory -- `--samples` triples of 2 context + 3 target
views, photo-like 360x640 JPEGs (~40-60 KB) -- as SeeU triple shards and as pixelSplat `.torch`
chunks (torch.save of a list of examples: url, timestamps int64 [N], cameras float32 [N, 18],
images list of uint8 tensors, key; one example per triple, so the peer loader reads no extra
frames), then measures side by side, interleaved, with DataLoader num_workers 1 and 2, batch 4,
output 256x256:

* seeu:       `seeu_data.loader.make_loader` as it comes (Arrow, image bytes by pread, OpenCV decode, bilinear cover
              resize of the kept span + centre crop with intrinsics, workers hand plain tensors
              to the DataLoader; uint8 (B, V, 3, 256, 256) batches, made float32 on the device by
              `batch_to_device` in the training/evaluation loops);
* pixelsplat: the peers' dataset code path -- `torch.load` the chunk, PIL decode + `ToTensor`,
              back to uint8 + PIL Lanczos resize to 256x455, centre crop, w2c -> c2w, default collate;
* raw:        `cv2.imdecode` of the same JPEG bytes (held in memory) and nothing else;
* references: seeu with `image_dtype="float32"` (the conversion to [0, 1] in the loader's main
              process), and raw decode + bilinear resize/crop (the least work any loader at this
              size must do).

Prints samples/s (median of `--repeats` interleaved runs), the ratios seeu/pixelsplat (target
>= 2) and seeu/raw (target >= 0.7), and each loader's CPU cost: CPU-seconds (main process plus its
DataLoader workers, user + system) per 1,000 decoded images (`cpu_s_per_1k_images`; 5 images a
sample), the figure that says how many cores a GPU's appetite needs. On a shared machine, re-measure
when it is quiet (CPU-seconds vary less under load than wall time).

Usage: .venv/bin/python benchmarks/loader.py [--samples 240] [--repeats 3] [--workers 1 2]
"""

from __future__ import annotations

import argparse
import io
import json
import os
import resource
import statistics
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import pyarrow as pa
import torch
from torch.utils.data import DataLoader, IterableDataset, get_worker_info

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from benchmarks.results_md import write_section  # noqa: E402
from seeu_data import cameras  # noqa: E402
from seeu_data.loader import make_loader  # noqa: E402
from seeu_data.store.arrow_io import write_table  # noqa: E402
from seeu_data.store.manifest import FileEntry, provenance, write_manifest  # noqa: E402
from seeu_data.store.schema import arrow_schema, schema_version  # noqa: E402
from seeu_data.store.triple_row import TripleRow  # noqa: E402

H, W, OUT = 360, 640, (256, 256)
VIEWS, CONTEXT = 5, 2


# ------------------------------------------------------------------------------------------ data


def photo_like_frames(n: int, seed: int = 0) -> list[bytes]:
    """`n` distinct 360x640 JPEGs with photo-like statistics (smooth shading, edges, texture, noise)."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        low = cv2.resize(rng.uniform(40, 215, (6, 10, 3)).astype(np.float32), (W, H), interpolation=cv2.INTER_CUBIC)
        mid = cv2.resize(rng.normal(0, 25, (45, 80, 3)).astype(np.float32), (W, H), interpolation=cv2.INTER_LINEAR)
        img = low + mid
        for _ in range(12):  # hard edges
            x0, y0 = rng.integers(0, W - 40), rng.integers(0, H - 40)
            cv2.rectangle(
                img,
                (int(x0), int(y0)),
                (int(x0 + rng.integers(20, 200)), int(y0 + rng.integers(20, 150))),
                rng.uniform(0, 255, 3).tolist(),
                -1,
            )
        img = cv2.GaussianBlur(img, (3, 3), 0) + rng.normal(0, 3, img.shape)
        ok, buf = cv2.imencode(".jpg", np.clip(img, 0, 255).astype(np.uint8), [cv2.IMWRITE_JPEG_QUALITY, 90])
        out.append(buf.tobytes())
    return out


INTRINSICS = [0.86, 1.53, 0.5, 0.5]  # RE10K-like normalised intrinsics


def make_triples(samples: int, distinct: int = 64) -> list[list[bytes]]:
    """`samples` rows of VIEWS distinct JPEGs each (drawn from `distinct` photo-like frames, fixed seeds)."""
    frames = photo_like_frames(distinct)
    rng = np.random.default_rng(1)
    return [[frames[i] for i in rng.choice(len(frames), VIEWS, replace=False)] for _ in range(samples)]


def camera_poses() -> list[np.ndarray]:
    """VIEWS camera-to-world 4x4 matrices, 0.1 apart along x."""
    poses = [np.eye(4) for _ in range(VIEWS)]
    for v, p in enumerate(poses):
        p[0, 3] = 0.1 * v
    return poses


def write_seeu_shards(shards: Path, triples: list[list[bytes]], shard_rows: int = 60) -> Path:
    """The triples as a SeeU triples dataset (Arrow shards of `shard_rows` rows + manifest) in `shards`."""
    intr, poses = INTRINSICS, camera_poses()
    schema = arrow_schema("seeu.triples")
    entries = []
    samples = len(triples)
    for k, start in enumerate(range(0, samples, shard_rows)):
        rows = [
            TripleRow(
                sample_id=f"scene{i}/interp/0",
                scene_id=f"scene{i}",
                mode="interp",
                num_context=CONTEXT,
                frame_index=np.arange(VIEWS),
                source_frame=np.arange(VIEWS),
                images=[memoryview(b) for b in triples[i]],
                image_format="jpeg",
                width=np.full(VIEWS, W),
                height=np.full(VIEWS, H),
                intrinsics_norm=np.array([intr] * VIEWS),
                cam_to_world=np.stack(poses),
                near=np.ones(VIEWS),
                far=np.full(VIEWS, 100.0),
                gap=VIEWS - 1,
                target_offset=np.zeros(VIEWS - CONTEXT, np.int64),
            ).to_pydict()
            for i in range(start, min(samples, start + shard_rows))
        ]
        path = shards / f"shard-{k:05d}.arrow"
        write_table(path, pa.Table.from_pylist(rows, schema=schema), max_chunksize=16)
        entries.append(FileEntry.for_file(shards, path, len(rows)))
    write_manifest(
        shards,
        "seeu.triples",
        schema_version("seeu.triples"),
        entries,
        params={"benchmark": True},
        provenance=provenance("benchmarks/loader.py"),
    )
    return shards


def write_pixelsplat_chunks(chunks: Path, triples: list[list[bytes]], shard_rows: int = 60) -> Path:
    """The triples as pixelSplat `.torch` chunks: world-to-camera 3x4 after fx fy cx cy 0 0."""
    intr, poses = INTRINSICS, camera_poses()
    chunks.mkdir()
    w2c = [cameras.world_to_cam_from_cam_to_world(p)[:3].reshape(-1) for p in poses]
    cams = torch.tensor(np.stack([np.concatenate([intr, [0, 0], m]) for m in w2c]), dtype=torch.float32)
    samples = len(triples)
    for k, start in enumerate(range(0, samples, shard_rows)):
        examples = [
            {
                "url": f"https://example.com/{i}",
                "timestamps": torch.arange(VIEWS, dtype=torch.int64) * 33_000,
                "cameras": cams.clone(),
                "images": [torch.frombuffer(bytearray(b), dtype=torch.uint8) for b in triples[i]],
                "key": f"scene{i}",
            }
            for i in range(start, min(samples, start + shard_rows))
        ]
        torch.save(examples, chunks / f"{k:06d}.torch")
    return chunks


def make_data(root: Path, samples: int, shard_rows: int = 60) -> tuple[Path, Path, list[list[bytes]]]:
    triples = make_triples(samples)
    shards = write_seeu_shards(root / "triples", triples, shard_rows)
    chunks = write_pixelsplat_chunks(root / "chunks", triples, shard_rows)
    return shards, chunks, triples


# -------------------------------------------------------------------------------- peer loaders


class PixelSplatStyle(IterableDataset):
    """The peers' RE10K dataset path: torch.load chunks, PIL decode, Lanczos rescale, centre crop."""

    def __init__(self, chunk_dir: Path):
        self.chunks = sorted(chunk_dir.glob("*.torch"))

    @staticmethod
    def _rescale_crop(images: torch.Tensor, shape: tuple[int, int]) -> torch.Tensor:
        from PIL import Image

        h_in, w_in = images.shape[-2:]
        scale = max(shape[0] / h_in, shape[1] / w_in)
        h_s, w_s = round(h_in * scale), round(w_in * scale)
        out = []
        for image in images:
            arr = (image * 255).clip(0, 255).type(torch.uint8).permute(1, 2, 0).numpy()
            pil = Image.fromarray(arr).resize((w_s, h_s), Image.LANCZOS)
            out.append(torch.tensor(np.array(pil) / 255, dtype=torch.float32).permute(2, 0, 1))
        scaled = torch.stack(out)
        r0, c0 = (h_s - shape[0]) // 2, (w_s - shape[1]) // 2
        return scaled[:, :, r0 : r0 + shape[0], c0 : c0 + shape[1]]

    def __iter__(self):
        from PIL import Image
        from torchvision.transforms import ToTensor

        to_tensor = ToTensor()
        info = get_worker_info()
        chunks = self.chunks if info is None else self.chunks[info.id :: info.num_workers]
        for path in chunks:
            for ex in torch.load(path, weights_only=True):
                images = torch.stack([to_tensor(Image.open(io.BytesIO(im.numpy().tobytes()))) for im in ex["images"]])
                cams = ex["cameras"]
                w2c = torch.eye(4).repeat(len(cams), 1, 1)
                w2c[:, :3] = cams[:, 6:].reshape(-1, 3, 4)
                c2w = w2c.inverse()
                images = self._rescale_crop(images, OUT)
                yield {
                    "context": {"image": images[:CONTEXT], "extrinsics": c2w[:CONTEXT]},
                    "target": {"image": images[CONTEXT:], "extrinsics": c2w[CONTEXT:]},
                    "scene": ex["key"],
                }


class RawDecode(IterableDataset):
    """OpenCV decode of the same JPEG bytes, nothing else: the decode limit (`resize=True`: plus the
    bilinear cover resize + crop, the least any loader must do; a reference, not a target)."""

    def __init__(self, triples: list[list[bytes]], batch: int, resize: bool = False):
        self.triples, self.batch, self.resize = triples, batch, resize

    def __iter__(self):
        info = get_worker_info()
        w, k = (info.id, info.num_workers) if info else (0, 1)
        batches = range(0, len(self.triples), self.batch)
        for j, start in enumerate(batches):
            if j % k != w:
                continue
            n = 0
            for views in self.triples[start : start + self.batch]:
                for b in views:
                    img = cv2.imdecode(np.frombuffer(b, np.uint8), cv2.IMREAD_COLOR)
                    if self.resize:
                        img = cv2.resize(img, (455, 256), interpolation=cv2.INTER_LINEAR)[:, 99:355]
                    n += img.shape[0] > 0
            yield torch.tensor(n)


CPU_PER_1K: dict[str, list[float]] = {}  # variant -> CPU-seconds per 1,000 images of each pass


def cpu_seconds() -> float:
    """CPU seconds (user + system) of this process and of its children that ended (DataLoader workers
    are joined when an epoch ends, so a pass's workers are counted once it is over)."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def measure(name: str, workers: int, batch: int, shards: Path, chunks: Path, triples, cache: Path) -> float:
    """samples/s of one full pass; its CPU-seconds per 1,000 images go to CPU_PER_1K[name]."""
    if name.startswith("seeu"):
        dtype = {"image_dtype": "float32"} if name == "seeu-float32" else {}  # "seeu": the defaults
        loader = make_loader(shards, batch, num_workers=workers, image_hw=OUT, seed=0, cache_dir=str(cache), **dtype)
    elif name == "pixelsplat":
        loader = DataLoader(PixelSplatStyle(chunks), batch_size=batch, num_workers=workers)
    else:
        loader = DataLoader(
            RawDecode(triples, batch, resize=name == "raw+resize"), batch_size=None, num_workers=workers
        )
    t0, c0 = time.perf_counter(), cpu_seconds()
    n = 0
    for b in loader:
        n += int(b) if name.startswith("raw") else len(b["context"]["image"])
    dt = time.perf_counter() - t0
    del loader  # no worker outlives the pass
    CPU_PER_1K.setdefault(name, []).append(1000 * (cpu_seconds() - c0) / (len(triples) * VIEWS))
    if name.startswith("raw"):
        n //= VIEWS
    assert n == len(triples), (name, n)
    return n / dt


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--samples", type=int, default=240)
    ap.add_argument("--batch", type=int, default=4)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument(
        "--variants",
        nargs="+",
        default=None,
        help="measure only these (of seeu, seeu-float32, pixelsplat, raw, raw+resize); for quick checks",
    )
    ap.add_argument("--json", type=Path, default=None, help="also write the results here")
    ap.add_argument("--write", action="store_true", help="write the loader section of benchmarks/RESULTS.md")
    args = ap.parse_args()
    torch.set_num_threads(1)
    cv2.setNumThreads(1)  # one decode per worker process for all three (and fork-safe, see dataset.py)
    with tempfile.TemporaryDirectory(prefix="seeu-loader-bench-") as tmp:
        root = Path(tmp)
        shards, chunks, triples = make_data(root, args.samples)
        kb = np.mean([len(b) for t in triples for b in t]) / 1024
        print(
            f"data: {args.samples} triples x {VIEWS} views of {H}x{W} JPEG (mean {kb:.0f} KB) -> {OUT[0]}x{OUT[1]}, "
            f"batch {args.batch}; {args.repeats} interleaved repeats, median"
        )
        cache = root / "cache"
        list(make_loader(shards, 64, image_hw=(8, 8), cache_dir=str(cache)))  # sha256 stamps + page cache
        results = {}
        lines = [
            "## Streaming loader (2 context + 3 targets, 360x640 JPEG -> 256x256, batch 4)",
            "",
            f"- machine: {os.cpu_count()} CPUs, torch {torch.__version__}, OpenCV {cv2.__version__}; "
            f"{args.samples} triples, median of {args.repeats} interleaved runs (samples/s)",
        ]
        for workers in args.workers:
            runs = {"seeu": [], "seeu-float32": [], "pixelsplat": [], "raw": [], "raw+resize": []}
            if args.variants:
                runs = {k: [] for k in args.variants}
            for _ in range(args.repeats):
                for name in runs:
                    runs[name].append(measure(name, workers, args.batch, shards, chunks, triples, cache))
            med = {k: statistics.median(v) for k, v in runs.items()}
            cpu = {k: statistics.median(CPU_PER_1K.pop(k)) for k in runs}
            cpu_line = "CPU-s per 1,000 images: " + ", ".join(f"{k} {c:.2f}" for k, c in cpu.items())
            if args.variants:  # a quick partial check: the figures, and each against raw decode if measured
                print(
                    f"workers={workers}: samples/s  "
                    + ", ".join(
                        f"{k} {m:.1f}" + (f" ({100 * m / med['raw']:.0f} % of raw)" if "raw" in med else "")
                        for k, m in med.items()
                    )
                    + "   runs: "
                    + json.dumps({k: [round(x) for x in v] for k, v in runs.items()})
                    + f"\n    {cpu_line}"
                )
                continue
            results[workers] = {
                **med,
                "seeu/pixelsplat": med["seeu"] / med["pixelsplat"],
                "seeu/raw": med["seeu"] / med["raw"],
                "seeu-float32/raw": med["seeu-float32"] / med["raw"],
                "cpu_s_per_1k_images": cpu,
                "runs": runs,
            }
            print(
                f"workers={workers}: samples/s  seeu {med['seeu']:.1f} (float32 out: {med['seeu-float32']:.1f}) | "
                f"pixelsplat-style {med['pixelsplat']:.1f} | raw decode {med['raw']:.1f} "
                f"(decode+resize {med['raw+resize']:.1f})"
            )
            print(
                f"    seeu/pixelsplat {med['seeu'] / med['pixelsplat']:.2f}x (target >= 2); seeu/raw decode "
                f"{100 * med['seeu'] / med['raw']:.0f} % (float32 out {100 * med['seeu-float32'] / med['raw']:.0f} %; "
                f"target >= 70 %); seeu/(decode+resize) {100 * med['seeu'] / med['raw+resize']:.0f} %"
            )
            print(f"    {cpu_line}")
            lines.append(
                f"- workers={workers}: seeu {med['seeu']:.1f} (float32 out {med['seeu-float32']:.1f}), "
                f"pixelSplat-style {med['pixelsplat']:.1f}, raw decode {med['raw']:.1f}, decode+resize "
                f"{med['raw+resize']:.1f}; seeu/pixelSplat {med['seeu'] / med['pixelsplat']:.2f}x, "
                f"seeu/raw {100 * med['seeu'] / med['raw']:.0f} % (float32 {100 * med['seeu-float32'] / med['raw']:.0f} %); "
                f"{cpu_line}"
            )
        if args.write:
            write_section("loader", "\n".join(lines))
        if args.json:
            args.json.write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
