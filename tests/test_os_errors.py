"""One error path for operating-system failures: a full disk, a read-only file
system, permission denied, an existing file given as --out. Each command answers with one line
`seeu CMD: error: PATH: <what> (errno text)`, exit status 2, and leaves no temporary file and no
complete-looking output.

The tests run as root on CI machines, where file modes do not stop writes, and no test may mount
a small file system: the failures are injected where bytes reach the disk (the IPC writer's file writes go to /dev/full,
`Path.write_bytes` fails half-way, as a full disk makes them fail) or where a directory is
created; the rest of each command runs for real.
"""

from __future__ import annotations

import errno
import io
import os
from pathlib import Path

import pytest

from pipelines.cli import main as cli_main
from pipelines.cli import os_error_line
from seeu_data.store import arrow_io


def _one_line(capsys) -> str:
    err = capsys.readouterr().err.strip()
    lines = [ln for ln in err.splitlines() if ln.startswith("seeu ")]
    assert len(lines) == 1 and "internal error" not in err and "Traceback" not in err, err
    return lines[0]


def _leftovers(root: Path) -> list[str]:
    """Temporary or complete-looking files left under `root`."""
    return sorted(
        str(p.relative_to(root))
        for p in root.rglob("*")
        if p.name.endswith((".tmp", ".pending")) or p.name in ("manifest.json", "train_summary.json")
    )


def _fail_writes(monkeypatch, code: int) -> None:
    """Every write of file data fails with OSError(code), as `write(2)` fails on a full disk (the
    error names no file: the writer must say which): the IPC writer's file is created, then its
    writes go to /dev/full (the kernel's ENOSPC; other codes re-raised as `code`), and
    `Path.write_bytes` writes half of its bytes."""
    real_open, real_write_bytes = open, Path.write_bytes

    class Failing(io.FileIO):
        def write(self, data):
            try:
                return super().write(data)
            except OSError as exc:
                raise OSError(code, os.strerror(code)) from exc

    def open_for_arrow_io(path, mode="r", *args, **kwargs):
        if "w" not in mode:
            return real_open(path, mode, *args, **kwargs)
        real_open(path, mode).close()  # the temporary file exists, as on a full disk
        return io.BufferedWriter(Failing("/dev/full", "wb"))

    def write_bytes(self, data):
        real_write_bytes(self, bytes(data)[: len(data) // 2])
        raise OSError(code, os.strerror(code))

    monkeypatch.setattr(arrow_io, "open", open_for_arrow_io, raising=False)
    monkeypatch.setattr(Path, "write_bytes", write_bytes)


def _argv(command: str, ws: dict, out: Path) -> list[str]:
    return {
        "ingest": ["ingest", str(ws["clip"]), "--out", str(out), "--threads", "1"],
        "build": ["build", str(ws["posed"]), "--out", str(out), "--gap-min", "3", "--gap-max", "5", "--workers", "1"],
        "import": ["import", "nerfstudio", str(ws["transforms"]), "--out", str(out)],
        "train": [
            "train",
            "--data",
            str(ws["triples"]),
            "--config",
            "configs/cpu_tiny.json",
            "--out",
            str(out),
            "--max-steps",
            "1",
            "checkpoint.every=1",
        ],
    }[command]


COMMANDS = ["ingest", "build", "import", "train"]


@pytest.mark.parametrize("command", COMMANDS)
def test_out_an_existing_file(tmp_path, capsys, workspace, command):
    out = tmp_path / "taken"
    out.write_text("not a directory")
    assert cli_main(_argv(command, workspace, out)) == 2
    line = _one_line(capsys)
    assert line.startswith(f"seeu {command}: error: {out}: is a file, a directory is needed here ("), line
    assert out.read_text() == "not a directory"


@pytest.mark.parametrize("command", COMMANDS)
def test_disk_full(tmp_path, capsys, monkeypatch, workspace, command):
    _fail_writes(monkeypatch, errno.ENOSPC)
    out = tmp_path / "out"
    assert cli_main(_argv(command, workspace, out)) == 2
    line = _one_line(capsys)
    assert f"seeu {command}: error: {out}" in line, line
    assert line.endswith(": cannot write: no space left on the device (No space left on device)"), line
    assert _leftovers(tmp_path) == []


@pytest.mark.parametrize("command", COMMANDS)
def test_read_only_file_system(tmp_path, capsys, monkeypatch, workspace, command):
    _fail_writes(monkeypatch, errno.EROFS)
    out = tmp_path / "out"
    assert cli_main(_argv(command, workspace, out)) == 2
    assert _one_line(capsys).endswith(": cannot write: the file system is read-only (Read-only file system)")
    assert _leftovers(tmp_path) == []


@pytest.mark.parametrize("command", COMMANDS)
def test_permission_denied_creating_the_output(tmp_path, capsys, monkeypatch, workspace, command):
    real_mkdir = os.mkdir
    locked = tmp_path / "locked"

    def mkdir(path, *a, **kw):
        if Path(path).is_relative_to(locked):
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(path))
        return real_mkdir(path, *a, **kw)

    monkeypatch.setattr(os, "mkdir", mkdir)
    assert cli_main(_argv(command, workspace, locked / "out")) == 2
    line = _one_line(capsys)
    assert line.startswith(f"seeu {command}: error: {locked}") and line.endswith(
        ": permission denied (Permission denied)"
    )
    assert not locked.exists()


def test_os_error_line_forms(tmp_path):
    (tmp_path / "f").write_text("")
    assert (
        os_error_line(NotADirectoryError(errno.ENOTDIR, "Not a directory", str(tmp_path / "f" / "x" / "y")))
        == f"{tmp_path / 'f'}: is a file, a directory is needed here (Not a directory)"
    )
    assert (
        os_error_line(OSError(errno.ENOSPC, "No space left on device"))
        == "cannot write: no space left on the device (No space left on device)"
    )
    assert (
        os_error_line(OSError(errno.EXDEV, "Invalid cross-device link", "a"))
        == "a: operating-system error (Invalid cross-device link)"
    )
