"""Streaming loader on real shards: DataLoader partition/resume, pixels and cameras, errors, curriculum."""

from __future__ import annotations

import os
import shutil
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from seeu_data import cameras
from seeu_data.errors import SeeUError
from seeu_data.image_ops import resize_cover_crop
from seeu_data.loader import GapCurriculum, LoaderConfig, TripleStream, make_loader
from seeu_data.loader import source as source_mod
from tests.loader_fixtures import all_sample_ids, row_dict, write_triples

ROWS = [7, 5, 9]
HW = (8, 8)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    return write_triples(tmp_path_factory.mktemp("triples") / "ds", ROWS, hw=(10, 14))


def loader(ds, tmp_path, **kw):
    kw.setdefault("image_hw", HW)
    kw.setdefault("cache_dir", str(tmp_path / "cache"))
    return make_loader(ds, **kw)


def ids_of(batches):
    return [s for b in batches for s, p in zip(b["sample_id"], b["is_padding"].tolist()) if not p]


# ------------------------------------------------------------------------------- batch layout


def test_batch_layout_and_values(dataset, tmp_path):
    ld = loader(dataset, tmp_path, batch_size=3, seed=1, image_dtype="float32")
    batches = list(ld)
    b = batches[0]
    for part, v in (("context", 2), ("target", 3)):
        d = b[part]
        assert d["image"].shape == (3, v, 3, *HW) and d["image"].dtype == torch.float32
        assert d["cam_to_world"].shape == (3, v, 4, 4) and d["intrinsics"].shape == (3, v, 3, 3)
        assert d["near"].shape == d["far"].shape == d["frame_index"].shape == (3, v)
        assert d["frame_index"].dtype == torch.int64
        assert 0.0 <= d["image"].min() and d["image"].max() <= 1.0
    # Each view is a flat colour encoding (shard, row, view) in BGR: check the RGB values come back.
    for i, sid in enumerate(b["sample_id"]):
        shard, row = int(sid.split("/")[0][1:]), int(sid.split("/")[-1])
        for v in range(5):
            part, k = ("context", v) if v < 2 else ("target", v - 2)
            rgb = b[part]["image"][i, k, :, 4, 4].numpy() * 255
            expect = [30 + 40 * v, 10 + 12 * (row % 20), 20 + 40 * (shard % 6)]
            assert np.allclose(rgb, expect, atol=3), (sid, v, rgb, expect)
        assert b["context"]["frame_index"][i].tolist() == [row, row + 1]
        assert b["context"]["far"][i, 0] == 10.0 + shard
    assert len(batches) == 7 and ld.state_dict()["epoch"] == 1 and ld.stats["padding"] == 0
    assert sorted(ids_of(batches)) == sorted(all_sample_ids(ROWS))
    # uint8 images (the default; converted on the device), also handed over from a worker: the same pixels.
    raw = list(loader(dataset, tmp_path, batch_size=3, seed=1, num_workers=1))
    for a, r in zip(batches, raw):
        assert r["context"]["image"].dtype == torch.uint8 and isinstance(r["context"]["near"], torch.Tensor)
        assert torch.equal((a["target"]["image"] * 255).round().to(torch.uint8), r["target"]["image"])
        assert torch.equal(r["is_padding"], a["is_padding"]) and r["sample_id"] == a["sample_id"]
    # The training/evaluation loops' batch_to_device makes uint8 batches float32 on the device: the same values.
    from seeu_data.loader import batch_to_device

    for a, r in zip(batches, raw):
        moved = batch_to_device(r, "cpu")
        for part in ("context", "target"):
            assert moved[part]["image"].dtype == torch.float32 and torch.equal(moved[part]["image"], a[part]["image"])
            assert torch.equal(moved[part]["intrinsics"], a[part]["intrinsics"])
        assert r["target"]["image"].dtype == torch.uint8  # the loader's batch itself is left as it was
        assert batch_to_device(a, "cpu")["target"]["image"] is a["target"]["image"]  # float32 just moves


def test_worker_batches_equal_the_in_process_ones(dataset, tmp_path):
    # Workers decode into a reused buffer and hand copies over: many batches per worker, a slow
    # consumer, and every batch still equals the in-process one.
    import time

    ref = list(loader(dataset, tmp_path, batch_size=1, seed=3, flip_p=0.5))
    ld = loader(dataset, tmp_path, batch_size=1, seed=3, flip_p=0.5, num_workers=2)
    got = []
    for i, b in enumerate(ld):
        if i % 4 == 0:
            time.sleep(0.05)  # the workers run ahead until their ring is full
        got.append(b)
    assert len(got) == len(ref) == 21
    for a, b in zip(ref, got):
        assert a["sample_id"] == b["sample_id"]
        assert torch.equal(a["context"]["image"], b["context"]["image"])
        assert torch.equal(a["target"]["image"], b["target"]["image"])
        assert b["target"]["image"].is_contiguous()


# ------------------------------------------------------------------------- partition and resume


@pytest.mark.parametrize("world", [1, 2, 3])
@pytest.mark.parametrize("workers", [0, 2])
def test_dataloader_exactly_once_across_ranks_and_workers(dataset, tmp_path, world, workers):
    streams = []
    for r in range(world):
        ld = loader(dataset, tmp_path, batch_size=2, rank=r, world_size=world, num_workers=workers, seed=7, flip_p=0.5)
        assert len(ld) == -(-21 // (2 * world))
        streams.append(list(ld))
    assert len({len(s) for s in streams}) == 1  # DDP-safe: same batch count on every rank
    got = [i for s in streams for i in ids_of(s)]
    assert sorted(got) == sorted(all_sample_ids(ROWS))
    # The rank's output (ids, pixels, cameras) does not depend on the worker count.
    ref = list(
        loader(
            dataset,
            tmp_path,
            batch_size=2,
            rank=0,
            world_size=world,
            num_workers=1 - min(workers, 1),
            seed=7,
            flip_p=0.5,
        )
    )
    for a, b in zip(streams[0], ref):
        assert a["sample_id"] == b["sample_id"]
        assert torch.equal(a["context"]["image"], b["context"]["image"])
        assert torch.equal(a["target"]["cam_to_world"], b["target"]["cam_to_world"])


def test_resume_mid_epoch_with_other_ranks_workers_and_batch_size(dataset, tmp_path):
    # Run 1: 2 ranks x 2 workers, batch 2; stop after 2 steps and checkpoint.
    ranks = [loader(dataset, tmp_path, batch_size=2, rank=r, world_size=2, num_workers=2, seed=3) for r in range(2)]
    before = []
    for ld in ranks:
        it = iter(ld)
        before += ids_of([next(it), next(it)])
        del it
    state = ranks[0].state_dict()
    assert state == ranks[1].state_dict() and state["samples_seen"] == 8 and state["step"] == 2
    # Run 2: 3 ranks x 1 worker, batch 1 (global batch 3), resumed from the checkpoint.
    after = []
    for r in range(3):
        ld = loader(dataset, tmp_path, batch_size=1, rank=r, world_size=3, num_workers=1, seed=3)
        ld.load_state_dict(state)
        after += ids_of(list(ld))
        assert ld.state_dict()["epoch"] == 1
    assert not set(before) & set(after)
    assert sorted(before + after) == sorted(all_sample_ids(ROWS))


def test_resume_equals_uninterrupted_run(dataset, tmp_path):
    full = list(loader(dataset, tmp_path, batch_size=2, seed=11, flip_p=0.5))
    first = loader(dataset, tmp_path, batch_size=2, seed=11, flip_p=0.5, num_workers=2)
    it = iter(first)
    head = [next(it) for _ in range(4)]
    state = first.state_dict()
    resumed = loader(dataset, tmp_path, batch_size=2, seed=0, flip_p=0.5, num_workers=1)
    resumed.load_state_dict(state)  # adopts the checkpoint's seed
    tail = list(resumed)
    assert [b["sample_id"] for b in head + tail] == [b["sample_id"] for b in full]
    assert all(torch.equal(a["target"]["image"], b["target"]["image"]) for a, b in zip(head + tail, full))
    # Next epoch: a different order, still every sample once.
    nxt = list(resumed)
    assert resumed.state_dict()["epoch"] == 2 and sorted(ids_of(nxt)) == sorted(all_sample_ids(ROWS))
    assert [b["sample_id"] for b in nxt] != [b["sample_id"] for b in full]


def test_set_epoch_and_foreign_checkpoint(dataset, tmp_path):
    ld = loader(dataset, tmp_path, batch_size=4, remainder="drop")
    assert len(ld) == 5
    ld.set_epoch(3)
    assert ld.state_dict()["epoch"] == 3 and len(list(ld)) == 5
    other = write_triples(tmp_path / "other", [4])
    with pytest.raises(SeeUError, match="different dataset"):
        loader(other, tmp_path, batch_size=1).load_state_dict(ld.state_dict())


# ---------------------------------------------------------------------- pixels and cameras round trip


def _blob_rows(src_hw, point):
    h, w = src_hw

    def rows_fn(shard, j):
        base = row_dict(shard, j, 2, 3, src_hw, gap=3)
        images = []
        for v in range(5):
            c2w = np.asarray(base["cam_to_world"][v]).reshape(4, 4)
            (uv,), _ = cameras.project_points(point[None], c2w, np.asarray(base["intrinsics_norm"][v]), w, h)
            ys, xs = np.mgrid[0:h, 0:w] + 0.5
            blob = 250 * np.exp(-((xs - uv[0]) ** 2 + (ys - uv[1]) ** 2) / (2 * 3.0**2))
            ramp = np.stack(
                [2 * np.arange(w)[None].repeat(h, 0), 3 * np.arange(h)[:, None].repeat(w, 1), blob], -1
            )  # B: 2x, G: 3y, R: blob
            ok, buf = cv2.imencode(".png", ramp.round().astype(np.uint8))
            images.append(buf.tobytes())
        base.update(image=images, image_format="png")
        return base

    return rows_fn


@pytest.mark.parametrize("interpolation", ["linear", "area"])
def test_known_frame_pixels_and_cameras_match_the_crop_math(tmp_path, interpolation):
    src_hw, out_hw = (60, 100), (32, 32)
    point = np.array([0.25, 0.05, 0.3])
    ds = write_triples(tmp_path / "ds", [2], rows_fn=_blob_rows(src_hw, point))
    (sh, sw), (oy, ox) = (32, 53), (0, 10)  # closed form: scale 32/60 -> 32x53.33 -> 32x53, crop 10 px each side
    assert cameras.cover_crop_geometry(src_hw, out_hw) == ((sh, sw), (oy, ox))
    kw = dict(batch_size=2, image_hw=out_hw, shuffle=False, interpolation=interpolation)
    plain = list(loader(ds, tmp_path, **kw))[0]
    mirrored = list(loader(ds, tmp_path, flip_p=1.0, **kw))[0]
    for i, j in enumerate([0, 1]):
        row = row_dict(0, j, 2, 3, src_hw, gap=3)
        for v in range(5):
            part, k = ("context", v) if v < 2 else ("target", v - 2)
            img = plain[part]["image"][i, k].numpy().astype(np.float64)  # (3, H, W) RGB, uint8 values
            # Pixels: area or bilinear resampling of a linear ramp is the ramp at the output pixel's centre.
            x_src = (np.arange(32) + ox + 0.5) * 100 / sw - 0.5
            y_src = (np.arange(32) + oy + 0.5) * 60 / sh - 0.5
            assert np.abs(img[2][:, 1:-1] - 2 * x_src[None, 1:-1]).max() < 1.01
            assert np.abs(img[1][1:-1] - 3 * y_src[1:-1, None]).max() < 1.01
            # Intrinsics: the closed form of the cover crop.
            fx, fy, cx, cy = row["intrinsics_norm"][v]
            want = np.array([[fx * sw / 32, 0, (cx * sw - ox) / 32], [0, fy * sh / 32, (cy * sh - oy) / 32], [0, 0, 1]])
            got = plain[part]["intrinsics"][i, k].numpy()
            assert np.allclose(got, want, atol=1e-6)
            c2w = np.asarray(row["cam_to_world"][v]).reshape(4, 4)
            assert np.allclose(plain[part]["cam_to_world"][i, k].numpy(), c2w, atol=1e-6)
            # Geometry: the blob (a projected world point) sits where the output camera projects it.
            red = img[0]
            ys, xs = np.mgrid[0:32, 0:32] + 0.5
            centroid = np.array([(red * xs).sum(), (red * ys).sum()]) / red.sum()
            intr_out = cameras.intrinsics_norm_vector(got.astype(np.float64))
            (uv,), _ = cameras.project_points(point[None], c2w, intr_out, 32, 32)
            assert np.allclose(centroid, uv, atol=0.25), (centroid, uv)
            # Flip: the image is mirrored; the mirrored world point projects onto the mirrored blob.
            mimg = mirrored[part]["image"][i, k].numpy().astype(np.float64)
            assert np.array_equal(mimg, img[:, :, ::-1])
            mc2w = mirrored[part]["cam_to_world"][i, k].numpy().astype(np.float64)
            assert np.allclose(mc2w, np.diag([-1, 1, 1, 1]) @ c2w @ np.diag([-1, 1, 1, 1]), atol=1e-6)
            mintr = cameras.intrinsics_norm_vector(mirrored[part]["intrinsics"][i, k].numpy().astype(np.float64))
            (muv,), _ = cameras.project_points((point * [-1, 1, 1])[None], mc2w, mintr, 32, 32)
            mred = mimg[0]
            mcentroid = np.array([(mred * xs).sum(), (mred * ys).sum()]) / mred.sum()
            assert np.allclose(mcentroid, muv, atol=0.25) and np.isclose(muv[0], 32 - uv[0], atol=1e-4)


def test_flip_is_deterministic_and_about_half(dataset, tmp_path):
    a = list(loader(dataset, tmp_path, batch_size=7, flip_p=0.5, seed=5, image_hw=(10, 14)))
    b = list(loader(dataset, tmp_path, batch_size=7, flip_p=0.5, seed=5, image_hw=(10, 14)))
    plain = {
        s: (bt, i)
        for bt in list(loader(dataset, tmp_path, batch_size=7, seed=5, image_hw=(10, 14)))
        for i, s in enumerate(bt["sample_id"])
    }
    flipped = 0
    for x, y in zip(a, b):
        assert torch.equal(x["context"]["image"], y["context"]["image"])
        for i, s in enumerate(x["sample_id"]):
            bt, j = plain[s]
            c = x["context"]["cam_to_world"][i]
            if not torch.allclose(c, bt["context"]["cam_to_world"][j]):
                flipped += 1
                assert torch.equal(x["target"]["image"][i], bt["target"]["image"][j].flip(-1))
    assert 3 <= flipped <= 18


# ------------------------------------------------------------------------------------- errors


def _copy(dataset, tmp_path) -> Path:
    dst = tmp_path / "copy"
    shutil.copytree(dataset, dst)
    return dst


def test_truncated_shard_names_the_shard(dataset, tmp_path):
    ds = _copy(dataset, tmp_path)
    shard = ds / "shard-00001.arrow"
    shard.write_bytes(shard.read_bytes()[:-100])
    with pytest.raises(SeeUError, match=r"shard-00001\.arrow.*truncated"):
        list(loader(ds, tmp_path, batch_size=3, shuffle=False))


def test_corrupt_shard_raises_or_is_skipped_and_counted(dataset, tmp_path):
    ds = _copy(dataset, tmp_path)
    shard = ds / "shard-00001.arrow"
    data = bytearray(shard.read_bytes())
    data[len(data) // 2] ^= 0xFF  # same size, different bytes
    shard.write_bytes(bytes(data))
    with pytest.raises(SeeUError, match=r"shard-00001\.arrow: sha256") as err:
        list(loader(ds, tmp_path, batch_size=3, num_workers=1))
    assert "\n" not in str(err.value) and err.value.path.endswith("shard-00001.arrow")  # one line, from a worker
    ld = loader(ds, tmp_path, batch_size=3, on_error="skip")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        batches = list(ld)
    assert any("shard-00001.arrow" in str(w.message) for w in caught)
    assert ld.stats["skipped_corrupt"] == 5
    good = [s for s in all_sample_ids(ROWS) if not s.startswith("s1/")]
    assert sorted(ids_of(batches)) == sorted(good)
    assert all(len(b["sample_id"]) == 3 for b in batches) and len(batches) == 7
    assert all(not s.startswith("s1/") for b in batches for s in b["sample_id"])  # replacements are good rows


def test_undecodable_image_names_shard_and_sample(tmp_path):
    def rows_fn(shard, j):
        row = row_dict(shard, j, 2, 3, (10, 14), gap=3)
        if j == 1:
            row["image"][3] = row["image"][3][:40]  # truncated JPEG inside a shard whose checksum is right
        return row

    ds = write_triples(tmp_path / "ds", [3], rows_fn=rows_fn)
    with pytest.raises(
        SeeUError, match=r"shard-00000\.arrow sample s0/interp/1 view 3.*(does not decode|failed to decode)"
    ):
        list(loader(ds, tmp_path, batch_size=1, shuffle=False))


def test_sha256_verified_once_per_file_version(dataset, tmp_path, monkeypatch):
    calls = []
    real = source_mod.sha256_file
    monkeypatch.setattr(source_mod, "sha256_file", lambda p: calls.append(p) or real(p))
    monkeypatch.setattr(source_mod, "_VERIFIED", set())
    cfg = LoaderConfig(batch_size=7, image_hw=HW, cache_dir=str(tmp_path / "c"))
    list(iter(TripleStream(dataset, cfg)))
    assert len(calls) == 3
    monkeypatch.setattr(source_mod, "_VERIFIED", set())  # a new process: the stamp in the cache is used
    list(iter(TripleStream(dataset, cfg)))
    assert len(calls) == 3
    shard = dataset / "shard-00002.arrow"
    st = shard.stat()
    os.utime(shard, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000))  # the file may have changed: hash again
    monkeypatch.setattr(source_mod, "_VERIFIED", set())
    list(iter(TripleStream(dataset, cfg)))
    assert [Path(p).name for p in calls[3:]] == ["shard-00002.arrow"]


def test_rank_and_world_size_from_the_environment(dataset, tmp_path, monkeypatch):
    got = []
    for r in range(3):
        monkeypatch.setenv("RANK", str(r))
        monkeypatch.setenv("WORLD_SIZE", "3")
        ld = loader(dataset, tmp_path, batch_size=2)
        assert (ld.dataset.rank, ld.dataset.world_size) == (r, 3)
        got += ids_of(list(ld))
    assert sorted(got) == sorted(all_sample_ids(ROWS))


# ----------------------------------------------------------------------------------- curriculum


def test_gap_curriculum_in_the_loader(tmp_path):
    gaps = lambda k, j: 2 + (3 * j + k) % 9  # 2 .. 10
    ds = write_triples(tmp_path / "ds", [10, 10], gaps=gaps, hw=(6, 6))
    gap_of = {f"s{k}/interp/{j}": gaps(k, j) for k in range(2) for j in range(10)}
    cur = GapCurriculum(initial_gap=3, final_gap=10, warm_up_steps=4)
    ld = loader(ds, tmp_path, batch_size=2, curriculum=cur, num_workers=1, image_hw=(6, 6))
    batches = list(ld)
    for step, b in enumerate(batches):
        for s in b["sample_id"]:
            assert gap_of[s] <= cur.max_gap(step)
    used = ids_of(batches)
    assert len(used) == len(set(used))
    assert len(used) + ld.stats["skipped_curriculum"] == 20
    assert ld.stats["skipped_curriculum"] > 0 and ld.state_dict()["step"] == len(batches)


def test_workers_do_not_deadlock_after_the_parent_used_opencv_threads(dataset, tmp_path):
    # A forked child inherits OpenCV's idle thread pool without its threads; touching the pool there
    # (cv2.setNumThreads in a worker_init_fn) hung forever. The loader forks with OpenCV single-threaded.
    import time

    previous = cv2.getNumThreads()
    cv2.setNumThreads(2)
    try:
        img = np.random.default_rng(0).integers(0, 255, (720, 1280, 3), dtype=np.uint8)
        for _ in range(3):
            cv2.GaussianBlur(cv2.resize(img, (640, 360), interpolation=cv2.INTER_AREA), (5, 5), 0)
        time.sleep(0.3)  # let the pool threads go idle
        ld = make_loader(dataset, 7, num_workers=1, image_hw=HW, cache_dir=str(tmp_path / "c"), timeout=30)
        assert len(list(ld)) == 3
        assert cv2.getNumThreads() == 2  # the caller's setting is restored
    finally:
        cv2.setNumThreads(previous)


@settings(max_examples=80, deadline=None)
@given(
    h=st.integers(6, 160),
    w=st.integers(6, 160),
    oh=st.integers(2, 96),
    ow=st.integers(2, 96),
    seed=st.integers(0, 99),
    interpolation=st.sampled_from(["area", "linear", "cubic", "lanczos"]),
)
def test_span_resize_equals_full_resize_then_crop(h, w, oh, ow, seed, interpolation):
    # resize_cover_crop resizes only the block-aligned span it keeps; the reference resizes the whole frame.
    img = np.random.default_rng(seed).integers(0, 256, (h, w, 3), dtype=np.uint8)
    fast = resize_cover_crop(img, (oh, ow), interpolation)
    (sh, sw), (oy, ox) = cameras.cover_crop_geometry((h, w), (oh, ow))
    flag = {
        "area": cv2.INTER_AREA,
        "linear": cv2.INTER_LINEAR,
        "cubic": cv2.INTER_CUBIC,
        "lanczos": cv2.INTER_LANCZOS4,
    }[interpolation]
    if interpolation == "area" and (sh > h or sw > w):
        flag = cv2.INTER_CUBIC  # enlarging
    full = img if (sh, sw) == (h, w) else cv2.resize(img, (sw, sh), interpolation=flag)
    full = full[oy : oy + oh, ox : ox + ow]
    assert fast.shape == full.shape == (oh, ow, 3) and fast.flags.c_contiguous
    diff = np.abs(fast.astype(int) - full)
    if interpolation in ("area", "cubic"):
        assert diff.max() == 0
    else:  # fixed-point weights may round differently: by one grey level, in a few % of the values at most
        assert diff.max() <= 1 and (diff > 0).mean() < 0.1  # (6 % of a 2x39 lanczos crop of a 152x6 frame)


def test_reads_what_seeu_build_writes(tmp_path):
    # The writer's own output (`seeu build`, resized at build time) streams with the cameras it stored.
    from pipelines.cli import main as cli_main
    from seeu_data.build.triples import TripleShards
    from seeu_data.store.posed import PosedDatasetWriter
    from tests.helpers import make_posed_scene

    posed = tmp_path / "posed"
    with PosedDatasetWriter(posed, params={}, provenance={}) as w:
        for i, (sid, n) in enumerate({"a": 20, "b": 26}.items()):
            w.add(make_posed_scene(sid, n=n, height=24, width=32, seed=i))
    out = tmp_path / "triples"
    assert (
        cli_main(
            ["build", str(posed), "--out", str(out), "--gap-min", "4", "--gap-max", "8", "--samples-per-scene", "3"]
        )
        == 0
    )
    rows = {r.sample_id: r for r in TripleShards(out, verify=True).rows()}
    batches = list(make_loader(out, 2, image_hw=(24, 32), cache_dir=str(tmp_path / "c"), num_workers=1))
    assert sorted(ids_of(batches)) == sorted(rows)
    for b in batches:
        for i, sid in enumerate(b["sample_id"]):
            r = rows[sid]
            c2w = torch.cat([b["context"]["cam_to_world"][i], b["target"]["cam_to_world"][i]]).numpy()
            assert np.allclose(c2w, r.cam_to_world, atol=1e-6)
            k = torch.cat([b["context"]["intrinsics"][i], b["target"]["intrinsics"][i]]).numpy()
            assert np.allclose(k, cameras.intrinsics_norm_matrix(r.intrinsics_norm), atol=1e-6)  # same size: unchanged
            img = b["context"]["image"][i, 0].numpy().astype(np.float64)
            want = cv2.cvtColor(cv2.imdecode(np.frombuffer(r.images[0], np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
            assert np.abs(img - want.transpose(2, 0, 1)).max() < 0.01
            assert b["target"]["frame_index"][i].tolist() == r.target


def test_one_row_type_written_and_read_back_by_both_readers(dataset):
    """`TripleRow.to_pydict` wrote the fixture rows; `TripleShards` and the loader's `ShardReader`
    give every row back as the same `TripleRow`, equal to the row written."""
    from seeu_data.build.triples import TripleShards
    from seeu_data.loader.shard_reader import ShardReader
    from seeu_data.store.triple_row import TripleRow

    shards = TripleShards(dataset)
    read = list(shards.iter_rows())
    assert [r.sample_id for r in read] == all_sample_ids(ROWS)
    k = 0
    for s, n in enumerate(ROWS):
        reader = ShardReader(dataset / shards.files[s], shards.files[s], expected_rows=n)
        for j in range(n):
            written = row_dict(s, j, 2, 3, (10, 14), 5 + (j % 3))
            for row in (read[k], reader.sample(j)):
                assert isinstance(row, TripleRow) and row.to_pydict() == written  # values exact in float32
                assert row.context == written["frame_index"][:2] and row.target == written["frame_index"][2:]
                assert row.images == written["image"] and row.intrinsics_norm.shape == (5, 4)
                assert row.cam_to_world.shape == (5, 4, 4) and row.near.dtype == np.float32
            k += 1
