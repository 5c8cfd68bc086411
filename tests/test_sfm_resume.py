"""SfM resumes inside its stage, after real interruptions (SIGINT to `seeu ingest` while it extracts,
matches, or maps): the re-run keeps the features, verified pairs and finished mapping runs the
interrupted one committed, and ends with the same poses as a run never interrupted. The heartbeat
names each SfM step with its own unit and never counts past its total."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from seeu_data.store.posed import PosedDataset
from seeu_data.synthetic import write_clip

ROOT = Path(__file__).resolve().parents[1]
# "seeu ingest: walk: sfm match 12/49 pairs, 3 s, ETA 9 s"
HEARTBEAT = re.compile(r"^seeu ingest: walk: (sfm [\w-]+) (\d+)/(\d+) (\w+), \d+ s(, ETA .+)?$")


@pytest.fixture(scope="module")
def clip(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("resume")
    write_clip(root / "walk.mp4", n_frames=20, size=(136, 240), seed=0)
    return root / "walk.mp4"


def _ingest(clip: Path, out: Path, stop_at=None) -> tuple[int, list[str]]:
    """`seeu ingest` on one thread (so the solution check's two mapping runs go one after the other), a
    heartbeat every 0.05 s; with `stop_at(step, done, total)`, SIGINT once a heartbeat line satisfies it.
    Returns (exit status, the heartbeat lines)."""
    argv = [sys.executable, "-m", "pipelines.cli", "ingest", str(clip), "--out", str(out), "--threads", "1"]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen(
        [*argv, "--no-progress", "--heartbeat", "0.05"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        cwd=ROOT,
    )
    lines = []
    try:
        assert proc.stderr is not None
        for line in proc.stderr:
            lines.append(line.rstrip("\n"))
            m = HEARTBEAT.match(lines[-1])
            if stop_at is not None and m and stop_at(m.group(1), int(m.group(2)), int(m.group(3))):
                proc.send_signal(signal.SIGINT)
                stop_at = None
        rc = proc.wait(timeout=600)
    finally:
        proc.kill()
    return rc, lines


def _poses(out: Path) -> np.ndarray:
    ds = PosedDataset(out / "walk")
    return np.concatenate([ds.load_scene(s).cam_to_world for s in ds.scene_ids])


@pytest.fixture(scope="module")
def uninterrupted(clip, tmp_path_factory) -> tuple[Path, list[str]]:
    out = tmp_path_factory.mktemp("resume") / "posed"
    rc, lines = _ingest(clip, out)
    assert rc == 0, lines[-5:]
    return out, lines


def test_heartbeat_names_each_sfm_step_in_its_unit_within_its_total(uninterrupted):
    _, lines = uninterrupted
    counts = [HEARTBEAT.match(line) for line in lines]
    seen = {m.group(1): m.group(4) for m in counts if m}
    assert seen.get("sfm extract") == "images" and seen.get("sfm match") == "pairs", seen
    assert seen.get("sfm map") == "registered", seen
    for m in filter(None, counts):
        assert int(m.group(2)) <= int(m.group(3)), m.group(0)
    assert any(m.group(5) for m in counts if m), "no ETA shown"


@pytest.mark.parametrize(
    ("step", "stop_at", "kept"),
    [
        ("extract", lambda s, k, n: s == "sfm extract" and 0 < k <= n // 2, "images"),
        ("match", lambda s, k, n: s == "sfm match" and 8 <= k <= n // 2, "pairs"),
        ("map", lambda s, k, n: s == "sfm map-check", "map_runs"),
    ],
)
def test_interrupted_sfm_resumes_from_its_last_finished_step_with_identical_poses(
    step, stop_at, kept, clip, uninterrupted, tmp_path
):
    out = tmp_path / "posed"
    rc, lines = _ingest(clip, out, stop_at)
    assert rc == 130, lines[-5:]
    assert not (out / "walk" / "manifest.json").exists()
    rc, lines = _ingest(clip, out)
    assert rc == 0, lines[-5:]
    report = json.loads((out / "walk" / "report.json").read_text())
    resumed = report["sfm"]["resumed"]
    done = json.loads((uninterrupted[0] / "walk" / "report.json").read_text())["sfm"]
    total = {"images": report["frames_selected"], "pairs": done["matcher"]["pairs_matched"], "map_runs": 2}[kept]
    assert 0 < resumed[kept] < total, resumed  # kept part of the step, not all of it, and continued
    assert np.array_equal(_poses(out), _poses(uninterrupted[0]))
