"""Evaluation indices: the standard files read as they are, reproduced exactly by eval builds,
per-entry problem reports, the latentSplat format, and `seeu index` generation."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from pipelines.cli import main as cli_main
from seeu_data.build.eval_index import read_index
from seeu_data.build.triples import TripleShards
from seeu_data.store.posed import PosedDatasetWriter
from tests.helpers import make_posed_scene

ASSETS = Path(__file__).resolve().parent.parent / "seeu_data" / "assets"  # shipped, unchanged copies
SHARED = Path(__file__).resolve().parent.parent.parent / "shared" / "data"  # the peers' files, when beside us
RE10K = ASSETS / "evaluation_index_re10k.json"
DTU = ASSETS / "evaluation_index_dtu_nctx2.json"


@pytest.mark.skipif(not (SHARED / RE10K.name).exists(), reason="../shared/data not beside the checkout")
def test_shipped_indices_are_unchanged_copies():
    for name in (RE10K.name, DTU.name):
        assert (ASSETS / name).read_bytes() == (SHARED / name).read_bytes()


def _write_posed(root: Path, scenes: dict[str, int], size=(16, 16)) -> Path:
    with PosedDatasetWriter(root, params={}, provenance={}) as w:
        for i, (sid, n) in enumerate(scenes.items()):
            w.add(make_posed_scene(sid, n=n, height=size[0], width=size[1], seed=i))
    return root


def test_read_standard_re10k_index_as_is():
    idx = read_index(RE10K)
    assert idx.format == "pixelsplat"
    assert idx.num_keys == 7194 and idx.num_null == 720 and len(idx.entries) == 6474  # REFERENCE.md facts
    raw = json.loads(RE10K.read_text())
    non_null = [(k, v) for k, v in raw.items() if v is not None]
    for e, (k, v) in zip(idx.entries, non_null):
        assert (e.key, e.scene_id, list(e.context), list(e.target), e.k) == (k, k, v["context"], v["target"], 0)
    gaps = np.array([e.context[1] - e.context[0] for e in idx.entries])
    assert gaps.min() >= 45 and gaps.max() <= 136


def test_read_standard_dtu_index():
    idx = read_index(DTU)
    assert idx.format == "dtu" and len(idx.entries) == 64 and idx.num_null == 0
    scans = [1, 8, 21, 30, 31, 34, 38, 40, 41, 45, 55, 63, 82, 103, 110, 114]
    assert sorted({e.scene_id for e in idx.entries}, key=lambda s: int(s[4:])) == [f"scan{n}" for n in scans]
    assert all(e.context == (33, 31) for e in idx.entries)
    assert [e.target[0] for e in idx.entries if e.scene_id == "scan1"] == [32, 24, 23, 44]
    assert [e.k for e in idx.entries if e.scene_id == "scan8"] == [0, 1, 2, 3]


def test_eval_build_reproduces_re10k_index_exactly(tmp_path, capsys):
    raw = json.loads(RE10K.read_text())
    non_null = [k for k, v in raw.items() if v is not None]
    chosen = non_null[:5]
    short = non_null[5]  # present, but too few frames for its entry
    scenes = {k: max(raw[k]["context"] + raw[k]["target"]) + 1 for k in chosen}
    scenes[short] = max(raw[short]["context"]) - 1
    scenes["not_in_index"] = 30
    posed = _write_posed(tmp_path / "posed", scenes)
    out = tmp_path / "eval"
    assert cli_main(["build", str(posed), "--out", str(out), "--mode", "eval", "--index", str(RE10K)]) == 0
    printed = capsys.readouterr().out
    assert "6474 entries, 5 written, 6469 not written" in printed and "720 null skipped" in printed
    rows = TripleShards(out).rows()
    # exactly the index's entries: scene, contexts, targets, in file order
    assert [(r.scene_id, r.context, r.target) for r in rows] == [
        (k, raw[k]["context"], raw[k]["target"]) for k in chosen
    ]
    assert all(r.mode == "eval" and r.sample_id == f"{r.scene_id}/eval/0" for r in rows)
    for r in rows:
        lo, hi = min(r.context), max(r.context)
        assert r.gap == hi - lo and all(o == 0 for o in r.target_offset)
    rep = json.loads((out / "manifest.json").read_text())["report"]
    assert rep["index_null_skipped"] == 720 and rep["written"] == 5 and rep["not_written"] == 6469
    assert rep["problems_by_kind"] == {"scene not in the posed data": 6468, "frames out of range": 1}
    bad = [p for p in rep["problems"] if p["scene_id"] == short]
    assert len(bad) == 1 and "outside 0.." in bad[0]["problem"]


def test_eval_build_dtu_index(tmp_path):
    posed = _write_posed(tmp_path / "posed", {"scan1": 49, "scan8": 49})
    out = tmp_path / "dtu"
    assert cli_main(["build", str(posed), "--out", str(out), "--mode", "eval", "--index", str(DTU)]) == 0
    rows = TripleShards(out).rows()
    assert [(r.scene_id, r.context, r.target) for r in rows] == [
        (s, [33, 31], [t]) for s in ("scan1", "scan8") for t in (32, 24, 23, 44)
    ]
    assert [r.target_offset.tolist() for r in rows[:4]] == [[0], [-7], [-8], [11]]


def test_latentsplat_format_and_problems(tmp_path, capsys):
    index = {
        "a": [{"context": [2, 8], "target": [0, 1, 9]}, None, {"context": [3, 6], "target": [10, 11, 12]}],
        "b": [{"context": [1, 4], "target": [5, 6, 7]}],
        "c": None,
        "zz": [{"context": [0, 1], "target": [2]}],
    }
    path = tmp_path / "extra.json"
    path.write_text(json.dumps(index))
    idx = read_index(path)
    assert idx.format == "latentsplat" and idx.num_null == 2 and len(idx.entries) == 4
    assert [(e.scene_id, e.k) for e in idx.entries] == [("a", 0), ("a", 1), ("b", 0), ("zz", 0)]
    posed = _write_posed(tmp_path / "posed", {"a": 12, "b": 8})
    out = tmp_path / "ex"
    assert cli_main(["build", str(posed), "--out", str(out), "--mode", "eval", "--index", str(path)]) == 0
    printed = capsys.readouterr().out
    assert "not written: a: frame(s) [12] outside 0..11" in printed
    assert "not written: zz: scene not in the posed data" in printed
    rows = TripleShards(out).rows()
    assert [(r.sample_id, r.context, r.target) for r in rows] == [
        ("a/eval/0", [2, 8], [0, 1, 9]),
        ("b/eval/0", [1, 4], [5, 6, 7]),
    ]
    assert rows[0].target_offset.tolist() == [-2, -1, 1]


def test_bad_index_files(tmp_path, capsys):
    posed = _write_posed(tmp_path / "posed", {"a": 12})
    (tmp_path / "bad.json").write_text("{not json")
    assert (
        cli_main(
            ["build", str(posed), "--out", str(tmp_path / "o"), "--mode", "eval", "--index", str(tmp_path / "bad.json")]
        )
        == 2
    )
    assert "bad.json: evaluation index is not valid JSON" in capsys.readouterr().err
    (tmp_path / "none.json").write_text(json.dumps({"q": {"context": [0, 1], "target": [2]}}))
    assert (
        cli_main(
            [
                "build",
                str(posed),
                "--out",
                str(tmp_path / "o"),
                "--mode",
                "eval",
                "--index",
                str(tmp_path / "none.json"),
            ]
        )
        == 2
    )
    err = capsys.readouterr().err
    assert "none of the 1 index entries match" in err and "q: scene not in the posed data" in err
    assert not (tmp_path / "o" / "manifest.json").exists()
    (tmp_path / "shape.json").write_text(json.dumps({"a": {"context": [0, 1]}}))
    assert (
        cli_main(
            [
                "build",
                str(posed),
                "--out",
                str(tmp_path / "o"),
                "--mode",
                "eval",
                "--index",
                str(tmp_path / "shape.json"),
            ]
        )
        == 2
    )
    assert "entry 'a' is not" in capsys.readouterr().err


def test_seeu_index_generation_round_trip(tmp_path):
    posed = _write_posed(tmp_path / "posed", {"s0": 40, "s1": 60, "tiny": 5})
    idx_path = tmp_path / "own.json"
    args = ["index", str(posed), "--out", str(idx_path), "--gap-min", "10", "--gap-max", "20", "--seed", "3"]
    args += ["--pairs", "gap"]  # the frame-gap rule alone: a scene too short for it gets null
    assert cli_main(args) == 0
    first = idx_path.read_bytes()
    assert cli_main(args) == 0 and idx_path.read_bytes() == first  # seeded: identical
    doc = json.loads(first)
    assert doc["tiny"] is None and set(doc) == {"s0", "s1", "tiny"}
    for sid, n in (("s0", 40), ("s1", 60)):
        l, r = doc[sid]["context"]
        assert 10 <= r - l <= 20 and all(l <= t <= r for t in doc[sid]["target"]) and r < n
    # its own random stream: not the first training sample of a build with the same seed and options
    from seeu_data.build.sampling import SamplingConfig, sample_scene

    train = [
        sample_scene(SamplingConfig(gap_min=10, gap_max=20, samples_per_scene=1), n, sid, 3)[0]
        for sid, n in (("s0", 40), ("s1", 60))
    ]
    assert [(list(t.context), list(t.target)) for t in train] != [
        (doc[s]["context"], doc[s]["target"]) for s in ("s0", "s1")
    ]
    out = tmp_path / "ev"
    assert cli_main(["build", str(posed), "--out", str(out), "--mode", "eval", "--index", str(idx_path)]) == 0
    rows = TripleShards(out).rows()
    assert [(r.scene_id, r.context, r.target) for r in rows] == [
        (k, v["context"], v["target"]) for k, v in doc.items() if v
    ]


def test_seeu_index_latentsplat_extrap_by_overlap_bins(tmp_path):
    """--bins: entries spread over NoPoSplat's bins, each context pair's stored overlap inside its bin
    and recorded in the entry; extrapolation targets share at least the bin's floor with a context."""
    from seeu_data.overlap import BINS, context_overlap
    from seeu_data.store.posed import PosedDataset

    posed = _write_posed(tmp_path / "posed", {"s0": 60})
    idx_path = tmp_path / "extra.json"
    args = ["index", str(posed), "--out", str(idx_path), "--format", "latentsplat", "--mode", "extrap"]
    assert cli_main([*args, "--samples-per-scene", "6", "--bins", "small,medium,large"]) == 0
    entries = json.loads(idx_path.read_text())["s0"]
    m = PosedDataset(posed).overlap("s0").matrix()
    assert len(entries) == 6
    for k, e in enumerate(entries):
        lo, hi = BINS[("small", "medium", "large")[k % 3]]
        assert lo <= e["overlap"] <= hi and e["overlap"] == pytest.approx(context_overlap(m, e["context"]), abs=1e-4)
        a, b = e["context"]
        assert all(t not in (a, b) and max(m[t, a], m[t, b]) >= lo for t in e["target"])
    assert (
        read_index(idx_path).format == "latentsplat"
        and read_index(idx_path).entries[0].overlap == entries[0]["overlap"]
    )
    assert cli_main([*args, "--bins", "tiny"]) == 2


DEPTHSPLAT = Path(__file__).resolve().parent / "fixtures" / "depthsplat"  # copies of DepthSplat's assets/


def test_depthsplat_dl3dv_indices_read_and_built(tmp_path):
    raw = json.loads((DEPTHSPLAT / "dl3dv_start_0_distance_10_ctx_2v_tgt_4v.json").read_text())
    idx = read_index(DEPTHSPLAT / "dl3dv_start_0_distance_10_ctx_2v_tgt_4v.json")
    assert idx.format == "dl3dv" and idx.num_keys == 140 and len(idx.entries) == 140 and idx.num_null == 0
    for e, (k, v) in zip(idx.entries, raw.items()):
        assert (e.scene_id, list(e.context), list(e.target)) == (f"dl3dv_{k}", v["context"], v["target"])
    six = DEPTHSPLAT / "dl3dv_start_0_distance_50_ctx_6v_video_0_50.first3.json"
    raw6 = json.loads(six.read_text())
    posed = _write_posed(tmp_path / "posed", {f"dl3dv_{k}": 50 for k in raw6})
    out = tmp_path / "dl3dv"
    assert cli_main(["build", str(posed), "--out", str(out), "--mode", "eval", "--index", str(six)]) == 0
    got: dict[str, tuple[list[int], list[int]]] = {}
    for r in TripleShards(out).rows():
        ctx, tgt = got.setdefault(r.scene_id, (list(r.context), []))
        assert ctx == list(r.context)
        tgt.extend(r.target)
    assert got == {f"dl3dv_{k}": (v["context"], v["target"]) for k, v in raw6.items()}
