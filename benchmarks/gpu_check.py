"""The GPU check: one command, at most 8 minutes on one H100, that measures what CPU machines cannot and
writes a JSON (and, with --write, the GPU section of benchmarks/RESULTS.md).

    python3 benchmarks/gpu_check.py --write            # on a CUDA machine (make gpu-check)
    python3 benchmarks/gpu_check.py --dry-run          # anywhere: every step at a tiny size on the CPU, or
                                                       # "skipped: no CUDA" (CI: tests/test_gpu_check.py)

A GPU machine without a package index needs the working tree plus `.gpu_carry/` (made where an index is
by `make gpu-carry`, benchmarks/gpu_carry.py: gsplat's sources and the pure-Python packages the check
imports; appended to the END of sys.path here, so the machine's own packages win).

Steps, in this order (each one's figures, or why it could not run, go to the JSON; a failing step never
stops the rest, and the JSON is rewritten after every step, so a run cut short keeps what it measured):

  environment        torch, CUDA, the device, the carried packages in use
  (gsplat's kernels start compiling in a background process, its own build folder, one CUDA arch)
  decode_jpeg        torchvision.io.decode_jpeg on the device (batched) vs one CPU core (OpenCV and
                     torchvision), images/s, 360x640 photo-like JPEGs
  latency_paper      the paper preset: encoder + 3 target renders at 2 x 256x256, warm, median of 20, torch
                     rasterizer (the paper: 0.089 s on an H800, table 1)
  latency_mvsplat    MVSplat's encoder (+ renders), the same (table 1: 0.044 s)
  shards             synthetic triple shards (360x640 JPEGs, RE10K-like) made on the spot
  train_torch        configs/re10k_paper.json (bf16 autocast, batch 8, 256x256; LPIPS through a random VGG
                     trunk and a random DINOv3: no weights can be fetched) for 50 steps through the real
                     loader and Trainer, torch rasterizer: steps/s after 5 warm-up steps, peak memory (CUDA
                     max allocated while training, less what earlier steps still hold), the share of step
                     time spent waiting for data, the loader's own samples/s
  gsplat_build       waits for the build (--gsplat-build-s at most)
  rasterizer_parity  gsplat vs the tiled torch rasterizer on the same pixel-aligned Gaussians: images and
                     gradients, max differences
  latency_paper_gsplat, latency_mvsplat_gsplat, train_gsplat: the same with gsplat

Each step is time-boxed against --budget-s (training runs stop early and say so); the dry run uses the
tiny preset (and a narrow MVSplat) at 32x32, 2 training steps of batch 2 with one loader worker, precision
bf16 (CPU autocast) and no LPIPS, one thread: as close to the GPU path as a CPU goes, in seconds.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import os
import platform
import signal
import statistics
import subprocess
import sys
import tempfile
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
CARRIED = ROOT / ".gpu_carry" / "site"
if CARRIED.is_dir():
    sys.path.append(str(CARRIED))  # last: only what the machine lacks comes from here

import numpy as np  # noqa: E402
import torch  # noqa: E402

from benchmarks.model import MVSPLAT_LATENCY_S, PAPER_LATENCY_S, bench_inference, make_batch  # noqa: E402
from benchmarks.results_md import write_section  # noqa: E402

SECTION = "gpu"
MAKE_COMMAND = "make gpu-carry` (where a package index is), then on the GPU machine `make gpu-check"
ONE_LINER = "python3 benchmarks/gpu_check.py --write --json out/gpu_check.json"


@dataclass(frozen=True)
class Sizes:
    """How big each step is: the real check, or the CPU dry run."""

    image: int
    paper_preset: str
    mvsplat_overrides: dict = field(default_factory=dict)
    repeats: int = 20
    warmup: int = 3
    train_overrides: tuple[str, ...] = ()
    train_steps: int = 50
    warmup_steps: int = 5
    train_seconds: float = 150.0  # at most, per training run
    samples: int = 240
    parity_size: int = 128
    decode_images: int = 64


FULL = Sizes(image=256, paper_preset="paper")
DRY = Sizes(
    image=32,
    paper_preset="tiny",
    mvsplat_overrides={  # MVSplat's structure, narrow
        "num_depth_candidates": 8,
        "mv_layers": 1,
        "mvsplat_cnn_channels": (16, 24, 32),
        "mvsplat_feature_dim": 32,
        "mvsplat_cost_unet_channels": 16,
        "mvsplat_cost_unet_levels": 2,
        "mvsplat_cost_unet_attention": (),
        "mvsplat_depth_unet_channels": 8,
        "mvsplat_depth_unet_levels": 2,
        "mvsplat_depth_unet_attention": (),
    },
    repeats=2,
    warmup=1,
    train_overrides=(
        "model.preset=tiny",
        "data.image_size=[32,32]",
        "data.batch_size=2",
        "data.num_workers=1",
        "precision=bf16",
        "loss.lpips_weight=0",
    ),
    train_steps=2,
    warmup_steps=1,
    train_seconds=120.0,
    samples=8,
    parity_size=16,
    decode_images=8,
)


class Skip(Exception):
    """A step that cannot run here; its reason goes to the JSON as "skipped: REASON"."""


class OutOfTime(Exception):
    """A training run reached the seconds it was given."""


class TimeBoxed:
    """A loader whose iteration raises OutOfTime once `seconds` have passed since it was made."""

    def __init__(self, loader, seconds: float):
        self.loader, self.end = loader, time.perf_counter() + seconds

    def __iter__(self):
        for batch in self.loader:
            if time.perf_counter() > self.end:
                raise OutOfTime
            yield batch

    def state_dict(self) -> dict:
        return self.loader.state_dict()


def sync() -> None:
    if torch.cuda.is_available():
        torch.cuda.synchronize()


def need_cuda() -> torch.device:
    if not torch.cuda.is_available():
        raise Skip("no CUDA")
    return torch.device("cuda")


class Check:
    """The steps and their shared state; `run(name, fn)` records one step's result in `report`."""

    def __init__(self, sizes: Sizes, json_path: Path, budget_s: float, gsplat_build_s: float, work: Path):
        self.sizes, self.json_path, self.work = sizes, json_path, work
        self.t0 = time.perf_counter()
        self.deadline = self.t0 + budget_s
        self.gsplat_build_s = gsplat_build_s
        self.device = torch.device("cuda" if torch.cuda.is_available() else "cpu")
        self.report: dict = {
            "dry_run": sizes is DRY,
            "cuda": self.device.type == "cuda",
            "device": torch.cuda.get_device_name() if self.device.type == "cuda" else "CPU (no CUDA)",
            "date": time.strftime("%Y-%m-%d"),
            "budget_s": budget_s,
            "steps": {},
        }
        self.models: dict = {}
        self.shards: Path | None = None
        self.build: subprocess.Popen | None = None
        self.build_started = 0.0
        self.build_log = work / "gsplat_build.log"
        self.gsplat_ok = False

    def left(self) -> float:
        return self.deadline - time.perf_counter()

    def run(self, name: str, fn, *args) -> dict:
        t0 = time.perf_counter()
        try:
            if self.left() < 10:
                raise Skip(f"out of time (the check's {self.report['budget_s']:g} s)")
            result = {"status": "ok", **fn(*args)}
        except Skip as why:
            result = {"status": f"skipped: {why}"}
        except Exception as exc:  # noqa: BLE001 - one step's failure is reported, the rest still run
            first = (str(exc).splitlines() or [""])[0][:300]
            result = {"status": f"failed: {type(exc).__name__}: {first}", "traceback": traceback.format_exc()[-2000:]}
        result["seconds"] = round(time.perf_counter() - t0, 2)
        self.report["steps"][name] = result
        self.report["total_s"] = round(time.perf_counter() - self.t0, 1)
        self.save()
        shown = {k: v for k, v in result.items() if k not in ("traceback", "status", "seconds")}
        print(f"gpu_check: {name}: {result['status']} ({result['seconds']} s) {json.dumps(shown)[:400]}", flush=True)
        return result

    def save(self) -> None:
        from seeu_data.store.arrow_io import atomic_write_text

        self.json_path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(self.json_path, json.dumps(self.report, indent=1) + "\n")

    # ------------------------------------------------------------------ steps
    def environment(self) -> dict:
        import torchvision

        env = {
            "python": platform.python_version(),
            "torch": torch.__version__,
            "torchvision": torchvision.__version__,
            "cuda": torch.version.cuda,
            "cpus": os.cpu_count(),
            "carried": sorted(name.split("-")[0] for name in os.listdir(CARRIED) if name.endswith(".dist-info"))
            if CARRIED.is_dir()
            else [],
        }
        for name in ("timm", "gsplat", "lpips", "tensorboard", "jsonschema", "scipy"):
            why = not_importable(name)
            module = sys.modules.get(name)
            where = "carried" if str(CARRIED) in str(getattr(module, "__file__", "")) else "machine"
            env[name] = f"{_version(name)} ({where})" if why is None else f"missing: {why}"
        if self.device.type == "cuda":
            props = torch.cuda.get_device_properties(0)
            env.update(
                gpu=props.name,
                capability=f"{props.major}.{props.minor}",
                gpu_memory_gib=round(props.total_memory / 2**30, 1),
                bf16=torch.cuda.is_bf16_supported(),
            )
        return env

    def start_gsplat_build(self) -> None:
        """Compile gsplat's kernels in a background process (the torch steps run meanwhile)."""
        if self.device.type != "cuda" or importlib.util.find_spec("gsplat") is None:
            return
        major, minor = torch.cuda.get_device_capability()
        os.environ.setdefault("TORCH_CUDA_ARCH_LIST", f"{major}.{minor}")  # this GPU only: a shorter build
        os.environ.setdefault("TORCH_EXTENSIONS_DIR", str(self.work / "torch_extensions"))
        os.environ.setdefault("MAX_JOBS", str(max(1, (os.cpu_count() or 2) - 4)))  # cores left for the loader
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}  # the same order
        code = "from gsplat.cuda._backend import _C\nassert _C is not None, 'gsplat found no CUDA toolkit (nvcc)'"
        with open(self.build_log, "w") as log:
            self.build = subprocess.Popen(
                [sys.executable, "-c", code], stdout=log, stderr=subprocess.STDOUT, env=env, start_new_session=True
            )
        self.build_started = time.perf_counter()

    def gsplat_build(self) -> dict:
        need_cuda()
        if self.build is None:
            raise Skip("gsplat is not installed (make gpu-carry where a package index is, and bring .gpu_carry)")
        limit = min(self.gsplat_build_s - (time.perf_counter() - self.build_started), self.left() - 60)
        try:
            rc = self.build.wait(timeout=max(limit, 1))
        except subprocess.TimeoutExpired:
            end_session(self.build)
            raise RuntimeError(f"the build did not finish in the {self.gsplat_build_s:g} s it was given") from None
        tail = self.build_log.read_text(errors="replace").strip().splitlines()[-3:]
        if rc != 0:
            raise RuntimeError(f"the build failed (exit {rc}): {' | '.join(tail)}")
        import gsplat

        self.gsplat_ok = True
        return {
            "version": gsplat.__version__,
            "build_s": round(time.perf_counter() - self.build_started, 1),
            "torch_cuda_arch_list": os.environ["TORCH_CUDA_ARCH_LIST"],
            "max_jobs": os.environ["MAX_JOBS"],
        }

    def need_gsplat(self) -> None:
        need_cuda()
        if not self.gsplat_ok:
            raise Skip(f"gsplat is not built ({self.report['steps'].get('gsplat_build', {}).get('status')})")

    def decode_jpeg(self) -> dict:
        import cv2
        from torchvision.io import decode_jpeg

        from benchmarks.loader import photo_like_frames

        frames = photo_like_frames(self.sizes.decode_images)
        data = [torch.frombuffer(bytearray(b), dtype=torch.uint8) for b in frames]
        cv2.setNumThreads(1)
        threads = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            t0 = time.perf_counter()
            cpu_cv2 = [cv2.imdecode(np.frombuffer(b, np.uint8), cv2.IMREAD_COLOR) for b in frames]
            t1 = time.perf_counter()
            cpu_tv = [decode_jpeg(d) for d in data]
            t2 = time.perf_counter()
        finally:
            torch.set_num_threads(threads)
        out = {
            "images": len(frames),
            "size": f"{cpu_cv2[0].shape[0]}x{cpu_cv2[0].shape[1]}",
            "cpu_opencv_images_per_s": round(len(frames) / (t1 - t0), 1),
            "cpu_torchvision_images_per_s": round(len(frames) / (t2 - t1), 1),
        }
        if self.device.type != "cuda":
            out["device"] = "skipped: no CUDA"
            return out
        decode_jpeg(data, device="cuda")  # warm-up (nvJPEG handles)
        times = []
        for _ in range(5):
            sync()
            t0 = time.perf_counter()
            gpu = decode_jpeg(data, device="cuda")
            sync()
            times.append(time.perf_counter() - t0)
        diff = max(float((g.cpu().float() - c.float()).abs().mean()) for g, c in zip(gpu, cpu_tv))
        out.update(
            device_images_per_s=round(len(frames) / statistics.median(times), 1),
            device_vs_cpu_mean_abs_diff=round(diff, 3),  # nvJPEG and libjpeg round their IDCTs differently
        )
        return out

    def model(self, preset: str):
        if preset not in self.models:
            from seeu_model.config import SeeUConfig
            from seeu_model.seeu import SeeU

            torch.manual_seed(0)
            overrides = self.sizes.mvsplat_overrides if preset == "mvsplat" else {}
            cfg = SeeUConfig.preset(preset, semantic_pretrained=False, semantic_weights=None, **overrides)
            self.models[preset] = SeeU(cfg).to(self.device).eval()
        return self.models[preset]

    def latency(self, preset: str, backend: str) -> dict:
        if backend == "gsplat":
            self.need_gsplat()
        s = self.sizes
        batch = make_batch(1, 2, 3, s.image, self.device)
        res = bench_inference(self.model(preset), batch, self.device, s.repeats, s.warmup, backend)
        paper = MVSPLAT_LATENCY_S if preset == "mvsplat" else PAPER_LATENCY_S
        return {
            "preset": preset,
            "backend": backend,
            "views": f"2 x {s.image}x{s.image}, 3 targets",
            "median_of": s.repeats,
            **{k: round(v, 4) for k, v in res.items()},
            "paper_s": paper,
        }

    def make_shards(self) -> dict:
        from benchmarks.loader import make_triples, write_seeu_shards

        distinct = max(5, min(64, self.sizes.samples))  # 5 views of a sample are distinct frames
        self.shards = write_seeu_shards(self.work / "shards", make_triples(self.sizes.samples, distinct))
        return {"samples": self.sizes.samples, "views": 5, "jpeg": "360x640", "path": str(self.shards)}

    def train(self, rasterizer: str) -> dict:
        if rasterizer == "gsplat":
            self.need_gsplat()
        if self.shards is None:
            raise Skip("no shards (see the shards step)")
        s = self.sizes
        if self.left() < 60:
            raise Skip(f"out of time (the check's {self.report['budget_s']:g} s)")
        from pipelines.train import make_lpips, make_train_loader
        from seeu_model.evaluation import peak_memory_mb
        from seeu_model.training.config import load_config
        from seeu_model.training.distributed import DistInfo
        from seeu_model.training.effective_batch import plan_batches
        from seeu_model.training.factory import build_model, make_render_fn
        from seeu_model.training.loop import Trainer

        notes = ["random DINOv3 (semantic_pretrained=false) and a random LPIPS VGG trunk: no weights to fetch"]
        overrides = [
            "model.semantic_pretrained=false",
            "loss.lpips_random_trunk=true",
            *s.train_overrides,
            f"optim.max_steps={s.train_steps}",
            f"checkpoint.every={s.train_steps}",
            "log.every=1",
            f"log.image_every={s.train_steps}",
            "log.progress=false",
            f"rasterizer={rasterizer}",
        ]
        why = not_importable("lpips")
        if why is not None:
            overrides.append("loss.lpips_weight=0")
            notes.append(f"LPIPS left out: lpips does not import here ({why})")
        cfg = load_config(ROOT / "configs" / "re10k_paper.json", overrides)
        dist = DistInfo(device=self.device)
        batches = plan_batches(cfg.data.batch_size, cfg.optim.accumulate, 1)
        out = self.work / f"run_{rasterizer}"
        loader_rate = loader_samples_per_s(
            make_train_loader(str(self.shards), cfg, dist, str(out / "cache")),
            min(30, s.samples // cfg.data.batch_size),
            self.left() / 20,
        )
        loader = make_train_loader(str(self.shards), cfg, dist, str(out / "cache"))
        before = torch.cuda.memory_allocated() if self.device.type == "cuda" else 0  # the latency steps' models
        if self.device.type == "cuda":
            torch.cuda.reset_peak_memory_stats()
        torch.manual_seed(cfg.seed)
        model, model_cfg = build_model(cfg.model)
        trainer = Trainer(
            model, cfg, out, make_render_fn(cfg.rasterizer), dist, make_lpips(cfg), model_cfg, batches=batches
        )
        seconds = min(s.train_seconds, self.left() - 20)
        try:
            trainer.fit(TimeBoxed(loader, seconds))
            cut = None
        except OutOfTime:
            cut = f"stopped after {trainer.step} steps: the {seconds:.0f} s it was given ran out"
        peak, kind = peak_memory_mb(self.device)
        peak -= before / 2**20
        timed = [h for h in trainer.history if h["step"] > s.warmup_steps]
        if not timed:
            raise RuntimeError(f"no step after the {s.warmup_steps} warm-up steps ({cut})")
        step_s = [1 / h["it_per_s"] for h in timed]
        steps_per_s = len(timed) / sum(step_s)
        building = self.build is not None and self.build.poll() is None
        return {
            "rasterizer": rasterizer,
            "precision": cfg.precision,
            "effective_batch": batches.effective,
            "image_size": list(cfg.data.image_size),
            "num_workers": cfg.data.num_workers,
            "steps": trainer.step,
            "timed_steps": len(timed),
            "steps_per_s": round(steps_per_s, 3),
            "samples_per_s": round(steps_per_s * batches.effective, 2),
            "first_step_s": round(1 / trainer.history[0]["it_per_s"], 2),
            "peak_memory_gib": round(peak / 1024, 2),
            "memory_kind": kind,
            "data_wait_share": round(sum(h["data_wait_s"] for h in timed) / sum(step_s), 4),
            "loader_alone_samples_per_s": round(loader_rate, 1),
            "final_loss": round(trainer.history[-1]["loss"], 5),
            "gsplat_build_alongside": building,
            "cut_short": cut,
            "notes": notes,
        }

    def parity(self) -> dict:
        self.need_gsplat()
        from dataclasses import replace

        from benchmarks.render import pixel_aligned_scene
        from seeu_model.rasterizer import rasterize

        size = self.sizes.parity_size
        g, c2w, k = pixel_aligned_scene(size, views=2)
        gen = torch.Generator().manual_seed(0)
        g = replace(
            g, scales=g.scales * (0.5 + torch.rand(g.scales.shape, generator=gen))
        )  # anisotropic: rotations matter
        cot = torch.randn(1, 2, 3, size, size, generator=gen).cuda()  # a fixed upstream gradient of the colours
        g, c2w, k = g.map(lambda t: t.cuda()), c2w.cuda(), k.cuda()
        outs, grads = {}, {}
        for backend in ("torch", "gsplat"):
            leaves = g.map(lambda t: t.detach().clone().requires_grad_())
            out = rasterize(leaves, c2w, k, size, size, backend=backend)
            (out.color * cot).sum().backward()
            outs[backend] = out
            grads[backend] = {f: getattr(leaves, f).grad for f in ("means", "scales", "rotations", "opacities", "sh")}
        a, b = outs["torch"], outs["gsplat"]
        diff = lambda x, y: float((x.detach() - y.detach()).abs().max())  # noqa: E731
        mse = float((a.color.detach() - b.color.detach()).pow(2).mean())
        return {
            "scene": f"{size}x{size} pixel-aligned anisotropic Gaussians, 2 views",
            "color_max_abs_diff": diff(a.color, b.color),
            "color_psnr_db": round(-10 * math.log10(max(mse, 1e-20)), 2),
            "alpha_max_abs_diff": diff(a.alpha, b.alpha),
            "depth_max_abs_diff": diff(a.depth, b.depth),
            "grad_max_abs_diff_relative": {  # to the field's largest torch gradient
                f: diff(grads["torch"][f], grads["gsplat"][f]) / max(float(grads["torch"][f].abs().max()), 1e-30)
                for f in grads["torch"]
            },
        }


def end_session(proc: subprocess.Popen) -> None:
    """Kill `proc` (started with start_new_session=True) and every process of its session, then reap it:
    ninja puts each compiler job in a process group of its own, so killing the group would leave them."""
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            fields = Path(f"/proc/{entry}/stat").read_text().rsplit(")", 1)[1].split()  # state ppid pgrp session
            if int(fields[3]) == proc.pid:
                os.kill(int(entry), signal.SIGKILL)
        except (OSError, ValueError, IndexError):
            continue  # gone meanwhile
    proc.wait()


def not_importable(name: str) -> str | None:
    """None when module `name` imports here, else why not (one line)."""
    try:
        importlib.import_module(name)
    except Exception as exc:  # noqa: BLE001 - any failure means the module cannot be used
        return f"{type(exc).__name__}: {(str(exc).splitlines() or [''])[0][:200]}"
    return None


def _version(dist: str) -> str | None:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(dist)
    except PackageNotFoundError:
        return None


def loader_samples_per_s(loader, batches: int, seconds: float) -> float:
    """The loader alone (no model): samples/s over up to `batches` batches after the first, or `seconds`."""
    it = iter(loader)
    next(it)  # workers started, first batch made
    n, t0 = 0, time.perf_counter()
    for _ in range(max(batches, 1)):
        batch = next(it, None)
        if batch is None or time.perf_counter() - t0 > seconds:
            break
        n += len(batch["sample_id"])
    del it
    return n / max(time.perf_counter() - t0, 1e-9)


# ---------------------------------------------------------------------------------------- report


def section(report: dict) -> str:
    """The GPU section of benchmarks/RESULTS.md for a check's report."""
    steps = report["steps"]
    lines = ["## GPU check (`benchmarks/gpu_check.py`)", ""]
    if not report["cuda"] or report["dry_run"]:
        where = "No GPU was available" if not report["cuda"] else f"Only a dry run on {report['device']}"
        lines += [
            f"{where} when this section was written ({report['date']}): what stands is the dry run, the same "
            "script at tiny sizes, which checks the script and the CPU side of the training path, not GPU speed "
            "(CI runs it: tests/test_gpu_check.py; its timings are not figures to keep). The GPU figures are "
            f"still to be measured: `{MAKE_COMMAND}` (or `{ONE_LINER}` with `.gpu_carry/` beside the working "
            "tree), at most 8 minutes on one H100; it rewrites this section with the device named.",
            "",
            "- dry-run steps: " + "; ".join(f"{k} {v['status']}" for k, v in steps.items()),
        ]
        return "\n".join(lines)
    env = steps.get("environment", {})
    lines.append(
        f"- device: {report['device']} ({env.get('gpu_memory_gib')} GiB), torch {env.get('torch')}, CUDA "
        f"{env.get('cuda')}, {env.get('cpus')} CPUs; {report['date']}, {report.get('total_s')} s in all (`{ONE_LINER}`)"
    )
    for name in ("latency_paper", "latency_paper_gsplat", "latency_mvsplat", "latency_mvsplat_gsplat"):
        r = steps.get(name, {})
        if r.get("status") == "ok":
            lines.append(
                f"- latency, {r['preset']} preset, {r['backend']} rasterizer ({r['views']}, warm, median of "
                f"{r['median_of']}): encoder {r['encode_s']:.4f} s + renders {r['render3_s']:.4f} s, together "
                f"{r['total_s']:.4f} s (paper: {r['paper_s']} s)"
                + (f"; peak {r['peak_mem_gib']:.2f} GiB" if "peak_mem_gib" in r else "")
            )
    for name in ("train_torch", "train_gsplat"):
        r = steps.get(name, {})
        if r.get("status") == "ok":
            lines.append(
                f"- training, configs/re10k_paper.json, {r['rasterizer']} rasterizer ({r['precision']}, batch "
                f"{r['effective_batch']}, {r['image_size'][0]}x{r['image_size'][1]}, {r['num_workers']} loader workers): "
                f"{r['steps_per_s']} steps/s ({r['samples_per_s']} samples/s) over {r['timed_steps']} steps after "
                f"warm-up, peak {r['peak_memory_gib']} GiB ({r['memory_kind']}), data wait "
                f"{100 * r['data_wait_share']:.1f} % of step time, the loader alone {r['loader_alone_samples_per_s']} "
                "samples/s"
                + (f"; {r['cut_short']}" if r["cut_short"] else "")
                + ("; gsplat's build ran alongside" if r["gsplat_build_alongside"] else "")
            )
    r = steps.get("rasterizer_parity", {})
    if r.get("status") == "ok":
        worst = max(r["grad_max_abs_diff_relative"].items(), key=lambda kv: kv[1])
        lines.append(
            f"- gsplat vs the torch rasterizer ({r['scene']}): colour max |diff| {r['color_max_abs_diff']:.2e} "
            f"(PSNR {r['color_psnr_db']} dB), alpha {r['alpha_max_abs_diff']:.2e}, depth {r['depth_max_abs_diff']:.2e}; "
            f"gradients within {worst[1]:.2e} of the largest (worst: {worst[0]})"
        )
    r = steps.get("decode_jpeg", {})
    if r.get("status") == "ok":
        device = r.get("device_images_per_s", r.get("device"))
        lines.append(
            f"- JPEG decode ({r['images']} x {r['size']}): device (torchvision.io.decode_jpeg, batched) {device} "
            f"images/s; one CPU core: OpenCV {r['cpu_opencv_images_per_s']}, torchvision "
            f"{r['cpu_torchvision_images_per_s']} images/s"
        )
    lines.append("- steps: " + "; ".join(f"{k} {v['status']}" for k, v in steps.items()))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dry-run", action="store_true", help="tiny sizes (the CPU rehearsal CI runs)")
    ap.add_argument("--json", type=Path, default=ROOT / "out" / "gpu_check.json", help="the report")
    ap.add_argument("--write", action="store_true", help="write the GPU section of --results")
    ap.add_argument("--results", type=Path, default=ROOT / "benchmarks" / "RESULTS.md")
    ap.add_argument("--budget-s", type=float, default=480.0, help="the whole check's time (8 minutes)")
    ap.add_argument("--gsplat-build-s", type=float, default=300.0, help="the most gsplat's build may take")
    args = ap.parse_args(argv)
    threads = torch.get_num_threads()
    if args.dry_run:
        torch.set_num_threads(1)  # tiny tensors: threads only contend
    with tempfile.TemporaryDirectory(prefix="seeu-gpu-check-") as tmp:
        check = Check(DRY if args.dry_run else FULL, args.json, args.budget_s, args.gsplat_build_s, Path(tmp))
        try:
            check.run("environment", check.environment)
            check.start_gsplat_build()
            check.run("decode_jpeg", check.decode_jpeg)
            check.run("latency_paper", check.latency, check.sizes.paper_preset, "torch")
            check.run("latency_mvsplat", check.latency, "mvsplat", "torch")
            check.run("shards", check.make_shards)
            check.run("train_torch", check.train, "torch")
            check.run("gsplat_build", check.gsplat_build)
            check.run("rasterizer_parity", check.parity)
            check.run("latency_paper_gsplat", check.latency, check.sizes.paper_preset, "gsplat")
            check.run("latency_mvsplat_gsplat", check.latency, "mvsplat", "gsplat")
            check.run("train_gsplat", check.train, "gsplat")
        finally:
            torch.set_num_threads(threads)
            if check.build is not None:
                end_session(check.build)
    text = section(check.report)
    print(text)
    if args.write:
        write_section(SECTION, text, args.results)
    print(f"gpu_check: {args.json} ({check.report['total_s']} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
