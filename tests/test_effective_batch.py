"""Effective batch (per device x devices x accumulation): the plans, and --keep-effective-batch on 1 vs 2
processes giving the same first steps (4 accumulation steps on one, DDP with 2 each on two)."""

from __future__ import annotations

import json
import socket

import pytest
import torch

from seeu_data.errors import SeeUError
from seeu_model.training import checkpoint as ckpt_io
from seeu_model.training.effective_batch import BatchPlan, plan_batches
from tests.training_fixtures import ddp_worker, tiny_model_factory


def test_plans_keep_the_effective_batch_and_never_exceed_the_device_batch():
    assert plan_batches(8, 1, 2) == BatchPlan(8, 2, 1)  # without the flag: grows with the devices
    assert plan_batches(8, 1, 2).effective == 16
    assert plan_batches(8, 1, 2, keep_effective=True) == BatchPlan(4, 2, 1)
    assert plan_batches(8, 1, 8, keep_effective=True) == BatchPlan(1, 8, 1)
    assert plan_batches(2, 4, 1, keep_effective=True) == BatchPlan(2, 1, 4)
    assert plan_batches(2, 4, 2, keep_effective=True) == BatchPlan(2, 2, 2)
    for batch in range(1, 9):
        for accumulate in range(1, 5):
            for devices in range(1, 9):
                if (batch * accumulate) % devices:
                    with pytest.raises(SeeUError, match="cannot be split evenly over"):
                        plan_batches(batch, accumulate, devices, keep_effective=True)
                    continue
                plan = plan_batches(batch, accumulate, devices, keep_effective=True)
                assert plan.effective == batch * accumulate and plan.devices == devices
                assert plan.per_device <= batch and plan.accumulate <= accumulate
    assert BatchPlan(2, 2, 2).describe() == "effective batch 8 = 2 per device x 2 devices x 2 accumulation steps"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_keep_effective_batch_one_vs_two_processes_same_first_steps(workspace, tmp_path, capfd):
    import torch.multiprocessing as mp

    from pipelines.train import TrainRunConfig, train

    # the preset: 1 sample per device, 4 accumulation steps (effective batch 4): one process accumulates 4
    # micro-batches, two accumulate 2 each (DDP all-reducing on the last); a larger Adam eps keeps the update
    # linear in the gradient (see tests/test_training.py's DDP test)
    ov = [
        "data.batch_size=1",
        "optim.accumulate=4",
        "data.num_workers=0",
        "data.image_size=[32,32]",
        "data.flip=true",
        "optim.max_steps=2",
        "optim.warmup_steps=0",
        "optim.lr=1e-2",
        "optim.eps=1e-3",
        "loss.lpips_weight=0",
        "log.every=1",
        "checkpoint.every=2",
        "precision=fp32",
        "rasterizer=torch",
    ]
    common = dict(data=str(workspace["triples"]), overrides=ov, keep_effective_batch=True)
    one = train(TrainRunConfig(out=tmp_path / "one", model_factory=tiny_model_factory, **common))
    assert "effective batch 4 = 1 per device x 1 device x 4 accumulation steps" in capfd.readouterr().err
    kwargs = dict(out=str(tmp_path / "two"), model_factory=tiny_model_factory, **common)
    mp.spawn(ddp_worker, args=(2, _free_port(), kwargs), nprocs=2, join=True)
    two = json.loads((tmp_path / "two" / "train_summary.json").read_text())
    assert one["effective_batch"] == {"per_device": 1, "devices": 1, "accumulate": 4, "effective": 4}
    assert two["effective_batch"] == {"per_device": 1, "devices": 2, "accumulate": 2, "effective": 4}
    a = ckpt_io.load_checkpoint(tmp_path / "one" / "checkpoints")
    b = ckpt_io.load_checkpoint(tmp_path / "two" / "checkpoints")
    assert (a["effective_batch"]["effective"], b["effective_batch"]["effective"]) == (4, 4)
    # the same samples per step: equal losses (step 1 from equal weights, step 2 after one equal update)
    for h1, h2 in zip(one["history"], two["history"]):
        assert h1["loss"] == pytest.approx(h2["loss"], rel=1e-5), (h1, h2)
    init = tiny_model_factory({})[0].state_dict()
    moved = max((a["model"][k] - init[k]).abs().max().item() for k in init)
    assert moved > 1e-4  # training changed the weights, so their agreement means something
    for k in init:
        assert torch.allclose(a["model"][k], b["model"][k], atol=1e-5, rtol=1e-4), k
