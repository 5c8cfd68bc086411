"""Fixtures shared by several test modules (helpers that are plain functions live in tests/helpers.py,
tests/loader_fixtures.py and tests/training_fixtures.py). Imports stay inside the fixtures, so that
collecting a test module loads only what it uses."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import settings

# The property tests draw the same examples on every run (a fresh `make test` passes or fails the same
# way); HYPOTHESIS_PROFILE=explore draws new ones each run, to look for failures.
settings.register_profile("repeatable", derandomize=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "repeatable"))


@pytest.fixture(scope="session")
def workspace(tmp_path_factory) -> dict[str, Path]:
    """Valid inputs of every kind, made once per session; tests damage copies, never these.

    posed: a posed-frames dataset (synthetic corridor, 12 frames at 32x32); triples: shards built
    from it (4 samples per scene, gap 3-5); transforms: its nerfstudio export's transforms.json;
    clip: a 6-frame 48x64 (HxW) synthetic video.
    """
    from pipelines.cli import main as cli_main
    from tests.training_fixtures import synthetic_posed, synthetic_triples

    root = tmp_path_factory.mktemp("workspace")
    triples = synthetic_triples(root, n_frames=12, hw=(32, 32), samples_per_scene=4, gap=(3, 5))
    posed = synthetic_posed(root, n_frames=12, hw=(32, 32))
    assert cli_main(["export", "nerfstudio", str(posed), "--out", str(root / "ns")]) == 0
    assert cli_main(["synth", "--out", str(root / "clip"), "--frames", "6", "--size", "48x64"]) == 0
    return {
        "posed": posed,
        "triples": triples,
        "transforms": next((root / "ns").rglob("transforms.json")),
        "clip": root / "clip" / "clip.mp4",
    }


@pytest.fixture
def no_heartbeat(monkeypatch) -> None:
    """No ingest heartbeat lines (stderr is not a terminal under pytest): they would break the
    one-line error checks. Use with `pytestmark = pytest.mark.usefixtures("no_heartbeat")`."""
    monkeypatch.setenv("SEEU_HEARTBEAT_S", "0")


@pytest.fixture
def fsyncs(monkeypatch):
    """Record os.fsync and os.replace calls in order (the real calls still run): ("fsync", path of
    the file descriptor) and ("replace", source path)."""
    import os

    calls = []
    real_fsync, real_replace = os.fsync, os.replace

    def fsync(fd):
        calls.append(("fsync", os.readlink(f"/proc/self/fd/{fd}") if os.path.exists("/proc/self/fd") else fd))
        return real_fsync(fd)

    def replace(src, dst):
        calls.append(("replace", str(src)))
        return real_replace(src, dst)

    monkeypatch.setattr(os, "fsync", fsync)
    monkeypatch.setattr(os, "replace", replace)
    return calls


@pytest.fixture(scope="session")
def overlap_scenes(tmp_path_factory) -> dict:
    """The view-overlap test scenes, exact cameras and tracks, 160x120 JPEGs (`tests/overlap_fixtures.py`): posed
    datasets `orbit` (24 views on a circle, in order), `shuffled` (the same photos shuffled and renamed:
    `shuffled_order[k]` is the orbit frame at position k) and `wide` (10 views scattered around the
    object, in no path order); `truth_orbit` / `truth_wide` their exact overlap matrices."""
    from tests.overlap_fixtures import make_overlap_scenes

    return make_overlap_scenes(tmp_path_factory.mktemp("overlap_scenes"))
