"""COLMAP models written by learned posers' own exporters import with `seeu import colmap` at 1e-6.

The fixtures were made by running the posers' writer code on synthetic arrays
(tests/fixtures/learned_posers/make_*_fixture.py, kept beside them, says how); `expected.json` holds
those arrays.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from pipelines.cli import main as cli_main
from seeu_data.store.posed import PosedDataset

FIXTURES = Path(__file__).resolve().parent / "fixtures" / "learned_posers"


def test_vggt_colmap_export_imports_at_float_precision(tmp_path):
    fx = FIXTURES / "vggt"
    exp = json.loads((fx / "expected.json").read_text())
    out = tmp_path / "out"
    argv = ["import", "colmap", str(fx / "sparse"), "--images", str(fx / "images"), "--out", str(out)]
    assert cli_main(argv + ["--scene-id", "vggt", "--near", "0.1", "--far", "100"]) == 0
    scene = PosedDataset(out).load_scene("vggt")
    ext, intr = np.asarray(exp["extrinsics"]), np.asarray(exp["intrinsics"])
    w2c = np.tile(np.eye(4), (len(ext), 1, 1))
    w2c[:, :3] = ext
    assert len(scene) == len(ext) and list(scene.source_name) == [f"image_{k + 1}" for k in range(len(ext))]
    np.testing.assert_allclose(scene.cam_to_world, np.linalg.inv(w2c), atol=1e-6)
    w, h = exp["width"], exp["height"]
    norm = np.stack([intr[:, 0, 0] / w, intr[:, 1, 1] / h, intr[:, 0, 2] / w, intr[:, 1, 2] / h], 1)
    np.testing.assert_allclose(scene.intrinsics_norm, norm, atol=1e-6)
    assert (scene.width == w).all() and (scene.height == h).all()


@pytest.mark.parametrize(
    "model,prefix",
    [("sparse", ""), ("mapper/0", "mapper_")],
    ids=["posed-triangulator", "unposed-mapper"],
)
def test_mast3r_colmap_model_imports_at_float_precision(tmp_path, model, prefix):
    """kapture_mast3r_mapping.py: kapture -> database, MASt3R's matches, pycolmap's triangulator (posed
    input: the synthetic arrays) or incremental mapper (unposed: its own gauge, refined focals)."""
    fx = FIXTURES / "mast3r"
    exp = json.loads((fx / "expected.json").read_text())
    out = tmp_path / "out"
    argv = ["import", "colmap", str(fx / model), "--images", str(fx / "images"), "--out", str(out)]
    assert cli_main(argv + ["--scene-id", "mast3r", "--near", "0.1", "--far", "100"]) == 0
    scene = PosedDataset(out).load_scene("mast3r")
    ext, intr = np.asarray(exp[prefix + "extrinsics"]), np.asarray(exp[prefix + "intrinsics"])
    w2c = np.tile(np.eye(4), (len(ext), 1, 1))
    w2c[:, :3] = ext
    assert list(scene.source_name) == exp["names"]
    np.testing.assert_allclose(scene.cam_to_world, np.linalg.inv(w2c), atol=1e-6)
    w, h = exp["width"], exp["height"]
    norm = np.stack([intr[:, 0, 0] / w, intr[:, 1, 1] / h, intr[:, 0, 2] / w, intr[:, 1, 2] / h], 1)
    np.testing.assert_allclose(scene.intrinsics_norm, norm, atol=1e-6)
    assert (scene.width == w).all() and (scene.height == h).all()
