"""Data wait in the training log: the seconds each step waits for the loader and their share of the step
time, in the history and TensorBoard; a loader slowed by a known delay makes them rise by that delay."""

from __future__ import annotations

import time

import pytest
import torch

from seeu_model.training.config import load_config


class SlowLoader:
    """`batches`, each handed out `delay` seconds after it is asked for (a loader that cannot keep up)."""

    def __init__(self, batches: list[dict], delay: float):
        self.batches, self.delay = batches, delay

    def __iter__(self):
        for batch in self.batches:
            time.sleep(self.delay)
            yield batch


@pytest.fixture(scope="module")
def batches(workspace) -> list[dict]:
    from seeu_data.loader import make_loader

    return list(make_loader(workspace["triples"], 2, image_hw=(32, 32), flip_p=0.0, shuffle=False))


def _fit(out, loader):
    from seeu_model.training.factory import make_render_fn
    from seeu_model.training.loop import Trainer
    from tests.training_fixtures import tiny_model_factory

    cfg = load_config(
        None,
        [
            "optim.max_steps=4",
            "optim.warmup_steps=0",
            "loss.lpips_weight=0",
            "checkpoint.every=4",
            "log.every=2",
            "log.progress=false",
            "precision=fp32",
        ],
    )
    return Trainer(tiny_model_factory({})[0], cfg, out, make_render_fn("torch")).fit(loader)


def test_slow_loader_raises_the_logged_data_wait(batches, tmp_path):
    assert batches[0]["context"]["image"].dtype == torch.uint8  # the loop makes them float on the device
    delay = 0.3
    fast = _fit(tmp_path / "fast", batches)
    slow = _fit(tmp_path / "slow", SlowLoader(batches, delay))
    assert [h["step"] for h in slow.history] == [2, 4]
    for fh, sh in zip(fast.history, slow.history):
        assert 0 <= fh["data_wait_share"] <= 1 and 0 <= sh["data_wait_share"] <= 1
        assert fh["data_wait_s"] < 0.05  # batches already in memory
        assert sh["data_wait_s"] >= delay  # every step waited at least the loader's delay
        assert sh["data_wait_share"] > fh["data_wait_share"]
        # the share is the wait over the interval's wall time: wait per step x steps per second
        for h in (fh, sh):
            assert h["data_wait_share"] == pytest.approx(h["data_wait_s"] * h["it_per_s"], rel=1e-9)
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    ea = EventAccumulator(str(tmp_path / "slow" / "tb"))
    ea.Reload()
    shares = [e.value for e in ea.Scalars("train/data_wait_share")]
    assert shares == pytest.approx([h["data_wait_share"] for h in slow.history], rel=1e-6)
    assert [e.step for e in ea.Scalars("train/data_wait_s")] == [2, 4]
