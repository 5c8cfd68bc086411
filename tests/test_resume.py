"""seeu_data.store.resume: the journal of completed units, stamps, stage reuse and the stale-file sweep."""

from __future__ import annotations

import hashlib
import json
import shutil

import pytest

from seeu_data.store.resume import Journal, StageCache, claim_dir, file_intact, files_fingerprint, stamp_of, sweep


def test_journal_keeps_complete_lines_and_ignores_a_torn_last_one(tmp_path):
    j = Journal(tmp_path / "j.jsonl")
    assert j.read() == []
    j.add({"unit": "a", "stamp": "1"})
    j.add({"unit": "b", "stamp": "2", "n": 3})
    with open(j.path, "a") as fh:  # an interruption mid-write
        fh.write('{"unit": "c", "sta')
    assert j.read() == [{"unit": "a", "stamp": "1"}, {"unit": "b", "stamp": "2", "n": 3}]
    j.reset([{"unit": "z"}])
    assert j.path.read_text() == '{"unit": "z"}\n' and not list(tmp_path.glob(".*"))
    j.path.write_text('{"unit": "a"}\n[1, 2]\n{"unit": "b"}\n')  # not a record: the rest is not trusted
    assert j.read() == [{"unit": "a"}]
    j.remove()
    assert not j.path.exists() and j.read() == []


def test_stamp_is_canonical_and_files_fingerprint_sees_edits(tmp_path):
    assert stamp_of({"a": 1, "b": [1, 2]}) == stamp_of({"b": [1, 2], "a": 1})
    assert stamp_of({"a": 1}) == hashlib.sha256(b'{"a": 1}').hexdigest()
    assert stamp_of({"a": 1}) != stamp_of({"a": 2})
    f = tmp_path / "x"
    f.write_bytes(b"abc")
    fp = files_fingerprint([f])
    assert files_fingerprint([f]) == fp
    f.write_bytes(b"abcd")
    assert files_fingerprint([f]) != fp
    assert file_intact(f, 4, hashlib.sha256(b"abcd").hexdigest())
    assert not file_intact(f, 4, hashlib.sha256(b"abce").hexdigest()) and not file_intact(f, 3, "")
    assert not file_intact(tmp_path / "missing", 0, "")


def test_sweep_removes_unclaimed_outputs_and_partial_writes(tmp_path):
    for name in ("shard-00000.arrow", "shard-00001.arrow", "shard-00002.arrow", "other.arrow"):
        (tmp_path / name).write_bytes(b"x")
    for name in (".shard-00001.arrow.123.tmp", ".shard-00003.arrow.pending", ".keep-me"):
        (tmp_path / name).write_bytes(b"x")
    assert sweep(tmp_path, "shard-*.arrow", keep={"shard-00001.arrow"}) == ["shard-00000.arrow", "shard-00002.arrow"]
    assert sorted(p.name for p in tmp_path.iterdir()) == [".keep-me", "other.arrow", "shard-00001.arrow"]
    assert sweep(tmp_path / "absent", "*.ply", keep=()) == []


def test_stage_cache_reuses_redoes_and_forgets_before_redoing(tmp_path):
    calls: list[str] = []

    def stage(name, value):
        def fn():
            calls.append(name)
            (d / "out.txt").write_text(str(value))
            return {"value": value, "path": str(d / "out.txt")}

        d = tmp_path / "work" / name
        return fn, d

    cache = StageCache(tmp_path / "work")
    fn, d = stage("a", 1)
    d.mkdir(parents=True)
    (d / "leftover").write_text("old")
    assert cache.run("a", {"k": 1}, fn, d) == ({"value": 1, "path": str(d / "out.txt")}, False)
    assert not (d / "leftover").exists()  # the stage's directory is emptied before it runs
    fn_b, d_b = stage("b", 2)
    cache.run("b", {"a": cache.stamp("a")}, fn_b, d_b)
    # a second run reuses both, from the journal alone
    again = StageCache(tmp_path / "work")
    assert again.run("a", {"k": 1}, fn, d)[1] and again.run("b", {"a": again.stamp("a")}, fn_b, d_b)[1]
    assert calls == ["a", "b"] and again.reused == {"a": True, "b": True}
    assert again.records["a"]["seconds"] == cache.records["a"]["seconds"]  # the time when it ran
    # another setting redoes the stage and, through its stamp, the one that reads it
    again = StageCache(tmp_path / "work")
    fn2, _ = stage("a", 5)
    assert again.run("a", {"k": 2}, fn2, d) == ({"value": 5, "path": str(d / "out.txt")}, False)
    assert not again.run("b", {"a": again.stamp("a")}, fn_b, d_b)[1]
    # a missing output (or a missing stage directory) redoes it; force redoes everything
    (d / "out.txt").unlink()
    again = StageCache(tmp_path / "work")
    assert not again.run("a", {"k": 2}, fn2, d, outputs=lambda r: [r["path"]])[1]
    assert again.run("a", {"k": 2}, fn2, d, outputs=lambda r: [r["path"]])[1]
    shutil.rmtree(d_b)
    assert not again.run("b", {"a": again.stamp("a")}, fn_b, d_b)[1]
    assert not StageCache(tmp_path / "work", force=True).run("a", {"k": 2}, fn2, d)[1]
    units = [json.loads(line)["unit"] for line in (tmp_path / "work" / "stages.jsonl").read_text().splitlines()]
    assert sorted(units) == ["a", "b"]  # one record per stage

    # interrupted while redoing: the old record is gone, so the half-made stage is never reused
    def boom():
        (d / "out.txt").write_text("half")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        StageCache(tmp_path / "work").run("a", {"k": 3}, boom, d)
    calls.clear()
    assert not StageCache(tmp_path / "work").run("a", {"k": 2}, fn2, d)[1] and calls == ["a"]

    # a stage failing with an OSError leaves no directory behind
    def full():
        (d / "big").write_bytes(b"x")
        raise OSError(28, "No space left on device")

    with pytest.raises(OSError):
        StageCache(tmp_path / "work").run("c", {}, full, d)
    assert not d.exists()


def test_claim_dir_keeps_partial_work_of_the_same_stamp_only(tmp_path):
    d = tmp_path / "run"
    assert claim_dir(d, "s1") is False and d.is_dir()
    (d / "ckpt").write_text("step 5")
    assert claim_dir(d, "s1") is True and (d / "ckpt").exists()
    assert claim_dir(d, "s1", force=True) is False and not (d / "ckpt").exists()
    (d / "ckpt").write_text("step 5")
    assert claim_dir(d, "s2") is False and not (d / "ckpt").exists()
    assert claim_dir(d, "s2") is True


def test_file_intact_trusts_size_and_mtime_and_hashes_with_verify(tmp_path, monkeypatch):
    import os

    from seeu_data.store import resume

    path = tmp_path / "f.arrow"
    path.write_bytes(b"x" * 1000)
    size, sha, mtime = 1000, hashlib.sha256(b"x" * 1000).hexdigest(), resume.file_stat(path)
    hashed = []
    real = resume.sha256_file
    monkeypatch.setattr(resume, "sha256_file", lambda p: hashed.append(p) or real(p))
    assert resume.file_intact(path, size, sha, mtime) and hashed == []  # size + mtime: nothing read
    assert resume.file_intact(path, size, sha, mtime, verify=True) and hashed == [path]
    assert resume.file_intact(path, size, sha) and len(hashed) == 2  # no recorded mtime: hashed
    assert not resume.file_intact(path, size + 1, sha, mtime) and len(hashed) == 2
    # torn by a power loss that kept size and mtime: only verify sees it
    path.write_bytes(b"x" * 500 + b"\0" * 500)
    os.utime(path, ns=(mtime, mtime))
    assert resume.file_intact(path, size, sha, mtime)
    assert not resume.file_intact(path, size, sha, mtime, verify=True)
    # rewritten (a new mtime): hashed, and the new bytes fail
    os.utime(path, ns=(mtime, mtime + 1))
    assert not resume.file_intact(path, size, sha, mtime)
    assert not resume.file_intact(tmp_path / "missing", size, sha, mtime)
