"""Metrics against independent truths: scikit-image SSIM, the PSNR closed form, LPIPS loading."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from skimage.metrics import structural_similarity

from seeu_data.errors import SeeUError
from seeu_model.metrics import psnr, ssim


def _pair(seed: int, h: int, w: int, noise: float):
    rng = np.random.default_rng(seed)
    # smooth-ish content plus noise, so SSIM is well away from 0 and 1
    base = rng.random((3, h // 4 + 1, w // 4 + 1))
    img = torch.nn.functional.interpolate(
        torch.from_numpy(base)[None], size=(h, w), mode="bilinear", align_corners=False
    )[0].numpy()
    other = np.clip(img + noise * rng.standard_normal(img.shape), 0, 1)
    return img.astype(np.float32), other.astype(np.float32)


@pytest.mark.parametrize("h,w,noise", [(32, 32, 0.05), (48, 64, 0.2), (11, 17, 0.1), (64, 40, 0.01)])
def test_ssim_matches_scikit_image(h, w, noise):
    a, b = _pair(h * w, h, w, noise)
    ours = ssim(torch.from_numpy(a), torch.from_numpy(b)).item()
    ref = structural_similarity(a, b, win_size=11, gaussian_weights=True, sigma=1.5, data_range=1.0, channel_axis=0)
    assert abs(ours - ref) < 1e-6, (ours, ref)


def test_ssim_batched_and_population_covariance():
    pairs = [_pair(s, 24, 24, 0.1) for s in range(6)]
    a = torch.from_numpy(np.stack([p[0] for p in pairs])).view(2, 3, 3, 24, 24)
    b = torch.from_numpy(np.stack([p[1] for p in pairs])).view(2, 3, 3, 24, 24)
    out = ssim(a, b)
    assert out.shape == (2, 3)
    for i, (x, y) in enumerate(pairs):
        ref = structural_similarity(x, y, win_size=11, gaussian_weights=True, data_range=1.0, channel_axis=0)
        assert abs(out.flatten()[i].item() - ref) < 1e-6
    x, y = pairs[0]
    pop = ssim(torch.from_numpy(x), torch.from_numpy(y), use_sample_covariance=False).item()
    ref = structural_similarity(
        x, y, win_size=11, gaussian_weights=True, data_range=1.0, channel_axis=0, use_sample_covariance=False
    )
    assert abs(pop - ref) < 1e-6
    assert ssim(torch.from_numpy(x), torch.from_numpy(x)).item() == pytest.approx(1.0, abs=1e-9)


def test_psnr_closed_form_and_clipping():
    target = torch.full((2, 3, 8, 8), 0.5)
    pred = target + 0.1  # MSE 0.01 -> 20 dB
    assert torch.allclose(psnr(pred, target), torch.full((2,), 20.0), atol=1e-4)
    # out-of-range values are clipped first: 1.7 counts as 1.0 -> MSE 0.25 -> 6.0206 dB
    pred = torch.full((3, 4, 4), 1.7)
    assert psnr(pred, torch.full((3, 4, 4), 0.5)).item() == pytest.approx(-10 * math.log10(0.25), abs=1e-4)
    # per-image, not pooled: mean of the two PSNRs differs from the PSNR of the pooled MSE
    a = torch.zeros(2, 3, 4, 4)
    b = torch.stack([torch.full((3, 4, 4), 0.1), torch.full((3, 4, 4), 0.3)])
    per = psnr(b, a)
    assert per[0].item() == pytest.approx(20.0, abs=1e-4)
    assert per[1].item() == pytest.approx(-10 * math.log10(0.09), abs=1e-4)


def test_lpips_missing_weights_is_a_clear_error(tmp_path, monkeypatch):
    from seeu_model.lpips_loss import LPIPS, VGG16_FILENAME

    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "th"))
    with pytest.raises(SeeUError) as info:
        LPIPS()
    assert VGG16_FILENAME in str(info.value) and str(tmp_path / "th") in str(info.value)
    assert "--lpips-weights" in str(info.value)
    with pytest.raises(SeeUError, match="not found"):
        LPIPS(weights=tmp_path / "nope.pth")
    bad = tmp_path / "bad.pth"
    torch.save({"features.0.weight": torch.zeros(1)}, bad)
    with pytest.raises(SeeUError, match="VGG-16 state dict"):
        LPIPS(weights=bad)


def test_lpips_loads_trunk_from_file_and_is_frozen(tmp_path):
    from torchvision.models.vgg import cfgs, make_layers

    from seeu_model.lpips_loss import LPIPS

    torch.manual_seed(0)
    features = make_layers(cfgs["D"])
    path = tmp_path / "vgg16-397923af.pth"
    torch.save({f"features.{k}": v for k, v in features.state_dict().items()}, path)
    m = LPIPS(weights=path)
    assert torch.equal(getattr(m.net.net.slice1, "0").weight, features[0].weight)
    assert torch.equal(getattr(m.net.net.slice5, "28").bias, features[28].bias)
    assert not any(p.requires_grad for p in m.parameters())
    m.train()
    assert not m.training
    x = torch.rand(2, 3, 32, 32)
    y = torch.rand(2, 3, 32, 32)
    d = m(x, y)
    assert d.shape == (2,) and (d > 0).all()
    assert torch.allclose(m(x, x), torch.zeros(2), atol=1e-7)
    # the linear heads shipped with the wheel are loaded (not the default init of ones/zeros)
    assert m.net.lin0.model[-1].weight.abs().sum() > 0
    # gradients flow to the input even though the network is frozen (it is a loss)
    x.requires_grad_(True)
    m(x, y).sum().backward()
    assert x.grad is not None and x.grad.abs().sum() > 0


def test_depth_rmse_closed_form():
    from seeu_model.geometry_metrics import depth_rmse

    gt = torch.full((2, 4, 5), 2.0)
    gt[0, 0, :] = 0.0  # no ground truth there
    gt[1] = float("nan")  # an image without ground truth
    pred = torch.full((2, 4, 5), 2.0)
    pred[0, 1:] += 0.3
    pred[0, 0] += 5.0  # ignored (gt invalid)
    out = depth_rmse(pred, gt)
    assert out[0].item() == pytest.approx(0.3, abs=1e-6) and math.isnan(out[1].item())
    mask = torch.zeros(2, 4, 5, dtype=torch.bool)
    mask[0, 1, 0] = True
    pred[0, 1, 0] = 3.0
    assert depth_rmse(pred, gt, mask)[0].item() == pytest.approx(1.0, abs=1e-6)


def test_chamfer_dtueval_against_brute_force():
    from seeu_model.geometry_metrics import chamfer_dtueval, downsample_density, dtu_observation_filter

    g = np.stack(np.meshgrid(np.arange(10.0), np.arange(10.0), [0.0], indexing="ij"), -1).reshape(-1, 3)
    pred = g + [0.0, 0.0, 0.5]
    pred = np.concatenate([pred, [[100.0, 100.0, 100.0]], pred[:5].copy()])  # outlier + duplicates
    res = chamfer_dtueval(pred, g, density=0.2, max_dist=20.0)
    assert res.num_pred == 101  # the 5 duplicates are thinned away, the outlier stays
    assert res.accuracy == pytest.approx(0.5) and res.completeness == pytest.approx(0.5)
    assert res.overall == pytest.approx(0.5)
    # observation mask (a voxel volume) keeps only x < 5 for accuracy; plane keeps gt with y >= 3
    vol = np.zeros((200, 200, 10), dtype=bool)
    vol[:50] = True  # res 0.1 from bb min (0, 0, -0.4): x < 5
    in_mask, above = dtu_observation_filter(
        vol, np.array([[0.0, 0.0, -0.4], [20, 20, 0.6]]), 0.1, plane=np.array([0.0, 1.0, 0.0, -2.5])
    )
    pred2 = g + [0.0, 0.0, 0.5]
    pred2[g[:, 0] >= 5] += [0.0, 0.0, 1.0]  # outside the mask: worse, must not count for accuracy
    res2 = chamfer_dtueval(pred2, g, pred_in_mask=in_mask, gt_above_plane=above(g))
    d = np.linalg.norm(g[above(g)][:, None] - downsample_density(pred2, 0.2)[None], axis=-1).min(1)
    assert res2.accuracy == pytest.approx(0.5) and res2.num_pred_in_mask == 50
    assert res2.completeness == pytest.approx(d.mean()) and res2.num_gt == 70
    kept = downsample_density(np.random.default_rng(0).random((300, 3)), 0.2)
    dist = np.linalg.norm(kept[:, None] - kept[None], axis=-1) + np.eye(len(kept)) * 9
    assert dist.min() > 0.2


def test_depth_fn_aligns_ground_truth_with_the_loader_crop(tmp_path):
    from types import SimpleNamespace

    from pipelines.evaluate import make_depth_fn

    # 40x80 ground truth; evaluation at 20x20 -> cover-crop: resize to 20x40, keep columns 10..29
    gt = np.tile(np.arange(80, dtype=np.float32), (40, 1)) + 1.0
    (tmp_path / "sceneA").mkdir()
    np.save(tmp_path / "sceneA" / "000007.npy", gt)
    fn = make_depth_fn(tmp_path, (20, 20))
    expect = gt[::2, ::2][:, 10:30]  # nearest-neighbour resize, centre crop
    depth = torch.from_numpy(expect.copy())[None, None, None] + 0.5  # (B=1, T=1, 1, H, W)
    batch = {"scene_id": ["sceneA"], "target": {"frame_index": torch.tensor([[7]])}}
    out = fn(batch, SimpleNamespace(depth=depth))
    assert out.shape == (1, 1) and out[0, 0].item() == pytest.approx(0.5, abs=1e-5)
    batch["target"]["frame_index"] = torch.tensor([[8]])  # no file -> NaN
    assert math.isnan(fn(batch, SimpleNamespace(depth=depth))[0, 0].item())


def _write_pfm(path, depth: np.ndarray) -> None:
    h, w = depth.shape
    with open(path, "wb") as fh:
        fh.write(f"Pf\n{w} {h}\n-1.0\n".encode())
        fh.write(np.flipud(depth).astype("<f4").tobytes())


def test_dtu_ground_truth_found_through_the_shards(tmp_path):
    """Ground truth the DTU importer records in the scene meta reaches seeu eval via the shards' manifest."""
    from plyfile import PlyData, PlyElement

    from pipelines.build import BuildConfig, build
    from seeu_data.build.sampling import SamplingConfig
    from seeu_data.dtu_gt import posed_ground_truth, read_pfm
    from seeu_data.store.manifest import provenance
    from seeu_data.store.posed import PosedDatasetWriter
    from seeu_data.synthetic import synthetic_posed_scene

    gt_dir = tmp_path / "Depths" / "scan1_train"
    gt_dir.mkdir(parents=True)
    depth = np.arange(12 * 16, dtype=np.float32).reshape(12, 16) + 500.0  # mm
    _write_pfm(gt_dir / "depth_map_0005.pfm", depth)
    assert np.array_equal(read_pfm(gt_dir / "depth_map_0005.pfm"), depth)
    pts = np.random.default_rng(0).random((50, 3)).astype(np.float32)
    ply = tmp_path / "stl001_total.ply"
    PlyData(
        [
            PlyElement.describe(
                np.array([tuple(p) for p in pts], dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")]), "vertex"
            )
        ]
    ).write(str(ply))
    scene = synthetic_posed_scene(12, 24, 32, seed=0, scene_id="scan1")
    scene.meta = {
        "dataset": "dtu",
        "scale": 0.005,
        "gt_depth_dir": str(gt_dir),
        "gt_depth_units": "mm",
        "gt_depth_pattern": "depth_map_{view:04d}.pfm",
        "gt_points": str(ply),
    }
    with PosedDatasetWriter(tmp_path / "posed", {}, provenance("test")) as w:
        w.add(scene)
    build(
        BuildConfig(
            inputs=(str(tmp_path / "posed"),),
            out=str(tmp_path / "shards"),
            sampling=SamplingConfig(gap_min=3, gap_max=4, samples_per_scene=2),
        )
    )
    found = posed_ground_truth(str(tmp_path / "shards"))
    assert found is not None
    depth_loader, points_loader, to_mm = found
    assert np.allclose(depth_loader("scan1", 5), depth * 0.005) and depth_loader("scan1", 6) is None
    got = points_loader("scan1")
    assert np.allclose(got.points, pts, atol=1e-6) and got.observation is None and to_mm == pytest.approx(200.0)
    assert posed_ground_truth(str(tmp_path / "nope")) is None
