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
from seeu_data.arrow_io import atomic_write_text, commit_pending, fsync_enabled, fsync_policy, sha256_file, write_table
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
    return pa.table(
        {"a": np.arange(n), "b": [bytes([i % 251]) * ((3 << 20) if i % 1000 == 7 else i % 50) for i in range(n)]}
    )


def test_default_is_atomic_without_fsync(tmp_path, fsyncs):
    assert not fsync_enabled()
    size, digest = write_table(tmp_path / "x.arrow", _table(), max_chunksize=100)
    atomic_write_text(tmp_path / "m.json", "{}")
    write_table(tmp_path / "p.arrow", _table(), commit=False)
    commit_pending(tmp_path / "p.arrow")
    assert fsyncs == []
    assert digest == sha256_file(tmp_path / "x.arrow") and size == (tmp_path / "x.arrow").stat().st_size
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.json", "p.arrow", "x.arrow"]  # no temporary left


def test_fsync_policy_fsyncs_every_file_before_its_rename(tmp_path, fsyncs):
    with fsync_policy(True):
        assert fsync_enabled() and os.environ["SEEU_FSYNC"] == "1"
        size, digest = write_table(tmp_path / "x.arrow", _table(), max_chunksize=100)
        atomic_write_text(tmp_path / "m.json", "{}")
        write_table(tmp_path / "p.arrow", _table(), commit=False)  # pending: fsynced at commit
        assert len(fsyncs) == 2
        commit_pending(tmp_path / "p.arrow")
    assert len(fsyncs) == 3 and not fsync_enabled() and "SEEU_FSYNC" not in os.environ
    assert digest == sha256_file(tmp_path / "x.arrow")
    with fsync_policy(None):  # unchanged
        assert not fsync_enabled()


def test_env_var_turns_fsync_on():
    code = "import seeu_data.arrow_io as a; print(a.fsync_enabled())"
    env = dict(os.environ, SEEU_FSYNC="1", PYTHONPATH=os.getcwd())
    assert (
        subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True).stdout.strip() == "True"
    )
    env["SEEU_FSYNC"] = "0"
    assert (
        subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True).stdout.strip() == "False"
    )


def test_failed_write_leaves_nothing(tmp_path):
    writer = arrow_io.AtomicIpcWriter(tmp_path / "x.arrow", _table().schema)
    writer.write_table(_table())
    writer.abort()
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("block", [10_007, 1 << 20])
def test_hash_in_ranges_of_the_written_file(tmp_path, monkeypatch, block):
    """The hasher takes the file in ranges at any (unaligned) offsets: the digest is the file's."""
    monkeypatch.setattr(arrow_io, "_HASH_BLOCK", block)
    size, digest = write_table(tmp_path / "x.arrow", _table(), max_chunksize=77)
    assert (size, digest) == ((tmp_path / "x.arrow").stat().st_size, sha256_file(tmp_path / "x.arrow"))


def test_hash_reads_back_where_files_cannot_be_mapped(tmp_path, monkeypatch):
    def no_mmap(*args, **kwargs):
        raise OSError(19, "No such device")

    monkeypatch.setattr(arrow_io, "_HASH_BLOCK", 100_003)
    monkeypatch.setattr(arrow_io.mmap, "mmap", no_mmap)
    size, digest = write_table(tmp_path / "x.arrow", _table(), max_chunksize=500)
    assert digest == sha256_file(tmp_path / "x.arrow")


def test_a_failed_hash_is_an_error_and_leaves_no_file(tmp_path, monkeypatch):
    def fail(*args, **kwargs):
        raise OSError(5, "Input/output error")

    monkeypatch.setattr(arrow_io.mmap, "mmap", fail)
    real_open = open

    class FailingReads:
        def __init__(self, fh):
            self.fileno, self.seek, self.close = fh.fileno, fh.seek, fh.close

        def read(self, n):
            raise OSError(5, "Input/output error")

    def open_failing_reads(path, mode="r", **kwargs):
        fh = real_open(path, mode, **kwargs)
        return FailingReads(fh) if mode == "rb" else fh

    monkeypatch.setattr(arrow_io, "open", open_failing_reads, raising=False)
    with pytest.raises(arrow_io.SeeUError, match="could not hash .*Input/output error"):
        write_table(tmp_path / "x.arrow", _table())
    assert list(tmp_path.iterdir()) == []


def test_build_and_import_fsync_flag(tmp_path, fsyncs):
    posed = tmp_path / "posed"
    with PosedDatasetWriter(posed, params={}, provenance={}, target_file_bytes=30_000) as w:
        for i in range(3):
            w.add(make_posed_scene(f"s{i}", n=30, height=24, width=32, seed=i))
    assert fsyncs == []
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
def test_deferred_binary_writes_the_bytes_pyarrow_writes(tmp_path, max_chunksize):
    """A deferred column (pieces: numpy views into a mapped file, bytes, memoryviews, empty values;
    as a plain and as a list<binary> column, cut into batches at any row) gives exactly the file
    pyarrow writes for the same values copied into one buffer, and the sha256 of that file."""
    rng = np.random.default_rng(1)
    blob = rng.integers(0, 256, 3 << 20, dtype=np.uint8)
    (tmp_path / "src.bin").write_bytes(blob.tobytes())
    mapped = np.frombuffer(arrow_io.map_readonly(tmp_path / "src.bin", populate=True), dtype=np.uint8)
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
        return pa.table(
            {
                "flat": images.slice(0, n_rows),
                "views": pa.ListArray.from_arrays(offsets, images),
                "i": np.arange(n_rows),
            }
        )

    expected = _plain_ipc_bytes(table(pa.array(values, pa.binary())), max_chunksize)
    size, digest = write_table(
        tmp_path / "d.arrow", table(arrow_io.deferred_binary(pieces)), max_chunksize=max_chunksize
    )
    assert (tmp_path / "d.arrow").read_bytes() == expected
    assert (size, digest) == (len(expected), hashlib.sha256(expected).hexdigest())
    assert pa.ipc.open_file(str(tmp_path / "d.arrow")).read_all().column("views").to_pylist() == [
        values[i : i + 3] for i in range(0, 3 * n_rows, 3)
    ]


def test_deferred_binary_placeholders_are_released_and_short_writes_resume(tmp_path, monkeypatch):
    import gc

    arr = arrow_io.deferred_binary([b"abc", b"", b"defgh"])
    base = arr.buffers()[2].address
    # the finalizer of a dead placeholder that had the same address never drops a live one
    arrow_io._forget_placeholder(base)
    assert [bytes(v) for v in arrow_io._deferred_pieces(base, 8)] == [b"abc", b"defgh"]
    real = os.writev
    monkeypatch.setattr(os, "writev", lambda fd, views: real(fd, [bytes(memoryview(views[0]))[:2]]))  # 2 bytes a call
    size, digest = write_table(tmp_path / "s.arrow", pa.table({"x": arr}))
    monkeypatch.undo()
    plain = _plain_ipc_bytes(pa.table({"x": pa.array([b"abc", b"", b"defgh"])}), 10_000)
    assert (tmp_path / "s.arrow").read_bytes() == plain and digest == hashlib.sha256(plain).hexdigest()
    del arr
    gc.collect()
    assert not arrow_io._PLACEHOLDERS
    assert arrow_io._deferred_pieces(12345, 10) is None


def test_reading_a_deferred_column_outside_the_writer_faults():
    """A deferred column read anywhere but the writer's sink must fail loudly, never give zeros."""
    code = "from seeu_data.arrow_io import deferred_binary\nprint(deferred_binary([b'abc', b'de']).to_pylist())\n"
    res = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=dict(os.environ, PYTHONPATH=os.getcwd())
    )
    assert res.returncode != 0 and "abc" not in res.stdout and "\\x00" not in res.stdout
