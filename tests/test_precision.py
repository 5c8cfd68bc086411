"""bf16 autocast on the CPU (precision="bf16"), as close to the GPU path as a CPU goes: one training step
and one evaluation of the real SeeU model (tiny preset) equal their fp32 results within stated tolerances.

Tolerances (measured: loss 0.3 % apart, gradient cosine 0.993, PSNR within 0.12 dB, SSIM within 0.005;
bf16 keeps 8 bits of mantissa, so ~0.4 % per rounding): loss within 2 %, gradient direction cosine
>= 0.98, per-target PSNR within 0.3 dB and SSIM within 0.02, mean PSNR within 0.15 dB.
"""

from __future__ import annotations

import copy

import pytest
import torch


def test_bf16_train_step_and_evaluation_match_fp32(workspace, tmp_path):
    from seeu_data.loader import make_loader
    from seeu_model.evaluation import evaluate_model
    from seeu_model.training.config import load_config
    from seeu_model.training.factory import build_model, encode_context, make_render_fn, render_gaussians
    from seeu_model.training.loop import Trainer, autocast_context

    batch = next(iter(make_loader(workspace["triples"], 2, image_hw=(32, 32), flip_p=0.0, shuffle=False)))
    torch.manual_seed(0)
    model, _ = build_model({"preset": "tiny"})
    cpu = torch.device("cpu")
    out = {}
    for precision in ("fp32", "bf16"):
        cfg = load_config(
            None,
            ["optim.warmup_steps=0", "loss.lpips_weight=0", "optim.grad_clip=0", f"precision={precision}"],
        )
        trainer = Trainer(copy.deepcopy(model), cfg, tmp_path / precision, make_render_fn("torch"))
        parts, _ = trainer.train_step(batch)
        grads = torch.cat([p.grad.flatten() for p in trainer.model.parameters() if p.grad is not None])
        ev = evaluate_model(
            copy.deepcopy(model),
            [batch],
            cpu,
            encode_context,
            lambda g, t: render_gaussians(g, t, "torch"),
            warmup=0,
            autocast=lambda: autocast_context(precision, cpu),
        )
        out[precision] = (parts.loss, grads, ev.records)
    (loss32, g32, rec32), (loss16, g16, rec16) = out["fp32"], out["bf16"]
    assert loss16 != loss32 and not torch.equal(g16, g32)  # bf16 autocast did run
    assert loss16 == pytest.approx(loss32, rel=2e-2)
    assert float(torch.nn.functional.cosine_similarity(g32, g16, dim=0)) >= 0.98
    assert len(rec32) == len(rec16) == 6  # 2 samples x 3 targets
    for a, b in zip(rec32, rec16):
        assert abs(a.psnr - b.psnr) <= 0.3 and abs(a.ssim - b.ssim) <= 0.02
    mean = lambda rs: sum(r.psnr for r in rs) / len(rs)  # noqa: E731
    assert mean(rec16) == pytest.approx(mean(rec32), abs=0.15)


@pytest.mark.filterwarnings("ignore:CUDA is not available")  # building a CUDA autocast object without CUDA
def test_autocast_context_follows_precision_and_device():
    from seeu_model.training.loop import autocast_context

    cpu, cuda = torch.device("cpu"), torch.device("cuda")
    with autocast_context("bf16", cpu):
        assert torch.is_autocast_enabled("cpu") and torch.get_autocast_dtype("cpu") == torch.bfloat16
    for precision in ("auto", "fp32"):  # the CPU default stays fp32
        with autocast_context(precision, cpu):
            assert not torch.is_autocast_enabled("cpu")
    assert isinstance(autocast_context("auto", cuda), torch.autocast)
    assert not isinstance(autocast_context("fp32", cuda), torch.autocast)
