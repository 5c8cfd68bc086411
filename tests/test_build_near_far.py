"""`seeu build` takes near/far from the posed data unless `--near/--far` override them (e.g. the peers'
RealEstate10K 1 / 100); the override is recorded and is part of the shard plan."""

from __future__ import annotations

import json

import numpy as np
import pyarrow as pa

from pipelines.cli import main as cli_main
from seeu_data.store.posed import PosedDatasetWriter
from tests.helpers import make_posed_scene


def _near_far(out) -> tuple[np.ndarray, np.ndarray]:
    near, far = [], []
    for shard in sorted(out.glob("shard-*.arrow")):
        t = pa.ipc.open_file(pa.memory_map(str(shard))).read_all()
        near.append(t.column("near").combine_chunks().flatten().to_numpy())
        far.append(t.column("far").combine_chunks().flatten().to_numpy())
    return np.concatenate(near), np.concatenate(far)


def test_build_near_far_from_data_or_override(tmp_path, capsys):
    scene = make_posed_scene("s", n=12)
    scene.near, scene.far = 0.25, 7.5
    with PosedDatasetWriter(tmp_path / "posed", params={}, provenance={}) as w:
        w.add(scene)
    base = [
        "build",
        str(tmp_path / "posed"),
        "--gap-min",
        "4",
        "--gap-max",
        "6",
        "--samples-per-scene",
        "3",
        "--workers",
        "1",
    ]
    assert cli_main(base + ["--out", str(tmp_path / "data")]) == 0
    near, far = _near_far(tmp_path / "data")
    assert len(near) == 3 * 5 and (near == 0.25).all() and (far == 7.5).all()
    assert cli_main(base + ["--out", str(tmp_path / "re10k"), "--near", "1", "--far", "100"]) == 0
    near, far = _near_far(tmp_path / "re10k")
    assert (near == 1.0).all() and (far == 100.0).all()
    params = json.loads((tmp_path / "re10k" / "manifest.json").read_text())["params"]
    assert params["near_far"] == [1.0, 100.0]
    # a re-run with other bounds into the same place rebuilds instead of keeping the old shards
    assert cli_main(base + ["--out", str(tmp_path / "re10k"), "--near", "0.5", "--far", "100"]) == 0
    assert (_near_far(tmp_path / "re10k")[0] == 0.5).all()
    capsys.readouterr()
    for extra in (["--near", "1"], ["--near", "5", "--far", "2"]):
        assert cli_main(base + ["--out", str(tmp_path / "bad")] + extra) == 2
        err = capsys.readouterr().err.strip()
        assert "--near" in err and "\n" not in err
