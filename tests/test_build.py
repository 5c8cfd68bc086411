"""`seeu build` (local engine) and `seeu inspect`: row contents against the posed data, byte-identical
re-builds, resume, resize + crop geometry, skipped scenes, bad input, validate, statistics, sheet."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from pipelines.cli import main as cli_main
from pipelines.inspect_triples import triple_statistics
from pipelines.validate import validate_dataset
from seeu_data.build.sampling import SamplingConfig, sample_scene
from seeu_data.build.triples import TripleShards
from seeu_data.cameras import project_points
from seeu_data.errors import SeeUError
from seeu_data.store.posed import PosedDataset, PosedDatasetWriter, PosedScene
from tests.helpers import look_at_cam_to_world, make_posed_scene

SCENES = {"alpha": 30, "beta": 44, "gamma": 9, "delta": 37}  # gamma too short for gap_min 10


@pytest.fixture(scope="module")
def posed(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("posed") / "posed"
    with PosedDatasetWriter(root, params={}, provenance={}, target_file_bytes=60_000) as w:
        for i, (sid, n) in enumerate(SCENES.items()):
            w.add(make_posed_scene(sid, n=n, height=24, width=32, seed=i))
    return root


def _build(posed: Path, out: Path, *extra: str) -> int:
    return cli_main(
        [
            "build",
            str(posed),
            "--out",
            str(out),
            "--gap-min",
            "10",
            "--gap-max",
            "20",
            "--samples-per-scene",
            "3",
            "--shard-size",
            "20kB",
            "--pairs",
            "gap",  # the frame-gap protocol alone (by default gamma, too short for it, gets overlap pairs)
            *extra,
        ]
    )


def _shard_bytes(out: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(out.glob("shard-*.arrow"))}


def test_interp_rows_match_posed_data_and_plan(posed, tmp_path, capsys):
    out = tmp_path / "interp"
    assert _build(posed, out, "--workers", "1") == 0
    assert "skipped 1 of 4 scenes with fewer than 11 frames (e.g. gamma)" in capsys.readouterr().out
    shards = TripleShards(out, verify=True)
    rows = shards.rows()
    cfg = SamplingConfig(mode="interp", gap_min=10, gap_max=20, samples_per_scene=3)
    expected = [s for sid in sorted(SCENES) for s in sample_scene(cfg, SCENES[sid], sid, 0)]
    assert [(r.sample_id, r.context, r.target) for r in rows] == [
        (s.sample_id, list(s.context), list(s.target)) for s in expected
    ]
    assert len(shards.files) > 1  # cut by the target size
    ds = PosedDataset(posed)
    scenes = {sid: ds.load_scene(sid) for sid in ds.scene_ids}
    for r in rows:
        sc = scenes[r.scene_id]
        fi = r.frame_index
        assert r.images == [sc.images[i] for i in fi]  # encoded bytes copied as they are
        assert np.array_equal(r.cam_to_world, sc.cam_to_world[fi])
        assert np.array_equal(r.intrinsics_norm, sc.intrinsics_norm[fi])
        assert np.array_equal(r.source_frame, sc.source_frame[fi])
        assert (r.width == 32).all() and (r.height == 24).all()
        assert np.allclose(r.near, sc.near) and np.allclose(r.far, sc.far)
        assert r.mode == "interp" and r.image_format == "jpeg" and r.num_context == 2
        assert 10 <= r.gap <= 20 and (r.target_offset == 0).all()
        assert cv2.imdecode(np.frombuffer(r.images[0], np.uint8), cv2.IMREAD_COLOR).shape == (24, 32, 3)
    doc = json.loads((out / "manifest.json").read_text())
    assert doc["schema"] == "seeu.triples" and doc["total_rows"] == 9
    assert doc["params"]["sampling"]["gap_min"] == 10 and doc["params"]["seed"] == 0
    assert doc["report"]["scenes_skipped_too_short"] == 1 and doc["report"]["skipped_scene_examples"] == ["gamma"]
    assert validate_dataset(out)["rows"] == 9  # seeu validate accepts the shards


def test_byte_identical_across_workers_and_runs(posed, tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    assert _build(posed, a, "--mode", "extrap", "--extrap-frames", "7", "--workers", "1") == 0
    assert _build(posed, b, "--mode", "extrap", "--extrap-frames", "7", "--workers", "2") == 0
    sa, sb = _shard_bytes(a), _shard_bytes(b)
    assert sa == sb and len(sa) > 1
    ma, mb = (json.loads((d / "manifest.json").read_text()) for d in (a, b))
    assert ma["files"] == mb["files"] and ma["params"]["inputs"] == mb["params"]["inputs"]
    c = tmp_path / "c"
    assert _build(posed, c, "--mode", "extrap", "--extrap-frames", "7", "--workers", "1", "--seed", "1") == 0
    assert _shard_bytes(c) != sa  # the seed matters


def test_extrap_rows(posed, tmp_path):
    out = tmp_path / "extrap"
    assert _build(posed, out, "--mode", "extrap", "--extrap-frames", "6", "-V", "3", "-T", "4") == 0
    rows = TripleShards(out).rows()
    assert rows and all(r.mode == "extrap" and r.num_context == 3 and len(r.target) == 4 for r in rows)
    for r in rows:
        lo, hi = min(r.context), max(r.context)
        for t, off in zip(r.target, r.target_offset):
            assert (t < lo and off == t - lo >= -6) or (t > hi and 0 < off == t - hi <= 6)


def test_resume_keeps_good_shards_and_rebuilds_damaged(posed, tmp_path, capsys):
    out = tmp_path / "res"
    assert _build(posed, out) == 0
    before = _shard_bytes(out)
    manifest = (out / "manifest.json").read_bytes()
    mtimes = {p.name: p.stat().st_mtime_ns for p in out.glob("shard-*.arrow")}
    capsys.readouterr()
    # nothing to do: the output is left as it is (the manifest too)
    assert _build(posed, out) == 0
    assert f"; {len(before)} kept from a previous run" in capsys.readouterr().out
    assert (out / "manifest.json").read_bytes() == manifest
    assert {p.name: p.stat().st_mtime_ns for p in out.glob("shard-*.arrow")} == mtimes
    # an input touched (same content): planned again, every shard kept by its recorded size and mtime
    os.utime(next(posed.glob("posed-*.arrow")))
    assert _build(posed, out) == 0
    doc = json.loads((out / "manifest.json").read_text())
    assert doc["report"]["shards_resumed"] == len(before)
    assert {p.name: p.stat().st_mtime_ns for p in out.glob("shard-*.arrow")} == mtimes
    # --force: every shard written anew (new files, the same bytes)
    assert _build(posed, out, "--force") == 0
    assert json.loads((out / "manifest.json").read_text())["report"]["shards_resumed"] == 0
    assert (
        all(p.stat().st_mtime_ns != mtimes[p.name] for p in out.glob("shard-*.arrow")) and _shard_bytes(out) == before
    )
    # a truncated shard (crash mid-copy) is rebuilt, the others kept
    victim = out / "shard-00001.arrow"
    victim.write_bytes(victim.read_bytes()[:100])
    assert _build(posed, out) == 0
    doc = json.loads((out / "manifest.json").read_text())
    assert doc["report"]["shards_resumed"] == len(before) - 1
    assert _shard_bytes(out) == before
    # a torn shard that kept its size (power loss without --fsync) fails its sha256: rebuilt
    victim = out / "shard-00002.arrow"
    torn = bytearray(victim.read_bytes())
    torn[len(torn) // 2] ^= 0xFF
    victim.write_bytes(bytes(torn))
    assert _build(posed, out) == 0
    doc = json.loads((out / "manifest.json").read_text())
    assert doc["report"]["shards_resumed"] == len(before) - 1
    assert _shard_bytes(out) == before
    # ... and when it kept its mtime too, only --verify hashes it: rebuilt then
    stat = victim.stat()
    victim.write_bytes(bytes(torn))
    os.utime(victim, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    assert _build(posed, out) == 0 and _shard_bytes(out)["shard-00002.arrow"] == bytes(torn)
    assert _build(posed, out, "--verify") == 0
    doc = json.loads((out / "manifest.json").read_text())
    assert doc["report"]["shards_resumed"] == len(before) - 1
    assert _shard_bytes(out) == before
    # other parameters: every shard rebuilt; leftover shards of the bigger build removed
    assert _build(posed, out, "--shard-size", "1MB") == 0
    doc = json.loads((out / "manifest.json").read_text())
    assert doc["report"]["shards_resumed"] == 0 and len(doc["files"]) == 1
    assert sorted(p.name for p in out.glob("shard-*.arrow")) == ["shard-00000.arrow"]
    assert validate_dataset(out)["unlisted_files"] == []


def _gradient_scene(n: int = 14, h: int = 48, w: int = 96) -> PosedScene:
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    images = []
    for i in range(n):
        img = np.stack([xx * 2.0, yy * 4.0, np.full_like(xx, 10.0 * i)], -1).astype(np.uint8)  # RGB
        ok, buf = cv2.imencode(".png", cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
        images.append(buf.tobytes())
    poses = np.stack(
        [look_at_cam_to_world(np.array([0.05 * i, 0, -2.0]), np.array([0.05 * i, 0, 0.0])) for i in range(n)]
    )
    return PosedScene(
        "grad",
        images,
        "png",
        np.full(n, w),
        np.full(n, h),
        np.tile([0.6, 1.1, 0.48, 0.52], (n, 1)),
        poses,
        0.5,
        10.0,
        np.arange(n, dtype=np.int64),
        np.arange(n, dtype=np.int64) * 1000,
    )


def test_resize_center_crop_pixels_and_intrinsics(tmp_path):
    posed = tmp_path / "posed"
    with PosedDatasetWriter(posed, params={}, provenance={}) as w:
        w.add(_gradient_scene())
    out = tmp_path / "r"
    assert (
        cli_main(
            [
                "build",
                str(posed),
                "--out",
                str(out),
                "--gap-min",
                "4",
                "--gap-max",
                "6",
                "--samples-per-scene",
                "2",
                "--resize",
                "32x40",
            ]
        )
        == 0
    )
    rows = TripleShards(out).rows()
    # 48x96 -> cover 32x40: scale 2/3 -> 32x64, centre crop offset x = 12
    s, ox = 2.0 / 3.0, 12
    scene = _gradient_scene()
    for r in rows:
        assert (r.width == 40).all() and (r.height == 32).all() and r.image_format == "png"
        for v, f in enumerate(r.frame_index):
            img = cv2.cvtColor(cv2.imdecode(np.frombuffer(r.images[v], np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
            assert img.shape == (32, 40, 3)
            # pixel centre (j + 0.5) in the output is at ((j + 0.5 + ox) / s) in the source: R = 2 x, G = 4 y
            j = np.arange(40)
            src_x = (j + 0.5 + ox) / s - 0.5
            assert np.abs(img[16, 2:-2, 0].astype(float) - 2 * src_x[2:-2]).max() <= 2.0
            src_y = (np.arange(32) + 0.5) / s - 0.5
            assert np.abs(img[2:-2, 20, 1].astype(float) - 4 * src_y[2:-2]).max() <= 3.0
            assert abs(float(img[..., 2].mean()) - 10.0 * f) <= 1.0
            # geometry: a world point projects to the same place in the cropped image as (source pixel * s - offset)
            pts = np.array([[0.3, -0.2, 1.5], [-0.4, 0.1, 0.7]])
            uv_src, _ = project_points(pts, scene.cam_to_world[f], scene.intrinsics_norm[f], 96, 48)
            uv_out, _ = project_points(pts, r.cam_to_world[v], r.intrinsics_norm[v], 40, 32)
            assert np.allclose(uv_out, uv_src * s - np.array([ox, 0]), atol=1e-9)


def test_resize_jpeg_reencode_is_deterministic(posed, tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    assert _build(posed, a, "--resize", "16x16", "--workers", "1") == 0
    assert _build(posed, b, "--resize", "16x16", "--workers", "2") == 0
    assert _shard_bytes(a) == _shard_bytes(b)
    r = TripleShards(a).rows()[0]
    assert (r.width == 16).all() and r.images[0][:2] == b"\xff\xd8"


def test_skipped_scenes_and_bad_inputs(posed, tmp_path, capsys):
    # every scene too short -> one line, exit 2, no manifest
    assert (
        cli_main(
            [
                "build",
                str(posed),
                "--out",
                str(tmp_path / "o"),
                "--gap-min",
                "100",
                "--gap-max",
                "120",
                "--pairs",
                "gap",
            ]
        )
        == 2
    )
    err = capsys.readouterr().err
    assert err.startswith("seeu build: error:") and "no scene is long enough" in err and err.count("\n") == 1
    assert "--pairs overlap" in err
    assert not (tmp_path / "o" / "manifest.json").exists()
    # an unreadable posed chunk names the file
    broken = tmp_path / "broken"
    with PosedDatasetWriter(broken, params={}, provenance={}) as w:
        w.add(make_posed_scene("s", n=20, height=16, width=16))
    arrow = next(broken.glob("*.arrow"))
    data = arrow.read_bytes()
    arrow.write_bytes(data[: len(data) // 2] + b"\0" * (len(data) - len(data) // 2))
    assert cli_main(["build", str(broken), "--out", str(tmp_path / "o2"), "--gap-min", "5", "--gap-max", "6"]) == 2
    err = capsys.readouterr().err
    assert str(arrow) in err
    # not a posed dataset / missing input / invalid options
    assert cli_main(["build", str(tmp_path / "nope"), "--out", str(tmp_path / "o3")]) == 2
    assert "dataset directory not found" in capsys.readouterr().err
    assert cli_main(["build", str(posed), "--out", str(tmp_path / "o4"), "--gap-min", "9", "--gap-max", "3"]) == 2
    assert "gap_max must be >= gap_min" in capsys.readouterr().err
    assert cli_main(["build", str(posed), "--out", str(tmp_path / "o6"), "--shard-size", "3GB"]) == 2
    assert "shard size must be in" in capsys.readouterr().err
    # duplicate scene ids across inputs
    assert cli_main(["build", str(posed), str(posed), "--out", str(tmp_path / "o5")]) == 2
    assert "appears in two inputs" in capsys.readouterr().err


def test_shard_spec_out_of_range_and_missing_file_are_errors(posed):
    from dataclasses import replace

    from pipelines.build import scan_inputs
    from seeu_data.build.sampling import make_sample
    from seeu_data.build.triples import ImageOptions, ShardSpec, build_shard_table

    src = scan_inputs([str(posed)])["alpha"]
    sample = make_sample("alpha", "interp", 0, [0, 5], [30])
    spec = ShardSpec(0, "shard-00000.arrow", (sample,), {"alpha": src}, ImageOptions(), rows_per_batch=8)
    with pytest.raises(SeeUError, match="frame index out of range 0..29"):
        build_shard_table(spec)
    spec = replace(spec, sources={"alpha": replace(src, path="/nonexistent.arrow")})
    with pytest.raises(SeeUError, match="file not found"):
        build_shard_table(spec)


def test_inspect_statistics_and_sheet(posed, tmp_path, capsys):
    out = tmp_path / "x"
    assert _build(posed, out, "--mode", "extrap", "--extrap-frames", "5", "--interp-ratio", "0.5") == 0
    capsys.readouterr()
    rows = TripleShards(out).rows()
    stats = triple_statistics(out)
    offsets = np.concatenate([r.target_offset for r in rows])
    gaps = np.array([r.gap for r in rows])
    assert stats["rows"] == len(rows) == 9 and stats["scenes"] == 3 and stats["modes"] == {"extrap": 9}
    assert stats["target_offset"]["inside"] == int((offsets == 0).sum())
    assert stats["target_offset"]["before"] == int((offsets < 0).sum())
    assert stats["target_offset"]["after"] == int((offsets > 0).sum())
    assert stats["gap"]["min"] == gaps.min() and stats["gap"]["max"] == gaps.max()
    assert stats["gap"]["mean"] == pytest.approx(gaps.mean(), abs=1e-3)
    assert sum(stats["gap"]["histogram"]["counts"]) == 9
    assert stats["image_sizes"] == {"32x24": 45} and stats["num_target"] == {"3": 9}
    sheet = tmp_path / "sheet.png"
    assert cli_main(["inspect", str(out), "--json", "--sheet", str(sheet), "--sheet-rows", "4"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed["rows"] == 9 and len(printed["sheet"]["samples"]) == 4
    img = cv2.imread(str(sheet))
    # 4 examples x 5 views, 2.2 in wide and 2.2 in x the aspect 24/32 + 0.5 in of title high, at 80 dpi
    assert img is not None and img.shape == (4 * 172, 5 * 176, 3)
    assert cli_main(["inspect", str(out)]) == 0
    text = capsys.readouterr().out
    assert "9 triples" in text and "modes: extrap 9" in text and "inside the pair" in text


def test_progress_bar_on_request(posed, tmp_path, capsys):
    assert _build(posed, tmp_path / "p", "--progress") == 0
    err = capsys.readouterr().err
    rows = json.loads((tmp_path / "p" / "manifest.json").read_text())["total_rows"]
    assert "seeu build" in err and f"{rows}/{rows} [" in err and "triple/s" in err


def test_an_interrupted_resume_loses_no_completed_shard(posed, tmp_path, monkeypatch):
    """Shards are planned and checked as the build goes: a re-run interrupted before it reached some
    shards of the complete build it resumes still knows them (journal), and the next run keeps all."""
    import pipelines.build as build_mod

    out = tmp_path / "r"
    assert _build(posed, out) == 0
    good = _shard_bytes(out)
    real = build_mod.resumable_shard

    def interrupted(out_dir, spec, known, verify):
        if spec.index == 2:
            raise KeyboardInterrupt
        return real(out_dir, spec, known, verify)

    monkeypatch.setattr(build_mod, "resumable_shard", interrupted)
    assert _build(posed, out, "--verify") == 130 and not (out / "manifest.json").exists()
    monkeypatch.setattr(build_mod, "resumable_shard", real)
    assert _build(posed, out) == 0
    assert json.loads((out / "manifest.json").read_text())["report"]["shards_resumed"] == len(good) > 3
    assert _shard_bytes(out) == good


def test_hashed_writer_matches_plain_ipc_and_leftovers_are_cleared(posed, tmp_path, monkeypatch):
    import pyarrow as pa

    from seeu_data.store.arrow_io import sha256_file, write_table

    # large values too, so that the file has big writes as well as small ones
    table = pa.table(
        {
            "a": np.arange(5000),
            "b": [bytes([i % 251]) * (i % 300) for i in range(5000)],
            "c": [bytes([i % 251]) * ((2 << 20) if i % 1000 == 0 else 10) for i in range(5000)],
        }
    )
    size, digest = write_table(tmp_path / "x.arrow", table, max_chunksize=64)
    with pa.OSFile(str(tmp_path / "y.arrow"), "wb") as sink:
        with pa.ipc.new_file(sink, table.schema, options=pa.ipc.IpcWriteOptions(compression=None)) as w:
            w.write_table(table, max_chunksize=64)
    assert (tmp_path / "x.arrow").read_bytes() == (tmp_path / "y.arrow").read_bytes()
    assert size == (tmp_path / "x.arrow").stat().st_size and digest == sha256_file(tmp_path / "x.arrow")
    assert not list(tmp_path.glob(".*"))
    # an interrupted run leaves no manifest, a progress journal of the shards in place (and maybe a
    # temporary shard); the re-run keeps the recorded shards, clears the leftovers and completes
    out = tmp_path / "b"
    assert _build(posed, out) == 0
    good = _shard_bytes(out)
    shutil.rmtree(out)
    import pipelines.build as build_mod
    import seeu_data.build.shard_task as shard_task

    real = shard_task.write_shard

    def interrupted(spec, *args, **kwargs):
        if spec.index == 3:
            raise KeyboardInterrupt
        return real(spec, *args, **kwargs)

    monkeypatch.setattr(shard_task, "write_shard", interrupted)
    assert _build(posed, out, "--workers", "1") == 130
    assert not (out / "manifest.json").exists()
    assert [json.loads(line)["unit"] for line in (out / build_mod.PROGRESS_NAME).read_text().splitlines()] == [
        "shard-00000.arrow",
        "shard-00001.arrow",
        "shard-00002.arrow",
    ]
    (out / "shard-00002.arrow").rename(out / ".shard-00002.arrow.12345.tmp")  # caught before its rename
    (out / ".shard-00003.arrow.pending").write_bytes(b"left by an older version")
    monkeypatch.setattr(shard_task, "write_shard", real)
    assert _build(posed, out) == 0
    assert _shard_bytes(out) == good and not list(out.glob(".*"))
    assert json.loads((out / "manifest.json").read_text())["report"]["shards_resumed"] == 2


def test_undecodable_image_names_file_scene_and_frame(tmp_path, capsys):
    scene = make_posed_scene("bad", n=8, height=16, width=16)
    scene.images[3] = b"not a jpeg"
    posed = tmp_path / "posed"
    with PosedDatasetWriter(posed, params={}, provenance={}) as w:
        w.add(scene)
    index = tmp_path / "idx.json"
    index.write_text(json.dumps({"bad": {"context": [0, 7], "target": [3]}}))
    out = tmp_path / "o"
    args = ["build", str(posed), "--out", str(out), "--mode", "eval", "--index", str(index)]
    for more in (["--resize", "8x8"], []):  # the inputs' image headers are checked before anything is written
        assert cli_main([*args, *more]) == 2
        err = capsys.readouterr().err
        assert "scene 'bad' frame 3: image failed to decode" in err and str(next(posed.glob("*.arrow"))) in err
        assert not (out / "manifest.json").exists() and not list(out.glob("shard-*"))


def test_written_shards_equal_their_tables(posed, tmp_path):
    """What `materialise` writes (`write_shard`) equals the file pyarrow writes for `build_shard_table`'s
    table, shard by shard, several scenes per shard and several batches per shard, with and without
    resizing; the sha256 returned is the file's."""
    import pyarrow as pa

    from pipelines.build import BuildConfig, plan_sampled, scan_inputs, shard_specs
    from seeu_data.build.sampling import SamplingConfig
    from seeu_data.build.triples import ImageOptions, build_shard_table, write_shard
    from seeu_data.store.arrow_io import sha256_file

    for resize in (None, (8, 12)):
        cfg = BuildConfig(
            inputs=(str(posed),),
            out=str(tmp_path / "o"),
            rows_per_batch=3,
            shard_bytes=60_000,
            sampling=SamplingConfig(mode="extrap", gap_min=4, gap_max=8, samples_per_scene=9),
            image=ImageOptions(resize=resize),
        )
        scenes = scan_inputs(cfg.inputs)
        specs = list(shard_specs(cfg, plan_sampled(cfg, scenes), scenes))
        assert len(specs) > 1 and max(len(s.sources) for s in specs) > 1
        for spec in specs:
            table = build_shard_table(spec)
            with pa.OSFile(str(tmp_path / "plain.arrow"), "wb") as sink:
                with pa.ipc.new_file(sink, table.schema, options=pa.ipc.IpcWriteOptions(compression=None)) as w:
                    w.write_table(table, max_chunksize=3)
            rows, size, digest = write_shard(spec, tmp_path / "shard.arrow")
            assert (tmp_path / "plain.arrow").read_bytes() == (tmp_path / "shard.arrow").read_bytes()
            plain = tmp_path / "plain.arrow"
            assert (rows, size, digest) == (table.num_rows, plain.stat().st_size, sha256_file(plain))


def test_rewritten_posed_data_is_mapped_again(tmp_path):
    """A rewritten posed directory (same paths, other images) is read afresh by the next build."""

    def write(seed: int) -> None:
        with PosedDatasetWriter(tmp_path / "posed", params={}, provenance={}) as w:
            w.add(make_posed_scene("alpha", n=30, height=24, width=32, seed=seed))

    write(1)
    assert _build(tmp_path / "posed", tmp_path / "a", "--workers", "1") == 0
    write(2)  # same file names, sizes may even match
    assert _build(tmp_path / "posed", tmp_path / "b", "--workers", "1") == 0
    scene = PosedDataset(tmp_path / "posed").load_scene("alpha")
    rows = TripleShards(tmp_path / "b").rows()
    assert [r.images for r in rows] == [[scene.images[f] for f in r.frame_index] for r in rows]
    assert _shard_bytes(tmp_path / "a") != _shard_bytes(tmp_path / "b")


@pytest.mark.parametrize("cores, copy, resize", [(1, 1, 1), (2, 1, 2), (4, 1, 4), (6, 6, 6), (32, 8, 8)])
def test_default_workers(monkeypatch, cores, copy, resize):
    from seeu_data.process_pool import default_workers

    monkeypatch.setattr(os, "cpu_count", lambda: cores)
    assert (default_workers(), default_workers(resize=True)) == (copy, resize)


def test_shard_spec_and_result_round_trip_as_json_and_the_plan_hash(posed, tmp_path):
    """The Ray engine's rows carry specs and results as JSON: both come back equal. The plan hash
    covers the samples and the posed files' content, not their paths."""
    from dataclasses import replace

    from pipelines.build import BuildConfig, plan_sampled, scan_inputs, shard_specs
    from seeu_data.build.sampling import SamplingConfig
    from seeu_data.build.shard_task import ShardResult, materialise
    from seeu_data.build.triples import ShardSpec

    cfg = BuildConfig(
        inputs=(str(posed),),
        out=str(tmp_path / "o"),
        shard_bytes=60_000,
        near=0.5,
        far=20.0,
        sampling=SamplingConfig(mode="extrap", gap_min=4, gap_max=8, samples_per_scene=5),
    )
    scenes = scan_inputs(cfg.inputs)
    specs = list(shard_specs(cfg, plan_sampled(cfg, scenes), scenes))
    for spec in specs:
        back = ShardSpec.from_dict(json.loads(json.dumps(spec.as_dict())))
        assert back == spec and back.plan_sha256 == spec.plan_sha256
    spec = specs[0]
    sid = spec.samples[0].scene_id
    moved = replace(spec, sources={**spec.sources, sid: replace(spec.sources[sid], path="/elsewhere.arrow")})
    assert moved.plan_sha256 == spec.plan_sha256
    other = replace(spec, samples=spec.samples[1:])
    edited = replace(spec, sources={**spec.sources, sid: replace(spec.sources[sid], file_sha256="0" * 64)})
    assert len({spec.plan_sha256, other.plan_sha256, edited.plan_sha256, replace(spec, near_far=None).plan_sha256}) == 4
    (tmp_path / "o").mkdir()
    result = materialise(spec, str(tmp_path / "o"))
    assert result.entry is not None and result.entry.rows == len(spec.samples) and result.error is None
    assert ShardResult.from_dict(json.loads(json.dumps(result.as_dict()))) == result
    failed = materialise(moved, str(tmp_path / "o"))
    assert failed.entry is None and "file not found" in failed.error
    assert ShardResult.from_dict(json.loads(json.dumps(failed.as_dict()))) == failed
