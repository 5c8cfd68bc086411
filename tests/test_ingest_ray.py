"""`seeu ingest --engine ray` on a local Ray instance: the same posed files as the local engine with
--threads 1 (byte for byte), the same one-line failures with the others finished, resume per scene,
and an unreachable cluster refused in one line before anything is written."""

from __future__ import annotations

import contextlib
import io
import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from pipelines.cli import main as cli_main
from pipelines.validate import validate_dataset
from seeu_data.errors import SeeUError
from seeu_data.ray_cluster import check_address
from seeu_data.store.resume import STAGES_JOURNAL, Journal
from seeu_data.synthetic import write_clip

ray = pytest.importorskip("ray")

REPO = Path(__file__).resolve().parent.parent
GOOD = ("c0", "c1", "c4")  # synthetic clips (seeds 0, 1, 4) that register fully at this size
# --threads 1 for both engines (the two compared on equal terms); the rest keeps the clips tiny and fast
COMMON = ["--threads", "1", "--min-chunk-frames", "8"]


@pytest.fixture(scope="module")
def ray_local():
    ray.init(
        num_cpus=2,
        include_dashboard=False,
        logging_level="ERROR",
        log_to_driver=False,
        runtime_env={"env_vars": {"PYTHONPATH": str(REPO)}},
    )
    yield
    ray.shutdown()


@contextlib.contextmanager
def _in(directory: Path):
    """Run with `directory` as the working directory (relative paths, as a user types them)."""
    old = os.getcwd()
    os.chdir(directory)
    try:
        yield
    finally:
        os.chdir(old)


def _ingest(argv: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = cli_main(["ingest", *argv])
    return rc, out.getvalue(), err.getvalue()


@pytest.fixture(scope="module")
def runs(tmp_path_factory, request):
    """videos/: three good clips; bad/: a truncated clip and a 5-frame one. The local engine ingests
    videos/ (two scenes at a time, one COLMAP thread each), then Ray ingests videos/ and bad/
    (relative paths, from the same working directory)."""
    root = tmp_path_factory.mktemp("rayingest")
    for name in GOOD:
        write_clip(root / "videos" / f"{name}.mp4", n_frames=12, size=(136, 240), seed=int(name[1:]), path_length_m=2.5)
    data = (root / "videos" / "c0.mp4").read_bytes()
    (root / "bad").mkdir()
    (root / "bad" / "trunc.mp4").write_bytes(data[: len(data) // 2])
    write_clip(root / "bad" / "short.mp4", n_frames=5, size=(136, 240), seed=0)
    with _in(root), pytest.MonkeyPatch.context() as mp:
        mp.setenv("SEEU_HEARTBEAT_S", "0")  # no status lines on stderr from the local engine
        local = _ingest(["videos", "--out", "local", "--engine", "local", "--workers", "2", *COMMON])
        request.getfixturevalue("ray_local")  # started after the local run: its idle processes take CPU
        remote = _ingest(["videos", "bad", "--out", "ray", "--engine", "ray", *COMMON])
    return {"root": root, "local": local, "ray": remote}


def _posed_files(scene_dir: Path) -> dict[str, bytes]:
    """The data files of a posed dataset: Arrow shards and the SfM points."""
    files = sorted(scene_dir.glob("posed-*.arrow")) + sorted(scene_dir.glob("points3d/*.ply"))
    return {str(p.relative_to(scene_dir)): p.read_bytes() for p in files}


def _without_timings(report):
    """The report without what differs between runs: every duration (keys `*_s`, `seconds`), at any
    depth, and where the output went and what was reused."""
    if isinstance(report, list):
        return [_without_timings(v) for v in report]
    if not isinstance(report, dict):
        return report
    skip = ("output", "reused", "seconds")
    return {k: _without_timings(v) for k, v in report.items() if k not in skip and not k.endswith("_s")}


def _json(path: Path) -> dict:
    return json.loads(path.read_text())


def test_ray_matches_the_local_engine_and_lists_failures(runs):
    root = runs["root"]
    rc_local, out_local, err_local = runs["local"]
    rc, out, err = runs["ray"]
    assert rc_local == 0 and err_local == "", err_local
    # the two bad clips: one line each, the others finished, the count last, exit 2
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 2, err
    assert all(ln.startswith("seeu ingest: error: bad/") for ln in lines), lines
    by_name = {ln.split("bad/")[1].split(":")[0]: ln for ln in lines}
    assert set(by_name) == {"trunc.mp4", "short.mp4"}
    assert "truncated" in by_name["trunc.mp4"] and "only 5 usable frame" in by_name["short.mp4"]
    assert out.strip().splitlines()[-1] == "3/5 scenes ingested into ray"
    assert not (root / "ray" / "trunc" / "manifest.json").exists()
    assert not (root / "ray" / "short" / "manifest.json").exists()
    # every good scene: the same posed bytes, manifest (but its provenance) and report (but timings)
    for name in GOOD:
        local, remote = root / "local" / name, root / "ray" / name
        files = _posed_files(local)
        assert "posed-00000.arrow" in files and f"points3d/{name}_c0.ply" in files
        assert _posed_files(remote) == files, name
        ml, mr = _json(local / "manifest.json"), _json(remote / "manifest.json")
        assert {**ml, "provenance": None} == {**mr, "provenance": None}
        assert ml["params"]["inputs"] == [f"videos/{name}.mp4"]  # recorded as given, on either engine
        rl, rr = _json(local / "report.json"), _json(remote / "report.json")
        assert _without_timings(rl) == _without_timings(rr)
        assert rr["output"] == f"ray/{name}" and rr["registered"] == 12
        validate_dataset(remote)
        assert f"{name}: 12/12 frames registered" in out


def test_ray_rerun_resumes_each_scene(runs):
    """A re-run reuses the stages of complete scenes and redoes what an interrupted one lacks (c1 here,
    stopped during SfM: its journal record and manifest gone); the posed files come out the same."""
    root = runs["root"]
    (root / "ray" / "c1" / "manifest.json").unlink()
    journal = Journal(root / "ray" / ".work" / "c1" / STAGES_JOURNAL)  # as SfM left it when stopped
    journal.reset([r for r in journal.read() if r["unit"] != "sfm"])
    with _in(root):
        rc, out, err = _ingest(["videos", "--out", "ray", "--engine", "ray", *COMMON])
    assert rc == 0 and err == "", err
    assert out.strip().splitlines()[-1] == "3/3 scenes ingested into ray"
    reused = {name: _json(root / "ray" / name / "report.json")["reused"] for name in GOOD}
    assert reused == {
        "c0": {"decode": True, "sfm": True},
        "c1": {"decode": True, "sfm": False},
        "c4": {"decode": True, "sfm": True},
    }
    for name in GOOD:
        assert _posed_files(root / "ray" / name) == _posed_files(root / "local" / name), name


def test_unreachable_address_is_one_line_and_writes_nothing(tmp_path):
    """The real `seeu` process: nothing from Ray on stderr, exit 2, no OUT (timeout: a hang guard only)."""
    (tmp_path / "v.mp4").write_bytes(b"not looked at")
    out = tmp_path / "out"
    proc = subprocess.run(
        [sys.executable, "-m", "pipelines.cli", "ingest", str(tmp_path / "v.mp4"), "--out", str(out)]
        + ["--engine", "ray", "--ray-address", "127.0.0.1:1"],
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": str(REPO)},
        timeout=120,
    )
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.splitlines() == [
        "seeu ingest: error: 127.0.0.1:1: cannot reach the Ray cluster (Connection refused)"
    ]
    assert proc.stdout == "" and not out.exists()


def test_a_port_that_is_not_ray_is_refused_in_bounded_time():
    """Something accepts the connection but never speaks Ray: the join in a child process is cut off.
    (Bound to every interface: Ray turns 127.0.0.1 into the node's own address.)"""
    with socket.socket() as listener:
        listener.bind(("", 0))
        listener.listen()
        address = f"127.0.0.1:{listener.getsockname()[1]}"
        with pytest.raises(SeeUError, match="no Ray cluster answered within 3 s"):
            check_address(address, join_s=3)


@pytest.mark.parametrize(
    "flags, needle",
    [
        (["--engine", "ray", "--workers", "2"], "--workers is for the local engine"),
        (["--ray-address", "auto"], "--ray-address needs --engine ray"),
        (["--engine", "ray", "--map-threads", "-1"], "positive --threads and --map-threads"),
        (["--engine", "ray", "--threads", "0"], "positive --threads and --map-threads"),
    ],
)
def test_engine_flags_checked_before_ray_starts(tmp_path, flags, needle):
    write_clip(tmp_path / "v.mp4", n_frames=3, size=(24, 32), seed=0)
    rc, out, err = _ingest([str(tmp_path / "v.mp4"), "--out", str(tmp_path / "out"), *flags])
    assert rc == 2 and err.count("\n") == 1 and needle in err, err
    assert not (tmp_path / "out").exists()
