"""SeeU model benchmark: encoder and renderer timed separately, after warm-up.

    .venv/bin/python benchmarks/model.py                      # CPU: forward at 2 x 256^2, paper config
    .venv/bin/python benchmarks/model.py --preset cpu_small   # the CPU-demo model
    .venv/bin/python benchmarks/model.py --preset mvsplat --cuda --write   # MVSplat's encoder (0.044 s)
    .venv/bin/python benchmarks/model.py --cuda --write       # GPU: latency vs the paper's 0.089 s,
                                                              # peak memory, bf16 training step at batch 8;
                                                              # writes its section of benchmarks/RESULTS.md

CPU: median wall seconds of `encode` (2 context views) and of rendering 3 target views (torch
backend) under torch.no_grad(), with 2 threads; the semantic encoder is randomly initialised (same
architecture and cost as the pretrained one). CUDA: the same inference (encoder + 3 target renders,
gsplat when installed) synchronised, its peak allocated memory, and one AdamW training step at
batch 8 under bf16 autocast (MSE on 3 targets; LPIPS is left out and noted).
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import statistics
import sys
import time
from pathlib import Path

import torch
import torch.nn.functional as F

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.results_md import write_section  # noqa: E402
from seeu_data.cameras import intrinsics_norm_matrix  # noqa: E402
from seeu_model.config import SeeUConfig  # noqa: E402
from seeu_model.seeu import SeeU, parameter_counts  # noqa: E402

PAPER_LATENCY_S = 0.089  # paper table 1 (H800), encoder + rendering of the 3 target views
MVSPLAT_LATENCY_S = 0.044  # the same table's MVSplat row (the `mvsplat` preset: SeeU w/o refinement)


def make_batch(b: int, v: int, t: int, size: int, device) -> dict:
    n = v + t
    c2w = torch.eye(4).repeat(b, n, 1, 1)
    for i in range(n):
        a = math.radians(-5 + 10 * i / (n - 1))
        c2w[:, i, :3, :3] = torch.tensor([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
        c2w[:, i, 0, 3] = -0.5 + i / (n - 1)
    intr = intrinsics_norm_matrix(torch.tensor([0.9, 0.9, 0.5, 0.5])).expand(b, n, 3, 3).clone()
    img = F.interpolate(
        torch.rand(b * n, 3, size // 8, size // 8), size=(size, size), mode="bilinear", align_corners=False
    ).reshape(b, n, 3, size, size)

    def views(sl):
        k = len(range(n)[sl])
        return {
            "image": img[:, sl].to(device),
            "cam_to_world": c2w[:, sl].to(device),
            "intrinsics": intr[:, sl].to(device),
            "near": torch.ones(b, k, device=device),
            "far": torch.full((b, k), 100.0, device=device),
        }

    return {"context": views(slice(0, v)), "target": views(slice(v, n))}


def sync(device):
    if device.type == "cuda":
        torch.cuda.synchronize()


CPU_SECONDS: list[float] = []  # process CPU seconds of each timed call (contention-robust on CPU)


def timed(fn, device, repeats: int) -> list[float]:
    """Wall seconds of `repeats` calls (synchronised on CUDA); CPU seconds go to CPU_SECONDS."""
    out = []
    for _ in range(repeats):
        sync(device)
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        sync(device)
        out.append(time.perf_counter() - t0)
        CPU_SECONDS.append(time.process_time() - c0)
    return out


def bench_inference(model: SeeU, batch: dict, device, repeats: int, warmup: int, backend: str) -> dict:
    size = tuple(batch["target"]["image"].shape[-2:])
    with torch.no_grad():
        for _ in range(warmup):
            g = model.encode(batch["context"])
            model.render(g, batch["target"], size, backend=backend)
        if device.type == "cuda":
            torch.cuda.reset_peak_memory_stats()
        state = {}
        CPU_SECONDS.clear()
        enc = timed(lambda: state.__setitem__("g", model.encode(batch["context"])), device, repeats)
        enc_cpu = statistics.median(CPU_SECONDS)
        CPU_SECONDS.clear()
        ren = timed(lambda: model.render(state["g"], batch["target"], size, backend=backend), device, repeats)
        ren_cpu = statistics.median(CPU_SECONDS)
        tot = timed(
            lambda: model.render(model.encode(batch["context"]), batch["target"], size, backend=backend),
            device,
            repeats,
        )
    res = {
        "encode_s": statistics.median(enc),
        "render3_s": statistics.median(ren),
        "total_s": statistics.median(tot),
        "encode_cpu_s": enc_cpu,
        "render3_cpu_s": ren_cpu,
    }
    if device.type == "cuda":
        res["peak_mem_gib"] = torch.cuda.max_memory_allocated() / 2**30
    return res


def bench_train_step(model: SeeU, batch: dict, device, repeats: int, backend: str) -> dict:
    model.train()
    opt = torch.optim.AdamW(model.trainable_parameters(), lr=2e-4)

    def step():
        with torch.autocast(device_type=device.type, dtype=torch.bfloat16):
            out = model(batch, backend=backend)
            loss = F.mse_loss(out.render.color.float(), batch["target"]["image"])
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()

    step()  # warm-up (allocations, kernel selection)
    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats()
    times = timed(step, device, repeats)
    res = {"train_step_s": statistics.median(times)}
    if device.type == "cuda":
        res["train_peak_mem_gib"] = torch.cuda.max_memory_allocated() / 2**30
    return res


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--preset", default="paper", choices=["paper", "cpu_small", "tiny", "mvsplat"])
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--views", type=int, default=2)
    ap.add_argument("--targets", type=int, default=3)
    ap.add_argument("--cuda", action="store_true", help="run on the GPU (latency, peak memory, bf16 train step)")
    ap.add_argument("--train-batch", type=int, default=8)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--warmup", type=int, default=1)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--no-render", action="store_true", help="CPU: time the encoder only")
    ap.add_argument("--write", action="store_true", help="write the model section of benchmarks/RESULTS.md")
    args = ap.parse_args()

    device = torch.device("cuda" if args.cuda else "cpu")
    if args.cuda and not torch.cuda.is_available():
        print("benchmarks/model.py: --cuda given but no CUDA device is available", file=sys.stderr)
        return 2
    if device.type == "cpu":
        torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    cfg = SeeUConfig.preset(args.preset, semantic_pretrained=False, semantic_weights=None)
    model = SeeU(cfg).to(device).eval()
    counts = parameter_counts(model)
    trainable = sum(t for t, _ in counts.values())
    frozen = sum(f for _, f in counts.values())
    backend = "auto"

    batch = make_batch(1, args.views, args.targets, args.size, device)
    lines = [
        f"## SeeU model ({args.preset}, {args.views} x {args.size}^2, {args.targets} targets)",
        "",
        f"- machine: {platform.processor() or platform.machine()}, "
        + (torch.cuda.get_device_name() if device.type == "cuda" else f"CPU, {args.threads} threads")
        + f", torch {torch.__version__}",
        f"- parameters: {trainable / 1e6:.2f} M trainable, {frozen / 1e6:.2f} M frozen (MVSplat: 12.0 M)",
    ]
    if device.type == "cpu" and args.no_render:
        with torch.no_grad():
            model.encode(batch["context"])
            CPU_SECONDS.clear()
            enc = timed(lambda: model.encode(batch["context"]), device, args.repeats)
        res = {"encode_s": statistics.median(enc), "encode_cpu_s": statistics.median(CPU_SECONDS)}
        lines.append(
            f"- CPU encode (median of {args.repeats}): {res['encode_s']:.2f} s wall, "
            f"{res['encode_cpu_s']:.2f} s CPU time"
        )
    else:
        res = bench_inference(model, batch, device, args.repeats, args.warmup, backend)
        where = "GPU" if device.type == "cuda" else "CPU"
        lines.append(
            f"- {where} inference (median of {args.repeats} after {args.warmup} warm-up): encode "
            f"{res['encode_s']:.3f} s, 3 target renders {res['render3_s']:.3f} s, together "
            f"{res['total_s']:.3f} s (paper: "
            + (
                f"MVSplat {MVSPLAT_LATENCY_S} s, SeeU {PAPER_LATENCY_S} s"
                if args.preset == "mvsplat"
                else f"{PAPER_LATENCY_S} s"
            )
            + " on an H800)"
        )
        if device.type == "cpu":
            lines.append(
                f"- CPU time (all threads): encode {res['encode_cpu_s']:.2f} s, 3 target renders "
                f"{res['render3_cpu_s']:.2f} s (wall on a busy shared machine overstates; "
                f"CPU time / threads is the idle-machine estimate)"
            )
        if "peak_mem_gib" in res:
            lines.append(f"- inference peak allocated memory: {res['peak_mem_gib']:.2f} GiB")
    if device.type == "cpu":
        preset = "" if args.preset == "paper" else f" --preset {args.preset}"
        lines.append(
            "- GPU latency / peak memory / bf16 training step at batch 8: run "
            f"`benchmarks/model.py{preset} --cuda --write` on a CUDA machine (not measured on this CPU run)"
        )
    if device.type == "cuda":
        tb = make_batch(args.train_batch, args.views, args.targets, args.size, device)
        tr = bench_train_step(model, tb, device, args.repeats, backend)
        res.update(tr)
        lines.append(
            f"- training step, batch {args.train_batch}, bf16 autocast, AdamW, MSE (no LPIPS): "
            f"{tr['train_step_s']:.3f} s, peak {tr['train_peak_mem_gib']:.2f} GiB"
        )
    text = "\n".join(lines)
    print(text)
    print(json.dumps(res))
    if args.write:
        write_section("model" if args.preset != "mvsplat" else "model-mvsplat", text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
