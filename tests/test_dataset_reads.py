"""What the checks of a posed data set read: headers, not images.

`seeu validate --no-sha`, `seeu build`'s scan and plan of its inputs and `seeu index` over a 300 MB posed
file must read each image's header, not its bytes, and hold one file's columns at a time. Measured in
a child process from the kernel's own counters, each step starting with the file out of the page cache
(fsync, `POSIX_FADV_DONTNEED`): the bytes of the file in the page cache after the step (`mincore`: what
was read from the disk, the kernel's read-ahead included, through the memory map or read() alike),
the bytes read with read() calls (`rchar`) and the growth of the peak resident set (`VmHWM`, reset just
before the step). A first pass of the same steps loads every module, so the counters see the steps alone.
(A plain `pyarrow.memory_map` of this file reads 118 MB of it on `read_all()` alone: read-ahead.)
"""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from seeu_data.store.posed import PosedDatasetWriter, PosedScene

ROOT = Path(__file__).resolve().parents[1]
SIDE = 1000  # the size each fake JPEG's header declares
IMAGE_BYTES = 2 << 20
SCENES, FRAMES = 15, 10  # 150 images: 300 MB

CHILD = r"""
import json, sys
from pathlib import Path

import pyarrow.compute  # noqa: F401  (imports and their files read before the counters start)

from pipelines.build import BuildConfig, plan_sampled, scan_inputs, shard_specs
from pipelines.index import IndexFileConfig, write_index
from seeu_data.build.eval_index import IndexConfig
from seeu_data.build.sampling import SamplingConfig
from seeu_data.store.dataset_check import check_dataset
from tests.helpers import evict, page_cache_bytes


def counters():
    io = dict(line.split(": ") for line in Path("/proc/self/io").read_text().splitlines())
    status = dict(line.split(":", 1) for line in Path("/proc/self/status").read_text().splitlines())
    return int(io["rchar"]), int(status["VmRSS"].split()[0]) << 10, int(status["VmHWM"].split()[0]) << 10


def measure(step):
    evicted = evict(data)
    Path("/proc/self/clear_refs").write_text("5")  # VmHWM := VmRSS
    rchar0, rss0, _ = counters()
    step()
    rchar1, _, hwm = counters()
    return {"evicted": evicted, "disk": page_cache_bytes(data), "read": rchar1 - rchar0, "peak_growth": hwm - rss0}


posed, out = sys.argv[1], Path(sys.argv[2])
data = next(Path(posed).glob("posed-*.arrow"))


def build_reads():
    cfg = BuildConfig(inputs=(posed,), out=out / "shards", sampling=SamplingConfig(gap_min=2, gap_max=4))
    scenes = scan_inputs(cfg.inputs)
    specs = list(shard_specs(cfg, plan_sampled(cfg, scenes), scenes))
    assert sum(len(s.samples) for s in specs) > 0


def index_reads():
    gen = IndexConfig(SamplingConfig(gap_min=2, gap_max=4))
    write_index(IndexFileConfig(inputs=(posed,), out=out / "index.json", generation=gen))


steps = {"validate": lambda: check_dataset(posed, check_sha=False), "build": build_reads, "index": index_reads}
for step in steps.values():  # modules loaded, caches filled
    step()
print(json.dumps({name: measure(step) for name, step in steps.items()}))
"""


def fake_jpeg(nbytes: int, side: int) -> bytes:
    """SOI, a baseline frame header declaring `side` x `side`, filler, EOI: what the header check reads."""
    sof = b"\xff\xc0" + struct.pack(">HBHHB", 17, 8, side, side, 3) + bytes([1, 0x22, 0, 2, 0x11, 1, 3, 0x11, 1])
    return b"\xff\xd8" + sof + b"\x00" * (nbytes - len(sof) - 4) + b"\xff\xd9"


@pytest.mark.skipif(not Path("/proc/self/clear_refs").exists(), reason="needs Linux /proc counters")
def test_validate_build_and_index_read_headers_not_images(tmp_path):
    image = fake_jpeg(IMAGE_BYTES, SIDE)
    posed = tmp_path / "posed"
    with PosedDatasetWriter(posed, params={}, provenance={}, target_file_bytes=1 << 40) as writer:
        for s in range(SCENES):
            c2w = np.tile(np.eye(4), (FRAMES, 1, 1))
            c2w[:, 0, 3] = 0.1 * np.arange(FRAMES)
            writer.add(
                PosedScene(
                    scene_id=f"s{s:02d}",
                    images=[image] * FRAMES,
                    image_format="jpeg",
                    width=np.full(FRAMES, SIDE),
                    height=np.full(FRAMES, SIDE),
                    intrinsics_norm=np.tile([0.9, 0.9, 0.5, 0.5], (FRAMES, 1)),
                    cam_to_world=c2w,
                    near=0.5,
                    far=10.0,
                    source_frame=np.arange(FRAMES, dtype=np.int64),
                    timestamp_us=np.arange(FRAMES, dtype=np.int64),
                )
            )
    files = list(posed.glob("posed-*.arrow"))
    size = sum(p.stat().st_size for p in files)
    assert len(files) == 1 and size > 300e6
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    res = subprocess.run(
        [sys.executable, "-c", CHILD, str(posed), str(tmp_path)], capture_output=True, text=True, env=env, cwd=ROOT
    )
    assert res.returncode == 0, res.stderr[-2000:]
    result = json.loads(res.stdout.strip().splitlines()[-1])
    if not result["validate"]["evicted"]:
        pytest.skip("this file system keeps the file in the page cache (tmpfs?): nothing to measure reads by")
    for step, got in result.items():
        assert got["disk"] < 0.01 * size and got["read"] < 0.01 * size, (step, got)
        assert got["peak_growth"] < 0.05 * size, (step, got)


def test_a_rerun_with_nothing_to_do_reads_no_file_content(tmp_path, capsys):
    """`seeu import` and `seeu build` run again on unchanged inputs decide from sizes, mtimes and the
    recorded digests: no page of a chunk, posed file or shard is read (page cache emptied before,
    looked at after); with --verify they hash what they keep, which the same counter sees."""
    from pipelines.cli import main as cli_main
    from tests.helpers import evict, page_cache_bytes
    from tests.test_import_pixelsplat import make_example, write_chunks

    rng = np.random.default_rng(5)
    chunks = write_chunks(
        tmp_path / "ds", "train", [[make_example(f"c{c}s{i}", 5, rng) for i in range(2)] for c in range(3)]
    )
    posed, shards = tmp_path / "posed", tmp_path / "shards"
    imp = ["import", "pixelsplat", str(tmp_path / "ds"), "--out", str(posed)]
    bld = ["build", str(posed), "--out", str(shards), "--gap-min", "1", "--gap-max", "3", "--shard-size", "30kB"]
    assert cli_main(imp) == 0 and cli_main(bld) == 0
    outputs = sorted(posed.glob("posed-*.arrow")) + sorted(shards.glob("shard-*.arrow"))
    data = sorted(chunks.glob("*.torch")) + outputs
    assert len(outputs) >= 3
    if not all([evict(p) for p in data]):
        pytest.skip("this file system keeps files in the page cache (tmpfs?): nothing to measure reads by")
    capsys.readouterr()
    assert cli_main(imp) == 0 and cli_main(bld) == 0
    said = capsys.readouterr().out
    assert (
        "(6 scenes in 1 files kept from a previous run)" in said and "kept from a previous run" in said.splitlines()[1]
    )
    assert {str(p): page_cache_bytes(p) for p in data} == {str(p): 0 for p in data}
    assert cli_main(imp + ["--verify"]) == 0 and cli_main(bld + ["--verify"]) == 0
    assert all(page_cache_bytes(p) > 0 for p in outputs)
    assert all(page_cache_bytes(p) == 0 for p in chunks.glob("*.torch"))  # kept: not read again


def test_a_pass_over_the_scenes_opens_each_file_once_and_stays_small(tmp_path, monkeypatch):
    """`PosedDataset` (build's and index's reads) opens each posed file once for a pass in manifest order
    and reads a scene's own record batch (assembling the whole file's table for every scene made `seeu
    build` of 5,000 tiny scenes quadratic: 343 s, against 16 s now). The pages a read touched are given
    back before the next (`ReleasableIpcFile.release`): the map of a file read through stays about one
    scene resident, where the kernel's fault-around alone maps most of it (measured below)."""
    from dataclasses import replace

    import seeu_data.store.posed as posed_mod
    from seeu_data.store.arrow_io import ReleasableIpcFile
    from seeu_data.synthetic import synthetic_posed_scene

    one = synthetic_posed_scene(6, 48, 64)
    root = tmp_path / "posed"
    with PosedDatasetWriter(root, params={}, provenance={}, target_file_bytes=2 << 20) as writer:
        for i in range(300):
            writer.add(replace(one, scene_id=f"s{i:03d}"))
    opened, whole = [], []

    class Reader:  # the reader, with read_all counted
        def __init__(self, reader):
            self._reader = reader

        def read_all(self):
            whole.append(1)
            return self._reader.read_all()

        def __getattr__(self, name):
            return getattr(self._reader, name)

    class Counted(ReleasableIpcFile):
        def __init__(self, path):
            super().__init__(path)
            opened.append(path)
            self.reader = Reader(self.reader)

    monkeypatch.setattr(posed_mod, "ReleasableIpcFile", Counted)
    ds = posed_mod.PosedDataset(root)
    files = {ds.scene_info(sid)["file"] for sid in ds.scene_ids}
    assert len(files) >= 3
    cameras = {sid: ds.load_cameras(sid) for sid in ds.scene_ids}
    assert len(opened) == len(files) and not whole, (len(opened), len(whole), files)

    def resident_file_kb() -> int:
        status = Path("/proc/self/status").read_text()
        return int(status.split("RssFile:")[1].split()[0])

    size_kb = max((root / f).stat().st_size for f in files) >> 10  # one file is mapped at a time

    def grown_in_a_pass() -> int:
        """KB of posed file pages resident after reading every scene (the files are in the page cache)."""
        reader, before = posed_mod.PosedDataset(root), resident_file_kb()
        for sid in reader.scene_ids:
            scene = reader.load_scene(sid)
            c2w, intr, near, far = cameras[sid]
            assert np.array_equal(c2w, scene.cam_to_world) and np.array_equal(intr, scene.intrinsics_norm), sid
            assert (near, far) == (scene.near, scene.far), sid
        return resident_file_kb() - before

    kept = grown_in_a_pass()
    monkeypatch.setattr(Counted, "release", lambda self: None)
    assert grown_in_a_pass() > size_kb / 2 > 8 * kept, (kept, size_kb)  # without the releases: most of the file


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs Linux /proc counters")
def test_a_loader_epoch_stays_flat_in_memory(tmp_path, monkeypatch):
    """A loader epoch's resident size stays flat. Each batch's image tensors are freed into holes of the
    heap; a shard reader that decoded a record batch's columns when its rows were first read, keeping views
    into the batch (so the batch itself), pinned the holes (an epoch over 20,000 tiny scenes grew about
    1 MB a batch, to 1.7 GB). It makes every batch's column views when it opens the shard; here the same
    epoch both ways. And what a reader holds grows little with its rows: about 115 bytes a row at the
    default 64 rows a batch (its small columns decoded into copies took 1.35 kB a row)."""
    import tracemalloc
    from dataclasses import replace

    from pipelines.cli import main as cli_main
    from seeu_data.loader import make_loader
    from seeu_data.loader.shard_reader import ShardReader
    from seeu_data.synthetic import synthetic_posed_scene

    one = synthetic_posed_scene(24, 36, 64)
    with PosedDatasetWriter(tmp_path / "posed", params={}, provenance={}) as writer:
        for i in range(120):
            writer.add(replace(one, scene_id=f"s{i:03d}"))
    build = ["build", str(tmp_path / "posed"), "--out", str(tmp_path / "shards"), "--gap-min", "2", "--gap-max", "6"]
    # one row a record batch: as many decoded column sets as samples, the pinning at its worst
    assert cli_main(build + ["--samples-per-scene", "30", "--rows-per-batch", "1", "--no-progress"]) == 0

    def growth_mb() -> int:
        def anon() -> int:
            return int(Path("/proc/self/status").read_text().split("RssAnon:")[1].split()[0]) >> 10

        batches = iter(make_loader(tmp_path / "shards", 8, image_hw=(128, 128)))
        next(batches)
        before = anon()
        assert sum(1 for _ in batches) > 400
        return anon() - before

    flat = growth_mb()
    # the old reader: a batch's columns made as its rows are first read, each holding its record batch, and
    # the curriculum's gaps read from the file
    monkeypatch.setattr(ShardReader, "_decode_all", lambda self: None)
    columns = ShardReader._columns
    held: list = []

    def holding(self, b):
        if b not in self._batches:
            held.append(self._reader.get_batch(b))
        return columns(self, b)

    monkeypatch.setattr(ShardReader, "_columns", holding)
    monkeypatch.setattr(
        ShardReader,
        "gaps",
        lambda self: np.concatenate([self._reader.get_batch(b)["gap"] for b in range(len(self.batch_starts) - 1)]),
    )
    grown = growth_mb()
    assert flat < 60 and grown > 100, (flat, grown)

    # what readers hold, at build's default rows a batch
    monkeypatch.undo()
    wide = ["build", str(tmp_path / "posed"), "--out", str(tmp_path / "wide"), "--gap-min", "2", "--gap-max", "6"]
    assert cli_main(wide + ["--samples-per-scene", "30", "--no-progress"]) == 0
    tracemalloc.start()
    readers = [ShardReader(path, path.name) for path in sorted((tmp_path / "wide").glob("*.arrow"))]
    traced, _ = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    rows = sum(r.num_rows for r in readers)
    assert rows == 3600 and traced / rows < 300, traced / rows  # 115 B; copies: 1,350 B
