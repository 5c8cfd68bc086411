"""Training: schedule closed form, config overrides, exact resume, and DDP (2 gloo processes) vs one process."""

from __future__ import annotations

import json
import math
import socket
from pathlib import Path

import pytest
import torch

from seeu_data.errors import SeeUError
from seeu_model.training import checkpoint as ckpt_io
from seeu_model.training.config import load_config
from seeu_model.training.schedule import warmup_cosine_factor
from tests.training_fixtures import ddp_worker, initial_state, synthetic_triples

# The real SeeU model (tiny preset: same architecture, tiny widths, random 2-block ViT-S semantic encoder).
COMMON = [
    "model.preset=tiny",
    "data.num_workers=0",
    "data.image_size=[32,32]",
    "optim.warmup_steps=2",
    "optim.lr=2e-3",
    "loss.lpips_weight=0",
    "log.every=1",
    "log.image_every=1000",
    "precision=fp32",
    "rasterizer=torch",
]


@pytest.fixture(scope="module")
def shards(tmp_path_factory) -> Path:
    return synthetic_triples(tmp_path_factory.mktemp("train_data"), n_frames=16, hw=(32, 32), samples_per_scene=8)


def _params(run: Path) -> dict[str, torch.Tensor]:
    return ckpt_io.load_checkpoint(run / "checkpoints")["model"]


def test_warmup_cosine_closed_form():
    assert warmup_cosine_factor(0, 4, 20) == pytest.approx(0.25)
    assert warmup_cosine_factor(3, 4, 20) == pytest.approx(1.0)
    assert warmup_cosine_factor(4, 4, 20) == pytest.approx(1.0)
    assert warmup_cosine_factor(12, 4, 20) == pytest.approx(0.5)  # half way: cos(pi/2)
    assert warmup_cosine_factor(20, 4, 20) == pytest.approx(0.0, abs=1e-12)
    assert warmup_cosine_factor(8, 4, 20, 0.1) == pytest.approx(0.1 + 0.9 * 0.5 * (1 + math.cos(math.pi / 4)))


def test_config_presets_and_overrides(tmp_path):
    root = Path(__file__).resolve().parents[1] / "configs"
    paper = load_config(root / "re10k_paper.json")
    assert (paper.data.batch_size, paper.optim.max_steps, paper.loss.lpips_weight) == (8, 300_000, 0.05)
    assert paper.data.image_size == (256, 256)
    small = load_config(
        root / "cpu_small.json", ["optim.lr=5e-4", "data.image_size=32x48", "model.refiner=unet", "log.progress=true"]
    )
    assert small.optim.lr == 5e-4 and small.data.image_size == (32, 48) and small.model["refiner"] == "unet"
    assert small.log.progress is True
    for preset in sorted(root.glob("*.json")):  # every shipped preset parses and validates
        cfg = load_config(preset)
        assert cfg.model.get("preset") in ("paper", "cpu_small", "tiny"), preset
    with pytest.raises(SeeUError, match="unknown key"):
        load_config(None, ["optim.learning_rate=1"])
    with pytest.raises(SeeUError, match="integer"):
        load_config(None, ["data.batch_size=2.5"])
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(SeeUError, match="not valid JSON"):
        load_config(bad)


def test_resume_continues_the_same_run(shards, tmp_path):
    from pipelines.train import TrainRunConfig, train

    ov = COMMON + [
        "data.batch_size=2",
        "optim.max_steps=3",
        "checkpoint.every=1",
        "checkpoint.keep=2",
        "data.flip=true",
    ]
    full = train(TrainRunConfig(data=str(shards), out=tmp_path / "full", overrides=ov))
    part = train(TrainRunConfig(data=str(shards), out=tmp_path / "part", overrides=ov, stop_after=1))
    assert part["step"] == 1
    with pytest.raises(SeeUError, match="--resume"):
        train(TrainRunConfig(data=str(shards), out=tmp_path / "part", overrides=ov))
    rest = train(TrainRunConfig(data=str(shards), out=tmp_path / "part", overrides=ov, resume=True))
    assert rest["step"] == 3
    # keep-K: only the last two checkpoints remain, no temporaries
    names = sorted(p.name for p in (tmp_path / "part" / "checkpoints").iterdir())
    assert names == ["ckpt-00000002.pt", "ckpt-00000003.pt"]
    a, b = _params(tmp_path / "full"), _params(tmp_path / "part")
    assert a.keys() == b.keys()
    for k in a:
        assert torch.allclose(a[k], b[k], atol=1e-6, rtol=0), k
    # the resumed run continued the same loss curve (steps 2 and 3)
    la = {h["step"]: h["loss"] for h in full["history"]}
    lb = {h["step"]: h["loss"] for h in rest["history"]}
    assert la[2] == pytest.approx(lb[2], abs=1e-6) and la[3] == pytest.approx(lb[3], abs=1e-6)
    # TensorBoard: losses, PSNR, learning rate and the rendered-vs-ground-truth grid
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    ea = EventAccumulator(str(tmp_path / "full" / "tb"))
    ea.Reload()
    assert {"train/loss", "train/psnr", "train/lr", "train/mse"} <= set(ea.Tags()["scalars"])
    assert [e.step for e in ea.Scalars("train/loss")] == [1, 2, 3]
    assert "train/gt_vs_render" in ea.Tags()["images"]
    # and it learned something different from the initialisation
    init = initial_state({"preset": "tiny"})
    assert any(not torch.allclose(init[k], a[k]) for k in a)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_ddp_two_processes_match_one_process_with_double_batch(shards, tmp_path):
    import torch.multiprocessing as mp

    from pipelines.train import TrainRunConfig, train

    steps = 2
    # Adam turns gradients far below eps-scale into full +-lr steps whose sign is decided by float
    # summation order; a larger eps keeps the update linear in the gradient so the comparison is fair.
    ov = COMMON + [f"optim.max_steps={steps}", f"checkpoint.every={steps}", "data.flip=true", "optim.eps=1e-3"]
    single = train(TrainRunConfig(data=str(shards), out=tmp_path / "one", overrides=ov + ["data.batch_size=4"]))
    assert single["world_size"] == 1
    kwargs = dict(data=str(shards), out=str(tmp_path / "two"), overrides=ov + ["data.batch_size=2"])
    mp.spawn(ddp_worker, args=(2, _free_port(), kwargs), nprocs=2, join=True)
    two = json.loads((tmp_path / "two" / "train_summary.json").read_text())
    assert two["world_size"] == 2
    # same samples: the step-1 loss (mean over both ranks) equals the single process's
    assert two["history"][0]["loss"] == pytest.approx(single["history"][0]["loss"], rel=1e-5)
    a, b = _params(tmp_path / "one"), _params(tmp_path / "two")
    init = initial_state({"preset": "tiny"})
    moved = max((a[k] - init[k]).abs().max().item() for k in a)
    assert moved > 1e-4  # training changed the parameters, so the comparison means something
    for k in a:
        assert torch.allclose(a[k], b[k], atol=1e-5, rtol=1e-4), (k, (a[k] - b[k]).abs().max().item())
