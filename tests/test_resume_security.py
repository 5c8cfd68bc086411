"""Resume at any step (epoch boundaries included), no code runs from a file we read, and
config / CLI values refused with one line (exit 2) where they are parsed."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest
import torch
from torch import nn

from seeu_model.training import checkpoint as ckpt_io
from tests.training_fixtures import synthetic_triples

# 8 samples, batch 2: 4 steps per epoch, 2 epochs = 8 steps (the stand-in model keeps it fast)
FAST = [
    "data.num_workers=0",
    "data.image_size=[16,16]",
    "data.batch_size=2",
    "data.flip=true",
    "optim.warmup_steps=2",
    "optim.lr=2e-3",
    "optim.max_steps=8",
    "loss.lpips_weight=0",
    "log.every=1",
    "log.image_every=1000",
    "precision=fp32",
    "rasterizer=torch",
    "checkpoint.every=1",
    "checkpoint.keep=8",
]


class _ConvStandIn(nn.Module):
    """The loop's view of a model, without a rasterizer (fast): the first two context images ->
    one image for every target, (B, T, 3, H, W)."""

    def __init__(self):
        super().__init__()
        self.net = nn.Sequential(nn.Conv2d(6, 8, 3, padding=1), nn.ReLU(), nn.Conv2d(8, 3, 3, padding=1))

    def forward(self, batch: dict) -> torch.Tensor:
        ctx, t = batch["context"]["image"], batch["target"]["image"].shape[1]
        out = torch.sigmoid(self.net(ctx[:, :2].flatten(1, 2)))  # (B, 3, H, W)
        return out[:, None].expand(-1, t, -1, -1, -1)


def stand_in_factory(section: dict):
    torch.manual_seed(0)
    return _ConvStandIn(), {}


@pytest.fixture(scope="module")
def shards(tmp_path_factory) -> Path:
    return synthetic_triples(tmp_path_factory.mktemp("resume_data"), n_frames=16, hw=(16, 16), samples_per_scene=8)


def _final(run: Path) -> dict[str, torch.Tensor]:
    return ckpt_io.load_checkpoint(run / "checkpoints")["model"]


def test_resume_at_every_step_of_two_epochs_gives_the_uninterrupted_parameters(shards, tmp_path):
    """A run killed after any step k (its newest checkpoint is ckpt-k, epoch boundaries k = 4, 8
    included) and resumed with --resume ends with the parameters of the uninterrupted run."""
    from pipelines.train import TrainRunConfig, train

    full = train(
        TrainRunConfig(data=str(shards), out=tmp_path / "full", overrides=FAST, model_factory=stand_in_factory)
    )
    assert full["step"] == 8
    saved = ckpt_io.list_checkpoints(tmp_path / "full" / "checkpoints")
    assert [int(p.stem.split("-")[1]) for p in saved] == list(range(1, 9))
    ref = ckpt_io.load_checkpoint(saved[-1])["model"]
    init = stand_in_factory({})[0].state_dict()
    assert any(not torch.allclose(init[k], ref[k]) for k in ref)  # training moved the parameters
    for k in range(1, 8):
        # the state a kill after step k leaves: only ckpt-k in OUT/checkpoints
        loader_state = ckpt_io.load_checkpoint(saved[k - 1])["loader"]
        assert (loader_state["epoch"], loader_state["samples_seen"]) == ((k - 1) // 4, 2 * ((k - 1) % 4 + 1))
        run = tmp_path / f"killed{k}"
        (run / "checkpoints").mkdir(parents=True)
        shutil.copy(saved[k - 1], run / "checkpoints")
        rest = train(
            TrainRunConfig(data=str(shards), out=run, overrides=FAST, resume=True, model_factory=stand_in_factory)
        )
        assert rest["step"] == 8, k
        got = _final(run)
        for name in ref:
            assert torch.allclose(got[name], ref[name], atol=1e-6, rtol=0), (k, name)


def test_stop_at_epoch_end_then_resume(shards, tmp_path):
    """A stop at an epoch boundary, then a resume: --max-steps 4 (the end of epoch 0), then --resume to step 6."""
    from pipelines.train import TrainRunConfig, train

    ov = [o for o in FAST if not o.startswith("optim.max_steps")]
    train(
        TrainRunConfig(
            data=str(shards), out=tmp_path / "r", overrides=ov + ["optim.max_steps=4"], model_factory=stand_in_factory
        )
    )
    rest = train(
        TrainRunConfig(
            data=str(shards),
            out=tmp_path / "r",
            overrides=ov + ["optim.max_steps=6"],
            resume=True,
            model_factory=stand_in_factory,
        )
    )
    assert rest["step"] == 6
    assert ckpt_io.load_checkpoint(tmp_path / "r" / "checkpoints")["loader"]["epoch"] == 1


def test_verified_stamp_is_kept_in_the_chosen_cache_and_a_rewrite_is_hashed_again(shards, tmp_path, monkeypatch):
    from seeu_data.errors import SeeUError
    from seeu_data.loader import make_loader
    from seeu_data.store.manifest import read_manifest

    data, other = tmp_path / "data", tmp_path / "other"
    shutil.copytree(shards, data)
    shutil.copytree(shards, other)
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.delenv("SEEU_CACHE_DIR", raising=False)
    assert len(list(make_loader(other, 2, image_hw=(16, 16)))) == 4
    assert not (tmp_path / "home").exists()  # no cache dir chosen: nothing written to the home directory
    cache = tmp_path / "cache"
    assert len(list(make_loader(data, 2, image_hw=(16, 16), cache_dir=str(cache)))) == 4
    entry = read_manifest(data)["files"][0]
    assert (cache / "verified" / entry["sha256"]).is_file()
    # rewrite the shard in place: same size, one byte flipped, mtime set back
    shard = data / entry["path"]
    st = shard.stat()
    raw = bytearray(shard.read_bytes())
    raw[len(raw) // 2] ^= 0xFF
    shard.write_bytes(bytes(raw))
    os.utime(shard, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert shard.stat().st_size == st.st_size and shard.stat().st_mtime_ns == st.st_mtime_ns
    with pytest.raises(SeeUError, match="sha256 differs"):
        list(make_loader(data, 2, image_hw=(16, 16), cache_dir=str(cache)))


# ------------------------------------------------------------------------------------------------
# Part 1: no code runs from a file we read
# ------------------------------------------------------------------------------------------------


class _RunsCommand:
    """Unpickling this calls os.system (a sentinel file appears if the loader runs it)."""

    def __init__(self, sentinel: Path):
        self.sentinel = sentinel

    def __reduce__(self):
        return (os.system, (f"touch {self.sentinel}",))


class _OpensFile:
    """Unpickling this calls open(sentinel, "w"), which creates the file."""

    def __init__(self, sentinel: Path):
        self.sentinel = sentinel

    def __reduce__(self):
        return (open, (str(self.sentinel), "w"))


def _malicious(tmp_path: Path, kind: str, name: str = "evil.pt") -> tuple[Path, Path]:
    """A file whose pickle creates a sentinel file when loaded with plain pickle / torch.load(weights_only=False)."""
    import pickle

    sentinel = tmp_path / f"sentinel-{kind}"
    path = tmp_path / name
    if kind == "pickle":  # a non-SeeU pickle, not even a torch file
        path.write_bytes(pickle.dumps(_RunsCommand(sentinel), protocol=2))
    else:
        payload = _RunsCommand(sentinel) if kind == "system" else _OpensFile(sentinel)
        torch.save(
            {"format": "seeu-train-checkpoint", "version": 2, "step": 1, "config": {}, "model": {}, "rng": payload},
            path,
        )
    return path, sentinel


def test_the_malicious_files_would_run_code_with_an_unsafe_load(tmp_path):
    """The fixture is a real attack: an unrestricted load creates the sentinel."""
    for kind in ("system", "open"):
        path, sentinel = _malicious(tmp_path, kind, f"{kind}.pt")
        torch.load(path, weights_only=False)
        assert sentinel.exists(), kind


def _cli(argv: list[str], capsys) -> tuple[int, str]:
    from pipelines.cli import main

    code = main(argv)
    err = capsys.readouterr().err.strip()
    return code, err


@pytest.mark.parametrize("kind", ["system", "open", "pickle"])
@pytest.mark.parametrize(
    "entry",
    ["eval", "render", "train-resume-file", "train-resume-dropped", "lpips-weights", "semantic-weights", "ablate"],
)
def test_a_malicious_file_is_refused_before_it_runs(shards, tmp_path, capsys, entry, kind):
    evil, sentinel = _malicious(tmp_path, kind)
    out = tmp_path / "out"
    if entry == "eval":
        argv = ["eval", "--checkpoint", str(evil), "--data", str(shards), "--out", str(out), "--no-lpips"]
    elif entry == "render":
        argv = ["render", "--checkpoint", str(evil), "--data", str(shards), "--out", str(out)]
    elif entry == "train-resume-file":
        argv = ["train", "--data", str(shards), "--out", str(out), "--resume", str(evil)] + FAST
    elif entry == "train-resume-dropped":
        (out / "checkpoints").mkdir(parents=True)
        shutil.copy(evil, out / "checkpoints" / "ckpt-00000005.pt")
        argv = ["train", "--data", str(shards), "--out", str(out)] + FAST + ["--resume"]
    elif entry == "lpips-weights":
        argv = (
            ["train", "--data", str(shards), "--out", str(out), "--lpips-weights", str(evil)]
            + [o for o in FAST if not o.startswith("loss.")]
            + ["loss.lpips_weight=0.05"]
        )
    elif entry == "ablate":  # a finished variant whose summary names the malicious checkpoint
        (out / "full" / "eval").mkdir(parents=True)
        (out / "full" / "train_summary.json").write_text(json.dumps({"step": 1, "checkpoint": str(evil)}))
        (out / "full" / "eval" / "summary.json").write_text("{}")
        configs = Path(__file__).resolve().parents[1] / "configs"
        argv = [
            "ablate",
            "--config",
            str(configs / "cpu_small.json"),
            "--data",
            str(shards),
            "--eval",
            str(shards),
            "--out",
            str(out),
            "--variants",
            "full",
            "--no-lpips",
            "model.preset=tiny",
            "optim.max_steps=1",
        ]
    else:
        argv = (
            ["train", "--data", str(shards), "--out", str(out), "--no-lpips"]
            + FAST
            + ["model.preset=tiny", "model.semantic_pretrained=true", f"model.semantic_weights={evil}"]
        )
    code, err = _cli(argv, capsys)
    assert not sentinel.exists()
    assert code == 2, err
    assert len(err.splitlines()) == 1 and "internal error" not in err
    assert str(evil.name) in err or "ckpt-00000005.pt" in err
    assert ("refused" in err and ("posix.system" in err or "io.open" in err)) or (
        kind == "pickle" and "not a readable" in err
    ), err


def test_rng_state_round_trips_through_v2_and_v1_checkpoints(tmp_path):
    """v2 stores numpy's RNG state as plain values; a v1 file (numpy array) is still read, safely."""
    import random

    import numpy as np

    np.random.seed(7)
    random.seed(7)
    torch.manual_seed(7)
    v1 = {
        "format": ckpt_io.FORMAT,
        "version": 1,
        "step": 3,
        "config": {},
        "model": {"w": torch.ones(2)},
        "rng": {
            "torch": torch.get_rng_state(),
            "cuda": [],
            "numpy": np.random.get_state(),
            "python": random.getstate(),
        },
    }
    torch.save(v1, tmp_path / "ckpt-00000003.pt")
    v2_path = ckpt_io.save_checkpoint(
        tmp_path / "v2", 3, {"config": {}, "model": {"w": torch.ones(2)}, "rng": ckpt_io.rng_state()}, keep=1
    )
    expected = (np.random.rand(3), random.random(), torch.rand(3))
    for path in (tmp_path / "ckpt-00000003.pt", v2_path):
        ck = ckpt_io.load_checkpoint(path)
        np.random.seed(0), random.seed(0), torch.manual_seed(0)
        ckpt_io.set_rng_state(ck["rng"])
        got = (np.random.rand(3), random.random(), torch.rand(3))
        assert np.array_equal(got[0], expected[0]) and got[1] == expected[1] and torch.equal(got[2], expected[2])
    assert ckpt_io.load_checkpoint(v2_path)["version"] == ckpt_io.VERSION  # the current writer's (3: the digest)


# ------------------------------------------------------------------------------------------------
# Part 4: config / CLI values and render cameras: one line, exit 2
# ------------------------------------------------------------------------------------------------

SEEU_OV = [
    "model.preset=tiny",
    "data.batch_size=2",
    "data.num_workers=0",
    "data.image_size=[32,32]",
    "optim.max_steps=1",
    "loss.lpips_weight=0",
    "precision=fp32",
    "rasterizer=torch",
    "log.every=1",
]


@pytest.fixture(scope="module")
def seeu_run(shards, tmp_path_factory) -> Path:
    """A real (tiny) SeeU checkpoint after one step."""
    from pipelines.train import TrainRunConfig, train

    run = tmp_path_factory.mktemp("seeu_run") / "run"
    train(TrainRunConfig(data=str(shards), out=run, overrides=SEEU_OV))
    return run


def _one_line_exit_2(argv, capsys) -> str:
    code, err = _cli(argv, capsys)
    assert code == 2, err
    assert len(err.splitlines()) == 1 and "internal error" not in err and err.startswith(f"seeu {argv[0]}: error:"), err
    return err


@pytest.mark.parametrize(
    "override, says",
    [
        ("log.every=0", "log.every must be >= 1"),
        ("log.image_every=-5", "log.image_every must be >= 1"),
        ("data.num_workers=-1", "data.num_workers must be >= 0"),
        ("optim.lr=NaN", "finite"),
        ("optim.lr=Infinity", "finite"),
        ("optim.lr=-1e-4", "optim.lr must be in (0, 1e+10], got -0.0001"),
        ("optim.max_steps=NaN", "integer"),
        ("optim.max_steps=0", "optim.max_steps must be >= 1"),
        ("optim.betas=[0.9,1.5]", "optim.betas"),
        ("checkpoint.every=0", "checkpoint.every must be >= 1"),
        ("data.image_size=0x0", "data.image_size must be >= 1"),
        ("loss.lpips_weight=-0.1", "loss.lpips_weight must be >= 0"),
    ],
)
def test_bad_config_values_are_one_line(shards, tmp_path, capsys, override, says):
    err = _one_line_exit_2(["train", "--data", str(shards), "--out", str(tmp_path / "o")] + FAST + [override], capsys)
    assert says in err
    assert not (tmp_path / "o" / "checkpoints").exists()


def test_checkpoint_whose_model_config_disagrees_with_its_weights(seeu_run, shards, tmp_path, capsys):
    ck = torch.load(ckpt_io.latest_checkpoint(seeu_run / "checkpoints"), weights_only=True)
    ck["model_config"]["head_hidden"] = ck["model_config"]["head_hidden"] * 2  # the weights stay as they were
    bad = tmp_path / "ckpt-00000001.pt"
    ck["digest"] = ckpt_io.payload_digest(ck)  # written so (the digest checks the file, not the values)
    torch.save(ck, bad)
    for argv in (
        ["eval", "--checkpoint", str(bad), "--data", str(shards), "--out", str(tmp_path / "e"), "--no-lpips"],
        ["render", "--checkpoint", str(bad), "--data", str(shards), "--out", str(tmp_path / "r")],
    ):
        err = _one_line_exit_2(argv, capsys)
        assert str(bad) in err and "do not match its model config" in err


def _camera_files(tmp_path: Path) -> dict:
    import cv2
    import numpy as np

    for i in (0, 1):
        cv2.imwrite(str(tmp_path / f"v{i}.png"), np.full((32, 32, 3), 60 * (i + 1), np.uint8))
    pose = np.eye(4)
    return {
        "near": 0.5,
        "far": 20.0,
        "frames": [
            {"image": f"v{i}.png", "cam_to_world": pose.tolist(), "intrinsics_norm": [1.0, 1.0, 0.5, 0.5]}
            for i in (0, 1)
        ],
    }


def _bad_cameras(case: str, doc: dict) -> dict:
    f = doc["frames"][1]
    if case == "frames-strings":
        doc["frames"] = ["v0.png", "v1.png"]
    elif case == "nan-pose":
        f["cam_to_world"][0][3] = float("nan")
    elif case == "not-orthonormal":
        f["cam_to_world"][0][0] = 2.0
    elif case == "reflection":
        f["cam_to_world"][0][0] = -1.0
    elif case == "zero-focal":
        f["intrinsics_norm"] = [0.0, 1.0, 0.5, 0.5]
    elif case == "negative-focal-K":
        del f["intrinsics_norm"]
        f["K"] = [[-32.0, 0, 16], [0, 32.0, 16], [0, 0, 1]]
    elif case == "nan-far":
        doc["far"] = float("nan")
    return doc


@pytest.mark.parametrize(
    "case, says",
    [
        ("frames-strings", "must be an object"),
        ("nan-pose", "non-finite"),
        ("not-orthonormal", "not orthonormal"),
        ("reflection", "not orthonormal"),
        ("zero-focal", "focal lengths must be positive"),
        ("negative-focal-K", "focal lengths must be positive"),
        ("nan-far", "near < far"),
    ],
)
def test_render_refuses_bad_cameras(seeu_run, tmp_path, capsys, case, says):
    cams = tmp_path / "cams.json"
    cams.write_text(json.dumps(_bad_cameras(case, _camera_files(tmp_path))))
    out = tmp_path / "r"
    err = _one_line_exit_2(
        [
            "render",
            "--checkpoint",
            str(seeu_run / "checkpoints"),
            "--cameras",
            str(cams),
            "--out",
            str(out),
            "--frames",
            "2",
        ],
        capsys,
    )
    assert says in err and not (out / "render.json").exists()


def test_image_size_and_other_flags_are_checked(seeu_run, shards, tmp_path, capsys):
    ck = str(seeu_run / "checkpoints")
    cams = tmp_path / "cams.json"
    cams.write_text(json.dumps(_camera_files(tmp_path)))
    render = ["render", "--checkpoint", ck, "--cameras", str(cams), "--out", str(tmp_path / "r"), "--frames", "2"]
    evaluate = ["eval", "--checkpoint", ck, "--data", str(shards), "--out", str(tmp_path / "e"), "--no-lpips"]
    assert "must be >= 1" in _one_line_exit_2(evaluate + ["--image-size", "0x0"], capsys)
    assert "must be >= 1" in _one_line_exit_2(render + ["--image-size", "0x0"], capsys)
    assert "divisible by 16" in _one_line_exit_2(render + ["--image-size", "24x24"], capsys)
    assert "divisible by 16" in _one_line_exit_2(evaluate + ["--image-size", "40x32"], capsys)
    assert "--fps" in _one_line_exit_2(render + ["--fps", "0"], capsys)
    assert "--extrapolate" in _one_line_exit_2(render + ["--extrapolate", "nan"], capsys)
    assert "--num-workers" in _one_line_exit_2(evaluate + ["--num-workers", "-1"], capsys)
    assert not (tmp_path / "r" / "render.json").exists() and not (tmp_path / "e" / "summary.json").exists()
    # a size the model takes still renders
    assert _cli(render + ["--image-size", "48x32"], capsys)[0] == 0


@pytest.mark.parametrize("damage", ["optimizer", "loader", "rng"])
def test_resume_from_a_checkpoint_with_unfit_state_is_one_line(seeu_run, shards, tmp_path, capsys, damage):
    ck = torch.load(ckpt_io.latest_checkpoint(seeu_run / "checkpoints"), weights_only=True)
    if damage == "optimizer":
        ck["optimizer"]["param_groups"] = ck["optimizer"]["param_groups"][:1]  # AdamW has two groups here
    elif damage == "loader":
        ck["loader"]["samples_seen"] = "many"
    else:
        ck["rng"]["numpy"] = [1, 2]
        ck.pop("rng_per_rank", None)
    bad = tmp_path / "ckpt-00000001.pt"
    ck["digest"] = ckpt_io.payload_digest(ck)  # written so (the digest checks the file, not the values)
    torch.save(ck, bad)
    err = _one_line_exit_2(
        ["train", "--data", str(shards), "--out", str(tmp_path / "o"), "--resume", str(bad)]
        + SEEU_OV
        + ["optim.max_steps=2"],
        capsys,
    )
    assert str(bad) in err and "does not fit this run" in err
