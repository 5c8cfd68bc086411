"""The wheel works outside the checkout: build it, install it into a fresh virtualenv in a temporary
directory, and run the CLI from there (schemas and presets must come from the installed package).

The fresh virtualenv gets the wheel only (`--no-deps`); its third-party dependencies (torch, pyarrow,
pycolmap, ...) come from the test's own environment through a `.pth` line, so the test needs no
network and no second multi-GB install. The editable install of the checkout is not visible there:
the test asserts that `seeu_data` is imported from the fresh virtualenv.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.slow


def _run(cmd: list[str], cwd: Path, timeout: float = 600) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    res = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert res.returncode == 0, (
        f"{' '.join(map(str, cmd))} -> {res.returncode}\n{res.stdout[-2000:]}\n{res.stderr[-2000:]}"
    )
    return res


@pytest.fixture(scope="module")
def wheel_venv(tmp_path_factory) -> Path:
    tmp = tmp_path_factory.mktemp("wheel")
    _run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "--quiet",
            "--no-deps",
            "--no-build-isolation",
            "--wheel-dir",
            str(tmp / "dist"),
            str(ROOT),
        ],
        cwd=tmp,
    )
    (wheel,) = (tmp / "dist").glob("seeu-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    for required in (
        "seeu_data/schemas/triples.v1.json",
        "seeu_data/schemas/manifest.v1.json",
        "seeu_model/presets/re10k_paper.json",
        "seeu_model/presets/demo.json",
    ):
        assert required in names, f"{required} missing from {wheel.name}"
    assert not any(n.startswith(("tests/", "benchmarks/")) for n in names)

    venv = tmp / "venv"
    _run([sys.executable, "-m", "venv", str(venv)], cwd=tmp)
    _run(
        [str(venv / "bin" / "python"), "-m", "pip", "install", "--quiet", "--no-deps", "--no-index", str(wheel)],
        cwd=tmp,
    )
    site = Path(
        subprocess.check_output(
            [str(venv / "bin" / "python"), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], text=True
        ).strip()
    )
    # Dependencies from this environment, after the fresh venv's own site-packages on sys.path.
    (site / "zz_test_dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    return venv


def test_installed_wheel_runs_outside_the_checkout(wheel_venv: Path, tmp_path: Path) -> None:
    py, seeu = str(wheel_venv / "bin" / "python"), str(wheel_venv / "bin" / "seeu")
    where = _run(
        [py, "-c", "import seeu_data, seeu_model; print(seeu_data.__file__); print(seeu_model.__file__)"], cwd=tmp_path
    ).stdout
    assert all(line.startswith(str(wheel_venv)) for line in where.split()), where

    assert "ingest" in _run([seeu, "--help"], cwd=tmp_path).stdout
    version = _run([seeu, "--version"], cwd=tmp_path).stdout.split()[-1]
    assert (
        version
        == _run([py, "-c", "import importlib.metadata as m; print(m.version('seeu'))"], cwd=tmp_path).stdout.strip()
    )

    # A preset by name, read from the installed package.
    preset = _run(
        [
            py,
            "-c",
            "from seeu_model.training.config import load_config; c = load_config('re10k_paper');"
            " print(c.name, c.data.image_size)",
        ],
        cwd=tmp_path,
    ).stdout
    assert preset.split()[0] == json.loads((ROOT / "configs" / "re10k_paper.json").read_text())["name"]

    # synth -> ingest -> validate: the schemas come from the wheel.
    _run([seeu, "synth", "--out", "synth", "--frames", "20", "--size", "136x240", "--seed", "0"], cwd=tmp_path)
    _run([seeu, "ingest", "synth/clip.mp4", "--out", "posed"], cwd=tmp_path)
    out = _run([seeu, "validate", "posed/clip"], cwd=tmp_path)
    assert "error" not in (out.stdout + out.stderr).lower()
