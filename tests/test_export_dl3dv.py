"""`seeu export pixelsplat` of DL3DV scenes (from `seeu import dl3dv`) as DepthSplat's DL3DV loader reads
them: keyed by the bare scene hash (its evaluation indices' keys), frames 270x480 by default (its
`ori_image_shape`), no warning for a size it accepts, cameras unchanged; `seeu import pixelsplat` gives the
scenes back under their `dl3dv_<hash>` ids. (DepthSplat's own loader on such an export:
benchmarks/peer_loaders.py.)"""

from __future__ import annotations

import json

import cv2
import numpy as np
import torch

from pipelines.cli import main as cli_main
from seeu_data.build.eval_index import detect_format
from seeu_data.exporters.pixelsplat import peer_skip_reason
from seeu_data.store.posed import PosedDataset
from tests.dl3dv_fixtures import HASHES, make_release

IMPORTED = [HASHES[0], HASHES[2]]  # make_release's scenes that import (HASHES[1] is a wrong-size one)


def _export(tmp_path, posed, name, *extra):
    return cli_main(["export", "pixelsplat", str(posed), "--out", str(tmp_path / name), *extra])


def test_dl3dv_export_keys_sizes_cameras_and_round_trip(tmp_path, capsys):
    make_release(tmp_path / "dl3dv")
    posed = tmp_path / "posed"
    assert cli_main(["import", "dl3dv", str(tmp_path / "dl3dv"), "--out", str(posed)]) == 0
    capsys.readouterr()
    assert _export(tmp_path, posed, "ps", "--size-check", "refuse") == 0
    assert "warning" not in capsys.readouterr().err
    stage = tmp_path / "ps" / "test"
    index = json.loads((stage / "index.json").read_text())
    assert sorted(index) == IMPORTED  # bare hashes, as DepthSplat's converter and assets/dl3dv_*.json key them
    doc = {h: {"context": [0, 1], "target": [2]} for h in IMPORTED}  # an index in its layout names our keys
    assert detect_format(doc) == "dl3dv"
    examples = {ex["key"]: ex for ex in torch.load(stage / "000000.torch", weights_only=True)}
    ds = PosedDataset(posed)
    for h in IMPORTED:
        scene, ex = ds.load_scene(f"dl3dv_{h}"), examples[h]
        assert {cv2.imdecode(d.numpy(), cv2.IMREAD_COLOR).shape for d in ex["images"]} == {(270, 480, 3)}
        # 48x27 -> 480x270 (same aspect): normalised intrinsics unchanged, poses as imported
        np.testing.assert_allclose(ex["cameras"][:, :4].double().numpy(), scene.intrinsics_norm, atol=1e-6)
        w2c = torch.eye(4, dtype=torch.float64).repeat(len(scene), 1, 1)
        w2c[:, :3] = ex["cameras"][:, 6:].double().view(-1, 3, 4)
        np.testing.assert_allclose(w2c.inverse().numpy(), scene.cam_to_world, atol=1e-5)
    sidecar = json.loads((stage / "seeu_posed.json").read_text())
    assert {k: v["scene_id"] for k, v in sidecar.items()} == {h: f"dl3dv_{h}" for h in IMPORTED}
    # back through `seeu import pixelsplat`: the scene ids and the DL3DV meta
    assert cli_main(["import", "pixelsplat", str(stage), "--stage", "test", "--out", str(tmp_path / "back")]) == 0
    back = PosedDataset(tmp_path / "back")
    assert sorted(back.scene_ids) == [f"dl3dv_{h}" for h in IMPORTED]
    scene = back.load_scene(f"dl3dv_{IMPORTED[0]}")
    assert scene.meta["dl3dv_hash"] == IMPORTED[0] and (scene.width == 480).all() and (scene.height == 270).all()
    # DepthSplat's 960p size: accepted, no warning; the RE10K size is not its loader's: one warning line
    assert _export(tmp_path, posed, "ps960", "--resize", "540x960", "--size-check", "refuse") == 0
    assert "warning" not in capsys.readouterr().err
    assert _export(tmp_path, posed, "ps360", "--resize", "360x640") == 0
    err = capsys.readouterr().err.strip()
    assert "would skip 2 of 2 scenes" in err and "DepthSplat's DL3DV loader needs 480x270 or 960x540" in err


def test_peer_size_rule_per_dataset():
    intr = np.array([[0.6, 1.0, 0.5, 0.5]])  # 480x270 at a ~80 deg horizontal field of view
    for peer, accepted, refused in (
        ("dl3dv", [(480, 270), (960, 540)], [(640, 360), (48, 27)]),
        ("re10k", [(640, 360)], [(480, 270), (960, 540)]),
    ):
        for w, h in accepted:
            assert peer_skip_reason(np.array([w]), np.array([h]), intr, peer) is None, (peer, w, h)
        for w, h in refused:
            assert f"frames are {w}x{h}" in peer_skip_reason(np.array([w]), np.array([h]), intr, peer), (peer, w, h)
