"""Training throughput, peak memory and evaluation latency of `seeu train` / `seeu eval`.

Builds synthetic triple shards (the built-in corridor, exact cameras), trains a preset for a few
steps through the real pipeline (loader -> SeeU -> rasterizer -> loss -> AdamW), and reports
it/s after warm-up, peak memory (CUDA max allocated, or CPU peak RSS) and the evaluation latency
(encoder and renderer separately, after warm-up). On CUDA the rasterizer is gsplat (auto) and
training runs under bf16 autocast.

  .venv/bin/python benchmarks/train.py --config configs/cpu_small.json --size 64 --batch 2 --steps 6
  .venv/bin/python benchmarks/train.py --config configs/re10k_paper.json --size 256 --batch 8 --steps 30 \
      --write model.semantic_pretrained=false           # on a CUDA GPU (no DINOv3 weights at hand)
--write replaces the <!-- train:begin/end --> section of benchmarks/RESULTS.md.
"""

from __future__ import annotations

import argparse
import json
import platform
import resource
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", default=str(ROOT / "configs" / "cpu_small.json"))
    ap.add_argument("--out", type=Path, default=Path("/tmp/seeu_bench_train"))
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--batch", type=int, default=2)
    ap.add_argument("--steps", type=int, default=6)
    ap.add_argument("--warmup-steps", type=int, default=2, help="steps not counted in it/s")
    ap.add_argument("--eval-samples", type=int, default=4)
    ap.add_argument("--write", action="store_true")
    ap.add_argument("overrides", nargs="*")
    a = ap.parse_args()

    import torch

    from benchmarks.train_learning import make_data
    from pipelines.evaluate import EvalConfig, evaluate
    from pipelines.train import TrainRunConfig, train

    a.out.mkdir(parents=True, exist_ok=True)
    train_data, test_data = make_data(a.out, 32, a.size, 2)
    ov = list(a.overrides) + [
        f"data.image_size=[{a.size},{a.size}]",
        f"data.batch_size={a.batch}",
        f"optim.max_steps={a.steps}",
        "log.every=1",
        f"checkpoint.every={a.steps}",
        "loss.lpips_weight=0",
    ]
    run = a.out / f"run_{int(time.time())}"
    cpu0 = time.process_time()
    res = train(TrainRunConfig(data=train_data, out=run, config=a.config, overrides=ov, progress=False))
    cpu_train = time.process_time() - cpu0
    hist = res["history"][a.warmup_steps :]
    its = len(hist) / sum(1.0 / h["it_per_s"] for h in hist) if hist else float("nan")
    cuda = torch.cuda.is_available()
    peak_train = (
        torch.cuda.max_memory_allocated() / 2**20 if cuda else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    )
    ev = evaluate(
        EvalConfig(
            checkpoint=res["checkpoint"],
            data=test_data,
            out=run / "eval",
            max_samples=a.eval_samples,
            lpips=False,
            warmup=2,
            progress=False,
        )
    )
    report = {
        "device": res["device"],
        "torch": torch.__version__,
        "threads": torch.get_num_threads(),
        "config": a.config,
        "overrides": ov,
        "size": a.size,
        "batch": a.batch,
        "steps": res["step"],
        "train_it_per_s": its,
        "train_samples_per_s": its * a.batch,
        "train_cpu_seconds": cpu_train,
        "train_wall_seconds": res["seconds"],
        "peak_train_memory_mb": peak_train,
        "eval": ev["timing"],
        "gpu": torch.cuda.get_device_name() if cuda else None,
    }
    print(json.dumps(report, indent=2))
    if a.write:
        t = ev["timing"]
        section = "\n".join(
            [
                "<!-- train:begin -->",
                f"## Training and evaluation (`benchmarks/train.py`, {Path(a.config).name}, {a.size}^2, batch {a.batch})",
                "",
                f"- machine: {platform.machine()}, {report['gpu'] or 'CPU'}, {report['threads']} threads, torch {torch.__version__}",
                f"- training: {its:.3f} it/s ({its * a.batch:.2f} samples/s) after {a.warmup_steps} warm-up steps, "
                f"peak memory {peak_train:.0f} MiB ({'CUDA max allocated' if cuda else 'CPU peak RSS'})",
                f"- evaluation (per sample, after warm-up): encoder {t['encoder_ms']:.1f} ms, renderer {t['renderer_ms']:.1f} ms, "
                f"peak {t['peak_memory_mb']:.0f} MiB ({t['memory_kind']})",
                f"- overrides: `{' '.join(a.overrides) or '-'}`",
                "<!-- train:end -->",
                "",
            ]
        )
        path = ROOT / "benchmarks" / "RESULTS.md"
        text = path.read_text() if path.exists() else "# Benchmark results\n\n"
        if "<!-- train:begin -->" in text:
            head, rest = text.split("<!-- train:begin -->", 1)
            tail = rest.split("<!-- train:end -->", 1)[1].lstrip("\n")
            text = head + section + tail
        else:
            text = text.rstrip("\n") + "\n\n" + section
        path.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
