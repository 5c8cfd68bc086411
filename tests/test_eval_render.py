"""seeu eval / seeu render on a real (tiny) SeeU checkpoint, checked against independent computations."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from skimage.metrics import structural_similarity

from pipelines.cli import main
from seeu_data.store.posed import PosedDataset
from seeu_model.camera_path import camera_path, interpolate_pose, path_parameters, so3_exp, so3_log
from seeu_model.evaluation import TargetRecord, summarize
from tests.training_fixtures import synthetic_triples

OV = [
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
def run(tmp_path_factory) -> tuple[Path, Path]:
    from pipelines.train import TrainRunConfig, train

    root = tmp_path_factory.mktemp("evalrender")
    shards = synthetic_triples(root, n_frames=16, hw=(32, 32), seeds=(0, 1), samples_per_scene=4)
    train(TrainRunConfig(data=str(shards), out=root / "run", overrides=OV))
    return shards, root / "run"


def test_summary_is_mean_over_targets_then_scenes():
    recs = [
        TargetRecord("a", "a/0", 0, 0, 10.0, 0.5),
        TargetRecord("a", "a/0", 1, 1, 20.0, 0.7),
        TargetRecord("a", "a/1", 0, 2, 30.0, 0.9),
        TargetRecord("b", "b/0", 0, 0, 40.0, 0.1),
    ]
    s = summarize(recs)
    assert s["psnr"] == pytest.approx((20.0 + 40.0) / 2)  # scene a: 20, scene b: 40
    assert s["psnr_all_targets"] == pytest.approx(25.0)
    assert s["ssim"] == pytest.approx((0.7 + 0.1) / 2)
    assert (s["num_scenes"], s["num_samples"], s["num_targets"]) == (2, 3, 4)
    assert math.isnan(s["lpips"])


def test_camera_path_closed_form():
    rng = np.random.default_rng(1)
    a, b = np.eye(4), np.eye(4)
    a[:3, :3] = so3_exp(rng.normal(size=3) * 0.3)
    rel = np.array([0.1, -0.5, 0.2])
    b[:3, :3] = a[:3, :3] @ so3_exp(rel)
    a[:3, 3], b[:3, 3] = [0, 0, 0], [1, 2, 3]
    for t in (-0.5, 0.0, 0.25, 1.0, 1.5):
        p = interpolate_pose(a, b, t)
        assert np.allclose(p[:3, :3], a[:3, :3] @ so3_exp(t * rel), atol=1e-10)
        assert np.allclose(p[:3, 3], [t, 2 * t, 3 * t])
        assert np.allclose(p[:3, :3].T @ p[:3, :3], np.eye(3), atol=1e-10)
    assert np.allclose(so3_log(so3_exp(np.array([0.0, np.pi - 1e-7, 0.0]))), [0, np.pi - 1e-7, 0], atol=1e-4)
    ts = path_parameters(5, 0.5)
    assert np.allclose(ts, [-0.5, 0.0, 0.5, 1.0, 1.5])
    k = np.diag([1.0, 1.0, 1.0])
    poses, ks = camera_path(a, b, k, 2 * k, np.array([0.0, 0.5]))
    assert np.allclose(poses[0], a) and np.allclose(ks[1][:2, :2], 1.5 * np.eye(2)) and ks[1][2, 2] == 1


def test_eval_metrics_match_independent_computation(run, tmp_path, monkeypatch):
    from pipelines.evaluate import evaluate_on_data
    from seeu_model.training import checkpoint as ckpt_io
    from seeu_model.training.factory import model_from_checkpoint

    shards, run_dir = run
    ck = ckpt_io.load_checkpoint(run_dir / "checkpoints")
    model = model_from_checkpoint(ck)
    res = evaluate_on_data(
        model, str(shards), (32, 32), batch_size=2, max_samples=3, warmup=1, keep_renders=3, rasterizer="torch"
    )
    assert len(res.records) == 9 and len(res.renders) == 3
    for k, r in enumerate(res.renders):
        for j in range(3):
            pred = r["pred"][j].numpy().astype(np.float64)
            gt = r["gt"][j].numpy().astype(np.float64)
            rec = res.records[3 * k + j]
            assert rec.sample_id == r["sample_id"]
            mse = np.mean((np.clip(pred, 0, 1) - gt) ** 2)
            assert rec.psnr == pytest.approx(-10 * np.log10(mse), abs=1e-4)
            ref = structural_similarity(pred, gt, win_size=11, gaussian_weights=True, data_range=1.0, channel_axis=0)
            assert rec.ssim == pytest.approx(ref, abs=1e-5)
    assert res.timing.timed_batches == 1 and res.timing.encoder_ms > 0 and res.timing.renderer_ms > 0
    assert res.timing.peak_memory_mb > 0

    # the CLI: files, aggregation recomputed from per_target.csv
    out = tmp_path / "eval"
    assert (
        main(
            [
                "eval",
                "--checkpoint",
                str(run_dir / "checkpoints"),
                "--data",
                str(shards),
                "--out",
                str(out),
                "--no-lpips",
                "--batch-size",
                "2",
                "--warmup",
                "1",
            ]
        )
        == 0
    )
    summary = json.loads((out / "summary.json").read_text())
    rows = list(csv.DictReader((out / "per_target.csv").open()))
    assert len(rows) == summary["metrics"]["num_targets"] == 8 * 3
    per_scene: dict[str, list[float]] = {}
    for r in rows:
        per_scene.setdefault(r["scene_id"], []).append(float(r["psnr"]))
    expect = np.mean([np.mean(v) for v in per_scene.values()])
    assert summary["metrics"]["psnr"] == pytest.approx(expect, abs=1e-5)
    assert summary["metrics"]["lpips"] is None and summary["lpips"] == "off"
    scenes = list(csv.DictReader((out / "per_scene.csv").open()))
    assert sorted(s["scene_id"] for s in scenes) == ["syn0", "syn1"]
    assert summary["timing"]["timed_batches"] == 3 and summary["step"] == 1

    # LPIPS on but no VGG weights: one clear line, exit 2
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "no_torch_home"))
    assert (
        main(
            ["eval", "--checkpoint", str(run_dir / "checkpoints"), "--data", str(shards), "--out", str(tmp_path / "e2")]
        )
        == 2
    )


def _read_mp4_frames(path: Path) -> int:
    cap = cv2.VideoCapture(str(path))
    n = 0
    while cap.read()[0]:
        n += 1
    cap.release()
    return n


def test_render_shard_sample_and_user_cameras(run, tmp_path):
    from seeu_data.synthetic import camera_path as synth_path
    from seeu_data.synthetic import default_intrinsics_norm, make_scene, render_view
    from seeu_model.ply import load_ply

    shards, run_dir = run
    out = tmp_path / "r1"
    assert (
        main(
            [
                "render",
                "--checkpoint",
                str(run_dir / "checkpoints"),
                "--data",
                str(shards),
                "--sample",
                "2",
                "--out",
                str(out),
                "--frames",
                "3",
                "--extrapolate",
                "0.5",
            ]
        )
        == 0
    )
    rep = json.loads((out / "render.json").read_text())
    assert rep["sample_id"] and rep["extrap"]["t"] == [-0.5, 1.5]
    assert len(list((out / "frames").glob("interp_*.png"))) == 3 == _read_mp4_frames(out / "interp.mp4")
    assert _read_mp4_frames(out / "extrap.mp4") == 3
    g = load_ply(out / "gaussians.ply")
    assert g.means.shape == (1, 2 * 32 * 32, 3) and rep["num_gaussians"] == 2048
    assert set(rep["timing_s"]) == {"encode", "render_interp_per_frame", "render_extrap_per_frame"}
    assert all(v > 0 for v in rep["timing_s"].values())
    # beside it: the 3DGS viewers' cameras.json (contexts, then targets) and the SH-degree sidecar
    cams_json = json.loads((out / "cameras.json").read_text())
    assert [c["img_name"] for c in cams_json][:2] == ["context_0", "context_1"] and len(cams_json) == 5
    assert (
        json.loads((out / "gaussians.json").read_text())["sh_degree"]
        == rep["sh_degree"]
        == int(g.sh.shape[2] ** 0.5) - 1
    )
    assert cv2.imread(str(out / "targets.png")).shape == (64, 96, 3)

    # your own images + cameras (pixel K of 48x64 images: resized and centre-cropped to 32x32)
    scene = make_scene(0)
    poses = synth_path(16)
    intr = default_intrinsics_norm(64, 48)
    frames = []
    for i in (3, 7):
        rgb, _ = render_view(scene, poses[i], intr, 64, 48)
        cv2.imwrite(str(tmp_path / f"v{i}.png"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
        K = [[intr[0] * 64, 0, intr[2] * 64], [0, intr[1] * 48, intr[3] * 48], [0, 0, 1]]
        frames.append({"image": f"v{i}.png", "cam_to_world": poses[i].tolist(), "K": K})
    (tmp_path / "cams.json").write_text(json.dumps({"near": 0.5, "far": 20.0, "frames": frames}))
    out2 = tmp_path / "r2"
    assert (
        main(
            [
                "render",
                "--checkpoint",
                str(run_dir / "checkpoints"),
                "--cameras",
                str(tmp_path / "cams.json"),
                "--out",
                str(out2),
                "--frames",
                "2",
                "--extrapolate",
                "0",
            ]
        )
        == 0
    )
    first = cv2.imread(str(out2 / "frames" / "interp_000.png"))
    assert first.shape == (32, 32, 3) and not (out2 / "targets.png").exists()
    # bad cameras file -> exit 2
    (tmp_path / "bad.json").write_text(json.dumps({"near": 1, "far": 2, "frames": frames[:1]}))
    assert (
        main(
            [
                "render",
                "--checkpoint",
                str(run_dir / "checkpoints"),
                "--cameras",
                str(tmp_path / "bad.json"),
                "--out",
                str(tmp_path / "r3"),
            ]
        )
        == 2
    )


def test_predict_and_python_api_give_the_gaussians_render_gives(run, tmp_path, capsys):
    """`seeu predict` on the posed scene a shard example was built from, with that example's context
    frames, and `SeeU.from_checkpoint(...).predict(...)` on the example's views, give the Gaussians
    `seeu render --data --sample` gives (1e-6); --auto-context picks the widest default gap, centred."""
    from pipelines.render import shard_sample
    from seeu_model.ply import load_ply
    from seeu_model.seeu import SeeU
    from seeu_model.training.loop import batch_to

    shards, run_dir = run
    ckpt = str(run_dir / "checkpoints")
    batch = batch_to(shard_sample(str(shards), "1", (32, 32)), "cpu")
    scene_id, frames = batch["scene_id"][0], batch["context"]["frame_index"][0].tolist()
    common = ["--checkpoint", ckpt, "--frames", "2"]
    assert main(["render", "--data", str(shards), "--sample", "1", "--out", str(tmp_path / "r"), *common]) == 0
    posed = shards.parent / "posed"
    context = ",".join(map(str, frames))
    argv = ["predict", str(posed), "--scene", scene_id, "--context", context, "--out", str(tmp_path / "p"), *common]
    capsys.readouterr()
    assert main(argv) == 0
    line = capsys.readouterr().out.strip()
    assert "\n" not in line and f"from frames {context} (given)" in line
    rep = json.loads((tmp_path / "p" / "predict.json").read_text())
    assert rep["context_frames"] == frames and rep["num_gaussians"] == 2 * 32 * 32
    assert sorted(p.name for p in (tmp_path / "p" / "frames").iterdir()) == [
        "extrap_000.png",
        "extrap_001.png",
        "interp_000.png",
        "interp_001.png",
    ]
    assert len(json.loads((tmp_path / "p" / "cameras.json").read_text())) == 2
    rendered = load_ply(tmp_path / "r" / "gaussians.ply")
    predicted = load_ply(tmp_path / "p" / "gaussians.ply")
    ctx = batch["context"]
    api = SeeU.from_checkpoint(ckpt, device="cpu").predict(
        ctx["image"][0], ctx["intrinsics"][0], ctx["cam_to_world"][0], ctx["near"][0], ctx["far"][0]
    )
    api.rotations = api.rotations / api.rotations.norm(dim=-1, keepdim=True)  # the .ply holds unit quaternions
    for name in ("means", "scales", "rotations", "opacities", "sh"):
        ref = getattr(rendered, name)
        assert ref.shape == getattr(predicted, name).shape == getattr(api, name).shape
        assert (ref - getattr(predicted, name)).abs().max() <= 1e-6, name
        assert (ref - getattr(api, name)).abs().max() <= 1e-6, name
    # --auto-context: the pair of the scene's overlap table that covers its frames best, above the floor
    assert main(["predict", str(posed), "--scene", scene_id, "--out", str(tmp_path / "a"), *common]) == 0
    rep = json.loads((tmp_path / "a" / "predict.json").read_text())
    m = PosedDataset(posed).overlap(scene_id).matrix()
    i, j = rep["context_frames"]
    assert rep["context_rule"] == "auto" and rep["auto_context"]["overlap"] == pytest.approx(min(m[i, j], m[j, i]))
    assert rep["auto_context"]["overlap"] >= rep["auto_context"]["floor"]
    assert 0 <= rep["auto_context"]["extrapolate"]["used"] <= rep["auto_context"]["extrapolate"]["requested"]


def test_eval_reports_metrics_per_overlap_bin(run, tmp_path, capsys):
    """An index whose entries carry NoPoSplat's "overlap" (a value, or a bin name): the eval build
    records it per row, and `seeu eval` reports each bin's metrics, aggregated like the whole (mean
    over targets, then scenes), recomputed here from per_target.csv."""
    shards, run_dir = run
    posed = shards.parent / "posed"
    index = {
        "syn0": [
            {"context": [0, 5], "target": [2, 3], "overlap": 0.7},
            {"context": [2, 12], "target": [6], "overlap": "small"},
            {"context": [1, 4], "target": [2], "overlap": 0.95},  # outside every bin
        ],
        "syn1": [{"context": [3, 9], "target": [5, 6], "overlap": 0.2}],
    }
    (tmp_path / "index.json").write_text(json.dumps(index))
    data = tmp_path / "ev"
    assert (
        main(["build", str(posed), "--out", str(data), "--mode", "eval", "--index", str(tmp_path / "index.json")]) == 0
    )
    out = tmp_path / "e"
    common = ["--checkpoint", str(run_dir / "checkpoints"), "--no-lpips", "--warmup", "0"]
    assert main(["eval", "--data", str(data), "--out", str(out), *common]) == 0
    assert '"by_overlap"' in capsys.readouterr().out
    summary = json.loads((out / "summary.json").read_text())
    rows = list(csv.DictReader((out / "per_target.csv").open()))
    bins = {"syn0/eval/0": "large", "syn0/eval/1": "small", "syn1/eval/0": "small"}
    assert set(summary["by_overlap"]) == {"small", "large"}
    for name, got in summary["by_overlap"].items():
        picked = [r for r in rows if bins.get(r["sample_id"]) == name]
        per_scene: dict[str, list[float]] = {}
        for r in picked:
            per_scene.setdefault(r["scene_id"], []).append(float(r["psnr"]))
        expect = np.mean([np.mean(v) for v in per_scene.values()])
        assert got["psnr"] == pytest.approx(expect, abs=1e-5) and got["num_targets"] == len(picked)
