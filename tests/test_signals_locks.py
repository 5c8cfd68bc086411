"""One writer per output directory (`seeu_data/store/out_lock.py`) and interrupted commands (SIGTERM /
SIGINT end the child processes: `seeu_data/interrupts.py`), with real processes; entries of an image
folder that cannot be read as images are skipped and named."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import pytest

from pipelines.cli import main as cli_main
from seeu_data.synthetic import write_clip

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT), "SEEU_HEARTBEAT_S": "0"}
# holds the lock of argv[1] until its stdin closes (or it is killed)
HOLD = (
    "import sys\nfrom seeu_data.store.out_lock import out_lock\n"
    "with out_lock(sys.argv[1]):\n    print('held', flush=True)\n    sys.stdin.read()\n"
)

pytestmark = pytest.mark.usefixtures("no_heartbeat")


def _holder(directory: Path) -> subprocess.Popen:
    proc = subprocess.Popen(
        [sys.executable, "-c", HOLD, str(directory)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
        env=ENV,
        cwd=ROOT,
    )
    assert proc.stdout is not None and proc.stdout.readline().strip() == "held"
    return proc


def _refusals(ws: dict[str, Path], out: Path) -> dict[str, list[str]]:
    """A command of each kind writing into `out`."""
    return {
        "build": ["build", str(ws["posed"]), "--out", str(out), "--samples-per-scene", "2", "--gap-min", "3"],
        "export": ["export", "nerfstudio", str(ws["posed"]), "--out", str(out)],
        "import": ["import", "nerfstudio", str(ws["transforms"].parent), "--out", str(out)],
        "ingest": ["ingest", str(ws["clip"]), "--out", str(out)],
        "synth": ["synth", "--out", str(out), "--frames", "2", "--size", "24x32"],
    }


def test_a_second_writer_is_refused_naming_the_holder(workspace, tmp_path, capsys):
    """While another process holds OUT, every writing command refuses it with one line naming the
    holder's pid (exit 2) and writes nothing; afterwards the build runs, validates, leaves no .lock."""
    out = tmp_path / "out"
    holder = _holder(out)
    try:
        for name, argv in _refusals(workspace, out).items():
            assert cli_main(argv) == 2, name
            err = capsys.readouterr().err.strip()
            assert err.count("\n") == 0 and f"pid {holder.pid}" in err and err.startswith(f"seeu {name}: error: "), err
        assert sorted(p.name for p in out.iterdir()) == [".lock"]
    finally:
        assert holder.stdin is not None
        holder.stdin.close()
        holder.wait(timeout=30)
    assert not out.exists()  # made for the lock, nothing written: removed again
    build = _refusals(workspace, out)["build"]
    assert cli_main(build) == 0
    assert cli_main(["validate", str(out)]) == 0
    assert not (out / ".lock").exists()


def test_a_lock_left_by_a_dead_process_is_taken_over(workspace, tmp_path, capsys):
    """A holder killed outright leaves OUT/.lock with its pid; the kernel released the lock, so the
    next build takes it over (the stale pid text is no obstacle), and its output validates."""
    out = tmp_path / "shards"
    holder = _holder(out)
    holder.kill()
    holder.wait(timeout=30)
    assert (out / ".lock").read_text().strip() == str(holder.pid)  # left behind
    assert cli_main(_refusals(workspace, out)["build"]) == 0
    assert cli_main(["validate", str(out)]) == 0
    assert not (out / ".lock").exists()


# ---------------------------------------------------------------------------------------- signals


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    """20 frames of the synthetic corridor as JPEGs, a FIFO and an unreadable file with image names."""
    root = tmp_path_factory.mktemp("signals")
    write_clip(root / "walk.mp4", n_frames=20, size=(136, 240), seed=0)
    images = root / "walk"
    images.mkdir()
    cap = cv2.VideoCapture(str(root / "walk.mp4"))
    i = 0
    while True:
        ok, bgr = cap.read()
        if not ok:
            break
        cv2.imwrite(str(images / f"f{i:03d}.jpg"), bgr)
        i += 1
    cap.release()
    assert i == 20
    os.mkfifo(images / "pipe.jpg")
    if os.geteuid() == 0:  # root reads any file: a link to nothing cannot be read either
        (images / "locked.jpg").symlink_to(root / "nothing")
    else:
        (images / "locked.jpg").write_bytes((images / "f000.jpg").read_bytes())
        (images / "locked.jpg").chmod(0)
    return images


def _ingest_argv(folder: Path, out: Path) -> list[str]:
    return ["ingest", str(folder), "--out", str(out), "--threads", "1", "--no-sfm-check", "--no-progress"]


def _sfm_child(parent: int, timeout: float = 120.0, marker: bytes = b"seeu_data.ingest.sfm") -> int:
    """The pid of `parent`'s SfM child process (`python -m seeu_data.ingest.sfm_child`; with `marker`
    b"seeu_data.ingest.mapping": the SfM child's mapping process), once it exists."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for d in Path("/proc").iterdir():
            if not d.name.isdigit():
                continue
            try:
                ppid = int((d / "stat").read_text().rsplit(")", 1)[1].split()[1])
                cmd = (d / "cmdline").read_bytes()
            except (OSError, IndexError, ValueError):
                continue
            if ppid == parent and marker in cmd:
                return int(d.name)
        time.sleep(0.01)
    raise AssertionError("no SfM child appeared")


def _alive(pid: int) -> bool:
    """Whether `pid` runs (a zombie left to a parent that does not reap it has ended)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return False


def _interrupt(folder: Path, out: Path, sig: signal.Signals, at_mapping: bool = False) -> tuple[int, str, int]:
    """Start `seeu ingest`, send `sig` once its SfM child runs (`at_mapping`: the moment the SfM child
    starts its mapping process, which then must end with ingest, not when it notices, seconds later);
    (exit status, stderr, the child's pid)."""
    if not Path("/proc/self/stat").exists():
        pytest.skip("needs Linux /proc")
    proc = subprocess.Popen(
        [sys.executable, "-m", "pipelines.cli", *_ingest_argv(folder, out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=ENV,
        cwd=ROOT,
    )
    try:
        child = _sfm_child(proc.pid)
        mapping = _sfm_child(child, marker=b"seeu_data.ingest.mapping") if at_mapping else None
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=60)
        assert mapping is None or not _alive(mapping), "the mapping process outlived seeu ingest"
    finally:
        proc.kill()
    deadline = time.monotonic() + 1.0
    while Path(f"/proc/{child}").exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not Path(f"/proc/{child}").exists(), "the SfM child outlived seeu ingest"
    return proc.returncode, err, child


def test_sigterm_ends_the_sfm_child_and_a_rerun_resumes(folder, tmp_path, capsys):
    """SIGTERM while SfM starts mapping: exit 143 with one line, the SfM child and its mapping process
    are gone when ingest exits, no lock is held; the same
    command right after completes, naming the two image-named entries it skipped (summary, report)."""
    out = tmp_path / "posed"
    rc, err, _ = _interrupt(folder, out, signal.SIGTERM, at_mapping=True)
    assert rc == 143, err
    assert err.strip().splitlines() == ["seeu ingest: interrupted (SIGTERM); re-run the same command to resume"]
    assert not (out / ".lock").exists()
    assert cli_main(_ingest_argv(folder, out)) == 0
    summary = capsys.readouterr().out
    assert "skipped: 2 (locked.jpg: " in summary and "pipe.jpg: a FIFO" in summary, summary
    report = json.loads((out / "walk" / "report.json").read_text())
    assert [f["name"] for f in report["skipped_files"]] == ["locked.jpg", "pipe.jpg"]
    assert report["frames_selected"] == 20


def test_sigint_ends_the_sfm_child(folder, tmp_path):
    rc, err, _ = _interrupt(folder, tmp_path / "posed", signal.SIGINT)
    assert rc == 130, err
    assert err.strip().splitlines() == ["seeu ingest: interrupted (SIGINT); re-run the same command to resume"]


def _sleep(seconds: float) -> float:
    time.sleep(seconds)
    return seconds


def test_end_pool_ends_every_worker_at_once():
    """`end_pool` (what build and ingest call when interrupted) leaves no worker behind, also while
    the workers are busy and more tasks wait; a worker that ignores SIGTERM is killed."""
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    from seeu_data.interrupts import end_pool

    pool = ProcessPoolExecutor(
        max_workers=2,
        mp_context=mp.get_context("fork"),
        initializer=signal.signal,
        initargs=(signal.SIGTERM, signal.SIG_IGN),
    )
    futures = [pool.submit(_sleep, 30) for _ in range(4)]
    while sum(f.running() for f in futures) < 2:
        time.sleep(0.05)
    pids = [p.pid for p in mp.active_children()]
    assert len(pids) == 2
    end_pool(pool, grace_s=1.0)
    # the executor's own thread may be reaping a worker as end_pool returns (seen once in ~10 runs): allow
    # it a moment, far below the 30 s the workers would have slept
    deadline = time.monotonic() + 2.0
    while any(Path(f"/proc/{pid}").exists() for pid in pids) and time.monotonic() < deadline:
        time.sleep(0.05)
    for pid in pids:
        assert not Path(f"/proc/{pid}").exists(), f"worker {pid} outlived end_pool"
    assert not any(f.running() for f in futures[2:])


_SIGTERM_WHERE_PYTHON_CANNOT_RAISE = """
import os, signal, time
from seeu_data.interrupts import sigterm_raises, terminated

class SignalledWhileCollected:
    def __del__(self):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(1)  # the handler runs here, inside __del__: Python reports the exception and goes on

class FailsWhileCollected:
    def __del__(self):
        raise ValueError("another error")

with sigterm_raises():
    SignalledWhileCollected()
    FailsWhileCollected()
print(terminated())
"""


def test_a_sigterm_python_cannot_raise_is_recorded_without_a_report():
    """A SIGTERM that lands where Python ignores exceptions (a `__del__`, a fork's callback such as
    logging's lock release, seen in CI as "Exception ignored in: <function _releaseLock>") prints no
    report: it is recorded, and `seeu` ends with its one line. Other ignored errors are still reported."""
    proc = subprocess.run(
        [sys.executable, "-c", _SIGTERM_WHERE_PYTHON_CANNOT_RAISE], capture_output=True, text=True, timeout=60
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "True"
    assert "Terminated" not in proc.stderr
    assert "ValueError: another error" in proc.stderr


_ORPHAN = """
import multiprocessing as mp, os, sys, time
sys.path.insert(0, {root!r})
from seeu_data.interrupts import end_with_parent

def child(end):
    null = os.open(os.devnull, os.O_WRONLY)
    os.dup2(null, 1)  # not the caller's pipe: run() returns when the parent exits
    os.dup2(null, 2)
    if end:
        end_with_parent()
    time.sleep(60)

p = mp.get_context("fork").Process(target=child, args=({end},))
p.start()
time.sleep(0.5)
print(p.pid, flush=True)
os._exit(0)  # the parent ends without ending its child
"""


def _alive(pid: int) -> bool:
    """Whether process `pid` runs (a zombie, which nobody may reap in a container, does not)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0] != "Z"
    except FileNotFoundError:
        return False


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")
def test_a_child_that_ends_with_its_parent_never_outlives_it():
    """`interrupts.end_with_parent` (pool workers, matching workers, mapping runs): a forked child that called it is
    killed when its parent exits without ending it; one that did not outlives it (and would keep a caller reading
    the command's stderr waiting: a SIGTERM'd `seeu build` once did, for 120 s)."""
    root = str(Path(__file__).resolve().parents[1])
    for end in (True, False):
        out = subprocess.run([sys.executable, "-c", _ORPHAN.format(root=root, end=end)], capture_output=True, text=True)
        pid = int(out.stdout.split()[0])
        deadline = time.monotonic() + (10 if end else 1)  # long enough to see it die, short where it must not
        while _alive(pid) and time.monotonic() < deadline:
            time.sleep(0.05)
        try:
            assert _alive(pid) is (not end)
        finally:
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)
