"""seeu ablate: equal budgets, one table, deltas against the full model, extrapolation ranges through the data."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pyarrow.ipc as ipc
import pytest

from pipelines.ablate import build_ext_shards, write_table
from pipelines.cli import main
from tests.training_fixtures import synthetic_posed, synthetic_triples

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def test_table_deltas_against_full(tmp_path):
    rows = [
        {
            "variant": "full",
            "label": "Full",
            "psnr": 27.56,
            "ssim": 0.888,
            "lpips": 0.114,
            "num_targets": 9,
            "trainable_params": 10,
            "train_seconds": 1.0,
        },
        {
            "variant": "no_refiner",
            "label": "w/o",
            "psnr": 25.47,
            "ssim": 0.849,
            "lpips": None,
            "num_targets": 9,
            "trainable_params": 5,
            "train_seconds": 1.0,
        },
    ]
    write_table(tmp_path, rows, {"steps": 3, "batch_size": 2, "lr": 1e-3, "seed": 0, "eval": "E"})
    md = (tmp_path / "ablation.md").read_text()
    assert "| no_refiner | w/o | 25.47 | 0.849 | — | -2.09 | -0.039 | — |" in md
    assert "3 steps x batch 2 (6 training samples)" in md
    got = list(csv.DictReader((tmp_path / "ablation.csv").open()))
    assert float(got[1]["d_psnr"]) == pytest.approx(-2.09) and got[1]["d_lpips"] == ""


def test_extrapolation_range_shards(tmp_path):
    posed = synthetic_posed(tmp_path, n_frames=16, hw=(32, 32))
    like = synthetic_triples(tmp_path, n_frames=16, hw=(32, 32), samples_per_scene=6)
    paths = build_ext_shards(str(posed), tmp_path / "abl", [0, 3], like=str(like))
    offsets = {}
    for n in paths:
        vals = []
        for f in sorted((tmp_path / "abl" / f"shards_ext{n}").glob("*.arrow")):
            t = ipc.open_file(str(f)).read_all()
            vals += [o for row in t.column("target_offset").to_pylist() for o in row]
        offsets[n] = vals
    assert offsets[0] and all(o == 0 for o in offsets[0])
    assert all(abs(o) <= 3 for o in offsets[3]) and any(o != 0 for o in offsets[3])


def test_ablate_cli_equal_budgets(tmp_path):
    shards = synthetic_triples(tmp_path, n_frames=16, hw=(32, 32), samples_per_scene=4)
    out = tmp_path / "abl"
    args = [
        "ablate",
        "--config",
        str(CONFIGS / "cpu_small.json"),
        "--data",
        str(shards),
        "--eval",
        str(shards),
        "--out",
        str(out),
        "--variants",
        "full,no_refiner",
        "--max-eval-samples",
        "1",
        "--no-lpips",
        "model.preset=tiny",
        "optim.max_steps=1",
        "data.image_size=[32,32]",
        "data.batch_size=1",
    ]
    assert main(args) == 0
    rows = list(csv.DictReader((out / "ablation.csv").open()))
    assert [r["variant"] for r in rows] == ["full", "no_refiner"]
    assert int(rows[0]["trainable_params"]) > int(rows[1]["trainable_params"])  # the refiner is gone
    for r in rows:
        assert int(r["steps"]) == 1 and r["num_targets"] == "3"
        cfg = json.loads((out / r["variant"] / "config.json").read_text())
        assert cfg["optim"]["max_steps"] == 1 and cfg["data"]["batch_size"] == 1
    assert json.loads((out / "no_refiner" / "config.json").read_text())["model"]["refiner"] == "none"
    mtime = (out / "full" / "eval" / "summary.json").stat().st_mtime
    assert main(args) == 0  # re-run reuses finished variants
    assert (out / "full" / "eval" / "summary.json").stat().st_mtime == mtime
    assert main(args[:-4] + ["--variants", "nope"]) == 2
