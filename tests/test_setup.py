"""The README's set-up: what `make test` installs before the tests (scripts/system-deps.sh, run here
through make with chromium absent: PATH holds only fakes that record their calls), and the repository
rules that keep every module committed and linted (no source folder ignored, ruff sees every module)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SOURCE_DIRS = ("seeu_data", "seeu_model", "pipelines", "tests")


def fake_path(tmp_path: Path, uid: int, sudo: bool = False, chromium: bool = False) -> tuple[dict, Path]:
    """(environment, log): PATH is one folder holding bash (the script's interpreter) and fakes of `id`
    (prints `uid`), `apt-get`, optionally `sudo` (passwordless) and `chromium`; each fake appends its
    command line to the log."""
    bin_dir, log = tmp_path / "bin", tmp_path / "calls.log"
    bin_dir.mkdir()
    bash = shutil.which("bash")
    assert bash is not None
    (bin_dir / "bash").symlink_to(bash)
    fakes = {"id": f"echo {uid}", "apt-get": f'echo "apt-get $*" >> {log}'}
    if sudo:
        fakes["sudo"] = f'echo "sudo $*" >> {log}\nif [ "$1" = -n ]; then exit 0; fi\nexec "$@"'  # -n: no password
    if chromium:
        fakes["chromium"] = f'echo "chromium $*" >> {log}'
    for name, body in fakes.items():
        (bin_dir / name).write_text(f"#!/bin/sh\n{body}\n")
        (bin_dir / name).chmod(0o755)
    return {"PATH": str(bin_dir), "HOME": str(tmp_path)}, log


def make(target: str, env: dict) -> subprocess.CompletedProcess:
    make_exe = shutil.which("make")
    assert make_exe is not None, "make is missing (the README's set-up commands are make targets)"
    return subprocess.run(
        [make_exe, "--no-print-directory", "-C", str(ROOT), target],
        env=env,
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
        timeout=60,
    )


def calls(log: Path) -> list[str]:
    return log.read_text().splitlines() if log.exists() else []


def test_make_test_installs_chromium_as_root(tmp_path):
    env, log = fake_path(tmp_path, uid=0)
    done = make("system-deps", env)
    assert done.returncode == 0, done.stderr
    assert calls(log) == ["apt-get update -q", "apt-get install -y -q chromium"]


def test_make_test_installs_chromium_through_sudo(tmp_path):
    env, log = fake_path(tmp_path, uid=1000, sudo=True)
    done = make("system-deps", env)
    assert done.returncode == 0, done.stderr
    assert calls(log) == [
        "sudo -n true",
        "sudo apt-get update -q",
        "apt-get update -q",
        "sudo apt-get install -y -q chromium",
        "apt-get install -y -q chromium",
    ]


def test_make_test_without_root_stops_first_with_the_command(tmp_path):
    """No root, no sudo: `make test` itself stops before anything else (no venv, no lint) with one
    line of ours naming the command, then make's own error line."""
    env, log = fake_path(tmp_path, uid=1000)
    done = make("test", env)
    assert done.returncode != 0 and done.stdout == "", done.stdout
    ours, *rest = done.stderr.splitlines()
    assert ours.startswith("make test: chromium is missing") and "'sudo apt-get install -y chromium'" in ours
    assert len(rest) == 1 and "system-deps" in rest[0], done.stderr  # make's "*** [Makefile:N: system-deps] Error 1"
    assert calls(log) == []


def test_make_test_with_chromium_installs_nothing(tmp_path):
    env, log = fake_path(tmp_path, uid=0, chromium=True)
    done = make("system-deps", env)
    assert (done.returncode, done.stdout, done.stderr) == (0, "", "")
    assert calls(log) == []


def git(*args: str, check: bool = True) -> subprocess.CompletedProcess:
    return subprocess.run(["git", "-C", str(ROOT), *args], capture_output=True, text=True, check=check)


@pytest.fixture(scope="module")
def tracked() -> list[str]:
    if shutil.which("git") is None or git("rev-parse", "--git-dir", check=False).returncode != 0:
        pytest.skip("not a git checkout")
    return git("ls-files").stdout.splitlines()


def test_no_source_folder_is_ignored(tracked):
    """Neither a tracked file nor a new module in any folder of the source trees is matched by an
    ignore rule (an unanchored `build/` once hid seeu_data/build/ from git and from ruff)."""
    files = [f for f in tracked if f.startswith(tuple(d + "/" for d in SOURCE_DIRS))]
    folders = sorted({str(Path(f).parent) for f in files})
    assert "seeu_data/build" in folders
    paths = files + [f"{d}/new_module.py" for d in folders]
    done = subprocess.run(
        ["git", "-C", str(ROOT), "check-ignore", "--no-index", "--verbose", "--stdin"],
        input="\n".join(paths),
        capture_output=True,
        text=True,
    )
    assert done.returncode == 1, f"ignored:\n{done.stdout}{done.stderr}"  # 1: none of them is ignored


def test_ruff_sees_every_module(tracked):
    """`ruff check` (which honours .gitignore) lists every tracked .py file but the fixtures' generator
    scripts, which pyproject excludes."""
    assert 'extend-exclude = ["tests/fixtures"]' in (ROOT / "pyproject.toml").read_text()
    wanted = {f for f in tracked if f.endswith(".py") and not f.startswith("tests/fixtures/")}
    listed = subprocess.run(
        [sys.executable, "-m", "ruff", "check", "--show-files", "."],
        cwd=ROOT,
        capture_output=True,
        text=True,
        env={**os.environ, "NO_COLOR": "1"},
        check=True,
    ).stdout.split()
    seen = {str(Path(p).resolve().relative_to(ROOT)) for p in listed if p.endswith(".py")}
    assert "seeu_data/build/__init__.py" in wanted
    assert not wanted - seen, f"ruff does not check: {sorted(wanted - seen)}"
