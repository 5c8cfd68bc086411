"""Per-frame masks of excluded pixels: storage (posed frames schema 1.1), import, build, loader, loss, eval."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pyarrow as pa
import pytest
import torch

from pipelines.validate import validate_dataset
from seeu_data.errors import SeeUError
from seeu_data.masks import decode_mask, encode_mask
from seeu_data.store.arrow_io import read_table, sha256_file, write_table
from seeu_data.store.posed import PosedDataset, PosedDatasetWriter
from tests.helpers import make_posed_scene


def box_mask(height: int, width: int, i: int) -> np.ndarray:
    """(H, W) bool: a box that moves right by 3 px per frame `i`."""
    m = np.zeros((height, width), bool)
    m[10:30, 5 + 3 * i : 25 + 3 * i] = True
    return m


def masked_scene(scene_id: str = "m", n: int = 6, every: int = 2):
    """make_posed_scene with a moving-box mask on every `every`-th frame (None on the others)."""
    scene = make_posed_scene(scene_id, n=n)
    scene.masks = [encode_mask(box_mask(48, 64, i)) if i % every == 0 else None for i in range(n)]
    return scene


# ---- storage ---------------------------------------------------------------------------------


def test_mask_png_round_trip_and_format():
    m = box_mask(48, 64, 2)
    data = encode_mask(m)
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert img.dtype == np.uint8 and img.shape == (48, 64) and set(np.unique(img)) == {0, 255}
    assert np.array_equal(decode_mask(data), m)
    with pytest.raises(SeeUError, match="8-bit single-channel"):
        decode_mask(cv2.imencode(".png", np.zeros((4, 4, 3), np.uint8))[1].tobytes())


def test_posed_masks_round_trip_and_validate(tmp_path):
    scenes = [masked_scene("m"), make_posed_scene("plain", n=4)]
    with PosedDatasetWriter(tmp_path / "ds", params={}, provenance={}) as w:
        for s in scenes:
            w.add(s)
    ds = PosedDataset(tmp_path / "ds", verify=True)
    assert ds.manifest["schema_version"] == "1.1"
    got = ds.load_scene("m")
    assert got.masks == scenes[0].masks and got.masks[1] is None
    assert np.array_equal(decode_mask(got.masks[4]), box_mask(48, 64, 4))
    assert ds.load_scene("plain").masks is None
    assert validate_dataset(tmp_path / "ds")["rows"] == 10


def test_posed_version_1_0_without_mask_column_still_reads(tmp_path):
    """A dataset written before masks (schema 1.0: no `mask` column) validates and loads as mask-less."""
    with PosedDatasetWriter(tmp_path / "ds", params={}, provenance={}) as w:
        w.add(make_posed_scene("old", n=5))
    doc = json.loads((tmp_path / "ds" / "manifest.json").read_text())
    entry = doc["files"][0]
    path = tmp_path / "ds" / entry["path"]
    table = read_table(path).drop_columns(["mask"])
    table = table.replace_schema_metadata({**table.schema.metadata, b"seeu.schema_version": b"1.0"})
    write_table(path, table)
    entry["bytes"], entry["sha256"] = path.stat().st_size, sha256_file(path)
    doc["schema_version"] = "1.0"
    (tmp_path / "ds" / "manifest.json").write_text(json.dumps(doc))
    assert validate_dataset(tmp_path / "ds")["schema_version"] == "1.0"
    scene = PosedDataset(tmp_path / "ds", verify=True).load_scene("old")
    assert scene.masks is None and len(scene) == 5


@pytest.mark.parametrize(
    "mask, text",
    [
        (encode_mask(np.ones((40, 64), bool)), "mask is 64x40, its frame 64x48"),
        (cv2.imencode(".png", np.zeros((48, 64, 3), np.uint8))[1].tobytes(), "8-bit greyscale expected"),
        (cv2.imencode(".jpg", np.zeros((48, 64), np.uint8))[1].tobytes(), "not a PNG"),
        (b"nope", "failed to decode"),
    ],
)
def test_posed_scene_check_refuses_bad_masks(mask, text):
    scene = masked_scene()
    scene.masks = list(scene.masks)
    scene.masks[2] = mask
    with pytest.raises(SeeUError, match=text) as exc:
        scene.check()
    assert "frame 2" in str(exc.value)
    scene.masks = scene.masks[:3]
    with pytest.raises(SeeUError, match="masks has 3 entries for 6 frames"):
        scene.check()


def test_validate_refuses_a_mask_of_another_size_in_the_file(tmp_path):
    with PosedDatasetWriter(tmp_path / "ds", params={}, provenance={}) as w:
        w.add(masked_scene())
    doc = json.loads((tmp_path / "ds" / "manifest.json").read_text())
    entry = doc["files"][0]
    path = tmp_path / "ds" / entry["path"]
    table = read_table(path)
    masks = table.column("mask").to_pylist()
    masks[3] = encode_mask(np.ones((8, 8), bool))
    i = table.schema.get_field_index("mask")
    write_table(path, table.set_column(i, table.schema.field(i), pa.array(masks, pa.binary())))
    entry["bytes"], entry["sha256"] = path.stat().st_size, sha256_file(path)
    (tmp_path / "ds" / "manifest.json").write_text(json.dumps(doc))
    with pytest.raises(SeeUError, match="scene 'm' frame 3: mask is 8x8, its frame 64x48"):
        validate_dataset(tmp_path / "ds")


# ---- build -> loader -> training ---------------------------------------------------------------

TARGETS = (2, 3, 4)  # the eval index's targets; contexts 0 and 6


def _mover_posed(root, box_colour) -> None:
    """PNG frames (48x64) of a textured scene with a box moving right across every frame, its exact mask
    on every frame; the box is red on the context frames and `box_colour` on the target frames."""
    scene = make_posed_scene("walk", n=8, height=48, width=64, image_format="png")
    images = []
    for i, data in enumerate(scene.images):
        img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
        img[box_mask(48, 64, i)] = box_colour if i in TARGETS else (0, 0, 255)
        images.append(cv2.imencode(".png", img)[1].tobytes())
    scene.images = images
    scene.masks = [encode_mask(box_mask(48, 64, i)) for i in range(len(images))]
    with PosedDatasetWriter(root / "posed", params={}, provenance={}) as w:
        w.add(scene)
    index = root / "index.json"
    index.write_text(json.dumps({"walk": {"context": [0, 6], "target": list(TARGETS)}}))
    from pipelines.cli import main as cli_main

    argv = ["build", str(root / "posed"), "--out", str(root / "shards"), "--mode", "eval", "--index", str(index)]
    assert cli_main([*argv, "--resize", "36x40", "--workers", "1"]) == 0


def _loader_batch(shards, **config):
    from seeu_data.loader import make_loader

    return next(iter(make_loader(shards, batch_size=1, image_hw=(24, 24), shuffle=False, **config)))


def test_masks_survive_build_and_loader(tmp_path):
    _mover_posed(tmp_path / "a", (0, 255, 0))
    _mover_posed(tmp_path / "b", (255, 255, 255))
    from seeu_data.build.triples import TripleShards

    (row,) = TripleShards(tmp_path / "a" / "shards").rows()
    assert validate_dataset(tmp_path / "a" / "shards")["schema_version"] == "1.1"
    # the build's resize 48x64 -> 36x40: scale 0.75 -> 36x48, 4 columns cropped on each side
    for v, f in enumerate(row.frame_index):
        ys, xs = np.nonzero(box_mask(48, 64, int(f)))
        rows, cols = np.zeros(36, bool), np.zeros(48, bool)
        rows[int(ys.min() * 0.75) : -(-(ys.max() + 1) * 3 // 4)] = True
        cols[int(xs.min() * 0.75) : -(-(xs.max() + 1) * 3 // 4)] = True
        # every output pixel the box's area reaches, and no other
        assert np.array_equal(decode_mask(row.masks[v]), rows[:, None] & cols[None, 4:44])
    for flip in (0.0, 1.0):
        a, b = (_loader_batch(tmp_path / k / "shards", flip_p=flip, batch_format="pixelsplat") for k in "ab")
        mask = a["target"]["mask"]
        assert mask.shape == (1, 3, 24, 24) and mask.dtype == torch.bool and torch.equal(mask, b["target"]["mask"])
        assert a["context"]["mask"].shape == (1, 2, 24, 24)
        # the box's colour differs on the targets only: every pixel where the loaded images differ is masked
        differs = (a["target"]["image"] != b["target"]["image"]).any(2)
        assert differs.any() and not (differs & ~mask).any() and mask.float().mean() < 0.5
        assert torch.equal(a["context"]["image"], b["context"]["image"])
    shards_no_masks = tmp_path / "plain"
    with PosedDatasetWriter(tmp_path / "plain_posed", params={}, provenance={}) as w:
        w.add(make_posed_scene("plain", n=8))
    from pipelines.cli import main as cli_main

    assert cli_main(["build", str(tmp_path / "plain_posed"), "--out", str(shards_no_masks), "--gap-min", "3"]) == 0
    assert "mask" not in _loader_batch(shards_no_masks)["target"]


def test_a_masked_moving_object_changes_no_gradient(tmp_path):
    """Two data sets differ only in the colour of the moving box on the target frames, where it is
    masked: built, loaded (flipped) and trained on, they give the same loss and the same gradient of
    every model parameter (MSE + LPIPS); without the masks the gradients differ."""
    from seeu_model.lpips_loss import LPIPS
    from seeu_model.training.config import load_config
    from seeu_model.training.factory import make_render_fn
    from seeu_model.training.loop import Trainer
    from tests.training_fixtures import tiny_model_factory

    _mover_posed(tmp_path / "a", (0, 255, 0))
    _mover_posed(tmp_path / "b", (255, 255, 255))
    torch.manual_seed(0)
    lpips_fn = LPIPS(random_trunk=True)
    cfg = load_config(None, ["optim.warmup_steps=0", "loss.lpips_weight=0.5", "log.progress=false", "precision=fp32"])

    def grads(name: str, masked: bool = True) -> tuple[float, list[torch.Tensor]]:
        batch = _loader_batch(tmp_path / name / "shards", flip_p=1.0)
        if not masked:
            for side in ("context", "target"):
                del batch[side]["mask"]
        trainer = Trainer(
            tiny_model_factory({})[0], cfg, tmp_path / name / "run", make_render_fn("torch"), lpips_fn=lpips_fn
        )
        parts, _ = trainer.train_step(batch)
        return parts.loss, [p.grad.clone() for p in trainer.model.parameters()]

    (loss_a, ga), (loss_b, gb) = grads("a"), grads("b")
    assert loss_a == pytest.approx(loss_b, rel=1e-6)
    assert all(torch.allclose(x, y, rtol=1e-5, atol=1e-9) for x, y in zip(ga, gb))
    assert any(x.abs().max() > 0 for x in ga)
    (_, ua), (_, ub) = grads("a", masked=False), grads("b", masked=False)
    assert not all(torch.allclose(x, y, rtol=1e-3, atol=1e-7) for x, y in zip(ua, ub))


# ---- import / export -------------------------------------------------------------------------


def _posed_dir(tmp_path, scene) -> str:
    with PosedDatasetWriter(tmp_path / "posed", params={}, provenance={}) as w:
        w.add(scene)
    return str(tmp_path / "posed")


def test_nerfstudio_masks_exported_in_its_convention_and_imported_back(tmp_path):
    from pipelines.cli import main as cli_main

    scene = masked_scene("walk")
    assert cli_main(["export", "nerfstudio", _posed_dir(tmp_path, scene), "--out", str(tmp_path / "ns")]) == 0
    doc = json.loads((tmp_path / "ns" / "walk" / "transforms.json").read_text())
    for i, frame in enumerate(doc["frames"]):
        if i % 2:
            assert "mask_path" not in frame
            continue
        # nerfstudio's dataparser reads the mask as bool(pixel): True = the pixel is used
        kept = cv2.imread(str(tmp_path / "ns" / "walk" / frame["mask_path"]), cv2.IMREAD_UNCHANGED).astype(bool)
        assert np.array_equal(kept, ~box_mask(48, 64, i))
    out = tmp_path / "back"
    assert cli_main(["import", "nerfstudio", str(tmp_path / "ns" / "walk" / "transforms.json"), "--out", str(out)]) == 0
    got = PosedDataset(out).load_scene("walk")
    assert [m is None for m in got.masks] == [m is None for m in scene.masks]
    for i in range(0, 6, 2):
        assert np.array_equal(decode_mask(got.masks[i]), box_mask(48, 64, i))


def test_nerfstudio_mask_path_of_its_own_convention(tmp_path, capsys):
    """A nerfstudio folder written by hand: masks 0 = ignore, any nonzero value (here 1) = keep."""
    from pipelines.cli import main as cli_main

    folder = tmp_path / "ns"
    (folder / "images").mkdir(parents=True)
    (folder / "m").mkdir()
    frames = []
    for i in range(3):
        cv2.imwrite(str(folder / "images" / f"f{i}.png"), np.full((20, 30, 3), 60 * i, np.uint8))
        keep = np.ones((20, 30), np.uint8)
        keep[5:9, i : i + 10] = 0
        cv2.imwrite(str(folder / "m" / f"f{i}.png"), keep)
        frames.append(
            {"file_path": f"images/f{i}.png", "mask_path": f"m/f{i}.png", "transform_matrix": np.eye(4).tolist()}
        )
    doc = {"fl_x": 30.0, "fl_y": 30.0, "w": 30, "h": 20, "camera_model": "PINHOLE", "frames": frames}
    (folder / "transforms.json").write_text(json.dumps(doc))
    assert cli_main(["import", "nerfstudio", str(folder / "transforms.json"), "--out", str(tmp_path / "o")]) == 0
    scene = PosedDataset(tmp_path / "o").load_scene("ns")
    for i in range(3):
        expect = np.zeros((20, 30), bool)
        expect[5:9, i : i + 10] = True
        assert np.array_equal(decode_mask(scene.masks[i]), expect)
    cv2.imwrite(str(folder / "m" / "f1.png"), np.ones((10, 30), np.uint8))
    assert cli_main(["import", "nerfstudio", str(folder / "transforms.json"), "--out", str(tmp_path / "o2")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "mask is 30x10, its frame 30x20" in err and "f1.png" in err


def test_a_users_mask_folder_on_import(tmp_path, capsys):
    """--masks DIR: files matched by frame name (or number), nonzero = excluded by default, --mask-convention
    keep for the other polarity; a folder that matches no frame or a mask of another size: one line, exit 2."""
    from pipelines.cli import main as cli_main

    scene = make_posed_scene("walk", n=6)  # frames named frame_00000.jpg, frame_00003.jpg, ...
    assert cli_main(["export", "nerfstudio", _posed_dir(tmp_path, scene), "--out", str(tmp_path / "ns")]) == 0
    transforms = str(tmp_path / "ns" / "walk" / "transforms.json")
    masks = tmp_path / "masks"
    masks.mkdir()
    for i in (1, 4):
        cv2.imwrite(str(masks / f"frame_{3 * i:05d}.png"), box_mask(48, 64, i).astype(np.uint8) * 255)
    assert cli_main(["import", "nerfstudio", transforms, "--out", str(tmp_path / "o"), "--masks", str(masks)]) == 0
    got = PosedDataset(tmp_path / "o").load_scene("walk")
    assert [m is not None for m in got.masks] == [False, True, False, False, True, False]
    assert np.array_equal(decode_mask(got.masks[4]), box_mask(48, 64, 4))
    assert got.meta["masks"]["frames"] == 2
    argv = ["import", "nerfstudio", transforms, "--masks", str(masks), "--mask-convention", "keep"]
    assert cli_main([*argv, "--out", str(tmp_path / "k")]) == 0
    got = PosedDataset(tmp_path / "k").load_scene("walk")
    assert np.array_equal(decode_mask(got.masks[1]), ~box_mask(48, 64, 1))
    (masks / "frame_00003.png").rename(masks / "other_7.png")
    cv2.imwrite(str(masks / "frame_00012.png"), np.zeros((40, 64), np.uint8))
    capsys.readouterr()
    assert cli_main([*argv, "--out", str(tmp_path / "bad")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "mask is 64x40, its frame 64x48" in err and "frame_00012.png" in err
    for p in masks.iterdir():
        p.rename(masks / f"x{p.name}")
    (masks / "xframe_00012.png").unlink()  # left: xother_7.png, whose number is no frame's
    assert cli_main([*argv, "--out", str(tmp_path / "none")]) == 2
    assert "no mask file matches a frame (frames are named like 'frame_00000'" in capsys.readouterr().err


# ---- metrics and evaluation --------------------------------------------------------------------


def test_masked_psnr_and_ssim_against_closed_form_and_scikit_image():
    from skimage.metrics import structural_similarity

    from seeu_model.metrics import fill_masked, psnr, ssim

    rng = np.random.default_rng(0)
    gt = torch.from_numpy(rng.random((2, 3, 32, 40)))
    pred = (gt + torch.from_numpy(rng.normal(0, 0.05, gt.shape))).clamp(0, 1)
    mask = torch.zeros(2, 32, 40, dtype=torch.bool)
    mask[0, 8:20, 10:30] = True
    gt[0, :, 8:20, 10:30] = 1.0 - pred[0, :, 8:20, 10:30]  # a "moving object" the masked metrics must not see
    keep = ~mask[0]
    err = (pred[0] - gt[0]).pow(2)[:, keep]
    assert psnr(pred, gt, mask=mask)[0].item() == pytest.approx(-10 * np.log10(err.mean().item()), rel=1e-9)
    assert psnr(pred, gt, mask=mask)[1].item() == pytest.approx(psnr(pred, gt)[1].item(), rel=1e-9)
    filled = fill_masked(pred, gt, mask)
    for k in range(2):
        _, smap = structural_similarity(
            pred[k].numpy(),
            filled[k].numpy(),
            win_size=11,
            gaussian_weights=True,
            sigma=1.5,
            use_sample_covariance=True,
            data_range=1.0,
            channel_axis=0,
            full=True,
        )
        centre = smap.mean(0)[5:-5, 5:-5]
        expect = centre[(~mask[k]).numpy()[5:-5, 5:-5]].mean()
        assert ssim(pred, gt, mask=mask)[k].item() == pytest.approx(expect, abs=1e-6)
    assert ssim(pred, gt, mask=mask)[1].item() == pytest.approx(ssim(pred, gt)[1].item(), abs=1e-12)


def test_eval_reports_metrics_with_and_without_masked_pixels():
    from seeu_model.evaluation import evaluate_model, summarize
    from seeu_model.rasterizer import RenderOutput

    rng = np.random.default_rng(1)
    gt = torch.from_numpy(rng.random((2, 2, 3, 24, 24)).astype(np.float32))
    pred = (gt + 0.02).clamp(0, 1)
    mask = torch.zeros(2, 2, 24, 24, dtype=torch.bool)
    mask[0, 1, :12] = True  # one target half masked; its top half is wrong in the data
    gt_moving = gt.clone()
    gt_moving[0, 1, :, :12] = 1 - pred[0, 1, :, :12]

    def batches(target_image, with_mask):
        target = {"image": target_image, "frame_index": torch.zeros(2, 2, dtype=torch.int64)}
        if with_mask:
            target["mask"] = mask
        yield {"context": {}, "target": target, "scene_id": ["a", "b"], "sample_id": ["a/0", "b/0"]}

    def run(image, with_mask):
        render = lambda g, t: RenderOutput(pred, torch.zeros(2, 2, 1, 24, 24), torch.ones(2, 2, 1, 24, 24))  # noqa: E731
        out = evaluate_model(
            NoModel(), batches(image, with_mask), torch.device("cpu"), lambda m, c: None, render, warmup=0
        )
        records.extend(out.records)
        return summarize(out.records)

    records: list = []

    class NoModel(torch.nn.Module):
        pass

    plain, masked, clean = run(gt_moving, False), run(gt_moving, True), run(gt, True)
    assert "psnr_kept" not in plain and plain["psnr"] == masked["psnr"] and plain["ssim"] == masked["ssim"]
    assert masked["masked_fraction"] == pytest.approx(0.5 * 0.5 * 0.5)  # half of 1 of 2 targets, scene a; 0 in b
    assert masked["psnr_kept"] == pytest.approx(clean["psnr_kept"], abs=1e-9)  # the moving content is not seen
    assert masked["psnr_kept"] > masked["psnr"] + 5
    # a batch without masks counts with its plain values among the kept-pixel numbers
    both = summarize(records[:4] + records[4:8])  # plain (no mask key) + masked, same targets
    kept = [r.psnr for r in records[:4]] + [r.psnr_kept for r in records[4:8]]
    assert both["psnr_kept_all_targets"] == pytest.approx(sum(kept) / 8)


def test_ingest_masks_follow_the_downscale_and_the_undistortion(tmp_path):
    """`seeu ingest --masks`: masks at the video's size, frames decoded at half size (--max-size) and
    undistorted by SfM: each mask is halved and warped like its frame (the frame's own undistortion,
    `undistort_files`, applied to the mask as an image gives the same pixels)."""
    from types import SimpleNamespace

    import pycolmap

    from pipelines.ingest import IngestConfig, chunk_masks
    from seeu_data.undistort import undistort_files

    cam = {"model": "SIMPLE_RADIAL", "width": 64, "height": 48, "params": [60.0, 32.0, 24.0, 0.08]}
    chunk = SimpleNamespace(
        meta={"camera_as_mapped": cam, "undistorted": True}, width=np.full(3, 64), height=np.full(3, 48)
    )
    frames = [{"source_name": "", "source_frame": 10 * i} for i in range(3)]
    folder = tmp_path / "masks" / "clip"
    folder.mkdir(parents=True)
    big = np.kron(box_mask(48, 64, 3), np.ones((2, 2), bool))  # the video's 96x128: each mask pixel 2x2
    cv2.imwrite(str(folder / "frame_000010.png"), big.astype(np.uint8) * 255)
    cfg = IngestConfig(out=tmp_path / "o", inputs=("clip.mp4",), masks=str(tmp_path / "masks"))
    got = chunk_masks(cfg, "clip", chunk, frames)
    assert got[0] is None and got[2] is None
    (tmp_path / "img").mkdir()
    cv2.imwrite(str(tmp_path / "img" / "m.png"), np.repeat(box_mask(48, 64, 3)[..., None], 3, 2).astype(np.uint8) * 255)
    camera = pycolmap.Camera(model=cam["model"], width=64, height=48, params=cam["params"])
    undistort_files(camera, tmp_path / "img", ["m.png"], tmp_path / "und")
    expect = cv2.imread(str(tmp_path / "und" / "m.png"), cv2.IMREAD_GRAYSCALE) > 0
    assert np.array_equal(decode_mask(got[1]), expect) and expect.sum() > box_mask(48, 64, 3).sum() * 0.8


def test_view_and_sheet_tint_masked_pixels(tmp_path):
    from pipelines.view import thumbnail

    scene = masked_scene()
    plain = thumbnail(scene.images[2], 64)
    tinted = thumbnail(scene.images[2], 64, scene.masks[2])
    m = box_mask(48, 64, 2)
    assert np.array_equal(tinted[~m], plain[~m])
    assert np.array_equal(tinted[m], (plain[m].astype(int) + [255, 0, 255]) // 2)
