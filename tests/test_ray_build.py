"""`seeu build --engine ray` on a local Ray instance gives shards byte-identical to the local engine."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from pipelines.cli import main as cli_main
from seeu_data.store.posed import PosedDatasetWriter
from tests.helpers import make_posed_scene

ray = pytest.importorskip("ray")


@pytest.fixture(scope="module")
def ray_local():
    ray.init(
        num_cpus=2,
        include_dashboard=False,
        logging_level="ERROR",
        log_to_driver=False,
        runtime_env={"env_vars": {"PYTHONPATH": str(Path(__file__).resolve().parent.parent)}},
    )
    yield
    ray.shutdown()


@pytest.fixture(scope="module")
def posed(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("rayposed") / "posed"
    with PosedDatasetWriter(root, params={}, provenance={}) as w:
        for i, n in enumerate((26, 33, 40, 8)):
            w.add(make_posed_scene(f"scene{i}", n=n, height=24, width=32, seed=i))
    return root


def _shards(out: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(out.glob("shard-*.arrow"))}


@pytest.mark.parametrize(
    "extra",
    [
        ["--mode", "extrap", "--extrap-frames", "9", "--interp-ratio", "0.3"],
        ["--mode", "interp", "--resize", "16x20", "-V", "3"],
    ],
)
def test_ray_engine_byte_identical_to_local(ray_local, posed, tmp_path, extra):
    common = [
        "build",
        str(posed),
        "--gap-min",
        "8",
        "--gap-max",
        "14",
        "--samples-per-scene",
        "4",
        "--shard-size",
        "30kB",
        "--seed",
        "5",
        "--pairs",
        "gap",  # the frame-gap protocol: the short scene is skipped (auto would pair its views by overlap)
        *extra,
    ]
    assert cli_main([*common, "--out", str(tmp_path / "local"), "--workers", "1"]) == 0
    assert cli_main([*common, "--out", str(tmp_path / "ray"), "--engine", "ray"]) == 0
    local, remote = _shards(tmp_path / "local"), _shards(tmp_path / "ray")
    assert len(local) > 2 and local == remote
    ml, mr = (json.loads((tmp_path / d / "manifest.json").read_text()) for d in ("local", "ray"))
    assert ml["files"] == mr["files"] and ml["params"] == mr["params"]
    assert mr["provenance"]["engine"] == "ray" and mr["report"]["scenes_skipped_too_short"] == 1
    # a re-run on Ray with nothing to do leaves the output as it is; with an input touched it plans
    # again and keeps every shard
    manifest = (tmp_path / "ray" / "manifest.json").read_bytes()
    assert cli_main([*common, "--out", str(tmp_path / "ray"), "--engine", "ray"]) == 0
    assert (tmp_path / "ray" / "manifest.json").read_bytes() == manifest
    os.utime(next(posed.glob("posed-*.arrow")))
    assert cli_main([*common, "--out", str(tmp_path / "ray"), "--engine", "ray"]) == 0
    assert json.loads((tmp_path / "ray" / "manifest.json").read_text())["report"]["shards_resumed"] == len(local)
    assert _shards(tmp_path / "ray") == local
