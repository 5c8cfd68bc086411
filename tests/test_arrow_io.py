"""Writes of seeu_data.store.arrow_io: atomic always, fsynced before the rename only when a writer is told
to (`fsync=True`, what `--fsync` on ingest/import/build passes down); the sha256 recorded while
writing equals the file's; the files are the bytes pyarrow writes."""

from __future__ import annotations

import hashlib
import mmap
import os
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

from pipelines.build import PROGRESS_NAME
from pipelines.cli import main as cli_main
from seeu_data.store import arrow_io
from seeu_data.store.arrow_io import AtomicIpcWriter, atomic_write_text, sha256_file, write_table
from seeu_data.store.posed import PosedDatasetWriter
from tests.helpers import make_posed_scene


def _fsynced(calls) -> list:
    return [c for c in calls if c[0] == "fsync"]


def _table(n=3000):
    return pa.table(
        {"a": np.arange(n), "b": [bytes([i % 251]) * ((3 << 20) if i % 1000 == 7 else i % 50) for i in range(n)]}
    )


def test_default_is_atomic_without_fsync(tmp_path, fsyncs):
    size, digest = write_table(tmp_path / "x.arrow", _table(), max_chunksize=100)
    atomic_write_text(tmp_path / "m.json", "{}")
    assert _fsynced(fsyncs) == [] and len(fsyncs) == 2
    assert digest == sha256_file(tmp_path / "x.arrow") and size == (tmp_path / "x.arrow").stat().st_size
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.json", "x.arrow"]  # no temporary left


def test_fsync_parameter_fsyncs_each_file_before_its_rename(tmp_path, fsyncs):
    size, digest = write_table(tmp_path / "x.arrow", _table(), max_chunksize=100, fsync=True)
    atomic_write_text(tmp_path / "m.json", "{}", fsync=True)
    write_table(tmp_path / "y.arrow", _table(), fsync=False)  # a parameter of each write, no state left behind
    kinds = [kind for kind, _ in fsyncs]
    assert kinds == ["fsync", "replace", "fsync", "replace", "replace"]
    if os.path.exists("/proc/self/fd"):  # the file fsynced is the one renamed next
        assert fsyncs[0][1] == fsyncs[1][1] and fsyncs[2][1] == fsyncs[3][1]
    assert digest == sha256_file(tmp_path / "x.arrow") and size == (tmp_path / "x.arrow").stat().st_size


def test_failed_write_leaves_nothing(tmp_path):
    writer = arrow_io.AtomicIpcWriter(tmp_path / "x.arrow", _table().schema)
    writer.write(_table())
    writer.abort()
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(KeyboardInterrupt), AtomicIpcWriter(tmp_path / "y.arrow", _table().schema) as w:
        w.write(_table())
        raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []


def test_build_fsync_flag(tmp_path, fsyncs):
    posed = tmp_path / "posed"
    with PosedDatasetWriter(posed, params={}, provenance={}, target_file_bytes=30_000) as w:
        for i in range(3):
            w.add(make_posed_scene(f"s{i}", n=30, height=24, width=32, seed=i))
    assert _fsynced(fsyncs) == []
    cmd = [
        "build",
        str(posed),
        "--gap-min",
        "10",
        "--gap-max",
        "20",
        "--samples-per-scene",
        "3",
        "--shard-size",
        "20kB",
        "--workers",
        "1",
    ]
    assert cli_main([*cmd, "--out", str(tmp_path / "a")]) == 0
    assert _fsynced(fsyncs) == []
    assert cli_main([*cmd, "--out", str(tmp_path / "b"), "--fsync"]) == 0
    shards = sorted((tmp_path / "b").glob("shard-*.arrow"))
    fsynced = [Path(f).name for _, f in _fsynced(fsyncs)]
    # every shard and the manifest before its rename; the progress journal's records as written
    renamed = [f for f in fsynced if PROGRESS_NAME not in f]  # the journal: reset (renamed), then appended
    assert len(shards) > 1 and len(renamed) == len(shards) + 1 and PROGRESS_NAME in fsynced, fsynced
    if os.path.exists("/proc/self/fd"):
        assert {f.split(".")[1] for f in renamed} == {"manifest"} | {p.stem for p in shards}
    assert sorted(os.listdir(tmp_path / "a")) == sorted(os.listdir(tmp_path / "b"))
    for name in os.listdir(tmp_path / "a"):
        if name.endswith(".arrow"):
            assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()


def _plain_ipc_bytes(table: pa.Table, max_chunksize: int) -> bytes:
    sink = pa.BufferOutputStream()
    with pa.ipc.new_file(sink, table.schema, options=pa.ipc.IpcWriteOptions(compression=None)) as w:
        w.write_table(table, max_chunksize=max_chunksize)
    return sink.getvalue().to_pybytes()


@pytest.mark.parametrize("max_chunksize", [7, 10_000])
def test_views_write_the_bytes_pyarrow_writes(tmp_path, max_chunksize):
    """A column of views (numpy views into a mapped file, bytes, memoryviews, empty values; as a plain
    and as a list<binary> column, cut into batches) made by `binary_array` and written by
    `AtomicIpcWriter` gives exactly the file pyarrow writes for the same values, and its sha256."""
    rng = np.random.default_rng(1)
    blob = rng.integers(0, 256, 3 << 20, dtype=np.uint8)
    (tmp_path / "src.bin").write_bytes(blob.tobytes())
    with open(tmp_path / "src.bin", "rb") as fh:
        mapped = np.frombuffer(mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ), dtype=np.uint8)
    cuts = np.sort(rng.integers(0, blob.size, 600))
    pieces = []
    for i, (a, b) in enumerate(zip(cuts[:-1], cuts[1:])):
        view = mapped[a:b]
        pieces.append([view, view.tobytes(), memoryview(view.tobytes())][i % 3])
    pieces[5] = b""
    pieces = pieces[: len(pieces) // 3 * 3]  # the list column holds every value
    values = [bytes(memoryview(p)) for p in pieces]
    offsets = pa.array(np.arange(0, len(pieces) + 1, 3).astype(np.int32))
    n_rows = len(offsets) - 1

    def table(images):
        return pa.table(
            {
                "flat": images.slice(0, n_rows),
                "views": pa.ListArray.from_arrays(offsets, images),
                "i": np.arange(n_rows),
            }
        )

    expected = _plain_ipc_bytes(table(pa.array(values, pa.binary())), max_chunksize)
    size, digest = write_table(tmp_path / "d.arrow", table(arrow_io.binary_array(pieces)), max_chunksize)
    assert (tmp_path / "d.arrow").read_bytes() == expected
    assert (size, digest) == (len(expected), hashlib.sha256(expected).hexdigest())
    assert pa.ipc.open_file(str(tmp_path / "d.arrow")).read_all().column("views").to_pylist() == [
        values[i : i + 3] for i in range(0, 3 * n_rows, 3)
    ]


def test_posed_files_are_the_bytes_pyarrow_writes_for_the_scenes(tmp_path):
    """The posed writer's files equal pyarrow's own writer's for the same batches, and the manifest's
    sha256 is the file's."""
    from seeu_data.store.manifest import read_manifest
    from seeu_data.store.posed import SCHEMA
    from seeu_data.store.schema import arrow_schema

    scenes = [make_posed_scene(f"s{i}", n=5 + i, height=24, width=32, seed=i) for i in range(3)]
    with PosedDatasetWriter(tmp_path / "p", params={}, provenance={}, target_file_bytes=10_000) as w:
        for scene in scenes:
            w.add(scene)
    files = read_manifest(tmp_path / "p")["files"]
    assert len(files) > 1
    start = 0
    for entry in files:
        n = entry["rows"]
        batches = []
        while n:
            batches.append(scenes[start].to_record_batch())
            n -= len(scenes[start])
            start += 1
        expected = _plain_ipc_bytes(pa.Table.from_batches(batches, arrow_schema(SCHEMA)), max_chunksize=10_000)
        data = (tmp_path / "p" / entry["path"]).read_bytes()
        assert data == expected and entry["sha256"] == hashlib.sha256(data).hexdigest()
