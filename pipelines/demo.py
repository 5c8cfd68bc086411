"""The demo stage: the whole toolkit on the built-in synthetic clip, leaving a report with pictures.

`demo(DemoConfig(out=...))` runs synth -> ingest -> build -> train -> eval -> render -> report, each
stage resumable (a re-run with the same config reuses every finished stage; `force` redoes them), and
writes OUT/report.md, OUT/metrics.json and OUT/figures/. `seeu demo --help` describes the stages and
their outputs; the flags map one to one onto the fields of `DemoConfig`.

Example:
    from pathlib import Path
    from pipelines.demo import DemoConfig, demo

    result = demo(DemoConfig(out=Path("out/quick"), frames=36, size=(180, 320), steps=60, image_size=(32, 32)))
    result["report"], result["stages"]["eval"]["mean"]["trained_psnr"]
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, replace
from pathlib import Path

from pipelines.demo_report import write_report
from seeu_data.errors import SeeUError
from seeu_data.limits import (
    MAX_IMAGE_SIDE,
    MAX_RENDER_FRAMES,
    MAX_SAMPLES,
    MAX_STEPS,
    MAX_VIDEO_FRAMES,
    MAX_VIDEO_SIDE,
    check_range,
)
from seeu_data.settings import parse_dims, parse_video_dims, setting
from seeu_data.store.out_lock import locks_output

STAGES = ("synth", "ingest", "build", "train", "eval", "render", "report")
STAMP_FORMAT = 1


@dataclass(frozen=True)
class DemoConfig:
    """One `seeu demo` run.

    out: the output directory; frames: frames per synthetic clip; size: the clips' (height, width);
    seed / heldout_seed: scene seeds of the training and held-out clips (None: seed + 100);
    image_size: training/evaluation (H, W), built into the shards; train_samples / eval_samples:
    triples per posed chunk / per evaluation set; config: a training preset's name or a config file;
    steps: training steps (None: the preset's optim.max_steps); lpips_weights: VGG-16 weights for
    LPIPS (None: the torch hub cache; skipped when missing); render_frames: frames per camera path.
    """

    out: Path = setting(Path("out/demo"), "output directory")
    frames: int = setting(72, "frames per synthetic clip")
    size: tuple[int, int] = setting((270, 480), "clip size HxW", parse=parse_video_dims, metavar="HxW")
    seed: int = setting(0, "scene seed of the training clip")
    heldout_seed: int | None = setting(None, "scene seed of the held-out evaluation clip (default: --seed + 100)")
    image_size: tuple[int, int] = setting(
        (64, 64), "training/evaluation image size, built into the shards", parse=parse_dims, metavar="HxW"
    )
    train_samples: int = setting(256, "training triples drawn per posed chunk")
    eval_samples: int = setting(8, "held-out triples per evaluation set, interp and extrap")
    config: str | Path = setting(
        "demo", "training preset: a shipped preset's name or a config file (demo = configs/demo.json)"
    )
    steps: int | None = setting(
        None, "training steps (default: the preset's optim.max_steps; demo.json: 300, ~3 min on an idle 2-core CPU)"
    )
    lpips_weights: str | None = setting(
        None,
        "torchvision's vgg16-397923af.pth for LPIPS (default: the torch hub cache; LPIPS is skipped when it is missing)",
        metavar="PATH",
    )
    render_frames: int = setting(30, "frames per rendered camera path")
    force: bool = False
    progress: bool = False

    @property
    def heldout(self) -> int:
        """The held-out clip's scene seed."""
        return self.seed + 100 if self.heldout_seed is None else self.heldout_seed

    def check(self) -> None:
        if Path(self.out).exists() and not Path(self.out).is_dir():
            raise SeeUError("--out must be a directory, but this is a file", self.out)
        check_range(self.frames, "--frames", 24, MAX_VIDEO_FRAMES)  # SfM and the triple sampler need a walk
        for side in self.size:
            check_range(side, "--size", 16, MAX_VIDEO_SIDE)
        for side in self.image_size:
            check_range(side, "--image-size", 16, MAX_IMAGE_SIDE)
        if self.steps is not None:
            check_range(self.steps, "--steps", 1, MAX_STEPS)
        check_range(self.train_samples, "--train-samples", 1, MAX_SAMPLES)
        check_range(self.eval_samples, "--eval-samples", 1, MAX_SAMPLES)
        check_range(self.render_frames, "--render-frames", 2, MAX_RENDER_FRAMES)
        if self.heldout == self.seed:
            raise SeeUError("--heldout-seed must differ from --seed (the held-out scene must be unseen)")


# ------------------------------------------------------------------------------------------------
# Stage bookkeeping: seeu_data.store.resume.StageCache, its journal in OUT/.stages/; here the [n/7] lines
# ------------------------------------------------------------------------------------------------


class Stages:
    def __init__(self, out: Path, force: bool):
        from seeu_data.store.resume import StageCache

        self.cache = StageCache(out / ".stages", force)
        self.info: dict[str, dict] = {}  # name -> {"seconds" (when it ran), "reused"}

    def run(self, name: str, key: dict, what: str, fn, outputs=lambda r: [], directory: Path | None = None) -> dict:
        """Reuse stage `name` when it completed with `key` and its outputs exist, else run `fn()`
        (`directory`: the stage's own output directory, emptied first)."""
        n = STAGES.index(name) + 1
        full_key = {"stage": name, "format": STAMP_FORMAT, **key}
        found = self.cache.lookup(name, full_key, outputs, directory)
        if found is not None:
            print(f"[{n}/{len(STAGES)}] {name}: reused ({found['seconds']:.1f} s when it ran)", flush=True)
        else:
            print(f"[{n}/{len(STAGES)}] {name}: {what}", flush=True)
        result, reused = self.cache.run(name, full_key, fn, directory, outputs)
        seconds = self.cache.records[name]["seconds"]
        self.info[name] = {"seconds": seconds, "reused": reused}
        if not reused:
            print(f"      {name} done in {seconds:.1f} s", flush=True)
        return result

    def hash(self, name: str) -> str:
        return self.cache.stamp(name)


def sampling_for(frames: int) -> dict:
    """Context gaps and extrapolation range scaled to the clip length (72 frames: gap 8-14, +-6)."""
    gap_min = max(3, frames // 9)
    gap_max = max(gap_min + 1, frames // 5)
    return {"gap_min": gap_min, "gap_max": gap_max, "extrap_frames": max(2, frames // 12)}


# ------------------------------------------------------------------------------------------------
# Stages
# ------------------------------------------------------------------------------------------------


def stage_synth(ctx: dict, stages: Stages) -> dict:
    from seeu_data.synthetic import ClipConfig, write_clip

    height, width = ctx["cfg"].size
    clips = {
        "clip": ClipConfig(n_frames=ctx["cfg"].frames, size=ctx["cfg"].size, seed=ctx["cfg"].seed),
        "heldout": ClipConfig(n_frames=ctx["cfg"].frames, size=ctx["cfg"].size, seed=ctx["heldout_seed"]),
    }

    def fn() -> dict:
        out = {}
        for name, cfg in clips.items():
            video = ctx["out"] / "clip" / f"{name}.mp4"
            doc = write_clip(video, cfg, progress=ctx["progress"])
            out[name] = {
                "video": str(video),
                "seed": cfg.seed,
                "frames": cfg.n_frames,
                "size": f"{height}x{width}",
                "path_length_m": doc["path_length"],
            }
        return out

    key = {name: dict(cfg.__dict__) for name, cfg in clips.items()}
    return stages.run(
        "synth",
        key,
        f"rendering 2 clips ({ctx['cfg'].frames} frames at {height}x{width}): "
        f"training scene seed {ctx['cfg'].seed}, held-out scene seed {ctx['heldout_seed']}",
        fn,
        lambda r: [v["video"] for v in r.values()],
    )


def stage_ingest(ctx: dict, stages: Stages, synth: dict) -> dict:
    from pipelines.ingest import IngestConfig, IngestRunConfig, ingest
    from seeu_data.ingest.chunks import ChunkConfig
    from seeu_data.ingest.scale import ScaleConfig
    from seeu_data.synthetic import accuracy_line, ingest_accuracy

    # The default camera model (SIMPLE_RADIAL), as a user's first ingest has: with SIMPLE_PINHOLE the
    # training clip (36 frames at 180x320) maps 5.8 % of the path and 16 % in focal length off, its two
    # mapping runs agreeing. SfM on every core (the solution check's two mapping runs at once); ingest's
    # poses do not depend on the thread count.
    cfg = IngestConfig(
        out=ctx["out"] / "posed",
        chunks=ChunkConfig(scale=ScaleConfig("median-depth")),  # the demo model's tight near/far
        run=IngestRunConfig(force=ctx["cfg"].force, progress=ctx["progress"], heartbeat_s=0),
    )

    def fn() -> dict:
        out = {}
        for name, clip in synth.items():
            (result,) = ingest(replace(cfg, inputs=(clip["video"],)))
            report = result.report
            assert report is not None  # a single input's error raises
            truth = ingest_accuracy(report["output"], clip["video"], report["registered"], report["frames_selected"])
            print(f"      {report['summary']} | {accuracy_line(truth)}", flush=True)
            out[name] = {
                "posed": report["output"],
                "summary": report["summary"],
                "frames_selected": report["frames_selected"],
                "registered": report["registered"],
                "chunks": len(report["chunks"]),
                "frames_in_chunks": report["frames_in_chunks"],
                "mean_reprojection_error_px": report["mean_reprojection_error_px"],
                "ground_truth": truth,
            }
        return out

    key = {"synth": stages.hash("synth"), "ingest": cfg.params()}
    return stages.run(
        "ingest",
        key,
        "decode -> select -> SfM (pycolmap) -> posed chunks, both clips",
        fn,
        lambda r: [Path(v["posed"]) / "manifest.json" for v in r.values()],
    )


def stage_build(ctx: dict, stages: Stages, ingest: dict) -> dict:
    from pipelines.build import BuildConfig, build
    from pipelines.inspect_triples import contact_sheet
    from seeu_data.build.sampling import SamplingConfig
    from seeu_data.build.triples import ImageOptions

    a = ctx["cfg"]
    hw = ctx["image_hw"]
    s = sampling_for(a.frames)
    shards = ctx["out"] / "shards"
    figures = ctx["out"] / "figures"
    sets = {  # name: (posed input, mode, interp_ratio, samples per chunk, seed)
        "train": (ingest["clip"]["posed"], "extrap", 0.5, a.train_samples, 0),
        "eval_interp": (ingest["heldout"]["posed"], "interp", 0.0, a.eval_samples, 1),
        "eval_extrap": (ingest["heldout"]["posed"], "extrap", 0.0, a.eval_samples, 2),
    }

    def fn() -> dict:
        from seeu_data.process_pool import default_workers

        out = {}
        for name, (posed, mode, ratio, n, seed) in sets.items():
            d = shards / name
            sampling = SamplingConfig(
                mode=mode,
                gap_min=s["gap_min"],
                gap_max=s["gap_max"],
                extrap_frames=s["extrap_frames"],
                interp_ratio=ratio,
                samples_per_scene=n,
            )
            manifest = build(
                BuildConfig(
                    inputs=(posed,),
                    out=str(d),
                    mode=mode,
                    sampling=sampling,
                    seed=seed,
                    image=ImageOptions(resize=hw),
                    workers=min(2, default_workers(hw is not None)),
                    progress=ctx["progress"],
                ),
                "seeu demo",
            )
            if manifest["total_rows"] == 0:
                from seeu_data.errors import SeeUError

                raise SeeUError(
                    f"no {name} triples: the posed chunks are shorter than the sampler needs "
                    f"(gap {s['gap_min']}-{s['gap_max']}, extrapolation {s['extrap_frames']}); use more --frames",
                    posed,
                )
            sheet = figures / f"sheet_{name}.png"
            contact_sheet(d, sheet, 6 if name == "train" else 4)
            out[name] = {
                "path": str(d),
                "rows": manifest["total_rows"],
                "shards": len(manifest["files"]),
                "mode": mode,
                "interp_ratio": ratio,
                "source": posed,
                "sheet": str(sheet),
            }
            print(
                f"      {name}: {manifest['total_rows']} triples ({mode}"
                f"{', half the targets inside the pair' if ratio else ''}) from {posed}",
                flush=True,
            )
        return out

    key = {
        "ingest": stages.hash("ingest"),
        "image_hw": list(hw),
        "sampling": s,
        "sets": {k: [v[1], v[2], v[3], v[4]] for k, v in sets.items()},
    }
    return stages.run(
        "build",
        key,
        f"triples at {hw[0]}x{hw[1]}: train (interp + extrap) from the training clip, "
        "eval_interp / eval_extrap from the held-out clip",
        fn,
        lambda r: [Path(v["path"]) / "manifest.json" for v in r.values()] + [v["sheet"] for v in r.values()],
        directory=shards,
    )


def train_overrides(ctx: dict) -> list[str]:
    hw = ctx["image_hw"]
    ov = [f"data.image_size=[{hw[0]},{hw[1]}]", "data.num_workers=0"]
    if ctx["cfg"].steps is not None:
        ov.append(f"optim.max_steps={ctx['cfg'].steps}")
    return ov


def stage_train(ctx: dict, stages: Stages, build: dict) -> dict:
    from pipelines.train import TrainRunConfig, train
    from seeu_model.training.config import load_config, read_config_file

    a = ctx["cfg"]
    ov = train_overrides(ctx)
    cfg = load_config(a.config, ov)
    steps = cfg.optim.max_steps
    val_every = max(1, steps // 5)
    ov_run = ov + [f"log.val_every={val_every}", f"checkpoint.every={max(1, min(cfg.checkpoint.every, steps))}"]
    run_dir = ctx["out"] / "run"
    preset = {k: v for k, v in read_config_file(a.config).items() if not str(k).startswith("_")}  # not comments
    key = {"build": stages.hash("build"), "config": preset, "overrides": ov_run}

    def fn() -> dict:
        from seeu_data.store.resume import claim_dir, stamp_of

        # An interrupted run with the same key continues from its newest checkpoint; any other is redone.
        claim_dir(run_dir, stamp_of(key), a.force)
        res = train(
            TrainRunConfig(
                data=build["train"]["path"],
                out=run_dir,
                config=a.config,
                overrides=tuple(ov_run),
                val=build["eval_interp"]["path"],
                resume=True,
                lpips=False,
                device="cpu",
                progress=ctx["progress"],
            )
        )
        return {
            "run": str(run_dir),
            "checkpoint": res["checkpoint"],
            "step": res["step"],
            "seconds": res["seconds"],
            "steps_per_s": res["steps_per_s"],
            "final": res["final"],
            "val": res["val"],
            "config": str(a.config),
            "overrides": ov_run,
            "batch_size": cfg.data.batch_size,
            "lr": cfg.optim.lr,
        }

    return stages.run(
        "train",
        key,
        f"{cfg.name} preset ({a.config.name}), {steps} steps of batch "
        f"{cfg.data.batch_size} at {ctx['image_hw'][0]}x{ctx['image_hw'][1]} on CPU "
        f"(held-out validation every {val_every} steps)",
        fn,
        lambda r: [r["checkpoint"]],
    )


def _lpips_module(weights: str | None, build: bool = True):
    """(LPIPS module or None, note); build=False only checks for the weights."""
    from seeu_data.errors import SeeUError
    from seeu_model.lpips_loss import LPIPS, resolve_vgg_weights

    try:
        path = resolve_vgg_weights(weights)
    except SeeUError as exc:
        return None, f"LPIPS skipped: the VGG-16 weights are not available offline ({exc})"
    return (LPIPS(weights=str(path)) if build else None), f"LPIPS(VGG) with {path}"


def stage_eval(ctx: dict, stages: Stages, build: dict, trained: dict) -> dict:
    a = ctx["cfg"]
    eval_dir = ctx["out"] / "eval"
    figures = ctx["out"] / "figures"
    lpips_state = _lpips_module(a.lpips_weights, build=False)[1]

    def fn() -> dict:
        import torch

        from pipelines.evaluate import evaluate_on_data, write_results
        from pipelines.train import seed_everything
        from seeu_model.training import checkpoint as ckpt_io
        from seeu_model.training.config import config_from_dict, load_config
        from seeu_model.training.factory import build_model, model_from_checkpoint

        lpips_fn, lpips_note = _lpips_module(a.lpips_weights)
        print(f"      {lpips_note}", flush=True)
        # The initial model: exactly the weights `train` starts from (same config, same seeding).
        cfg = load_config(a.config, trained["overrides"])
        seed_everything(cfg.seed)
        init_model, _ = build_model(cfg.model)
        init_model.eval()
        ck = ckpt_io.load_checkpoint(trained["checkpoint"])
        tcfg = config_from_dict(json.loads(json.dumps(ck["config"])))
        trained_model = model_from_checkpoint(ck, "cpu")
        results: dict = {
            "lpips": lpips_note if lpips_fn is not None else None,
            "lpips_note": lpips_note,
            "checkpoint": ck["path"],
            "step": ck["step"],
            "sets": {},
        }
        renders: dict = {}
        for set_name in ("eval_interp", "eval_extrap"):
            data = build[set_name]["path"]
            row = {}
            for label, model, c in (("init", init_model, cfg), ("trained", trained_model, tcfg)):
                res = evaluate_on_data(
                    model,
                    data,
                    ctx["image_hw"],
                    device="cpu",
                    lpips_fn=lpips_fn,
                    rasterizer=c.rasterizer,
                    precision=c.precision,
                    warmup=1,
                    keep_renders=2,
                    progress=ctx["progress"],
                )
                summary = write_results(
                    eval_dir / f"{label}_{set_name.removeprefix('eval_')}",
                    res,
                    {
                        "model": label,
                        "step": 0 if label == "init" else ck["step"],
                        "data": data,
                        "image_hw": list(ctx["image_hw"]),
                        "lpips": "vgg" if lpips_fn is not None else "off",
                        "device": "cpu",
                    },
                )
                m = summary["metrics"]
                row[label] = {
                    "psnr": m["psnr"],
                    "ssim": m["ssim"],
                    "lpips": m.get("lpips"),
                    "num_targets": m["num_targets"],
                    "num_samples": m["num_samples"],
                    "summary": str(eval_dir / f"{label}_{set_name.removeprefix('eval_')}" / "summary.json"),
                }
                renders.setdefault(set_name, {})[label] = res.renders
            row["gain_psnr_db"] = row["trained"]["psnr"] - row["init"]["psnr"]
            results["sets"][set_name] = row
            print(
                f"      held-out {set_name.removeprefix('eval_')}: PSNR {row['init']['psnr']:.2f} dB at "
                f"initialisation -> {row['trained']['psnr']:.2f} dB trained ({row['gain_psnr_db']:+.2f} dB), "
                f"SSIM {row['init']['ssim']:.3f} -> {row['trained']['ssim']:.3f}",
                flush=True,
            )
        all_init = [results["sets"][s]["init"]["psnr"] for s in results["sets"]]
        all_trained = [results["sets"][s]["trained"]["psnr"] for s in results["sets"]]
        results["mean"] = {
            "init_psnr": sum(all_init) / len(all_init),
            "trained_psnr": sum(all_trained) / len(all_trained),
        }
        results["mean"]["gain_psnr_db"] = results["mean"]["trained_psnr"] - results["mean"]["init_psnr"]
        results["renders_png"] = str(figures / "heldout_renders.png")
        render_grid(renders, Path(results["renders_png"]))
        from seeu_data.store.arrow_io import atomic_write_text

        atomic_write_text(ctx["out"] / "metrics.json", json.dumps(results, indent=2) + "\n")
        results["metrics_json"] = str(ctx["out"] / "metrics.json")
        del torch
        return results

    key = {"train": stages.hash("train"), "build": stages.hash("build"), "lpips": [a.lpips_weights, lpips_state]}
    return stages.run(
        "eval",
        key,
        "held-out PSNR / SSIM / LPIPS of the initial and the trained model",
        fn,
        lambda r: [r["metrics_json"], r["renders_png"]],
    )


def render_grid(renders: dict, path: Path) -> None:
    """Held-out examples: per example one row of contexts + ground-truth targets, then the initial
    model's renders and the trained model's renders of the same targets."""
    import io

    from matplotlib.figure import Figure

    from seeu_data.store.arrow_io import atomic_write_bytes

    rows = []  # (label, [images or None])
    for set_name, by_model in renders.items():
        for k, trained in enumerate(by_model["trained"]):
            init = by_model["init"][k]
            ctx_imgs = [c for c in trained["context"]]
            v = len(ctx_imgs)
            tag = f"{set_name.removeprefix('eval_')} {trained['sample_id'][-12:]}"
            rows.append((f"{tag}\ncontext | ground truth", [*ctx_imgs, *trained["gt"]], v))
            rows.append(("initial model", [None] * v + list(init["pred"]), v))
            rows.append(("trained model", [None] * v + list(trained["pred"]), v))
    cols = max(len(r[1]) for r in rows)
    fig = Figure(figsize=(1.7 * cols, 1.8 * len(rows)), dpi=80)
    axes = fig.subplots(len(rows), cols, squeeze=False)
    for r, (label, imgs, v) in enumerate(rows):
        for c in range(cols):
            ax = axes[r, c]
            ax.set_xticks([])
            ax.set_yticks([])
            img = imgs[c] if c < len(imgs) else None
            if img is None:
                for s in ax.spines.values():
                    s.set_visible(False)
                if c == 0:
                    ax.text(0.95, 0.5, label, ha="right", va="center", fontsize=8, transform=ax.transAxes)
                continue
            ax.imshow(img.float().clamp(0, 1).permute(1, 2, 0).numpy())
            if r % 3 == 0:
                ax.set_title(
                    "context" if c < v else f"target {c - v}", fontsize=8, color="tab:blue" if c < v else "tab:green"
                )
            if c == 0:
                ax.set_ylabel(label, fontsize=7)
    fig.suptitle("held-out scene: ground truth, initial model, trained model", fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.4 / (1.8 * len(rows))))
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    atomic_write_bytes(path, buf.getvalue())


def stage_render(ctx: dict, stages: Stages, build: dict, trained: dict) -> dict:
    from pipelines.render import RenderConfig, render

    a = ctx["cfg"]
    out = ctx["out"] / "render"

    def fn() -> dict:
        rep = render(
            RenderConfig(
                checkpoint=trained["checkpoint"],
                out=out,
                data=build["eval_extrap"]["path"],
                sample="0",
                frames=a.render_frames,
                extrapolate=0.5,
                fps=10.0,
                device="cpu",
            )
        )
        return {
            "dir": str(out),
            "interp_mp4": rep["interp"]["mp4"],
            "extrap_mp4": rep["extrap"]["mp4"],
            "ply": rep["ply"],
            "num_gaussians": rep["num_gaussians"],
            "sample_id": rep["sample_id"],
            "context_png": str(out / "context.png"),
            "targets_png": str(out / "targets.png"),
            "frames": rep["interp"]["frames"],
        }

    key = {"train": stages.hash("train"), "build": stages.hash("build"), "frames": a.render_frames}
    return stages.run(
        "render",
        key,
        f"interp + extrap camera paths ({a.render_frames} frames each, MP4) and "
        "the Gaussians (.ply) from a held-out example",
        fn,
        lambda r: [r["interp_mp4"], r["extrap_mp4"], r["ply"]],
        directory=out,
    )


# ------------------------------------------------------------------------------------------------
# Report
# ------------------------------------------------------------------------------------------------


# ------------------------------------------------------------------------------------------------


@locks_output(lambda cfg: cfg.out)
def demo(cfg: DemoConfig) -> dict:
    """Run (or resume) every stage; returns {"report": OUT/report.md, "stages": each stage's result,
    "seconds": this run's time}. Prints one line per stage as it goes."""
    from seeu_model.training.config import resolve_config

    t0 = time.perf_counter()
    cfg.check()
    cfg = replace(cfg, config=resolve_config(cfg.config))
    out = Path(cfg.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SeeUError(f"cannot create the output directory ({exc.strerror})", out) from None
    ctx = {
        "cfg": cfg,
        "out": out,
        "progress": cfg.progress,
        "image_hw": tuple(cfg.image_size),
        "heldout_seed": cfg.heldout,
    }
    stages = Stages(out, cfg.force)
    r: dict = {}
    r["synth"] = stage_synth(ctx, stages)
    r["ingest"] = stage_ingest(ctx, stages, r["synth"])
    r["build"] = stage_build(ctx, stages, r["ingest"])
    r["train"] = stage_train(ctx, stages, r["build"])
    r["eval"] = stage_eval(ctx, stages, r["build"], r["train"])
    r["render"] = stage_render(ctx, stages, r["build"], r["train"])
    print(f"[7/7] report: writing {out / 'report.md'}", flush=True)
    report = write_report(out, cfg.out, stages.info, r)
    return {"report": report, "stages": r, "seconds": time.perf_counter() - t0}
