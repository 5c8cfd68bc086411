"""pixelSplat chunk import: conventions against the MVSplat loader's own projection, streaming,
skips of bad scenes, the CLI, and the round trips with `seeu export pixelsplat`."""

from __future__ import annotations

import json
import os
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from pipelines.cli import main as cli_main
from pipelines.validate import validate_dataset
from seeu_data import cameras as cam
from seeu_data.errors import SeeUError
from seeu_data.exporters.pixelsplat import PixelSplatExportConfig, export_pixelsplat
from seeu_data.importers import ImportReport, write_import
from seeu_data.importers import pixelsplat as ps
from seeu_data.importers.read_ahead import SPILL_DIR
from seeu_data.store.posed import PosedDataset, PosedDatasetWriter, PosedScene
from tests.helpers import look_at_cam_to_world, make_posed_scene

H, W = 36, 64


def _jpeg(rng, h=H, w=W) -> bytes:
    ok, buf = cv2.imencode(".jpg", (rng.random((h, w, 3)) * 255).astype(np.uint8))
    assert ok
    return buf.tobytes()


def _w2c_rows(n: int, rng) -> np.ndarray:
    """(n, 3, 4) world-to-camera of cameras looking at the origin from random places."""
    out = []
    for _ in range(n):
        eye = rng.normal(size=3) * 2 + np.array([0, 0, -4.0])
        c2w = look_at_cam_to_world(eye, rng.normal(size=3) * 0.1)
        out.append(np.linalg.inv(c2w)[:3])
    return np.stack(out)


def make_example(key: str, n: int, rng, url: str = "https://www.youtube.com/watch?v=abc") -> dict:
    """A chunk example exactly as the peers' convert scripts build it."""
    intr = np.tile([0.86, 1.53, 0.5, 0.5], (n, 1)) + rng.normal(size=(n, 4)) * 0.01
    w2c = _w2c_rows(n, rng)
    cameras = np.concatenate([intr, np.zeros((n, 2)), w2c.reshape(n, 12)], axis=1)
    return {
        "url": url,
        "timestamps": torch.tensor(np.sort(rng.integers(0, 10**8, size=n)), dtype=torch.int64),
        "cameras": torch.tensor(cameras, dtype=torch.float32),
        "images": [torch.tensor(np.frombuffer(_jpeg(rng), dtype=np.uint8)) for _ in range(n)],
        "key": key,
    }


def write_chunks(root: Path, stage: str, chunks: list[list[dict]]) -> Path:
    directory = root / stage
    directory.mkdir(parents=True, exist_ok=True)
    index = {}
    for i, chunk in enumerate(chunks):
        name = f"{i:06d}.torch"
        torch.save(chunk, directory / name)
        index.update({ex["key"]: name for ex in chunk})
    (directory / "index.json").write_text(json.dumps(index))
    return directory


def _import(root, out, **kw) -> ImportReport:
    cfg = ps.PixelSplatImportConfig(root=root, **kw)
    report = ImportReport("pixelsplat")
    return write_import(ps.iter_scenes(cfg), out, report, params={}, provenance={})


def test_cameras_match_the_mvsplat_loader_projection(tmp_path):
    rng = np.random.default_rng(0)
    examples = [make_example(f"scene{i}", 5, rng) for i in range(3)]
    write_chunks(tmp_path / "re10k", "test", [examples[:2], examples[2:]])
    _import(tmp_path / "re10k", tmp_path / "posed", stage="test")
    ds = PosedDataset(tmp_path / "posed", verify=True)
    assert sorted(ds.scene_ids) == ["scene0", "scene1", "scene2"]
    point = np.array([[0.3, -0.2, 0.5]])
    for ex in examples:
        scene = ds.load_scene(ex["key"])
        assert scene.meta["url"] == ex["url"] and (scene.width == W).all() and (scene.height == H).all()
        assert np.array_equal(scene.timestamp_us, ex["timestamps"].numpy())
        assert scene.near == 1.0 and scene.far == 100.0
        for i in range(5):
            # The MVSplat loader: w2c = eye(4); w2c[:3] = cameras[:, 6:].view(3, 4); K normalised.
            c = ex["cameras"][i].double()
            w2c = torch.eye(4, dtype=torch.float64)
            w2c[:3] = c[6:].view(3, 4)
            K = torch.eye(3, dtype=torch.float64)
            K[0, 0], K[1, 1], K[0, 2], K[1, 2] = c[0], c[1], c[2], c[3]
            x_cam = (w2c @ torch.tensor([*point[0], 1.0], dtype=torch.float64))[:3]
            uvw = K @ x_cam
            expected = (uvw[:2] / uvw[2]).numpy() * [W, H]
            uv, depth = cam.project_points(point, scene.cam_to_world[i], scene.intrinsics_norm[i], W, H)
            assert np.allclose(uv[0], expected, atol=1e-6) and depth[0] > 0
            assert scene.images[i] == ex["images"][i].numpy().tobytes()


def test_bad_scenes_are_skipped_and_named(tmp_path):
    rng = np.random.default_rng(1)
    good = make_example("good", 4, rng)
    truncated = make_example("truncated", 4, rng)
    truncated["images"][2] = truncated["images"][2][:-200]  # a cut-off download
    garbage = make_example("garbage", 4, rng)
    garbage["images"][0] = torch.tensor(np.frombuffer(b"<html>not found</html>", dtype=np.uint8))
    mismatch = make_example("mismatch", 4, rng)
    mismatch["images"] = mismatch["images"][:3]
    nan_pose = make_example("nan_pose", 4, rng)
    nan_pose["cameras"][1, 9] = float("nan")
    skewed = make_example("skewed", 4, rng)
    skewed["cameras"][0, 6:9] *= 1.5  # not a rotation
    write_chunks(tmp_path / "ds", "train", [[good, truncated, garbage], [mismatch, nan_pose, skewed]])
    report = _import(tmp_path / "ds", tmp_path / "out")
    assert report.scenes == 1 and report.frames == 4
    reasons = {s.scene_id: s.reason for s in report.skipped}
    assert set(reasons) == {"truncated", "garbage", "mismatch", "nan_pose", "skewed"}
    assert "failed to decode" in reasons["truncated"] and "failed to decode" in reasons["garbage"]
    assert "disagree" in reasons["mismatch"]
    assert "non-finite" in reasons["nan_pose"] and "orthonormal" in reasons["skewed"]
    manifest = json.loads((tmp_path / "out" / "manifest.json").read_text())
    assert manifest["report"]["skipped_scenes"] == 5
    assert PosedDataset(tmp_path / "out").scene_ids == ["good"]


def test_nothing_usable_fails_without_manifest(tmp_path, capsys):
    rng = np.random.default_rng(2)
    bad = make_example("bad", 3, rng)
    bad["images"][0] = bad["images"][0][:10]
    write_chunks(tmp_path / "ds", "test", [[bad]])
    rc = cli_main(["import", "pixelsplat", str(tmp_path / "ds"), "--stage", "test", "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert rc == 2 and "no usable scene" in err and "bad" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "out" / "manifest.json").exists()
    # A corrupt chunk file: its scenes are skipped by name, the rest imports.
    write_chunks(tmp_path / "ds2", "test", [[make_example("ok", 3, rng)], [make_example("lost", 3, rng)]])
    (tmp_path / "ds2" / "test" / "000001.torch").write_bytes(b"PK\x03\x04 truncated")
    rc = cli_main(["import", "pixelsplat", str(tmp_path / "ds2"), "--stage", "test", "--out", str(tmp_path / "o2")])
    out = capsys.readouterr().out
    assert rc == 0 and "imported 1 scenes" in out and "skipped 1 scenes (lost)" in out
    # A missing directory is a one-line error.
    assert cli_main(["import", "pixelsplat", str(tmp_path / "nope"), "--out", str(tmp_path / "o3")]) == 2


def test_scene_filter_reads_only_needed_chunks(tmp_path, monkeypatch):
    rng = np.random.default_rng(3)
    write_chunks(
        tmp_path / "ds",
        "train",
        [[make_example(f"a{i}", 2, rng) for i in range(2)], [make_example(f"b{i}", 2, rng) for i in range(2)]],
    )
    loaded = []
    real = ps.load_chunk
    monkeypatch.setattr(ps, "load_chunk", lambda p: loaded.append(p.name) or real(p))
    report = _import(tmp_path / "ds", tmp_path / "out", scenes=frozenset({"b1", "zz"}))
    assert loaded == ["000001.torch"]
    assert report.scenes == 1 and [s.scene_id for s in report.skipped] == ["zz"]
    assert PosedDataset(tmp_path / "out").scene_ids == ["b1"]


def _posed_dataset(path: Path, scenes) -> PosedDataset:
    with PosedDatasetWriter(path, params={}, provenance={}) as w:
        for s in scenes:
            w.add(s)
    return PosedDataset(path)


def test_round_trip_posed_export_import(tmp_path):
    scenes = [make_posed_scene("s0", n=6, seed=0), make_posed_scene("s1", n=4, seed=1, image_format="png")]
    scenes[0].meta = {"url": "https://example.com/v"}
    ds = _posed_dataset(tmp_path / "posed", scenes)
    s = export_pixelsplat(
        ds, PixelSplatExportConfig(out=tmp_path / "chunks", stage="train", chunk_bytes=1, resize=None)
    )
    assert s["chunks"] == 2
    # Exactly the peer's keys and dtypes.
    chunk = torch.load(tmp_path / "chunks" / "train" / "000000.torch", weights_only=True)
    ex = chunk[0]
    assert list(ex) == ["url", "timestamps", "cameras", "images", "key"]
    assert ex["timestamps"].dtype == torch.int64 and ex["cameras"].dtype == torch.float32
    assert ex["cameras"].shape == (6, 18) and all(t.dtype == torch.uint8 and t.ndim == 1 for t in ex["images"])
    assert json.loads((tmp_path / "chunks" / "train" / "index.json").read_text()) == {
        "s0": "000000.torch",
        "s1": "000001.torch",
    }
    _import(tmp_path / "chunks", tmp_path / "back", stage="train")
    back = PosedDataset(tmp_path / "back")
    for orig in scenes:
        got = back.load_scene(orig.scene_id)
        assert got.images == orig.images and got.image_format == orig.image_format
        assert np.allclose(got.cam_to_world, orig.cam_to_world, atol=1e-6)
        assert np.allclose(got.intrinsics_norm, orig.intrinsics_norm, atol=1e-6)
        assert np.array_equal(got.timestamp_us, orig.timestamp_us)
        assert np.array_equal(got.source_frame, orig.source_frame) and got.source_name == orig.source_name
        assert (got.near, got.far) == (orig.near, orig.far)
        assert np.array_equal(got.width, orig.width) and np.array_equal(got.height, orig.height)
    assert back.load_scene("s0").meta["url"] == "https://example.com/v"
    validate_dataset(tmp_path / "back")


def test_round_trip_chunks_import_export(tmp_path):
    """export(import(chunks)) reproduces the chunks: same keys, camera floats, image bytes."""
    rng = np.random.default_rng(4)
    examples = [make_example(f"k{i}", 3, rng) for i in range(3)]
    write_chunks(tmp_path / "ds", "test", [examples])
    assert (
        cli_main(["import", "pixelsplat", str(tmp_path / "ds"), "--stage", "test", "--out", str(tmp_path / "p")]) == 0
    )
    assert (
        cli_main(["export", "pixelsplat", str(tmp_path / "p"), "--out", str(tmp_path / "again"), "--resize", "none"])
        == 0
    )
    again = torch.load(tmp_path / "again" / "test" / "000000.torch", weights_only=True)
    by_key = {ex["key"]: ex for ex in again}
    for ex in examples:
        got = by_key[ex["key"]]
        assert got["url"] == ex["url"] and torch.equal(got["timestamps"], ex["timestamps"])
        assert torch.allclose(got["cameras"], ex["cameras"], atol=1e-6)
        assert all(torch.equal(a, b) for a, b in zip(got["images"], ex["images"]))


class _NotPlainData:
    pass


def test_fast_chunk_reader_equals_torch_load_and_refuses_code(tmp_path):
    from seeu_data.importers.torch_chunk import UnsupportedChunk, load_plain

    base = torch.arange(60, dtype=torch.float32).view(6, 10)
    obj = [
        {
            "key": "k",
            "url": "u",
            "n": 3,
            "f": 0.5,
            "none": None,
            "t": (1, "a"),
            "slice": base[2:5, 1:4],  # storage offset + strides
            "transposed": base.t(),  # non-contiguous
            "shared": base[1],
            "same": base,  # one storage, several tensors
            "empty": torch.zeros(0, 18),
            "i64": torch.tensor([2**40, -3]),
            "u8": torch.tensor([1, 255], dtype=torch.uint8),
            "f64": torch.tensor([1e-300]),
            "b": torch.tensor([True, False]),
            "h": torch.tensor([1.5], dtype=torch.float16),
        }
    ]
    torch.save(obj, tmp_path / "c.torch")
    got = load_plain(tmp_path / "c.torch")
    ref = torch.load(tmp_path / "c.torch", weights_only=True)
    for k, v in ref[0].items():
        if isinstance(v, torch.Tensor):
            assert got[0][k].dtype == v.numpy().dtype and np.array_equal(got[0][k], v.numpy()), k
        else:
            assert got[0][k] == v, k
    torch.save([{"key": "x", "evil": _NotPlainData()}], tmp_path / "evil.torch")
    with pytest.raises(UnsupportedChunk):
        load_plain(tmp_path / "evil.torch")
    with pytest.raises(SeeUError, match="not a readable pixelSplat chunk"):
        ps.load_chunk(tmp_path / "evil.torch")  # torch.load(weights_only=True) refuses it too
    # A legacy (pre-zip) file goes through torch.load.
    torch.save(obj, tmp_path / "legacy.torch", _use_new_zipfile_serialization=False)
    with pytest.raises(UnsupportedChunk):
        load_plain(tmp_path / "legacy.torch")
    legacy = ps.load_chunk(tmp_path / "legacy.torch")
    assert torch.equal(legacy[0]["slice"], base[2:5, 1:4])


def test_verify_decode_catches_what_headers_cannot(tmp_path, capsys):
    rng = np.random.default_rng(5)
    ex = make_example("scanless", 3, rng)
    jpg = ex["images"][1].numpy().tobytes()
    no_scan = jpg[: jpg.index(b"\xff\xda")] + b"\xff\xd9"
    ex["images"][1] = torch.tensor(np.frombuffer(no_scan, dtype=np.uint8))
    write_chunks(tmp_path / "ds", "test", [[ex, make_example("fine", 3, rng)]])
    args = ["import", "pixelsplat", str(tmp_path / "ds"), "--stage", "test"]
    assert cli_main(args + ["--out", str(tmp_path / "fast")]) == 0
    assert sorted(PosedDataset(tmp_path / "fast").scene_ids) == ["fine", "scanless"]
    assert cli_main(args + ["--out", str(tmp_path / "full"), "--verify-decode"]) == 0
    assert PosedDataset(tmp_path / "full").scene_ids == ["fine"]
    assert "skipped 1 scenes (scanless)" in capsys.readouterr().out
    assert cli_main(args + ["--out", str(tmp_path / "strict"), "--verify-decode", "--strict"]) == 2


def test_prefetch_keeps_order_reraises_and_stops():
    import threading

    from seeu_data.importers.prefetch import prefetch

    assert list(prefetch(iter(range(50)), max_items=2)) == list(range(50))

    def failing():
        yield 1
        raise SeeUError("boom")

    got = []
    with pytest.raises(SeeUError, match="boom"):
        for x in prefetch(failing()):
            got.append(x)
    assert got == [1]
    produced = []

    def endless():
        i = 0
        while True:
            produced.append(i)
            yield i
            i += 1

    gen = prefetch(endless(), max_items=2)
    assert next(gen) == 0
    gen.close()  # the consumer stops: the producer thread must end too
    assert not any(t.name == "seeu-import-prefetch" and t.is_alive() for t in threading.enumerate())
    assert len(produced) <= 5


def _resumable_import(root, out, target_file_bytes=1, **kw) -> ImportReport:
    """An import whose every chunk closes its own output file (target size 1 byte)."""
    cfg = ps.PixelSplatImportConfig(root=root, **kw)
    return write_import(
        ps.import_plan(cfg),
        out,
        ImportReport("pixelsplat"),
        params={"near": cfg.near},
        provenance={},
        target_file_bytes=target_file_bytes,
    )


def _files(out: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(out.glob("posed-*.arrow"))}


def test_rerun_resumes_complete_chunks_and_redoes_the_rest(tmp_path, monkeypatch):
    from seeu_data.importers.common import RESUME_JOURNAL

    rng = np.random.default_rng(11)
    write_chunks(tmp_path / "ds", "train", [[make_example(f"c{c}s{i}", 3, rng) for i in range(2)] for c in range(3)])
    fresh = tmp_path / "fresh"
    _resumable_import(tmp_path / "ds", fresh)
    expected = _files(fresh)
    assert len(expected) == 3 and not (fresh / RESUME_JOURNAL).exists()
    loaded: list[str] = []
    real = ps.load_chunk

    def counting(p):
        loaded.append(p.name)
        return real(p)

    monkeypatch.setattr(ps, "load_chunk", counting)
    # a complete output: nothing is read again, nothing rewritten, the same manifest content
    mtimes = {p.name: p.stat().st_mtime_ns for p in fresh.glob("posed-*.arrow")}
    report = _resumable_import(tmp_path / "ds", fresh)
    assert loaded == [] and report.notes["resumed_files"] == 3 and report.scenes == 6
    assert {p.name: p.stat().st_mtime_ns for p in fresh.glob("posed-*.arrow")} == mtimes
    assert PosedDataset(fresh, verify=True).scene_ids == [f"c{c}s{i}" for c in range(3) for i in range(2)]

    # interrupted while reading the third chunk: two files in place, a journal, no manifest
    out = tmp_path / "out"

    def interrupted(p):
        if p.name == "000002.torch":
            raise KeyboardInterrupt
        return counting(p)

    monkeypatch.setattr(ps, "load_chunk", interrupted)
    with pytest.raises(KeyboardInterrupt):
        _resumable_import(tmp_path / "ds", out)
    assert not (out / "manifest.json").exists() and len((out / RESUME_JOURNAL).read_text().splitlines()) == 2
    monkeypatch.setattr(ps, "load_chunk", counting)
    loaded.clear()
    report = _resumable_import(tmp_path / "ds", out)
    assert loaded == ["000002.torch"] and report.notes["resumed_files"] == 2
    assert _files(out) == expected and not (out / RESUME_JOURNAL).exists()
    assert PosedDataset(out, verify=True).scene_ids == PosedDataset(fresh).scene_ids

    # a file torn without changing its size (power loss without --fsync): it and the later ones redone
    victim = out / "posed-00001.arrow"
    torn = bytearray(victim.read_bytes())
    torn[len(torn) // 2] ^= 0xFF
    victim.write_bytes(bytes(torn))
    loaded.clear()
    _resumable_import(tmp_path / "ds", out)
    assert loaded == ["000001.torch", "000002.torch"] and _files(out) == expected

    # other options, or a chunk replaced: not resumed
    loaded.clear()
    _resumable_import(tmp_path / "ds", out, near=0.5)
    assert loaded == ["000000.torch", "000001.torch", "000002.torch"]
    chunk = tmp_path / "ds" / "train" / "000000.torch"
    os.utime(chunk, ns=(chunk.stat().st_atime_ns, chunk.stat().st_mtime_ns + 10**9))
    loaded.clear()
    _resumable_import(tmp_path / "ds", out, near=0.5)
    assert loaded == ["000000.torch", "000001.torch", "000002.torch"]


def test_cli_rerun_resumes_and_reports_skips_again(tmp_path, capsys):
    rng = np.random.default_rng(12)
    bad = make_example("bad", 2, rng)
    bad["cameras"] = bad["cameras"][:1]
    write_chunks(tmp_path / "ds", "test", [[make_example("a", 2, rng), bad], [make_example("b", 2, rng)]])
    cmd = ["import", "pixelsplat", str(tmp_path / "ds"), "--stage", "test", "--out", str(tmp_path / "o")]
    assert cli_main(cmd) == 0
    first = capsys.readouterr().out
    doc1 = json.loads((tmp_path / "o" / "manifest.json").read_text())
    assert cli_main(cmd) == 0
    second = capsys.readouterr().out
    doc2 = json.loads((tmp_path / "o" / "manifest.json").read_text())
    assert (
        "kept from a previous run" in second
        and "skipped 1 scenes (bad)" in first
        and "skipped 1 scenes (bad)" in second
    )
    assert doc1["files"] == doc2["files"] and doc1["scenes"] == doc2["scenes"]
    assert doc1["report"]["skipped"] == doc2["report"]["skipped"]
    assert validate_dataset(tmp_path / "o")["unlisted_files"] == []
    # --force: nothing kept, the same files written anew
    mtime = (tmp_path / "o" / "posed-00000.arrow").stat().st_mtime_ns
    assert cli_main([*cmd, "--force"]) == 0
    assert "kept from a previous run" not in capsys.readouterr().out
    assert json.loads((tmp_path / "o" / "manifest.json").read_text())["files"] == doc1["files"]
    assert (tmp_path / "o" / "posed-00000.arrow").stat().st_mtime_ns != mtime


def test_import_fsyncs_only_with_the_flag(tmp_path, fsyncs):
    from seeu_data.importers.common import RESUME_JOURNAL

    rng = np.random.default_rng(13)
    write_chunks(tmp_path / "ds", "test", [[make_example("a", 2, rng)], [make_example("b", 2, rng)]])
    cmd = ["import", "pixelsplat", str(tmp_path / "ds"), "--stage", "test"]
    assert cli_main([*cmd, "--out", str(tmp_path / "a")]) == 0
    assert [c for c in fsyncs if c[0] == "fsync"] == []
    assert cli_main([*cmd, "--out", str(tmp_path / "b"), "--fsync"]) == 0
    synced = [Path(p).name for kind, p in fsyncs if kind == "fsync"]
    # the posed file and the manifest before their renames, the resume journal's records as written
    assert any(n.startswith(".posed-00000.arrow.") for n in synced), synced
    assert any(n.startswith(".manifest.json.") for n in synced), synced
    assert RESUME_JOURNAL in synced, synced
    fsyncs.clear()
    assert cli_main([*cmd, "--out", str(tmp_path / "c")]) == 0
    assert [c for c in fsyncs if c[0] == "fsync"] == []  # --fsync is a parameter of that one import
    assert _files(tmp_path / "a") == _files(tmp_path / "b")


class _CountingIndex(dict):
    """index.json as a dict that counts every entry it hands out (iteration, lookups, items)."""

    visits = 0

    def __iter__(self):
        for key in super().__iter__():
            _CountingIndex.visits += 1
            yield key

    def items(self):
        for item in super().items():
            _CountingIndex.visits += 1
            yield item

    def keys(self):
        return list(iter(self))

    def values(self):
        return [v for _, v in self.items()]

    def get(self, key, default=None):
        _CountingIndex.visits += 1
        return super().get(key, default)

    def __getitem__(self, key):
        _CountingIndex.visits += 1
        return super().__getitem__(key)

    def __contains__(self, key):
        _CountingIndex.visits += 1
        return super().__contains__(key)


def test_import_of_2000_scenes_in_200_chunks_visits_the_index_o_scenes_times(tmp_path, monkeypatch):
    """index.json is grouped by chunk once: an import touches each entry a few times, not once per chunk
    (the scan per chunk it replaced touched 2,000 x 200 = 400,000 entries)."""
    rng = np.random.default_rng(13)
    example = make_example("x", 1, rng)
    directory = tmp_path / "ds" / "train"
    directory.mkdir(parents=True)
    index = {}
    for c in range(200):
        chunk = [dict(example, key=f"c{c:03d}s{i}") for i in range(10)]
        index.update({ex["key"]: f"{c:06d}.torch" for ex in chunk})
        torch.save(chunk, directory / f"{c:06d}.torch")
    index["lost"] = "000000.torch"  # listed, not held: reported by name
    (directory / "index.json").write_text(json.dumps(index))
    real = ps.read_index
    monkeypatch.setattr(ps, "read_index", lambda d: _CountingIndex(real(d)))
    _CountingIndex.visits = 0
    items = list(ps.iter_scenes(ps.PixelSplatImportConfig(root=tmp_path / "ds")))
    assert sum(isinstance(s, PosedScene) for s in items) == 2000
    assert [(s.scene_id, s.reason) for s in items if not isinstance(s, PosedScene)] == [
        ("lost", "index.json lists it in 000000.torch, which does not hold it")
    ]
    assert _CountingIndex.visits <= 3 * len(index), _CountingIndex.visits


def test_import_in_worker_processes_writes_the_same_bytes_and_a_dead_worker_is_one_line(tmp_path, capsys, monkeypatch):
    """`seeu import --workers 2` reads the chunks (scenes checked, overlap measured) in two worker
    processes: the posed and overlap files are the bytes of a one-process import. A worker killed
    (out of memory, kill -9) is one line and exit 2, and the re-run resumes to the same bytes."""
    import signal

    from seeu_data.importers import common

    rng = np.random.default_rng(11)
    write_chunks(tmp_path / "ds", "train", [[make_example(f"c{c}s{i}", 6, rng) for i in range(2)] for c in range(5)])

    def run(out: str, workers: int) -> int:
        return cli_main(
            ["import", "pixelsplat", str(tmp_path / "ds"), "--out", str(tmp_path / out), "--workers", str(workers)]
        )

    def files(out: str) -> dict[str, bytes]:
        return {p.name: p.read_bytes() for p in sorted((tmp_path / out).glob("*.arrow"))}

    assert run("one", 1) == 0 and run("two", 2) == 0
    assert len(files("one")) >= 2 and files("two") == files("one")
    assert not (tmp_path / "two" / SPILL_DIR).exists()

    prepare = common._prepare

    def dies_on_c3(item):  # in the forked worker that reads chunk 3
        if item.scene_id.startswith("c3"):
            os.kill(os.getpid(), signal.SIGKILL)
        return prepare(item)

    monkeypatch.setattr(common, "_prepare", dies_on_c3)
    capsys.readouterr()
    assert run("killed", 2) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "died (killed by SIGKILL" in err[0] and "re-run the same command to resume" in err[0], err
    assert not (tmp_path / "killed" / "manifest.json").exists() and not (tmp_path / "killed" / SPILL_DIR).exists()
    monkeypatch.setattr(common, "_prepare", prepare)
    assert run("killed", 2) == 0 and files("killed") == files("one")


def test_a_worker_hands_images_over_in_a_file_not_the_pipe(tmp_path):
    """`read_ahead.spill` / `unspill`: what crosses the pool's pipe is the scenes without their images; the writer gets the same image bytes back (views of the mapped file, which is gone from
    the folder at once), and skips pass through."""
    import pickle

    from seeu_data.importers.common import SkippedScene
    from seeu_data.importers.read_ahead import spill, unspill

    items: list = [make_posed_scene(f"s{i}", 5, 180, 240, seed=i) for i in range(3)]
    items.insert(1, SkippedScene("bad", "no frames"))
    items[2].images[3] = b""  # an empty value keeps its place
    want = [[bytes(im) for im in s.images] for s in items if isinstance(s, PosedScene)]
    sent = spill(items, tmp_path)
    assert len(pickle.dumps(sent)) < 0.02 * sum(map(len, (im for scene in want for im in scene)))
    back = unspill(*pickle.loads(pickle.dumps(sent)))
    assert list(tmp_path.iterdir()) == []
    assert [[bytes(im) for im in s.images] for s in back if isinstance(s, PosedScene)] == want
    assert [s.scene_id for s in back] == ["s0", "bad", "s1", "s2"]
