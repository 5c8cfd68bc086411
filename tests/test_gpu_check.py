"""The GPU check's CPU dry run (benchmarks/gpu_check.py --dry-run): every step runs at a tiny size or
says why not ("skipped: no CUDA"), a failing step does not stop the rest, and the RESULTS.md section says
that no GPU was available, with the command to run when one is."""

from __future__ import annotations

import json
import math

import pytest
import torch

pytestmark = pytest.mark.skipif(torch.cuda.is_available(), reason="the dry run's CPU expectations")

GPU_ONLY = ("gsplat_build", "rasterizer_parity", "latency_paper_gsplat", "latency_mvsplat_gsplat", "train_gsplat")
ON_CPU = ("environment", "decode_jpeg", "latency_paper", "latency_mvsplat", "shards", "train_torch")


def test_dry_run_reports_every_step_and_writes_the_gpu_section(tmp_path):
    from benchmarks import gpu_check

    results = tmp_path / "RESULTS.md"
    results.write_text("# Benchmark results\n\n<!-- gpu:begin -->\nstale\n<!-- gpu:end -->\n\n## Next\n")
    report_path = tmp_path / "gpu_check.json"
    argv = ["--dry-run", "--json", str(report_path), "--write", "--results", str(results)]
    assert gpu_check.main(argv) == 0
    report = json.loads(report_path.read_text())
    steps = report["steps"]
    assert tuple(steps) == ON_CPU + GPU_ONLY  # in the order they run
    assert {name: steps[name]["status"] for name in GPU_ONLY} == dict.fromkeys(GPU_ONLY, "skipped: no CUDA")
    assert {name: steps[name]["status"] for name in ON_CPU} == dict.fromkeys(ON_CPU, "ok")
    assert report["dry_run"] and not report["cuda"]
    decode = steps["decode_jpeg"]
    assert decode["device"] == "skipped: no CUDA" and decode["cpu_opencv_images_per_s"] > 0
    for name, preset in (("latency_paper", "tiny"), ("latency_mvsplat", "mvsplat")):
        lat = steps[name]
        assert lat["preset"] == preset and lat["encode_s"] > 0 and lat["render3_s"] > 0, lat
    train = steps["train_torch"]
    assert (train["precision"], train["steps"], train["effective_batch"]) == ("bf16", 2, 2)
    assert 0 <= train["data_wait_share"] <= 1 and math.isfinite(train["final_loss"]) and train["cut_short"] is None
    text = results.read_text()
    assert "stale" not in text and text.endswith("<!-- gpu:end -->\n\n## Next\n")
    assert "No GPU was available" in text and "make gpu-check" in text
    assert "python3 benchmarks/gpu_check.py --write --json out/gpu_check.json" in text
    # the section a GPU run writes, from these steps' own results as a GPU run would return them
    gpu = {**report, "cuda": True, "dry_run": False, "device": "NVIDIA H100 80GB HBM3"}
    gpu["steps"] = {
        **steps,
        "latency_paper_gsplat": {**steps["latency_paper"], "backend": "gsplat", "peak_mem_gib": 1.5},
        "train_gsplat": {**steps["train_torch"], "rasterizer": "gsplat", "gsplat_build_alongside": False},
        "rasterizer_parity": {
            "status": "ok",
            "scene": "128x128 pixel-aligned Gaussians, 2 views",
            "color_max_abs_diff": 2e-4,
            "color_psnr_db": 71.0,
            "alpha_max_abs_diff": 1e-4,
            "depth_max_abs_diff": 3e-3,
            "grad_max_abs_diff_relative": {"means": 1e-3, "sh": 2e-4},
        },
    }
    text = gpu_check.section(gpu)
    assert "No GPU" not in text and "- device: NVIDIA H100 80GB HBM3" in text
    assert "tiny preset, gsplat rasterizer" in text and "gsplat rasterizer (bf16, batch 2" in text
    assert "gradients within 1.00e-03 of the largest (worst: means)" in text


def test_a_failing_step_is_reported_and_the_next_one_runs(tmp_path):
    from benchmarks.gpu_check import DRY, Check

    check = Check(DRY, tmp_path / "r.json", budget_s=60, gsplat_build_s=1, work=tmp_path)

    def broken():
        raise RuntimeError("nvcc exploded\nsecond line")

    check.run("broken", broken)
    check.run("fine", lambda: {"x": 1})
    saved = json.loads((tmp_path / "r.json").read_text())["steps"]
    assert saved["broken"]["status"] == "failed: RuntimeError: nvcc exploded"
    assert "Traceback" in saved["broken"]["traceback"]
    assert saved["fine"]["status"] == "ok" and saved["fine"]["x"] == 1
    check.deadline = 0  # the budget is spent: a step is skipped, not started
    assert check.run("late", lambda: {})["status"].startswith("skipped: out of time")
