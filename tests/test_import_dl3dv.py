"""`seeu import dl3dv`: both DL3DV layouts, the resolution folders, the size check, --exclude, resume."""

from __future__ import annotations

import json
import re

import numpy as np

from pipelines.cli import main as cli_main
from seeu_data import cameras as cam
from seeu_data.store.posed import PosedDataset
from tests.dl3dv_fixtures import FL, HASHES, H, W, make_benchmark, make_release


def _report(out) -> dict:
    return json.loads((out / "manifest.json").read_text())["report"]


def test_release_layout_480p_imports_checks_sizes_and_resumes(tmp_path, capsys):
    poses = make_release(tmp_path / "dl3dv")
    out = tmp_path / "out"
    argv = ["import", "dl3dv", str(tmp_path / "dl3dv"), "--out", str(out)]
    assert cli_main(argv) == 0
    report = _report(out)
    # the wrong-size scene is skipped, named, with its sizes
    assert report["imported_scenes"] == 2 and report["skipped_scenes"] == 1
    (skip,) = report["skipped"]
    assert skip["scene_id"] == f"dl3dv_{HASHES[1]}"
    assert "images_8/frame_00001.png is 48x36" in skip["reason"] and "384x216" in skip["reason"]
    assert f"dl3dv_{HASHES[1]}" in capsys.readouterr().out
    ds = PosedDataset(out)
    assert sorted(ds.scene_ids) == [f"dl3dv_{HASHES[0]}", f"dl3dv_{HASHES[2]}"]
    scene = ds.load_scene(f"dl3dv_{HASHES[0]}")
    assert (scene.width == W // 8).all() and (scene.height == H // 8).all()
    # normalised intrinsics: fl_x / w ... as DepthSplat's converter stores them
    np.testing.assert_allclose(scene.intrinsics_norm[0], [FL[0] / W, FL[1] / H, FL[2] / W, FL[3] / H], atol=1e-7)
    np.testing.assert_allclose(scene.cam_to_world, poses[HASHES[0]], atol=1e-6)
    assert scene.source_name[0] == "images_8/frame_00001.png"
    assert scene.meta["distortion_ignored"] == {"k1": 0.01, "k2": -0.002, "p1": 0.0, "p2": 0.0}
    assert (scene.near, scene.far) == (0.5, 200.0)
    # a re-run keeps every scene's file; --exclude drops a hash (a new run: other parameters)
    assert cli_main(argv) == 0
    assert _report(out)["resumed_files"] >= 1
    (tmp_path / "bench.txt").write_text(f"{HASHES[0]}\n")
    assert cli_main(argv + ["--exclude", f"@{tmp_path / 'bench.txt'}"]) == 0
    assert PosedDataset(out).scene_ids == [f"dl3dv_{HASHES[2]}"]


def test_benchmark_layout_960p(tmp_path):
    poses = make_benchmark(tmp_path / "bench")
    out = tmp_path / "out"
    assert cli_main(["import", "dl3dv", str(tmp_path / "bench"), "--resolution", "960p", "--out", str(out)]) == 0
    report = _report(out)
    assert report["imported_scenes"] == 1
    assert report["skipped"][0]["scene_id"] == f"dl3dv_{HASHES[3]}"
    assert "is 96x60" in report["skipped"][0]["reason"]
    scene = PosedDataset(out).load_scene(f"dl3dv_{HASHES[0]}")
    assert (scene.width == W // 4).all() and scene.meta["layout"] == "benchmark"
    K = cam.intrinsics_norm_matrix(scene.intrinsics_norm)
    np.testing.assert_allclose(K[:, 0, 0] * W, FL[0], rtol=1e-6)
    np.testing.assert_allclose(scene.cam_to_world, poses[HASHES[0]], atol=1e-6)


def test_progress_line_counts_scenes_with_an_eta_and_resumes_from_the_kept_ones(tmp_path, capsys):
    """`--progress`: the bar counts scenes of the whole release with elapsed<remaining time; a re-run
    starts it at the scenes already kept."""
    make_release(tmp_path / "dl3dv")
    argv = ["import", "dl3dv", str(tmp_path / "dl3dv"), "--out", str(tmp_path / "out"), "--progress"]
    assert cli_main(argv) == 0
    err = capsys.readouterr().err
    assert re.search(r"import dl3dv: +0%\|.*\| 0/3 \[00:00<\?", err) and re.search(r"3/3 \[\d\d:\d\d<00:00", err)
    assert cli_main(argv) == 0
    assert re.search(r"import dl3dv: +100%\|.*\| 3/3 \[", capsys.readouterr().err)
