"""`seeu build --pairs`: context pairs by view overlap on photo sets (the wide-baseline 10-view set,
the 24-view orbit in any order), targets defined by overlap, and the frame-gap protocol unchanged on
camera paths (the draws of the previous release, byte-identical shards with --pairs gap)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from pipelines.cli import main as cli_main
from seeu_data.build.sampling import SamplingConfig
from seeu_data.build.triples import TripleShards
from seeu_data.store.posed import PosedDataset, PosedDatasetWriter
from tests.helpers import make_posed_scene

FLOOR = SamplingConfig().min_overlap  # the stated floor of the default build
CEILING = SamplingConfig().max_overlap


def _build(posed: Path, out: Path, *extra: str) -> list:
    assert cli_main(["build", str(posed), "--out", str(out), "--no-progress", *extra]) == 0
    return TripleShards(out).rows()


def test_default_build_of_the_wide_set(overlap_scenes, tmp_path, capsys):
    """10 photos in no path order: the default build draws triples whose context pairs all overlap
    within [FLOOR, CEILING]; interpolation targets are seen by both contexts at least as well as the
    contexts see each other, extrapolation targets share at least FLOOR with a context."""
    root = overlap_scenes["wide"]
    m = PosedDataset(root).overlap("wide").matrix()
    for mode in ("interp", "extrap"):
        rows = _build(root, tmp_path / mode, "--mode", mode, "--samples-per-scene", "8")
        out = capsys.readouterr().out
        assert len(rows) == 8 and "0 scenes by frame gap, 1 by view overlap 0.3..0.8" in out, out
        for r in rows:
            a, b = (int(v) for v in r.frame_index[:2])
            score = min(m[a, b], m[b, a])
            assert FLOOR <= score <= CEILING
            for t in (int(v) for v in r.frame_index[2:]):
                assert t not in (a, b)
                inside = min(m[t, a], m[t, b]) >= score
                assert inside if mode == "interp" else (not inside and max(m[t, a], m[t, b]) >= FLOOR)
    manifest = json.loads((tmp_path / "extrap" / "manifest.json").read_text())
    assert manifest["report"]["pairs"]["overlap"] == 1 and manifest["params"]["sampling"]["pairs"] == "auto"


def test_shuffled_and_renamed_photos_give_the_same_triples(overlap_scenes, tmp_path):
    """The orbit in order, and shuffled and renamed: the same triples up to naming (every view the same
    photo and camera), by default and with --pairs overlap (an ordered 24-view orbit is a camera
    path, too short for the frame gaps: overlap pairs too)."""
    order = overlap_scenes["shuffled_order"]  # shuffled frame k is orbit frame order[k]
    for extra in ((), ("--pairs", "overlap", "--mode", "extrap")):
        a = _build(overlap_scenes["orbit"], tmp_path / "a", *extra)
        b = _build(overlap_scenes["shuffled"], tmp_path / "b", *extra)
        assert [r.sample_id for r in a] == [r.sample_id for r in b] and len(a) == 4
        for ra, rb in zip(a, b):
            v = ra.num_context
            mapped = order[rb.frame_index]
            assert sorted(mapped[:v]) == sorted(ra.frame_index[:v]) and sorted(mapped[v:]) == sorted(ra.frame_index[v:])
            assert sorted(map(bytes, ra.images)) == sorted(map(bytes, rb.images))
        for d in ("a", "b"):
            for p in (tmp_path / d).iterdir():
                p.unlink()


# Drawn by the previous release's sampler (before --pairs) for scene "syn0", seed 0, with these flags.
GAP_PROTOCOL = {
    "interp": (12, ["--gap-min", "3", "--gap-max", "5", "--samples-per-scene", "4"]),
    "extrap": (
        90,
        ["--mode", "extrap", "--gap-min", "25", "--gap-max", "45", "--extrap-frames", "45", "--samples-per-scene", "3"],
    ),
}
GAP_DRAWS = {
    "interp": [((3, 7), (4, 4, 5)), ((7, 11), (8, 11, 11)), ((0, 4), (2, 2, 3)), ((1, 6), (2, 5, 6))],
    "extrap": [((24, 59), (23, 62, 66)), ((48, 73), (20, 37, 85)), ((51, 80), (6, 18, 81))],
}


@pytest.mark.parametrize("mode", ["interp", "extrap"])
def test_camera_paths_keep_the_frame_gap_protocol(tmp_path, mode):
    """A video-like camera path (the peers' protocol: gaps 3-5, or 25-45 with 45-frame extrapolation):
    the default build draws exactly what the previous release drew, and its shards are byte-identical
    to --pairs gap."""
    n, flags = GAP_PROTOCOL[mode]
    posed = tmp_path / "posed"
    with PosedDatasetWriter(posed, {}, {}) as w:
        w.add(make_posed_scene("syn0", n=n, height=16, width=16))
    rows = _build(posed, tmp_path / "auto", *flags)
    assert [(tuple(r.frame_index[:2]), tuple(r.frame_index[2:])) for r in rows] == GAP_DRAWS[mode]
    _build(posed, tmp_path / "gap", *flags, "--pairs", "gap")
    shards = sorted((tmp_path / "auto").glob("shard-*.arrow"))
    assert shards and all(p.read_bytes() == (tmp_path / "gap" / p.name).read_bytes() for p in shards)


def test_no_usable_pair_is_one_line(overlap_scenes, tmp_path, capsys):
    args = [
        "build",
        str(overlap_scenes["wide"]),
        "--out",
        str(tmp_path / "o"),
        "--min-overlap",
        "0.9",
        "--max-overlap",
        "1",
    ]
    assert cli_main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "without a context pair of overlap 0.9..1" in err and "'wide'" in err
    assert cli_main([*args[:4], "--min-overlap", "0.6", "--max-overlap", "0.5"]) == 2
    assert "min_overlap <= max_overlap" in capsys.readouterr().err
