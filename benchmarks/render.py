"""Rasterizer benchmark (CPU): forward+backward time and peak memory, tiled torch backend vs the
dense reference, on 2 views of pixel-aligned Gaussians (one per pixel, 1 px standard deviation).

    .venv/bin/python benchmarks/render.py            # 64^2 and 128^2 (dense at 128^2 is slow)
    .venv/bin/python benchmarks/render.py --sizes 64 --repeats 5

Each measurement runs in a fresh process: median wall and CPU seconds of forward+backward, peak RSS
above the process's size after building the scene (peak CUDA allocation with --cuda; glibc's mmap
threshold is pinned to 1 MiB so freed chunk buffers go back to the OS and do not pile up), and the
dense/tiled ratio measured side by side in the same run. Target: <= 0.5 s for 64^2 on 2 cores.
With --cuda (on a GPU machine with the `cuda` extra) the torch and gsplat backends are timed too.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import resource
import statistics
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from seeu_data.cameras import unproject_pixels  # noqa: E402
from seeu_model.gaussians import Gaussians  # noqa: E402
from seeu_model.rasterizer import rasterize  # noqa: E402


def pixel_aligned_scene(size: int, views: int = 2, seed: int = 0):
    """`size`^2 Gaussians centred on the pixel centres of view 0 at depth ~2, 1 px sigma there."""
    gen = torch.Generator().manual_seed(seed)
    intr = torch.tensor([1.0, 1.0, 0.5, 0.5], dtype=torch.float64)  # f = size px
    ys, xs = torch.meshgrid(torch.arange(size) + 0.5, torch.arange(size) + 0.5, indexing="ij")
    uv = torch.stack([xs.reshape(-1), ys.reshape(-1)], -1).double()
    depth = 2.0 + 0.1 * torch.rand(size * size, generator=gen, dtype=torch.float64)
    means = unproject_pixels(uv, depth, torch.eye(4, dtype=torch.float64), intr, size, size)
    n = size * size
    g = Gaussians(
        means=means[None].float(),
        scales=(depth / size)[None, :, None].expand(1, n, 3).float().contiguous(),
        rotations=torch.randn(1, n, 4, generator=gen),
        opacities=0.2 + 0.6 * torch.rand(1, n, generator=gen),
        sh=torch.randn(1, n, 4, 3, generator=gen) * 0.3,
    )
    c2w = torch.eye(4).repeat(1, views, 1, 1)
    c2w[0, :, 0, 3] = torch.linspace(0.0, 0.05, views)  # second view slightly to the side
    from seeu_data.cameras import intrinsics_norm_matrix

    k = intrinsics_norm_matrix(intr.float()).repeat(1, views, 1, 1)
    return g, c2w, k


def fwd_bwd(backend: str, g: Gaussians, c2w, k, size: int, tile_size: int | None) -> tuple[float, float]:
    """One forward+backward; returns (wall seconds, CPU seconds of this process)."""
    leaves = g.map(lambda t: t.detach().clone().requires_grad_())
    t0, c0 = time.perf_counter(), time.process_time()
    out = rasterize(leaves, c2w, k, size, size, backend=backend, tile_size=tile_size)
    loss = out.color.mean() + out.depth.mean() + out.alpha.mean()
    loss.backward()
    if leaves.means.is_cuda:
        torch.cuda.synchronize()
    return time.perf_counter() - t0, time.process_time() - c0


def _rss_mib() -> float:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def _measure_worker(
    backend: str, size: int, repeats: int, tile_size: int | None, device: str, threads: int, queue
) -> None:
    torch.set_num_threads(threads)
    g, c2w, k = pixel_aligned_scene(size)
    g, c2w, k = g.map(lambda t: t.to(device)), c2w.to(device), k.to(device)
    base = _rss_mib()
    if device == "cuda":
        torch.cuda.reset_peak_memory_stats()
    warmup = 1 if (size <= 64 or backend != "dense") else 0  # first call: lazy init (CUDA: kernel compile)
    runs = [fwd_bwd(backend, g, c2w, k, size, tile_size) for _ in range(repeats + warmup)][warmup:]
    if device == "cuda":
        peak = torch.cuda.max_memory_allocated() / 2**20
    else:
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0 - base
    queue.put((statistics.median(r[0] for r in runs), statistics.median(r[1] for r in runs), peak))


def measure(
    backend: str, size: int, repeats: int, tile_size: int | None, device: str = "cpu", threads: int = 2
) -> tuple[float, float, float]:
    """(median wall s, median CPU s, peak memory MiB above the scene) in a fresh process, so peaks do not mix."""
    ctx = mp.get_context("spawn")
    queue = ctx.Queue()
    proc = ctx.Process(target=_measure_worker, args=(backend, size, repeats, tile_size, device, threads, queue))
    proc.start()
    result = queue.get()
    proc.join()
    return result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", type=int, nargs="+", default=[64, 128])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--tile-size", type=int, default=None, help="default: the backend's own (4 for torch)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--no-dense", action="store_true", help="skip the dense baseline")
    ap.add_argument("--cuda", action="store_true", help="also time torch and gsplat backends on the GPU")
    args = ap.parse_args()
    # glibc otherwise raises its mmap threshold after the first freed chunk buffer and keeps later ones
    # on the heap, where fragmentation inflates peak RSS several-fold (the dense 128^2 run: 17 GiB vs 0.4)
    os.environ.setdefault("MALLOC_MMAP_THRESHOLD_", str(1 << 20))  # read by the spawned workers at start
    print(
        f"torch {torch.__version__}, {args.threads} threads, float32, 2 views, tile {args.tile_size or 'default'}; "
        "times are median wall (CPU) seconds of forward+backward; memory is peak RSS above the scene "
        f"(MALLOC_MMAP_THRESHOLD_={os.environ['MALLOC_MMAP_THRESHOLD_']})"
    )
    for size in args.sizes:
        wall, cpu, mem = measure("torch", size, args.repeats, args.tile_size, threads=args.threads)
        line = f"{size}^2 Gaussians @ {size}^2: tiled {wall:.3f} s ({cpu:.3f} s CPU), {mem:.0f} MiB"
        if not args.no_dense:
            d_wall, d_cpu, d_mem = measure(
                "dense", size, args.repeats if size <= 64 else 1, args.tile_size, threads=args.threads
            )
            line += (
                f"; dense {d_wall:.3f} s ({d_cpu:.3f} s CPU), {d_mem:.0f} MiB; "
                f"dense/tiled = {d_wall / wall:.1f}x wall, {d_cpu / cpu:.1f}x CPU"
            )
        print(line, flush=True)
        if args.cuda:
            t_wall, _, t_mem = measure("torch", size, args.repeats, args.tile_size, "cuda")
            g_wall, _, g_mem = measure("gsplat", size, args.repeats, args.tile_size, "cuda")
            print(
                f"  CUDA: torch {t_wall * 1e3:.1f} ms, {t_mem:.0f} MiB; gsplat {g_wall * 1e3:.1f} ms, {g_mem:.0f} MiB; "
                f"torch/gsplat = {t_wall / g_wall:.1f}x",
                flush=True,
            )


if __name__ == "__main__":
    main()
