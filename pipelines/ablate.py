"""The ablation stage: the paper's variants trained with equal budgets, evaluated alike, one table.

`ablate(AblateConfig(...))` trains every variant (same config, seed, steps, batch size, schedule),
evaluates each on the same shards, and writes OUT/ablation.md and OUT/ablation.csv (deltas against
`full`); finished variants are reused on a re-run. `seeu ablate --help` describes the variants.

Example:
    from pipelines.ablate import AblateConfig, ablate

    rows = ablate(AblateConfig(config="cpu_small", data="out/shards/extrap", eval_data="out/shards/eval",
                               out="runs/ablate", variants=("full", "no_refiner"), lpips=False))
    [(r["variant"], r["psnr"]) for r in rows]
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

from seeu_data.errors import SeeUError
from seeu_data.limits import MAX_FRAMES, MAX_SAMPLES, check_range
from seeu_data.settings import parse_frame_counts, parse_int_path, parse_names, setting
from seeu_data.store.json_file import read_json
from seeu_data.store.out_lock import locks_output

# name -> (label as in the paper, model overrides)
MODEL_VARIANTS: dict[str, tuple[str, dict]] = {
    "full": ("Full model (CGT + CEA)", {}),
    "no_refiner": ("w/o Refinement", {"refiner": "none"}),
    "unet": ("w/ UNet Backbone", {"refiner": "unet"}),
    "cls": ("Class Embedding (DINOv3 CLS)", {"condition": "cls"}),
    "clip": ("CLIP Embedding", {"condition": "clip"}),
    "blip2": ("BLIP-2 Embedding", {"condition": "blip2"}),
}
DEFAULT_VARIANTS = ("full", "no_refiner", "unet", "cls")
DEFAULT_EXT_RANGES = (0, 45, 90)  # extrapolation ranges (frames) built from --posed


@dataclass(frozen=True, kw_only=True)
class AblateConfig:
    """One `seeu ablate` run.

    config: the shared training config; data: training shards of the model variants; eval_data: the
    evaluation shards (the same for every variant); out: the output directory; variants: names of
    MODEL_VARIANTS; ext_data: (N, training shards with extrapolation range N) pairs (adds variant extN);
    posed / ext_ranges: build those shards here from posed frames; overrides: config overrides for
    every variant; max_eval_samples: 0 = all; lpips: False trains with MSE only and leaves LPIPS out
    of the table; progress: bars (None: the config's log.progress).
    """

    config: str | Path = setting(help="the shared training config (equal budget for all)")
    data: str = setting(help="training shards of the model variants")
    eval_data: str = setting(help="evaluation shards (same for every variant)", flag="--eval")
    out: str | Path
    variants: tuple[str, ...] = setting(
        DEFAULT_VARIANTS,
        f"comma list of {', '.join(MODEL_VARIANTS)}",
        parse=parse_names,
    )
    ext_data: tuple[tuple[int, str], ...] = setting(
        (),
        "training shards with extrapolation range N frames (adds variant extN; repeat for more)",
        parse=parse_int_path,
        many=True,
        metavar="N=PATH",
    )
    posed: str | None = setting(None, "posed frames to build the extrapolation-range shards from")
    ext_ranges: tuple[int, ...] = setting(
        DEFAULT_EXT_RANGES,
        "with --posed: ranges to build",
        parse=parse_frame_counts,
    )
    max_eval_samples: int = setting(0, "evaluate at most N samples per variant; 0: all")
    lpips_weights: str | None = setting(None, "torchvision's vgg16-397923af.pth", metavar="PATH")
    lpips: bool = setting(True, "MSE-only training and no LPIPS in the table")
    device: str | None = setting(None, "cpu or cuda (default: cuda when available)")
    progress: bool | None = None
    overrides: tuple[str, ...] = setting(
        (), "config overrides for every variant", positional=True, many=True, optional=True, metavar="KEY=VALUE"
    )

    def check(self) -> None:
        unknown = [v for v in self.variants if v not in MODEL_VARIANTS]
        if unknown:
            raise SeeUError(f"unknown variant(s) {', '.join(unknown)}; choose from {', '.join(MODEL_VARIANTS)}")
        check_range(self.max_eval_samples, "--max-eval-samples", 0, MAX_SAMPLES)
        for n in (*self.ext_ranges, *dict(self.ext_data)):
            check_range(n, "extrapolation range (frames)", 0, MAX_FRAMES)


def build_ext_shards(
    posed: str, out: Path, ranges: list[int], like: str | None = None, progress: bool = False
) -> dict[int, str]:
    """Extrapolation-range training shards from posed frames (one build per range, same seed).

    Gap and sample counts follow the build recorded in `like`'s manifest when given (the main
    training shards), else the samplers' defaults."""
    from dataclasses import fields

    from pipelines.build import BuildConfig, build
    from seeu_data.build.sampling import SamplingConfig

    base = {}
    if like is not None and (Path(like) / "manifest.json").exists():
        params = read_json(Path(like) / "manifest.json", "manifest").get("params", {})
        base = {
            k: v for k, v in (params.get("sampling") or {}).items() if k in {f.name for f in fields(SamplingConfig)}
        }
    base.pop("mode", None)
    base.pop("extrap_frames", None)
    base.pop("interp_ratio", None)
    paths = {}
    for n in ranges:
        dst = out / f"shards_ext{n}"
        if not (dst / "manifest.json").exists():
            sampling = SamplingConfig(mode="extrap", extrap_frames=n, **base)
            build(
                BuildConfig(
                    inputs=(str(posed),), out=str(dst), mode="extrap", sampling=sampling, seed=0, progress=progress
                ),
                argv_command="seeu ablate",
            )
        paths[n] = str(dst)
    return paths


def _fmt(v, nd=3) -> str:
    return "—" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.{nd}f}"


def write_table(out: Path, rows: list[dict], budget: dict) -> None:
    from pipelines.evaluate import csv_text
    from seeu_data.store.arrow_io import atomic_write_text

    ref = next((r for r in rows if r["variant"] == "full"), None)
    for r in rows:
        for m in ("psnr", "ssim", "lpips"):
            r[f"d_{m}"] = (r[m] - ref[m]) if ref and r[m] is not None and ref[m] is not None else None
    lines = [
        "# SeeU ablations (equal budgets)",
        "",
        f"Budget per variant: {budget['steps']} steps x batch {budget['batch_size']} "
        f"({budget['steps'] * budget['batch_size']} training samples), lr {budget['lr']}, seed {budget['seed']}; "
        f"evaluated on `{budget['eval']}` ({rows[0]['num_targets'] if rows else 0} target views).",
        "",
        "| Variant | Setup | PSNR↑ | SSIM↑ | LPIPS↓ | ΔPSNR | ΔSSIM | ΔLPIPS | Trainable params | Train s |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['variant']} | {r['label']} | {_fmt(r['psnr'], 2)} | {_fmt(r['ssim'])} | {_fmt(r['lpips'])} | "
            f"{_fmt(r['d_psnr'], 2)} | {_fmt(r['d_ssim'])} | {_fmt(r['d_lpips'])} | "
            f"{r['trainable_params']:,} | {r['train_seconds']:.0f} |"
        )
    atomic_write_text(
        out / "ablation.csv", csv_text([{k: (math.nan if v is None else v) for k, v in r.items()} for r in rows])
    )
    atomic_write_text(out / "ablation.md", "\n".join(lines) + "\n")


@locks_output(lambda run: run.out)
def ablate(run: AblateConfig) -> list[dict]:
    """Python API of `seeu ablate`; returns the table rows (also OUT/ablation.md and OUT/ablation.csv)."""
    from pipelines.evaluate import EvalConfig, evaluate
    from pipelines.train import TrainRunConfig, train
    from seeu_model.training import checkpoint as ckpt_io
    from seeu_model.training.config import load_config

    run.check()
    out = Path(run.out)
    out.mkdir(parents=True, exist_ok=True)
    ext = dict(run.ext_data)
    if run.posed:
        ext.update(build_ext_shards(run.posed, out, list(run.ext_ranges), like=run.data, progress=bool(run.progress)))
    base_overrides = list(run.overrides) + (["loss.lpips_weight=0"] if not run.lpips else [])
    train_cfg = load_config(run.config, base_overrides)  # validates the shared config once
    plan = [(v, MODEL_VARIANTS[v][0], MODEL_VARIANTS[v][1], run.data) for v in run.variants]
    plan += [(f"ext{n}", f"Full model, extrapolation range {n} frames", {}, path) for n, path in sorted(ext.items())]
    rows = []
    for name, label, model_ov, train_data in plan:
        vdir = out / name
        done = vdir / "eval" / "summary.json"
        summary_path = vdir / "train_summary.json"
        ts = read_json(summary_path, "training summary") if summary_path.exists() else None
        if ts is None or ts.get("step", 0) < train_cfg.optim.max_steps:
            print(f"[ablate] {name}: {label} -- training {train_cfg.optim.max_steps} steps on {train_data}", flush=True)
            ov = base_overrides + [
                f"model.{k}={json.dumps(v) if not isinstance(v, str) else v}" for k, v in model_ov.items()
            ]
            ts = train(
                TrainRunConfig(
                    data=train_data,
                    out=vdir,
                    config=run.config,
                    overrides=tuple(ov),
                    resume=True,
                    lpips_weights=run.lpips_weights,
                    device=run.device,
                    progress=run.progress,
                )
            )
            done.unlink(missing_ok=True)
        if done.exists():
            es = read_json(done, "evaluation summary")
        else:
            print(f"[ablate] {name}: evaluating on {run.eval_data}", flush=True)
            es = evaluate(
                EvalConfig(
                    checkpoint=ts["checkpoint"],
                    data=run.eval_data,
                    out=vdir / "eval",
                    max_samples=run.max_eval_samples,
                    lpips=run.lpips,
                    lpips_weights=run.lpips_weights,
                    device=run.device,
                    progress=bool(run.progress),
                )
            )
        ck = ckpt_io.load_checkpoint(ts["checkpoint"])
        from seeu_model.training.factory import model_from_checkpoint

        model = model_from_checkpoint(ck)
        trainable = sum(p.numel() for p in model.parameters() if p.requires_grad)
        m = es["metrics"]
        rows.append(
            {
                "variant": name,
                "label": label,
                "train_data": train_data,
                "psnr": m["psnr"],
                "ssim": m["ssim"],
                "lpips": m["lpips"],
                "num_targets": m["num_targets"],
                "steps": ts["step"],
                "trainable_params": trainable,
                "train_seconds": ts.get("seconds", math.nan),
                "encoder_ms": es["timing"]["encoder_ms"],
                "renderer_ms": es["timing"]["renderer_ms"],
            }
        )
    budget = {
        "steps": train_cfg.optim.max_steps,
        "batch_size": train_cfg.data.batch_size,
        "lr": train_cfg.optim.lr,
        "seed": train_cfg.seed,
        "eval": str(run.eval_data),
    }
    write_table(out, rows, budget)
    return rows
