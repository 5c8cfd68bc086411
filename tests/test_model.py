"""The SeeU model on CPU with the tiny preset (2 views x 64^2 unless stated): forward/backward, gradient
flow, the frozen semantic encoder, zero-initialised refinement, view-permutation equivariance,
pixel-aligned unprojection, weights loading and the ablation switches."""

from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F

from seeu_data.cameras import intrinsics_norm_matrix, project_points
from seeu_data.errors import SeeUError
from seeu_model.config import SeeUConfig
from seeu_model.gaussians import Gaussians
from seeu_model.seeu import SeeU, parameter_counts
from seeu_model.semantic import FrozenViTEncoder


def _rot_y(deg: float) -> torch.Tensor:
    a = math.radians(deg)
    return torch.tensor([[math.cos(a), 0.0, math.sin(a)], [0.0, 1.0, 0.0], [-math.sin(a), 0.0, math.cos(a)]])


def random_batch(v: int = 2, t: int = 1, size: int = 64, seed: int = 0) -> dict:
    """Cameras on a small arc looking at +z, smooth random images."""
    g = torch.Generator().manual_seed(seed)
    n = v + t
    c2w = torch.eye(4).repeat(n, 1, 1)
    for i in range(n):
        c2w[i, :3, :3] = _rot_y(-4.0 + 8.0 * i / max(n - 1, 1))
        c2w[i, :3, 3] = torch.tensor([-0.3 + 0.6 * i / max(n - 1, 1), 0.02 * i, 0.05 * i])
    intr = intrinsics_norm_matrix(torch.tensor([0.9, 0.9, 0.5, 0.5])).expand(n, 3, 3)
    imgs = F.interpolate(
        torch.rand(n, 3, size // 8, size // 8, generator=g), size=(size, size), mode="bilinear", align_corners=False
    )

    def views(sl: slice) -> dict:
        k = len(range(n)[sl])
        return {
            "image": imgs[sl][None],
            "cam_to_world": c2w[sl][None],
            "intrinsics": intr[sl][None].clone(),
            "near": torch.full((1, k), 0.5),
            "far": torch.full((1, k), 20.0),
        }

    # context = views 0..v-1, targets after them
    return {"context": views(slice(0, v)), "target": views(slice(v, n))}


def _gaussians_equal(a: Gaussians, b: Gaussians) -> bool:
    return all(torch.equal(getattr(a, f), getattr(b, f)) for f in ("means", "scales", "rotations", "opacities", "sh"))


@pytest.fixture(scope="module")
def tiny_model() -> SeeU:
    torch.manual_seed(0)
    return SeeU(SeeUConfig.tiny())


def test_forward_backward_gradients_reach_every_trainable_module_and_not_the_frozen_encoder(tiny_model):
    torch.manual_seed(1)
    model = SeeU(SeeUConfig.tiny())
    model.train()
    semantic = model.condition.semantic
    assert not semantic.training and model.training  # frozen encoder stays in eval mode
    assert all(not p.requires_grad for p in semantic.parameters())
    batch = random_batch()
    out = model(batch, render_coarse=True)
    b, v, t = 1, 2, 1
    ent = out.entropy.detach()
    assert out.render.color.shape == (b, t, 3, 64, 64)
    assert out.render.depth.shape == (b, t, 1, 64, 64)
    assert out.depth.shape == (b, v, 64, 64) and out.encoding.coarse_depth.shape == (b, v, 16, 16)
    assert out.entropy.shape == (b, v, 16, 16)
    assert float(ent.min()) >= 0 and float(ent.max()) <= 1
    assert len(out.gaussians) == v * 64 * 64 and out.gaussians.sh.shape[-2:] == (4, 3)
    assert out.encoding.condition.shape == (b, 4, 64)
    # At initialisation the refiner's residual is exactly zero: refined == coarse.
    assert torch.count_nonzero(out.encoding.residual) == 0
    assert _gaussians_equal(out.gaussians, out.coarse_gaussians)
    assert torch.equal(out.render.color, out.coarse_render.color)

    # The zero-initialised output layer blocks gradients to the refiner's inner layers at step 0
    # (d residual / d inner = W_out = 0); one optimiser step opens it, as in training.
    opt = torch.optim.Adam(model.trainable_parameters(), lr=1e-3)
    F.mse_loss(out.render.color, batch["target"]["image"]).backward()
    opt.step()
    opt.zero_grad(set_to_none=True)
    out = model(batch)
    F.mse_loss(out.render.color, batch["target"]["image"]).backward()
    no_grad = [
        n
        for n, p in model.named_parameters()
        if p.requires_grad and (p.grad is None or not torch.isfinite(p.grad).all() or p.grad.abs().max() == 0)
    ]
    assert no_grad == []
    assert all(p.grad is None for p in semantic.parameters())
    # After the step the refinement is active.
    with torch.no_grad():
        enc = model.encode_all(batch["context"])
    assert torch.count_nonzero(enc.residual) > 0
    assert not _gaussians_equal(enc.gaussians, enc.coarse_gaussians)


@pytest.mark.parametrize("refiner,condition", [("unet", "cea"), ("transformer", "cls")])
def test_ablation_refiners_and_conditions_start_at_the_coarse_gaussians(refiner, condition):
    torch.manual_seed(0)
    model = SeeU(SeeUConfig.tiny(refiner=refiner, condition=condition)).eval()
    with torch.no_grad():
        enc = model.encode_all(random_batch()["context"])
    assert torch.count_nonzero(enc.residual) == 0
    assert _gaussians_equal(enc.gaussians, enc.coarse_gaussians)
    expected_tokens = 4 if condition == "cea" else 2
    assert enc.condition.shape == (1, expected_tokens, 64)


def test_no_refiner_builds_no_semantic_encoder():
    model = SeeU(SeeUConfig.tiny(refiner="none"))
    assert model.condition is None and model.refiner is None and model.frozen_prefixes() == []
    with torch.no_grad():
        enc = model.encode_all(random_batch()["context"])
    assert enc.gaussians is enc.coarse_gaussians and enc.condition is None


def test_clip_condition():
    """(The BLIP-2 condition has its own tests: tests/test_blip2.py.)"""
    torch.manual_seed(0)
    model = SeeU(SeeUConfig.tiny(condition="clip", clip_model_kwargs={"depth": 1}))
    with torch.no_grad():
        enc = model.encode_all(random_batch()["context"])
    assert enc.condition.shape == (1, 2, 64)


def test_trainable_state_dict_excludes_frozen_encoder_and_round_trips(tiny_model):
    state = tiny_model.trainable_state_dict()
    assert state and not any(k.startswith("condition.semantic.") for k in state)
    assert any(k.startswith("condition.semantic.") for k in tiny_model.state_dict())
    n_trainable = sum(p.numel() for p in tiny_model.trainable_parameters())
    assert sum(v.numel() for k, v in state.items() if "running" not in k) >= n_trainable
    torch.manual_seed(123)
    other = SeeU(SeeUConfig.tiny())
    other.load_trainable_state_dict(state)
    for k, v in other.trainable_state_dict().items():
        assert torch.equal(v, state[k]), k
    with pytest.raises(SeeUError, match="does not match"):
        SeeU(SeeUConfig.tiny(refiner="unet")).load_trainable_state_dict(state)


def test_latent_gaussians_are_pixel_aligned_at_the_matched_depth(tiny_model):
    """Independent check of the unprojection: projecting each coarse centre back into its own view gives
    the latent pixel centre and the plane-sweep depth."""
    ctx = random_batch()["context"]
    with torch.no_grad():
        enc = tiny_model.encode_all(ctx)
    means = enc.latent_gaussians.means.reshape(1, 2, 16 * 16, 3)
    uv, z = project_points(means, ctx["cam_to_world"], ctx["intrinsics"], 16, 16)
    ys, xs = torch.meshgrid(torch.arange(16) + 0.5, torch.arange(16) + 0.5, indexing="ij")
    expected = torch.stack([xs, ys], -1).reshape(1, 1, 256, 2).expand(1, 2, 256, 2)
    assert torch.allclose(uv, expected, atol=1e-3)
    assert torch.allclose(z, enc.coarse_depth.reshape(1, 2, 256), rtol=1e-3)
    assert float(enc.coarse_depth.min()) >= 0.5 - 1e-4 and float(enc.coarse_depth.max()) <= 20.0 + 1e-3


def test_permuting_context_views_permutes_gaussians_and_keeps_renders():
    torch.manual_seed(0)
    model = SeeU(SeeUConfig.tiny()).eval()
    with torch.no_grad():  # make the refiner non-trivial, as after training
        for lin in (model.refiner.out, model.refiner.ada_out[-1]):
            lin.weight.normal_(0, 0.05)
    batch = random_batch(v=3, t=1, size=32, seed=3)
    ctx = batch["context"]
    perm = torch.tensor([2, 0, 1])
    ctx_p = {k: val[:, perm] for k, val in ctx.items()}
    with torch.no_grad():
        enc = model.encode_all(ctx)
        enc_p = model.encode_all(ctx_p)
        assert torch.count_nonzero(enc.residual) > 0
        for f in ("means", "scales", "rotations", "opacities", "sh"):
            a = getattr(enc.gaussians, f).reshape(1, 3, 32 * 32, -1)
            b = getattr(enc_p.gaussians, f).reshape(1, 3, 32 * 32, -1)
            assert torch.allclose(b, a[:, perm], atol=1e-4, rtol=1e-4), f
        assert torch.allclose(enc_p.condition, enc.condition, atol=1e-5)
        r = model.render(enc.gaussians, batch["target"], (32, 32))
        r_p = model.render(enc_p.gaussians, batch["target"], (32, 32))
    assert torch.allclose(r.color, r_p.color, atol=1e-4)
    assert torch.allclose(r.alpha, r_p.alpha, atol=1e-4)


def test_rejects_bad_context():
    model = SeeU(SeeUConfig.tiny(refiner="none"))
    ctx = random_batch()["context"]
    with pytest.raises(ValueError, match="two context views"):
        model.encode({k: v[:, :1] for k, v in ctx.items()})
    with pytest.raises(ValueError, match="divisible by 16"):
        model.encode({**ctx, "image": ctx["image"][..., :40, :40]})


def test_semantic_weights_from_a_local_file(tmp_path):
    name, kwargs = "vit_small_patch16_dinov3.lvd1689m", {"depth": 1}
    torch.manual_seed(5)
    source = FrozenViTEncoder(name, pretrained=False, model_kwargs=kwargs)
    path = tmp_path / "dinov3_small.pth"
    torch.save(source.model.state_dict(), path)
    loaded = FrozenViTEncoder(name, weights=str(path), model_kwargs=kwargs)
    for (k, a), b in zip(source.model.state_dict().items(), loaded.model.state_dict().values()):
        assert torch.equal(a, b), k
    loaded.train()
    assert not loaded.training and all(not p.requires_grad for p in loaded.parameters())
    cls, patches = loaded(torch.rand(1, 2, 3, 64, 48))
    assert cls.shape == (1, 2, 384) and patches.shape == (1, 2, 384, 4, 3)


def test_semantic_weights_missing_give_clear_errors(tmp_path, monkeypatch):
    missing = tmp_path / "nope.safetensors"
    with pytest.raises(SeeUError, match="weights file not found") as err:
        FrozenViTEncoder("vit_small_patch16_dinov3.lvd1689m", weights=str(missing))
    assert str(missing) in str(err.value)
    import timm

    real = timm.create_model

    def offline(name, pretrained=False, **kw):  # what the hub does without network
        if pretrained and "pretrained_cfg_overlay" not in kw:
            raise OSError("We couldn't connect to 'https://huggingface.co'")
        return real(name, pretrained=pretrained, **kw)

    monkeypatch.setattr(timm, "create_model", offline)
    with pytest.raises(SeeUError, match="semantic_weights=PATH"):
        SeeU(SeeUConfig.tiny(semantic_pretrained=True))


def test_parameter_counts_split_trainable_and_frozen(tiny_model):
    counts = parameter_counts(tiny_model)
    assert counts["condition.semantic"][0] == 0 and counts["condition.semantic"][1] > 0
    total_trainable = sum(t for t, _ in counts.values())
    assert total_trainable == sum(p.numel() for p in tiny_model.trainable_parameters())
    assert sum(f for _, f in counts.values()) == sum(p.numel() for p in tiny_model.parameters() if not p.requires_grad)


def test_model_info_cli_prints_counts(capsys, tmp_path):
    from pipelines.cli import main

    out_json = tmp_path / "counts.json"
    assert main(["model-info", "--preset", "tiny", "--json", str(out_json)]) == 0
    text = capsys.readouterr().out
    assert "condition.semantic" in text and "MVSplat" in text and "12.0 M" in text
    import json

    data = json.loads(out_json.read_text())
    model = SeeU(SeeUConfig.tiny())
    assert data["total_trainable"] == sum(p.numel() for p in model.trainable_parameters())
    assert data["modules"]["condition.semantic"]["trainable"] == 0


def test_bf16_autocast_forward_backward_keeps_gaussians_and_renders_float32():
    torch.manual_seed(0)
    model = SeeU(SeeUConfig.tiny()).train()
    batch = random_batch(v=2, t=1, size=32, seed=2)
    with torch.autocast(device_type="cpu", dtype=torch.bfloat16):
        out = model(batch)
        loss = F.mse_loss(out.render.color, batch["target"]["image"])
    assert out.gaussians.means.dtype == torch.float32 and out.render.color.dtype == torch.float32
    assert out.encoding.latent.dtype == torch.float32
    loss.backward()
    assert model.backbone.stem[0].weight.grad is not None and torch.isfinite(model.backbone.stem[0].weight.grad).all()
