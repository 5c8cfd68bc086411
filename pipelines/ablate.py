"""Run the paper's ablations with equal budgets and write one comparison table.

Examples:
  seeu ablate --config configs/cpu_small.json --data out/shards/extrap --eval out/shards/eval --out runs/ablate
  seeu ablate --config configs/re10k_paper.json --data re10k/train_ext45 --eval re10k/test_extrap \
      --variants full,no_refiner,unet,cls,clip,blip2 --ext-data 0=re10k/train_ext0 --ext-data 90=re10k/train_ext90 \
      --out runs/ablate model.clip_weights=/weights/clip_b16.safetensors model.blip2_weights=/weights/blip2-image
  seeu ablate ... --posed out/posed --ext-ranges 0,45,90        # build the extrapolation-range shards here

Variants (paper tables 4-6): `full` (Conditional Gaussian Transformer + CEA), `no_refiner`
("w/o Refinement"), `unet` ("w/ UNet Backbone"), `cls` (DINOv3 class embedding), `clip` (CLIP
embedding; needs its weights), `blip2` (BLIP-2 embedding: ViT-g + Q-Former query tokens; needs
`pip install -e '.[blip2]'` and its weights, from the hub `model.blip2_model=REPO` or offline
`model.blip2_weights=DIR`), and `ext<N>` (the full model trained on shards whose extrapolated targets
reach N frames outside the context pair; from --ext-data N=PATH or built from --posed).
Every variant uses the same config, seed, steps, batch size and schedule (equal budgets), is
evaluated on the same --eval shards, and lands in OUT/ablation.md and OUT/ablation.csv (deltas
against `full`). Finished variants are reused on a re-run (delete OUT/<variant> to redo one).
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

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


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", required=True, help="the shared training config (equal budget for all)")
    parser.add_argument("--data", required=True, help="training shards of the model variants")
    parser.add_argument("--eval", required=True, dest="eval_data", help="evaluation shards (same for every variant)")
    parser.add_argument("--out", required=True)
    parser.add_argument(
        "--variants",
        default=",".join(DEFAULT_VARIANTS),
        help=f"comma list of {', '.join(MODEL_VARIANTS)} (default {','.join(DEFAULT_VARIANTS)})",
    )
    parser.add_argument(
        "--ext-data",
        action="append",
        default=[],
        metavar="N=PATH",
        help="training shards with extrapolation range N frames (adds variant extN)",
    )
    parser.add_argument("--posed", default=None, help="posed frames to build the extrapolation-range shards from")
    parser.add_argument("--ext-ranges", default="0,45,90", help="with --posed: ranges to build (default 0,45,90)")
    parser.add_argument("--max-eval-samples", type=int, default=0)
    parser.add_argument("--lpips-weights", default=None, metavar="PATH")
    parser.add_argument("--no-lpips", action="store_true", help="MSE-only training and no LPIPS in the table")
    parser.add_argument("--device", default=None)
    parser.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None)
    parser.add_argument("overrides", nargs="*", metavar="KEY=VALUE", help="config overrides for every variant")


def run(args: argparse.Namespace) -> int:
    from seeu_data.errors import SeeUError

    ext: dict[int, str] = {}
    for item in args.ext_data:
        n, _, path = item.partition("=")
        if not n.strip().isdigit() or not path:
            raise SeeUError(f"--ext-data {item!r} is not N=PATH")
        ext[int(n)] = path
    ranges = [int(x) for x in args.ext_ranges.split(",") if x.strip()] if args.posed else []
    rows = ablate(
        args.config,
        args.data,
        args.eval_data,
        args.out,
        variants=[v.strip() for v in args.variants.split(",") if v.strip()],
        ext_data=ext,
        posed=args.posed,
        ext_ranges=ranges,
        overrides=args.overrides,
        max_eval_samples=args.max_eval_samples,
        lpips=not args.no_lpips,
        lpips_weights=args.lpips_weights,
        device=args.device,
        progress=args.progress,
    )
    print((Path(args.out) / "ablation.md").read_text())
    return 0 if rows else 1


def build_ext_shards(posed: str, out: Path, ranges: list[int], like: str | None = None) -> dict[int, str]:
    """Extrapolation-range training shards from posed frames (one build per range, same seed).

    Gap and sample counts follow the build recorded in `like`'s manifest when given (the main
    training shards), else the samplers' defaults."""
    from dataclasses import fields

    from seeu_data.build import BuildConfig, build
    from seeu_data.sampling import SamplingConfig

    base = {}
    if like is not None and (Path(like) / "manifest.json").exists():
        params = json.loads((Path(like) / "manifest.json").read_text()).get("params", {})
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
                BuildConfig(inputs=(str(posed),), out=str(dst), mode="extrap", sampling=sampling, seed=0),
                argv_command="seeu ablate",
            )
        paths[n] = str(dst)
    return paths


def _fmt(v, nd=3) -> str:
    return "—" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.{nd}f}"


def write_table(out: Path, rows: list[dict], budget: dict) -> None:
    from seeu_data.arrow_io import atomic_write_text
    from pipelines.evaluate import csv_text

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


def ablate(
    config: str,
    data: str,
    eval_data: str,
    out: str | Path,
    *,
    variants=DEFAULT_VARIANTS,
    ext_data: dict[int, str] | None = None,
    posed: str | None = None,
    ext_ranges=(),
    overrides=(),
    max_eval_samples: int = 0,
    lpips: bool = True,
    lpips_weights: str | None = None,
    device: str | None = None,
    progress: bool | None = None,
) -> list[dict]:
    """Python API of `seeu ablate`; returns the table rows."""
    from pipelines.evaluate import evaluate
    from pipelines.train import train
    from seeu_data.errors import SeeUError
    from seeu_model.training import checkpoint as ckpt_io
    from seeu_model.training.config import load_config

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    unknown = [v for v in variants if v not in MODEL_VARIANTS]
    if unknown:
        raise SeeUError(f"unknown variant(s) {', '.join(unknown)}; choose from {', '.join(MODEL_VARIANTS)}")
    ext = dict(ext_data or {})
    if posed:
        ext.update(build_ext_shards(posed, out, list(ext_ranges), like=data))
    base_overrides = list(overrides) + (["loss.lpips_weight=0"] if not lpips else [])
    cfg = load_config(config, base_overrides)  # validates the shared config once
    plan = [(v, MODEL_VARIANTS[v][0], MODEL_VARIANTS[v][1], data) for v in variants]
    plan += [(f"ext{n}", f"Full model, extrapolation range {n} frames", {}, path) for n, path in sorted(ext.items())]
    rows = []
    for name, label, model_ov, train_data in plan:
        vdir = out / name
        done = vdir / "eval" / "summary.json"
        summary_path = vdir / "train_summary.json"
        ts = json.loads(summary_path.read_text()) if summary_path.exists() else None
        if ts is None or ts.get("step", 0) < cfg.optim.max_steps:
            print(f"[ablate] {name}: {label} -- training {cfg.optim.max_steps} steps on {train_data}", flush=True)
            ov = base_overrides + [
                f"model.{k}={json.dumps(v) if not isinstance(v, str) else v}" for k, v in model_ov.items()
            ]
            ts = train(
                train_data,
                vdir,
                config=config,
                overrides=ov,
                resume=True,
                lpips_weights=lpips_weights,
                device=device,
                progress=progress,
            )
            done.unlink(missing_ok=True)
        if done.exists():
            es = json.loads(done.read_text())
        else:
            print(f"[ablate] {name}: evaluating on {eval_data}", flush=True)
            es = evaluate(
                ts["checkpoint"],
                eval_data,
                vdir / "eval",
                max_samples=max_eval_samples,
                lpips=lpips,
                lpips_weights=lpips_weights,
                device=device,
                progress=progress,
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
        "steps": cfg.optim.max_steps,
        "batch_size": cfg.data.batch_size,
        "lr": cfg.optim.lr,
        "seed": cfg.seed,
        "eval": str(eval_data),
    }
    write_table(out, rows, budget)
    return rows
