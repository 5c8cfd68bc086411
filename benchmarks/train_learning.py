"""Learning, honestly measured: held-out PSNR at initialisation vs after training (synthetic corridor).

Builds synthetic posed scenes (exact cameras, no SfM), interp/extrap triple shards for training from
scenes with seeds 0..S-1 and evaluation shards from an unseen scene (seed 100), evaluates the
initial model, trains with a config preset, evaluates again, and prints/saves the numbers.

  .venv/bin/python benchmarks/train_learning.py --config configs/cpu_small.json --out /tmp/learn \
      [--steps 300] [--size 64] [--frames 48] [--scenes 2] [overrides ...]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def make_data(root: Path, frames: int, size: int, scenes: int) -> tuple[str, str]:
    from pipelines.build import BuildConfig, build
    from seeu_data.build.sampling import SamplingConfig
    from seeu_data.store.manifest import provenance
    from seeu_data.store.posed import PosedDatasetWriter
    from seeu_data.synthetic import synthetic_posed_scene

    def posed(name, seeds):
        out = root / name
        if not (out / "manifest.json").exists():
            with PosedDatasetWriter(out, {"benchmark": True}, provenance("benchmarks/train_learning.py")) as w:
                for s in seeds:
                    w.add(synthetic_posed_scene(frames, size, size, seed=s, scene_id=f"syn{s}"))
        return out

    train_posed, test_posed = posed("posed_train", range(scenes)), posed("posed_test", [100])
    gap = (max(2, frames // 8), max(3, frames // 5))
    paths = []
    for name, src, mode, n in (("train", train_posed, "extrap", 64), ("test", test_posed, "extrap", 8)):
        out = root / f"shards_{name}"
        if not (out / "manifest.json").exists():
            sampling = SamplingConfig(
                mode=mode,
                gap_min=gap[0],
                gap_max=gap[1],
                extrap_frames=max(1, frames // 10),
                samples_per_scene=n,
                interp_ratio=0.5,
            )
            build(
                BuildConfig(
                    inputs=(str(src),), out=str(out), mode=mode, sampling=sampling, seed=1 if name == "test" else 0
                )
            )
        paths.append(str(out))
    return paths[0], paths[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", default="configs/cpu_small.json")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--steps", type=int, default=None)
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--frames", type=int, default=48)
    ap.add_argument("--scenes", type=int, default=2)
    ap.add_argument("--eval-samples", type=int, default=8)
    ap.add_argument("overrides", nargs="*")
    a = ap.parse_args()

    import torch

    from pipelines.evaluate import EvalConfig, evaluate, evaluate_on_data
    from pipelines.train import TrainRunConfig, seed_everything, train
    from seeu_model.evaluation import summarize
    from seeu_model.training.config import load_config
    from seeu_model.training.factory import build_model

    a.out.mkdir(parents=True, exist_ok=True)
    train_data, test_data = make_data(a.out, a.frames, a.size, a.scenes)
    ov = list(a.overrides) + [f"data.image_size=[{a.size},{a.size}]"]
    if a.steps:
        ov.append(f"optim.max_steps={a.steps}")
    cfg = load_config(a.config, ov)
    seed_everything(cfg.seed)
    model, _ = build_model(cfg.model)
    t0 = time.perf_counter()
    init = summarize(
        evaluate_on_data(
            model,
            test_data,
            tuple(cfg.data.image_size),
            device="cpu",
            max_samples=a.eval_samples,
            warmup=0,
            rasterizer=cfg.rasterizer,
        ).records
    )
    run = a.out / "run"
    res = train(TrainRunConfig(data=train_data, out=run, config=a.config, overrides=ov, resume=True))
    after = evaluate(
        EvalConfig(
            checkpoint=res["checkpoint"],
            data=test_data,
            out=run / "eval",
            max_samples=a.eval_samples,
            lpips=False,
            warmup=1,
        )
    )
    report = {
        "config": a.config,
        "overrides": ov,
        "steps": res["step"],
        "train_seconds": res["seconds"],
        "steps_per_s": res["steps_per_s"],
        "init_psnr": init["psnr"],
        "init_ssim": init["ssim"],
        "trained_psnr": after["metrics"]["psnr"],
        "trained_ssim": after["metrics"]["ssim"],
        "gain_db": after["metrics"]["psnr"] - init["psnr"],
        "eval_timing": after["timing"],
        "wall_s": time.perf_counter() - t0,
        "torch_threads": torch.get_num_threads(),
    }
    (a.out / "learning.json").write_text(json.dumps(report, indent=2) + "\n")
    print(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
