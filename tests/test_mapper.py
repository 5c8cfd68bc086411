"""`seeu ingest --mapper global|auto` and `--features` guards: GLOMAP global mapping poses the
synthetic clip as accurately as the ground truth demands; `auto` reads the verified match graph
(a video is a chain of matched consecutive frames, the same frames in shuffled order are not)."""

from __future__ import annotations

import json

import numpy as np
import pycolmap
import pytest

from pipelines.cli import main as cli_main
from seeu_data.ingest.match_graph import CHAIN_PCT, choose_mapper, match_graph_stats
from seeu_data.synthetic import ingest_accuracy, write_clip

W, H, N = 320, 180, 24


@pytest.fixture(scope="module")
def global_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("mapper")
    write_clip(root / "walk.mp4", n_frames=N, size=(H, W), seed=0)
    assert (
        cli_main(
            [
                "ingest",
                str(root / "walk.mp4"),
                "--out",
                str(root / "posed"),
                "--mapper",
                "global",
                "--threads",
                "1",
                "--size",
                "120x160",
            ]
        )
        == 0
    )
    return root


def test_global_mapper_matches_ground_truth(global_run):
    report = json.loads((global_run / "posed" / "walk" / "report.json").read_text())
    assert report["sfm"]["mapper"]["used"] == "global" and report["sfm"]["mapper"]["requested"] == "global"
    assert report["registered"] / N >= 0.95
    video = global_run / "walk.mp4"
    acc = ingest_accuracy(global_run / "posed" / "walk", video, report["registered"], report["frames_selected"])
    acc = acc["chunks"][0]
    assert acc["centre_rmse_pct_path"] <= 0.5 and acc["rel_rot_err_mean_deg"] <= 0.2, acc


def test_auto_reads_the_match_graph(global_run):
    db = pycolmap.Database.open(global_run / "posed" / ".work" / "walk" / "sfm" / "database.db")
    names = sorted(img.name for img in db.read_all_images())
    video = match_graph_stats(db, names)
    shuffled = match_graph_stats(db, list(np.random.default_rng(0).permutation(names)))
    db.close()
    # in video order every frame matches the next; the same pairs in shuffled order rarely chain
    assert video["consecutive_matched_pct"] == 100.0 and video["verified_pairs"] == shuffled["verified_pairs"]
    assert shuffled["consecutive_matched_pct"] < CHAIN_PCT
    assert choose_mapper(video)[0] == "incremental" and choose_mapper(shuffled)[0] == "global"


def test_features_without_runtime_are_refused_before_sfm(tmp_path, capsys):
    options = pycolmap.FeatureExtractionOptions()
    options.type = pycolmap.FeatureExtractorType.ALIKED_N16ROT
    try:
        pycolmap.FeatureExtractor.create(options)
        pytest.skip("this pycolmap runs ALIKED (ONNX support built in)")
    except RuntimeError:
        pass
    assert cli_main(["ingest", str(tmp_path / "any.mp4"), "--out", str(tmp_path / "o"), "--features", "aliked"]) == 2
    err = capsys.readouterr().err.strip()
    assert "--features aliked" in err and "ONNX" in err and "\n" not in err
    assert not (tmp_path / "o").exists()  # refused before anything was started or written


def test_ingest_size_resizes_and_crops_with_intrinsics(global_run):
    """--size 120x160 on a 320x180 clip: scale 2/3 (to cover 120 rows), then 53 columns cropped
    from each side; the stored focal length is the true one (SfM-accurate) times 2/3."""
    import cv2

    from seeu_data.store.posed import PosedDataset
    from seeu_data.synthetic import load_ground_truth

    s = PosedDataset(global_run / "posed" / "walk").load_scene("walk_c0")
    assert (s.width == 160).all() and (s.height == 120).all() and s.meta["resized"]["to_hw"] == [120, 160]
    img = cv2.imdecode(np.frombuffer(s.images[0], np.uint8), cv2.IMREAD_COLOR)
    assert img.shape == (120, 160, 3)
    gt = load_ground_truth(global_run / "walk.mp4")
    fx_true = gt["intrinsics_norm"][0, 0] * W * (120 / H)
    assert s.intrinsics_norm[0, 0] * 160 == pytest.approx(fx_true, rel=0.02)  # SfM focal ~1%; unscaled: 50% off
    assert s.intrinsics_norm[0, 2] == pytest.approx(0.5, abs=0.01) and s.intrinsics_norm[0, 3] == pytest.approx(
        0.5, abs=0.01
    )
