"""The demo's report: OUT/report.md from one template (`TEMPLATE`, Markdown with `$name` fields) filled
with the stages' results, and the training-curve figure. Written once, after every stage.

`write_report(out, out_arg, info, r)`: `out` the demo's output directory, `out_arg` the `--out` as the user
gave it (for the re-run line), `info` each stage's {"seconds", "reused"} (`demo.Stages.info`), `r` each
stage's result (synth, ingest, build, train, eval, render).
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from string import Template

STAGE_NAMES = ("synth", "ingest", "build", "train", "eval", "render")

TEMPLATE = Template(
    """# SeeU demo report

The whole toolkit on the built-in synthetic corridor: two clips rendered with exact ground truth, posed with \
COLMAP SfM, sampled into context-target triples, a small SeeU trained on CPU, evaluated on a held-out scene, and \
rendered along novel camera paths.

## Result

Held-out PSNR (mean of interp and extrap): **$init_psnr dB at initialisation -> $trained_psnr dB after $steps \
training steps ($gain_psnr dB)**.

Held-out data: a separate synthetic clip of an unseen scene (seed $heldout_seed: other textures and box layout; \
the training clip is seed $clip_seed), posed by the same SfM ingest. No frame of it is trained on; it is used \
only for validation curves and this evaluation.

## Stages

| stage | time (s) | this run | result |
|---|---:|---|---|
$stage_rows
| **total** | **$total_s** | | time of each stage when it ran |

## Posing (SfM) vs ground truth

| clip | registered | chunks | reprojection (px) | centre RMSE (% of path) | rel. rotation (deg) | focal error (%) |
|---|---:|---:|---:|---:|---:|---:|
$posing_rows

![trajectory of the training clip]($trajectory_png)

Ingest reports: [$clip_report]($clip_report), [$heldout_report]($heldout_report).

## Triples

| set | source | mode | triples | shards |
|---|---|---|---:|---:|
$triple_rows

Contact sheet of the training triples (contexts, then targets with their offset outside the pair):

![contact sheet]($train_sheet)

Held-out sheets: [interp]($interp_sheet), [extrap]($extrap_sheet).

## Training

Preset `$preset` with overrides `$overrides`: batch $batch_size, AdamW lr $lr, MSE loss, fp32 on CPU. $steps \
steps in $train_s s ($steps_per_s steps/s). Checkpoint: [$checkpoint]($checkpoint); TensorBoard: \
`tensorboard --logdir $tb_dir`.

![training curve]($curve_png)

## Metrics on the held-out scene

Same evaluation code for both rows (`pipelines.evaluate`: PSNR on images clipped to [0, 1], SSIM with an \
11-pixel Gaussian window; mean over the targets of a scene, then over scenes). *Initial* is the model with the \
exact weights training starts from.

| set | model | PSNR (dB) | SSIM | LPIPS | targets |
|---|---|---:|---:|---:|---:|
$metric_rows

$lpips_note.
All numbers: [metrics.json]($metrics_json).

Renders next to ground truth (per held-out example: contexts and ground-truth targets, then the initial \
model's and the trained model's renders of the same targets):

![held-out renders]($renders_png)

## Novel views and Gaussians

From held-out example `$sample_id` ([contexts]($context_png), [targets: ground truth over render]($targets_png)):

- interpolated path (between the two context cameras): [$interp_mp4]($interp_mp4)
- extrapolated path (50% beyond both ends): [$extrap_mp4]($extrap_mp4)
- frames: [$frames_dir/]($frames_dir)
- Gaussians ($num_gaussians, standard 3DGS .ply, opens in any 3DGS viewer): [$ply]($ply)

![targets: ground truth (top) and render (bottom)]($targets_png)

## Re-run

`seeu demo --out $out_arg` again reuses every finished stage; `--force` redoes them; `--steps N` retrains \
(and re-evaluates) while keeping the clips, poses and shards.
""".replace("\\\n", "")
)


def _rel(path: str | Path, root: Path) -> str:
    return Path(os.path.relpath(Path(path).resolve(), root.resolve())).as_posix()


def _fmt(x, spec: str = ".2f") -> str:
    return "n/a" if x is None or (isinstance(x, float) and math.isnan(x)) else format(x, spec)


def write_report(out: Path, out_arg: Path, info: dict, r: dict) -> Path:
    """Write OUT/report.md (and its training-curve figure); returns its path."""
    from seeu_data.store.arrow_io import atomic_write_text

    ev, tr, ing, bd, syn, rd = r["eval"], r["train"], r["ingest"], r["build"], r["synth"], r["render"]
    curve_png = out / "figures" / "training_curve.png"
    plot_training_curve(read_training_curve(Path(tr["run"])), ev, curve_png)
    rel = lambda p: _rel(p, out)  # noqa: E731
    mean = ev["mean"]
    results = {
        "synth": f"2 clips, {syn['clip']['frames']} frames at {syn['clip']['size']} "
        f"([clip]({rel(syn['clip']['video'])}), [held-out]({rel(syn['heldout']['video'])}))",
        "ingest": "; ".join(
            f"{k}: {v['registered']}/{v['frames_selected']} registered, {v['chunks']} chunk(s)" for k, v in ing.items()
        ),
        "build": ", ".join(f"{k}: {v['rows']} triples" for k, v in bd.items()),
        "train": f"{tr['step']} steps, {tr['steps_per_s']:.2f} steps/s, final train PSNR "
        f"{_fmt(tr['final'].get('psnr'))} dB",
        "eval": f"held-out PSNR {mean['init_psnr']:.2f} -> {mean['trained_psnr']:.2f} dB",
        "render": f"{rd['frames']} + {rd['frames']} frames, {rd['num_gaussians']} Gaussians",
    }
    stage_rows, total = [], 0.0
    for name in STAGE_NAMES:
        s = info.get(name, {"seconds": 0.0, "reused": False})
        total += s["seconds"]
        stage_rows.append(f"| {name} | {s['seconds']:.1f} | {'reused' if s['reused'] else 'ran'} | {results[name]} |")
    posing_rows = []
    for k, v in ing.items():
        best = (v.get("ground_truth") or {}).get("largest") or {}
        posing_rows.append(
            f"| {k} | {v['registered']}/{v['frames_selected']} | {v['chunks']} | "
            f"{_fmt(v['mean_reprojection_error_px'])} | {_fmt(best.get('centre_rmse_pct_path'), '.3f')} | "
            f"{_fmt(best.get('rel_rot_err_mean_deg'), '.3f')} | {_fmt(best.get('focal_err_pct'))} |"
        )
    triple_rows = []
    for k, v in bd.items():
        mode = v["mode"] + (" (half the targets inside the pair: interp + extrap)" if v["interp_ratio"] else "")
        triple_rows.append(
            f"| [{k}]({rel(v['path'])}) | {Path(v['source']).name} | {mode} | {v['rows']} | {v['shards']} |"
        )
    metric_rows = []
    for k, row in ev["sets"].items():
        name = k.removeprefix("eval_")
        for label in ("init", "trained"):
            m = row[label]
            metric_rows.append(
                f"| {name} | {'initial' if label == 'init' else 'trained'} | [{m['psnr']:.2f}]({rel(m['summary'])}) | "
                f"{m['ssim']:.4f} | {_fmt(m.get('lpips'), '.4f')} | {m['num_targets']} |"
            )
        gain_ssim = row["trained"]["ssim"] - row["init"]["ssim"]
        metric_rows.append(f"| {name} | **gain** | **{row['gain_psnr_db']:+.2f}** | {gain_ssim:+.4f} | | |")
    text = TEMPLATE.substitute(
        init_psnr=f"{mean['init_psnr']:.2f}",
        trained_psnr=f"{mean['trained_psnr']:.2f}",
        gain_psnr=f"{mean['gain_psnr_db']:+.2f}",
        steps=tr["step"],
        heldout_seed=syn["heldout"]["seed"],
        clip_seed=syn["clip"]["seed"],
        stage_rows="\n".join(stage_rows),
        total_s=f"{total:.1f}",
        posing_rows="\n".join(posing_rows),
        trajectory_png=rel(Path(ing["clip"]["posed"]) / "trajectory.png"),
        clip_report=rel(Path(ing["clip"]["posed"]) / "report.json"),
        heldout_report=rel(Path(ing["heldout"]["posed"]) / "report.json"),
        triple_rows="\n".join(triple_rows),
        train_sheet=rel(bd["train"]["sheet"]),
        interp_sheet=rel(bd["eval_interp"]["sheet"]),
        extrap_sheet=rel(bd["eval_extrap"]["sheet"]),
        preset=Path(tr["config"]).name,
        overrides=" ".join(tr["overrides"]),
        batch_size=tr["batch_size"],
        lr=f"{tr['lr']:g}",
        train_s=f"{tr['seconds']:.0f}",
        steps_per_s=f"{tr['steps_per_s']:.2f}",
        checkpoint=rel(tr["checkpoint"]),
        tb_dir=Path(tr["run"]) / "tb",
        curve_png=rel(curve_png),
        metric_rows="\n".join(metric_rows),
        lpips_note=ev["lpips_note"],
        metrics_json=rel(ev["metrics_json"]),
        renders_png=rel(ev["renders_png"]),
        sample_id=rd["sample_id"],
        context_png=rel(rd["context_png"]),
        targets_png=rel(rd["targets_png"]),
        interp_mp4=rel(rd["interp_mp4"]),
        extrap_mp4=rel(rd["extrap_mp4"]),
        frames_dir=rel(Path(rd["dir"]) / "frames"),
        num_gaussians=rd["num_gaussians"],
        ply=rel(rd["ply"]),
        out_arg=out_arg,
    )
    path = out / "report.md"
    atomic_write_text(path, text)
    return path


def read_training_curve(run_dir: Path) -> dict[str, list[tuple[int, float]]]:
    """Scalars the training loop logged to TensorBoard (OUT/run/tb): {'train/loss': [(step, value)], ...}."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(str(run_dir / "tb"), size_guidance={"scalars": 0})
    acc.Reload()
    out = {}
    for tag in acc.Tags().get("scalars", []):
        by_step = {e.step: e.value for e in acc.Scalars(tag)}  # a resumed run rewrites steps: keep the last
        out[tag] = sorted(by_step.items())
    return out


def plot_training_curve(curves: dict, evals: dict, path: Path) -> None:
    import io

    from matplotlib.figure import Figure

    from seeu_data.store.arrow_io import atomic_write_bytes

    fig = Figure(figsize=(10, 3.8), dpi=90)
    ax1, ax2 = fig.subplots(1, 2)
    if curves.get("train/loss"):
        s, v = zip(*curves["train/loss"])
        ax1.plot(s, v, color="tab:red", label="training loss (MSE)")
        ax1.set_yscale("log")
    ax1.set_xlabel("step")
    ax1.set_title("training loss")
    ax1.grid(alpha=0.3)
    ax1.legend(fontsize=8)
    if curves.get("train/psnr"):
        s, v = zip(*curves["train/psnr"])
        ax2.plot(s, v, color="tab:red", alpha=0.7, label="training batch PSNR")
    if curves.get("val/psnr"):
        s, v = zip(*curves["val/psnr"])
        ax2.plot(s, v, "o-", color="tab:blue", label="held-out PSNR (validation, interp)")
    for name, row in evals.get("sets", {}).items():
        style = "--" if name.endswith("interp") else ":"
        ax2.axhline(
            row["init"]["psnr"],
            color="gray",
            ls=style,
            lw=1,
            label=f"held-out {name.removeprefix('eval_')} at initialisation",
        )
    ax2.set_xlabel("step")
    ax2.set_ylabel("PSNR (dB)")
    ax2.set_title("PSNR")
    ax2.grid(alpha=0.3)
    ax2.legend(fontsize=7)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    atomic_write_bytes(path, buf.getvalue())
