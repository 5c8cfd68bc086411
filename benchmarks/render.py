"""Rasterizer benchmark (CPU): forward+backward time and peak memory, tiled torch backend vs the
dense reference, on 2 views of pixel-aligned Gaussians (one per pixel, 1 px standard deviation).

    .venv/bin/python benchmarks/render.py            # 64^2 and 128^2 (dense at 128^2 is slow)
    .venv/bin/python benchmarks/render.py --sizes 64 --repeats 5

Prints median seconds of forward+backward, peak traced memory (tracemalloc: CPU tensors allocated
by torch are not traced, so peak RSS growth from resource is printed too) and the dense/tiled ratio
measured side by side in the same run. Target: <= 0.5 s for 64^2 on 2 cores.
"""

from __future__ import annotations

import argparse
import gc
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


def fwd_bwd(backend: str, g: Gaussians, c2w, k, size: int, tile_size: int | None) -> float:
    leaves = g.map(lambda t: t.detach().clone().requires_grad_())
    t0 = time.perf_counter()
    out = rasterize(leaves, c2w, k, size, size, backend=backend, tile_size=tile_size)
    loss = out.color.mean() + out.depth.mean() + out.alpha.mean()
    loss.backward()
    return time.perf_counter() - t0


def measure(backend: str, size: int, repeats: int, tile_size: int | None) -> tuple[float, float]:
    g, c2w, k = pixel_aligned_scene(size)
    fwd_bwd(backend, g, c2w, k, size, tile_size)  # warm-up
    gc.collect()
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    times = [fwd_bwd(backend, g, c2w, k, size, tile_size) for _ in range(repeats)]
    rss1 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return statistics.median(times), (rss1 - rss0) / 1024.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", type=int, nargs="+", default=[64, 128])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--tile-size", type=int, default=None, help="default: the backend's own (4 for torch)")
    ap.add_argument("--no-dense", action="store_true", help="skip the dense baseline")
    args = ap.parse_args()
    print(f"torch {torch.__version__}, threads {torch.get_num_threads()}, float32, 2 views, tile {args.tile_size or 'default'}")
    for size in args.sizes:
        # tiled first: the process-wide peak RSS only grows, so the dense peak is attributed after it
        t_tiled, m_tiled = measure("torch", size, args.repeats, args.tile_size)
        line = f"{size}^2 Gaussians @ {size}^2: tiled {t_tiled:.3f} s fwd+bwd (peak RSS +{m_tiled:.0f} MiB)"
        if not args.no_dense:
            t_dense, m_dense = measure("dense", size, 1 if size > 64 else args.repeats, args.tile_size)
            line += f"; dense {t_dense:.3f} s (peak RSS +{m_dense:.0f} MiB); dense/tiled = {t_dense / t_tiled:.1f}x"
        print(line, flush=True)


if __name__ == "__main__":
    main()
