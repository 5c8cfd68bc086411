"""benchmarks/scale.py: its inputs are what the importers read, and its arithmetic (no timed runs)."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

from benchmarks.scale import DL3DV_STEPS, STEPS, extrapolate_hours, report, write_dl3dv, write_pixelsplat
from seeu_data.importers.dl3dv import Dl3dvImportConfig, selected_scenes
from seeu_data.importers.dl3dv import iter_scene as dl3dv_scene
from seeu_data.importers.pixelsplat import PixelSplatImportConfig, iter_scenes
from seeu_data.store.posed import PosedScene


def test_generated_inputs_import_with_their_cameras_and_sizes(tmp_path):
    write_pixelsplat(tmp_path / "ps", 3, 5, 36, 64, per_chunk=2)
    scenes = list(iter_scenes(PixelSplatImportConfig(root=tmp_path / "ps")))
    assert len(scenes) == 3 and all(isinstance(s, PosedScene) for s in scenes)
    assert all(s.width[0] == 64 and s.height[0] == 36 and len(s) == 5 for s in scenes)
    assert np.allclose(scenes[0].cam_to_world[:, 0, 3], 0.02 * np.arange(5))  # moving along +x
    write_dl3dv(tmp_path / "dl", 1, 4, "480p")
    cfg = Dl3dvImportConfig(root=tmp_path / "dl")
    (found,) = list(dl3dv_scene(cfg, selected_scenes(cfg)[0]))
    assert isinstance(found, PosedScene) and (found.width[0], found.height[0], len(found)) == (480, 270, 4)
    assert np.allclose(found.intrinsics_norm[0], [3000 / 3840, 3000 / 2160, 0.5, 0.5])
    assert np.allclose(found.cam_to_world[:, :3, :3], np.eye(3)) and np.allclose(found.cam_to_world[3, 0, 3], 0.06)


def test_extrapolation_and_the_report():
    assert extrapolate_hours(36.0, 10, 1000, 1.0) == pytest.approx(1.0)
    assert extrapolate_hours(36.0, 10, 1000, 2.0) == pytest.approx(100.0)  # quadratic: 100x more per scene
    assert extrapolate_hours(36.0, 10, 1000, 0.5) == pytest.approx(1.0)  # never below linear
    ns = [100, 1000]
    run = lambda scale, n: {"cpu_s": scale * n, "wall_s": scale * n, "peak_rss": 2**30, "peak_anon": 2**29}  # noqa: E731
    tiny = {str(n): {s: run(0.01 if s not in ("import_again", "build_again") else 1e-4, n) for s in STEPS} for n in ns}
    tiny["1000"]["index"]["cpu_s"] = 10 * tiny["100"]["index"]["cpu_s"] * 10  # quadratic
    results = {
        "tiny": tiny,
        "re10k": {s: run(0.5, 2) for s in STEPS},
        "re10k_scenes": 2,
        "dl3dv": {s: run(1.0, 3) for s in DL3DV_STEPS},
        "dl3dv_scenes": 3,
    }
    results["re10k"]["import"]["cpu_self_s"] = 0.25 * results["re10k"]["import"]["cpu_s"]  # the writer's share
    text = report(results, argparse.Namespace(dl3dv_resolution="480p"))
    tiny_table = text.split("\n\n")[1]  # the growth table comes first
    rows = {line.split(" | ")[0].strip("| "): line for line in tiny_table.splitlines()}
    assert "| 2.000 |" in rows["index"] and "| 1.000 |" in rows["import"] and "1.0 %" in rows["import_again"]
    # RE10K: 0.5 CPU s a scene of a linear step over 67,477 scenes, 9.37 h; the quadratic index grows further
    # import: the writer's quarter in one process (2.34 h) outlasts the readers' 7.03 h over 8 processes
    assert "| import | 0.500 | 0.500 | 1024 / 512 | 9.37 | 2.34 |" in text
    assert "| build_interp | 0.500 | 0.500 | 1024 / 512 | 9.37 | 1.17 |" in text  # 8 build processes
    assert "DL3DV import + build interp + build extrap: 3.00 core-s a scene" in text
