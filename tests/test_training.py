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


# ------------------------------------------------------------------------------------------------
# Non-finite guard (Trainer level: a batch whose camera holds a NaN, weights that overflow)
# ------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def good_and_nan_batch(workspace) -> tuple[dict, dict]:
    """Two loader batches of the workspace triples: as read, and the same with one NaN camera value."""
    from seeu_data.loader import make_loader

    good = next(iter(make_loader(workspace["triples"], 2, image_hw=(32, 32), flip_p=0.0, shuffle=False)))
    cams = good["context"]["cam_to_world"].clone()
    cams[0, 0, 0, 3] = float("nan")
    return good, {**good, "context": {**good["context"], "cam_to_world": cams}}


def _trainer(tmp_path: Path, *overrides: str):
    from seeu_model.training.factory import make_render_fn
    from seeu_model.training.loop import Trainer
    from tests.training_fixtures import tiny_model_factory

    cfg = load_config(
        None,
        [
            "optim.max_steps=3",
            "optim.warmup_steps=0",
            "optim.lr=1e-3",
            "loss.lpips_weight=0",
            "checkpoint.every=1",
            "checkpoint.keep=5",
            "log.every=1",
            "log.progress=false",
            "precision=fp32",
            *overrides,
        ],
    )
    return Trainer(tiny_model_factory({})[0], cfg, tmp_path / "run", make_render_fn("torch"))


def _saved_are_finite(run: Path) -> list[str]:
    saved = ckpt_io.list_checkpoints(run / "checkpoints")
    for p in saved:
        assert ckpt_io.first_nonfinite(torch.load(p, weights_only=True)) is None, p
    return [p.name for p in saved]


def test_nan_camera_batch_stops_at_its_step_and_saves_nothing_of_it(good_and_nan_batch, tmp_path):
    good, bad = good_and_nan_batch
    trainer = _trainer(tmp_path)
    with pytest.raises(SeeUError) as err:
        trainer.fit([good, bad])
    msg = str(err.value)
    assert "step 2: non-finite" in msg and ", ".join(bad["sample_id"]) in msg and "\n" not in msg
    assert _saved_are_finite(tmp_path / "run") == ["ckpt-00000001.pt"]  # the last good one stays the newest
    assert trainer.step == 1 and all(torch.isfinite(p).all() for p in trainer.model.parameters())


def test_skip_batch_drops_the_nan_batch_and_goes_on(good_and_nan_batch, tmp_path, capsys):
    good, bad = good_and_nan_batch
    trainer = _trainer(tmp_path, "on_nonfinite=skip-batch")
    result = trainer.fit([good, bad])
    assert (result.step, result.skipped_batches) == (3, 2)  # good, bad, good, bad, good
    assert "step 2: skipped a batch with non-finite" in capsys.readouterr().err
    assert all(torch.isfinite(p).all() for p in trainer.model.parameters())
    assert _saved_are_finite(tmp_path / "run")[-1] == "ckpt-00000003.pt"


def test_skip_batch_stops_after_too_many_in_a_row(good_and_nan_batch, tmp_path, monkeypatch):
    from seeu_model.training import loop

    monkeypatch.setattr(loop, "MAX_CONSECUTIVE_SKIPS", 3)  # the bound of 20, cheaper
    trainer = _trainer(tmp_path, "on_nonfinite=skip-batch")
    with pytest.raises(
        SeeUError, match=r"step 1: non-finite .* in 3 batches in a row, the last on the batch of samples"
    ):
        trainer.fit([good_and_nan_batch[1]])
    assert trainer.skipped_batches == 2 and _saved_are_finite(tmp_path / "run") == []


def test_weights_overflowing_in_the_optimizer_step_stop_even_with_skip_batch(good_and_nan_batch, tmp_path):
    # finite gradients, but the decoupled decay factor 1 - lr * weight_decay = -3e38 takes a weight of 10
    # past the float32 range (3.4e38) in the optimizer step (optim.lr itself stays under its limit)
    trainer = _trainer(tmp_path, "on_nonfinite=skip-batch", "optim.lr=1e10", "optim.weight_decay=3e28")
    with torch.no_grad():
        trainer.model.net[0].weight[0, 0, 0, 0] = 10.0
    with pytest.raises(SeeUError, match="step 1: the weights became non-finite"):
        trainer.fit([good_and_nan_batch[0]])
    assert _saved_are_finite(tmp_path / "run") == []
    with pytest.raises(SeeUError, match="refusing to write a checkpoint whose tensor model.net.0.weight"):
        trainer.save(None)
    assert _saved_are_finite(tmp_path / "run") == []
