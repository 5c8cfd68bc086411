"""The BLIP-2 condition (paper table 5, "BLIP-2 Embedding"): a frozen ViT + Q-Former through Hugging Face
transformers, with tiny random BLIP-2 configs (hidden 32, one layer, 32x32 images, patch 8, 3 query tokens):
forward/backward through SeeU, frozen and out of the trainable state, loading only the image side from a
local directory or (mocked) hub repo and matching transformers' own `Blip2Model.get_qformer_features`,
the one-line errors, model-info and the ablation switch."""

from __future__ import annotations

import json
import sys

import pytest
import torch
import torch.nn.functional as F

pytest.importorskip("transformers")

from seeu_data.errors import SeeUError  # noqa: E402
from seeu_model.config import SeeUConfig  # noqa: E402
from seeu_model.seeu import SeeU, parameter_counts  # noqa: E402
from seeu_model.semantic import (  # noqa: E402
    BLIP2_PREFIXES,
    OPENAI_CLIP_MEAN,
    OPENAI_CLIP_STD,
    FrozenBLIP2ImageEncoder,
    export_blip2_image_part,
)
from tests.test_model import random_batch  # noqa: E402

Q = 3
TINY_BLIP2 = {
    "vision_config": {
        "hidden_size": 32,
        "intermediate_size": 64,
        "num_hidden_layers": 1,
        "num_attention_heads": 2,
        "image_size": 32,
        "patch_size": 8,
    },
    "qformer_config": {
        "hidden_size": 32,
        "intermediate_size": 64,
        "num_hidden_layers": 2,
        "num_attention_heads": 2,
        "cross_attention_frequency": 1,
        "vocab_size": 100,
        "max_position_embeddings": 32,
    },
    "num_query_tokens": Q,
}
TINY_OPT = {
    "model_type": "opt",
    "hidden_size": 16,
    "ffn_dim": 32,
    "num_hidden_layers": 1,
    "num_attention_heads": 2,
    "vocab_size": 1024,
    "max_position_embeddings": 32,
    "word_embed_proj_dim": 16,
}


def _tiny_cfg(**kw) -> SeeUConfig:
    return SeeUConfig.tiny(condition="blip2", blip2_model_kwargs=TINY_BLIP2, **kw)


def _one_line(exc: pytest.ExceptionInfo) -> str:
    text = str(exc.value)
    assert "\n" not in text and len(text) < 500, text
    return text


@pytest.fixture(scope="module")
def blip2_dir(tmp_path_factory):
    """A full tiny BLIP-2 (vision + Q-Former + OPT language model) saved as transformers does, in small
    shards with an index, so some shards hold only language-model tensors."""
    from transformers import Blip2Config, Blip2ForConditionalGeneration

    torch.manual_seed(0)
    full = Blip2ForConditionalGeneration(Blip2Config(text_config=TINY_OPT, **TINY_BLIP2)).eval()
    with torch.no_grad():
        full.query_tokens.normal_()  # transformers initialises them to zero
    out = tmp_path_factory.mktemp("blip2") / "tiny-blip2-opt"
    full.save_pretrained(out, max_shard_size="40KB")
    assert (out / "model.safetensors.index.json").is_file()
    return out


def test_blip2_condition_forward_backward_frozen_and_out_of_the_trainable_state():
    torch.manual_seed(0)
    model = SeeU(_tiny_cfg()).train()
    semantic = model.condition.semantic
    assert isinstance(semantic, FrozenBLIP2ImageEncoder)
    assert not semantic.training and not semantic.vision_model.training and not semantic.qformer.training
    assert model.training and all(not p.requires_grad for p in semantic.parameters())
    batch = random_batch()
    out = model(batch)
    assert out.encoding.condition.shape == (1, 2 * Q, 64)  # (B, V * Q, condition_dim)
    assert out.render.color.shape == (1, 1, 3, 64, 64)
    # Step 0: the refiner's zero-initialised output layer; one step opens the path to the condition.
    opt = torch.optim.Adam(model.trainable_parameters(), lr=1e-3)
    F.mse_loss(out.render.color, batch["target"]["image"]).backward()
    opt.step()
    opt.zero_grad(set_to_none=True)
    F.mse_loss(model(batch).render.color, batch["target"]["image"]).backward()
    proj = model.condition.project.weight.grad
    assert proj is not None and torch.isfinite(proj).all() and proj.abs().max() > 0
    assert all(p.grad is None for p in semantic.parameters())

    state = model.trainable_state_dict()
    assert not any(k.startswith("condition.semantic.") for k in state)
    assert any(k.startswith("condition.semantic.qformer.") for k in model.state_dict())
    assert "condition.project.weight" in state
    counts = parameter_counts(model)
    assert counts["condition.semantic"][0] == 0 and counts["condition.semantic"][1] > 0
    other = SeeU(_tiny_cfg())
    other.load_trainable_state_dict(state)  # round trip; the frozen encoder keeps its own weights


def test_blip2_loads_only_the_image_side_and_matches_transformers_qformer_features(blip2_dir, tmp_path):
    from transformers import Blip2Model

    enc = FrozenBLIP2ImageEncoder(weights=str(blip2_dir))
    assert not enc.training and all(not p.requires_grad for p in enc.parameters())
    assert all(k.startswith(BLIP2_PREFIXES) for k in enc.state_dict())
    assert enc.embed_dim == 32 and enc.num_query_tokens == Q and enc.input_size == (32, 32)

    ref = Blip2Model.from_pretrained(blip2_dir).eval()
    ref_state = ref.state_dict()
    for k, v in enc.state_dict().items():
        assert torch.equal(v, ref_state[k]), k
    images = torch.rand(2, 2, 3, 32, 32)  # native size: no resize
    pixel_values = (images.reshape(4, 3, 32, 32) - torch.tensor(OPENAI_CLIP_MEAN).view(1, 3, 1, 1)) / torch.tensor(
        OPENAI_CLIP_STD
    ).view(1, 3, 1, 1)
    with torch.no_grad():
        expected = ref.get_qformer_features(pixel_values=pixel_values)  # (4, Q, 32)
    got = enc(images)
    assert got.shape == (2, 2 * Q, 32)
    torch.testing.assert_close(got, expected.reshape(2, 2 * Q, 32), rtol=1e-5, atol=1e-5)
    assert enc(torch.rand(1, 2, 3, 48, 40)).shape == (1, 2 * Q, 32)  # any input size is resized

    # The image part alone, exported for offline use, loads the same tensors.
    part = export_blip2_image_part(str(blip2_dir), tmp_path / "blip2-image", dtype=None)
    assert sorted(p.name for p in part.iterdir()) == ["config.json", "model.safetensors"]
    again = FrozenBLIP2ImageEncoder(weights=str(part))
    for k, v in again.state_dict().items():
        assert torch.equal(v, enc.state_dict()[k]), k

    # Older checkpoints: pytorch_model.bin instead of safetensors.
    (tmp_path / "bin").mkdir()
    (tmp_path / "bin" / "config.json").write_text((blip2_dir / "config.json").read_text())
    torch.save(ref.state_dict(), tmp_path / "bin" / "pytorch_model.bin")
    from_bin = FrozenBLIP2ImageEncoder(weights=str(tmp_path / "bin"))
    for k, v in from_bin.state_dict().items():
        assert torch.equal(v, enc.state_dict()[k]), k

    # Through the model config (offline directory) too.
    model = SeeU(SeeUConfig.tiny(condition="blip2", blip2_weights=str(part)))
    assert torch.equal(model.condition.semantic.query_tokens, enc.query_tokens)


def test_blip2_from_the_hub_downloads_only_image_side_shards(blip2_dir, monkeypatch):
    import huggingface_hub
    from huggingface_hub.errors import EntryNotFoundError, LocalEntryNotFoundError

    index = json.loads((blip2_dir / "model.safetensors.index.json").read_text())["weight_map"]
    lm_only = {f for f in index.values()} - {f for k, f in index.items() if k.startswith(BLIP2_PREFIXES)}
    assert lm_only, "the fixture should have shards with language-model tensors only"
    asked: list[str] = []

    def fake_download(repo_id, filename, **kw):
        assert repo_id == "someone/tiny-blip2"
        asked.append(filename)
        if not (blip2_dir / filename).is_file():
            raise EntryNotFoundError(f"{filename} not in {repo_id}")
        return str(blip2_dir / filename)

    monkeypatch.setattr(huggingface_hub, "hf_hub_download", fake_download)
    enc = FrozenBLIP2ImageEncoder("someone/tiny-blip2", pretrained=True)
    local = FrozenBLIP2ImageEncoder(weights=str(blip2_dir))
    for k, v in enc.state_dict().items():
        assert torch.equal(v, local.state_dict()[k]), k
    assert "config.json" in asked and not lm_only & set(asked)

    def offline(repo_id, filename, **kw):
        raise LocalEntryNotFoundError(
            "Cannot find the requested files in the disk cache and outgoing traffic "
            "has been disabled.\nTo enable hf.co look-ups, set HF_HUB_OFFLINE=0."
        )

    monkeypatch.setattr(huggingface_hub, "hf_hub_download", offline)
    with pytest.raises(SeeUError, match="Hugging Face hub.*blip2_weights=DIR") as exc:
        SeeU(SeeUConfig.tiny(condition="blip2", semantic_pretrained=True, blip2_model="someone/tiny-blip2"))
    _one_line(exc)


def test_blip2_errors_are_one_line(tmp_path, monkeypatch, blip2_dir):
    with pytest.raises(SeeUError, match="weights directory not found.*blip2_weights") as exc:
        SeeU(SeeUConfig.tiny(condition="blip2", blip2_weights=str(tmp_path / "nowhere")))
    _one_line(exc)
    (tmp_path / "clip").mkdir()
    (tmp_path / "clip" / "config.json").write_text(json.dumps({"model_type": "clip"}))
    with pytest.raises(SeeUError, match="not a BLIP-2 checkpoint") as exc:
        FrozenBLIP2ImageEncoder(weights=str(tmp_path / "clip"))
    _one_line(exc)
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "config.json").write_text((blip2_dir / "config.json").read_text())
    with pytest.raises(SeeUError, match="no weights of BLIP-2's image side") as exc:
        FrozenBLIP2ImageEncoder(weights=str(tmp_path / "empty"))
    _one_line(exc)
    with pytest.raises(SeeUError, match="only apply to random initialisation") as exc:
        SeeU(_tiny_cfg(blip2_weights=str(blip2_dir)))
    _one_line(exc)
    with pytest.raises(SeeUError, match="invalid blip2_model_kwargs") as exc:
        SeeU(SeeUConfig.tiny(condition="blip2", blip2_model_kwargs={"no_such_field": 1, "vision_config": 3}))
    _one_line(exc)

    monkeypatch.setitem(sys.modules, "transformers", None)  # `import transformers` raises ImportError
    with pytest.raises(
        SeeUError, match=r"needs the optional 'transformers' package.*pip install -e '\.\[blip2\]'"
    ) as exc:
        SeeU(_tiny_cfg())
    _one_line(exc)
    from pipelines.cli import main

    assert main(["model-info", "--preset", "tiny", "--condition", "blip2"]) != 0  # one line, no traceback


def test_model_info_and_ablation_list_blip2(capsys, tmp_path):
    from pipelines.ablate import MODEL_VARIANTS
    from pipelines.cli import main

    assert MODEL_VARIANTS["blip2"] == ("BLIP-2 Embedding", {"condition": "blip2"})
    out_json = tmp_path / "counts.json"
    # The paper-size BLIP-2 image side (Salesforce/blip2-opt-2.7b: ViT-g + Q-Former), counted on the meta device.
    assert main(["model-info", "--preset", "tiny", "--condition", "blip2", "--json", str(out_json)]) == 0
    text = capsys.readouterr().out
    assert "condition=blip2" in text and "blip2-opt-2.7b" in text
    data = json.loads(out_json.read_text())
    assert data["modules"]["condition.semantic"] == {"trainable": 0, "frozen": 985_952_256 + 105_137_664 + 32 * 768}
    assert data["modules"]["condition.project"]["trainable"] == 768 * 64 + 64
