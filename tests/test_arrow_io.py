"""Output durability policy (seeu_data.arrow_io): atomic writes always, fsync only when asked for
(`set_fsync` / `fsync_policy`, `--fsync` on import/build, SEEU_FSYNC=1); the sha256 recorded while
writing equals the file's."""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys

import numpy as np
import pyarrow as pa
import pytest

from pipelines.cli import main as cli_main
from seeu_data import arrow_io
from seeu_data.arrow_io import atomic_write_text, binary_array, fsync_enabled, fsync_policy, sha256_file, write_table
from seeu_data.posed import PosedDatasetWriter
from tests.helpers import make_posed_scene


@pytest.fixture
def fsyncs(monkeypatch):
    """Count os.fsync calls (the real call still runs)."""
    calls = []
    real = os.fsync

    def counting(fd):
        calls.append(fd)
        return real(fd)

    monkeypatch.setattr(os, "fsync", counting)
    return calls


def _table(n=3000):
    return pa.table({"a": np.arange(n), "b": [bytes([i % 251]) * ((3 << 20) if i % 1000 == 7 else i % 50) for i in range(n)]})


def test_default_is_atomic_without_fsync(tmp_path, fsyncs):
    assert not fsync_enabled()
    size, digest = write_table(tmp_path / "x.arrow", _table(), max_chunksize=100)
    atomic_write_text(tmp_path / "m.json", "{}")
    assert fsyncs == []
    assert digest == sha256_file(tmp_path / "x.arrow") and size == (tmp_path / "x.arrow").stat().st_size
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.json", "x.arrow"]  # no temporary left


def test_fsync_policy_fsyncs_every_file_before_its_rename(tmp_path, fsyncs):
    with fsync_policy(True):
        assert fsync_enabled() and os.environ["SEEU_FSYNC"] == "1"
        size, digest = write_table(tmp_path / "x.arrow", _table(), max_chunksize=100)
        atomic_write_text(tmp_path / "m.json", "{}")
    assert len(fsyncs) == 2 and not fsync_enabled() and "SEEU_FSYNC" not in os.environ
    assert digest == sha256_file(tmp_path / "x.arrow")
    with fsync_policy(None):  # unchanged
        assert not fsync_enabled()


def test_env_var_turns_fsync_on():
    code = "import seeu_data.arrow_io as a; print(a.fsync_enabled())"
    env = dict(os.environ, SEEU_FSYNC="1", PYTHONPATH=os.getcwd())
    assert subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True).stdout.strip() == "True"
    env["SEEU_FSYNC"] = "0"
    assert subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True).stdout.strip() == "False"


def test_failed_write_leaves_nothing(tmp_path):
    writer = arrow_io.AtomicIpcWriter(tmp_path / "x.arrow", _table().schema)
    writer.write_table(_table())
    writer.abort()
    assert list(tmp_path.iterdir()) == []


def test_a_failed_write_is_an_error_and_leaves_no_file(tmp_path, monkeypatch):
    """A write that fails half-way (a full disk) raises and leaves neither the file nor its temporary."""
    import errno

    real_write = arrow_io._HashingSink.write
    written = []

    def write_then_fail(self, data):
        if written:
            raise OSError(errno.ENOSPC, "No space left on device")
        written.append(len(memoryview(data)))
        return real_write(self, data)

    monkeypatch.setattr(arrow_io._HashingSink, "write", write_then_fail)
    with pytest.raises(OSError, match="No space left"):
        write_table(tmp_path / "x.arrow", _table(), max_chunksize=100)
    assert list(tmp_path.iterdir()) == []


def test_build_and_import_fsync_flag(tmp_path, fsyncs):
    posed = tmp_path / "posed"
    with PosedDatasetWriter(posed, params={}, provenance={}, target_file_bytes=30_000) as w:
        for i in range(3):
            w.add(make_posed_scene(f"s{i}", n=30, height=24, width=32, seed=i))
    assert fsyncs == []
    cmd = ["build", str(posed), "--gap-min", "10", "--gap-max", "20", "--samples-per-scene", "3",
           "--shard-size", "20kB", "--workers", "1"]
    assert cli_main([*cmd, "--out", str(tmp_path / "a")]) == 0
    assert fsyncs == []
    assert cli_main([*cmd, "--out", str(tmp_path / "b"), "--fsync"]) == 0
    shards = len(list((tmp_path / "b").glob("shard-*.arrow")))
    assert shards > 1 and len(fsyncs) == shards + 2  # every shard, the progress journal, the manifest
    assert not fsync_enabled()
    assert sorted(os.listdir(tmp_path / "a")) == sorted(os.listdir(tmp_path / "b"))
    for name in os.listdir(tmp_path / "a"):
        if name.endswith(".arrow"):
            assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()


def _plain_ipc_bytes(table: pa.Table, max_chunksize: int) -> bytes:
    sink = pa.BufferOutputStream()
    with pa.ipc.new_file(sink, table.schema, options=pa.ipc.IpcWriteOptions(compression=None)) as w:
        w.write_table(table, max_chunksize=max_chunksize)
    return sink.getvalue().to_pybytes()


@pytest.mark.parametrize("max_chunksize", [1, 7, 64, 10_000])
def test_written_file_and_its_hash_are_pyarrows(tmp_path, max_chunksize):
    """`binary_array` over mixed bytes-likes (numpy views into a mapped file, bytes, memoryviews,
    empty values), as a plain and a list<binary> column cut into batches at any row: the file is
    exactly what pyarrow's own writer gives for the same values, and the recorded (bytes, sha256)
    are those of that file (hashlib over the whole independent copy)."""
    import mmap

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
    values = [bytes(memoryview(p)) for p in pieces]
    offsets = pa.array(np.arange(0, len(pieces) + 1, 3)[: len(pieces) // 3 + 1].astype(np.int32))
    n_rows = len(offsets) - 1

    def table(images):
        return pa.table({"flat": images.slice(0, n_rows), "views": pa.ListArray.from_arrays(offsets, images),
                         "i": np.arange(n_rows)})

    expected = _plain_ipc_bytes(table(pa.array(values, pa.binary())), max_chunksize)
    size, digest = write_table(tmp_path / "d.arrow", table(binary_array(pieces)), max_chunksize=max_chunksize)
    assert (tmp_path / "d.arrow").read_bytes() == expected
    assert (size, digest) == (len(expected), hashlib.sha256(expected).hexdigest())
    assert pa.ipc.open_file(str(tmp_path / "d.arrow")).read_all().column("views").to_pylist() == \
        [values[i:i + 3] for i in range(0, 3 * n_rows, 3)]
