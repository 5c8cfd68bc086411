"""The stages that pick views by overlap, on the exact-camera test scenes in every frame order:
check-cameras (pairs by overlap, filtered matches, the same verdict and pairs whatever the order,
every broken-camera variant still named), predict --auto-context, and seeu view's overlap graph."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from pipelines.cli import main as cli_main
from pipelines.predict import auto_context_pair, extrapolation_limit
from pipelines.view import best_partners
from seeu_data.build.sampling import SamplingConfig
from seeu_data.cameras import intrinsics_norm_matrix
from seeu_data.store.posed import PosedDataset
from tests.test_check_cameras import BROKEN, broken_copy
from tests.test_view import read_viser_file

FLOOR = SamplingConfig().min_overlap


def _check(root: Path, out: Path, capsys) -> tuple[int, dict, str]:
    rc = cli_main(["check-cameras", str(root), "--out", str(out)])
    text = capsys.readouterr().out
    return rc, json.loads((out / "check.json").read_text()), text


def _photos(scene_dir: Path, sid: str, frames) -> list[bytes]:
    scene = PosedDataset(scene_dir).load_scene(sid)
    return [bytes(scene.images[k]) for k in frames]


def test_check_cameras_passes_in_every_frame_order(overlap_scenes, tmp_path, capsys):
    """Exit 0 on the orbit, its shuffled and renamed copy and the wide set; check.json lists the pairs
    used (by overlap, with inlier counts) and they are the same photos in both orders."""
    reports = {}
    for name in ("orbit", "shuffled", "wide"):
        rc, rep, text = _check(overlap_scenes[name], tmp_path / name, capsys)
        scene = rep["scenes"][0]
        assert rc == 0 and rep["verdict"] == "consistent", text
        assert scene["median_error_px"] < 0.5 and scene["overlap_method"] == "tracks"
        used = [d for d in scene["pair_details"] if d["used"]]
        assert len(used) == len(scene["pairs"]) >= 2 and all(d["overlap"] >= FLOOR for d in used)
        assert all(d["inliers"] <= d["matches"] for d in scene["pair_details"]) and "inlier matches" in text
        reports[name] = scene
    a, b = reports["orbit"], reports["shuffled"]
    sid = "orbit"
    assert [_photos(overlap_scenes["orbit"], sid, d["frames"]) for d in a["pair_details"]] == [
        _photos(overlap_scenes["shuffled"], sid, d["frames"]) for d in b["pair_details"]
    ]
    assert a["median_error_px"] == b["median_error_px"] and a["matches"] == b["matches"]


@pytest.mark.parametrize("variant", sorted(BROKEN))
def test_broken_cameras_named_on_the_shuffled_orbit(overlap_scenes, tmp_path, capsys, variant):
    change, words = BROKEN[variant]
    rc = cli_main(
        ["check-cameras", str(broken_copy(overlap_scenes["shuffled"], tmp_path, change)), "--out", str(tmp_path / "o")]
    )
    out = capsys.readouterr().out
    scene = json.loads((tmp_path / "o" / "check.json").read_text())["scenes"][0]
    assert rc == 1 and words in out and scene["cause"] == variant, out


def test_auto_context_pair_overlaps_above_the_floor_in_every_order(overlap_scenes):
    """predict --auto-context's pair: at least the floor, the best coverage among such pairs, and the
    same photos whatever the order; the extrapolated path stops where the contexts still see it."""
    picked = {}
    for name, sid in (("orbit", "orbit"), ("shuffled", "orbit"), ("wide", "wide")):
        ds = PosedDataset(overlap_scenes[name])
        scene, table = ds.load_scene(sid), ds.overlap(sid)
        (i, j), overlap, cover = auto_context_pair(table, scene.cam_to_world, scene.intrinsics_norm)
        m = table.matrix()
        assert overlap == pytest.approx(min(m[i, j], m[j, i])) and overlap >= FLOOR
        s = np.minimum(m, m.T)
        covers = [
            np.maximum(m[:, a], m[:, b]).mean() for a in range(len(m)) for b in range(a + 1, len(m)) if s[a, b] >= FLOOR
        ]
        assert cover == pytest.approx(max(covers))
        picked[name] = sorted(_photos(overlap_scenes[name], sid, (i, j)))
        if name == "wide":
            k = np.stack([intrinsics_norm_matrix(scene.intrinsics_norm[x]) for x in (i, j)])
            e = extrapolation_limit(scene.cam_to_world[[i, j]], k, scene.near, scene.far, 4.0)
            assert 0.0 <= e < 4.0  # four baselines out, the path leaves what the contexts see
            assert extrapolation_limit(scene.cam_to_world[[i, j]], k, scene.near, scene.far, 0.1) == pytest.approx(0.1)
    assert picked["orbit"] == picked["shuffled"]


def test_view_draws_the_overlap_graph_and_best_partners(overlap_scenes, tmp_path, capsys):
    out = tmp_path / "wide.viser"
    assert cli_main(["view", str(overlap_scenes["wide"]), "--save", str(out)]) == 0
    names = {m[1].get("name") for m in read_viser_file(out)["messages"]}
    assert {"/scene/overlap", "/scene/frame_partners"} <= names and "/scene/trajectory" not in names  # no path order
    scores = PosedDataset(overlap_scenes["wide"]).overlap("wide").pair_scores()
    best = best_partners(scores, 0)
    assert [v for _, v in best] == sorted((v for _, v in best), reverse=True) and best[0][1] == scores[0, 1:].max()
