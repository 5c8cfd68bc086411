"""Scale conventions of ingested chunks (`seeu ingest --scale`): closed-form checks on a known SfM
model (cameras on a line, known point depths), the recorded meta, and the bad-input lines."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipelines.cli import main as cli_main
from seeu_data import cameras as cam
from seeu_data.errors import SeeUError
from seeu_data.ingest.chunks import ChunkConfig, plan_chunks
from seeu_data.ingest.scale import ScaleConfig

N = 12
DEPTHS = np.linspace(0.5, 6.5, 601)  # model units; p5 = 0.8, median = 3.5


def _model(tmp_path: Path) -> tuple[list[str], dict]:
    """Cameras 0.25 model units apart along +x, looking along +z (the first at x = 1)."""
    names = [f"{i:06d}.jpg" for i in range(N)]
    c2w = np.tile(np.eye(4), (N, 1, 1))
    c2w[:, 0, 3] = 1.0 + 0.25 * np.arange(N)
    np.save(tmp_path / "points_depth_0.npy", DEPTHS)
    w2c = cam.world_to_cam_from_cam_to_world(c2w)
    model = {
        "index": 0,
        "undistorted": False,
        "image_dir": str(tmp_path),
        "mean_reprojection_error": 0.3,
        "camera": {
            "model": "PINHOLE",
            "width": 64,
            "height": 36,
            "params": [50, 50, 32, 18],
            "fx": 50.0,
            "fy": 50.0,
            "cx": 32.0,
            "cy": 18.0,
        },
        "images": [{"name": n, "world_to_cam": w[:3].tolist()} for n, w in zip(names, w2c)],
    }
    return names, {"models": [model]}


def _chunk(tmp_path, scale: ScaleConfig, distance_names=None):
    names, res = _model(tmp_path)
    (c,), _ = plan_chunks("s", names, res, tmp_path, ChunkConfig(min_chunk_frames=5, scale=scale), distance_names)
    return c


def test_median_depth_scale(tmp_path):
    c = _chunk(tmp_path, ScaleConfig("median-depth"))
    assert c.meta["scale_convention"] == "median-depth" and c.meta["scale_factor"] == pytest.approx(1 / 3.5)
    assert c.cam_to_world[-1, 0, 3] == pytest.approx(0.25 * (N - 1) / 3.5)
    assert c.near == pytest.approx(0.4 * np.percentile(DEPTHS, 0.1) / 3.5)


def test_re10k_scale_puts_the_near_bound_at_the_peers_near(tmp_path):
    c = _chunk(tmp_path, ScaleConfig("re10k"))
    p01 = 0.5 + 0.001 * 6.0  # 0.1th percentile of a uniform grid on [0.5, 6.5]
    s = 1.0 / (0.4 * p01)
    assert c.meta["scale_factor"] == pytest.approx(s)
    assert (c.near, c.far) == (1.0, 100.0) and c.meta["scale_convention"] == "re10k"
    assert c.meta["points_nearer_than_near_pct"] == 0.0 and c.meta["points_farther_than_far_pct"] == 0.0
    assert c.meta["near_far_from_depths"][0] == pytest.approx(1.0)
    assert c.cam_to_world[-1, 0, 3] == pytest.approx(0.25 * (N - 1) * s)


def test_metric_scale_from_known_distance(tmp_path):
    # first-to-last camera: 2.75 model units = 5.5 m -> 2 m per unit
    c = _chunk(tmp_path, ScaleConfig("metric", known_distance=5.5))
    assert c.meta["scale_factor"] == pytest.approx(2.0) and c.cam_to_world[-1, 0, 3] == pytest.approx(5.5)
    assert c.near == pytest.approx(0.4 * np.percentile(DEPTHS, 0.1) * 2.0)
    # between two named frames: 3 and 7 are 1.0 unit apart = 0.8 m
    c = _chunk(tmp_path, ScaleConfig("metric", known_distance=0.8), ("000003.jpg", "000007.jpg"))
    assert c.cam_to_world[7, 0, 3] - c.cam_to_world[3, 0, 3] == pytest.approx(0.8)
    with pytest.raises(SeeUError, match="same place"):
        _chunk(tmp_path, ScaleConfig("metric", known_distance=1.0), ("000003.jpg", "000003.jpg"))


def test_scale_bad_input_is_one_line_before_any_work(tmp_path, capsys):
    video = tmp_path / "missing_is_fine.mp4"
    for extra, needle in (
        (["--scale", "metric"], "--known-distance"),
        (["--scale", "metric", "--known-distance", "-1"], "positive"),
        (["--known-distance", "3"], "only apply with --scale metric"),
    ):
        assert cli_main(["ingest", str(video), "--out", str(tmp_path / "o")] + extra) == 2
        err = capsys.readouterr().err.strip()
        assert needle in err and "\n" not in err, err


def test_each_rule_is_said_once_in_help_meta_and_docs(tmp_path, capsys, monkeypatch):
    """The rule of each convention (SCALE_RULES) is what `seeu ingest --help` says for --scale, what
    the chunk meta records and, word for word, what docs/ingest.md says."""
    from seeu_data.ingest.scale import SCALE_RULES, SCALES

    def words(text: str) -> str:
        return " ".join(text.split())

    monkeypatch.setenv("COLUMNS", "1000")  # argparse wraps the help at hyphens too
    with pytest.raises(SystemExit):
        cli_main(["ingest", "--help"])
    help_text = words(capsys.readouterr().out)
    docs = words((Path(__file__).resolve().parents[1] / "docs" / "ingest.md").read_text())
    assert set(SCALE_RULES) == set(SCALES)
    for name, rule in SCALE_RULES.items():
        assert f"{name}: {words(rule)}" in help_text, name
        assert f"- `{name}`{' (default)' if name == ScaleConfig().scale else ''}: {words(rule)}" in docs, name
    for name in ("re10k", "median-depth"):
        assert _chunk(tmp_path, ScaleConfig(name)).meta["scale_method"] == SCALE_RULES[name]
