"""Prepare what travels with the working tree to a GPU machine that has no package index, for
`benchmarks/gpu_check.py`: `.gpu_carry/site/`, the unpacked wheels of

* gsplat (pure Python plus its CUDA sources: the GPU machine compiles them on first use, with its nvcc
  and ninja) and what it imports (jaxtyping, rich and their needs);
* the packages the check's training path imports beyond what such a machine is known to hold (torch with
  CUDA, torchvision, numpy, pyarrow, timm, OpenCV, lightning, tqdm, ninja): jsonschema (the manifest
  reader) and its needs, tensorboard (the training log) with protobuf and absl-py, lpips, kornia (the rasterizer's
  quaternions) with kornia-rs, plyfile, threadpoolctl (the overlap's BLAS threads).

gpu_check.py appends `.gpu_carry/site` to the END of `sys.path`: a package the GPU machine has is
used as it is, a carried one only fills a gap. A package still missing there makes the steps that need
it report why (e.g. LPIPS left out), not stop the check.

    .venv/bin/python benchmarks/gpu_carry.py                 # here, with the package index
    .venv/bin/python benchmarks/gpu_carry.py --python-version 3.11   # for another Python on the GPU side

Versions: the ones installed here (what the tests ran with), gsplat and its jaxtyping at the pins below.
Binary wheels (rpds-py, protobuf) are fetched for CPython `--python-version` on x86_64 manylinux. The
folder must stay under `--max-mib` (the 64 MiB that travel, less the repository itself).
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import zipfile
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# distribution -> pinned version (None: the version installed here)
CARRY: dict[str, str | None] = {
    "gsplat": "1.5.3",
    "jaxtyping": "0.3.11",
    "wadler-lindig": "0.1.8",
    "rich": None,
    "markdown-it-py": None,
    "mdurl": None,
    "pygments": None,
    "jsonschema": None,
    "jsonschema-specifications": None,
    "referencing": None,
    "rpds-py": None,
    "attrs": None,
    "tensorboard": None,
    "protobuf": None,
    "absl-py": None,
    "lpips": None,
    "kornia": None,
    "kornia-rs": None,
    "plyfile": None,
    "threadpoolctl": None,
}
PRUNE = ("gsplat/cuda/csrc/third_party/glm/doc", "gsplat/cuda/csrc/third_party/glm/test")  # not built (17 MiB)
PLATFORMS = ("manylinux_2_28_x86_64", "manylinux_2_17_x86_64", "manylinux2014_x86_64")


def pinned(name: str, pin: str | None) -> str:
    if pin is not None:
        return f"{name}=={pin}"
    try:
        return f"{name}=={version(name)}"
    except PackageNotFoundError:
        raise SystemExit(
            f"gpu_carry: {name} is not installed here, so its version is unknown: run `make install`"
        ) from None


def download(requirements: list[str], wheels: Path, python_version: str) -> None:
    platforms = [arg for p in PLATFORMS for arg in ("--platform", p)]
    cmd = [sys.executable, "-m", "pip", "download", "--quiet", "--no-deps", "--only-binary=:all:"]
    cmd += ["--python-version", python_version, "--implementation", "cp", *platforms, "-d", str(wheels)]
    subprocess.run(cmd + requirements, check=True)


def folder_mib(path: Path) -> float:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file()) / 2**20


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dest", type=Path, default=ROOT / ".gpu_carry")
    ap.add_argument("--python-version", default="3.12", help="the GPU machine's Python (major.minor)")
    ap.add_argument("--max-mib", type=float, default=48.0)
    args = ap.parse_args()
    wheels, site = args.dest / "wheels", args.dest / "site"
    shutil.rmtree(args.dest, ignore_errors=True)
    wheels.mkdir(parents=True)
    requirements = [pinned(name, pin) for name, pin in CARRY.items()]
    download(requirements, wheels, args.python_version)
    for wheel in sorted(wheels.glob("*.whl")):
        with zipfile.ZipFile(wheel) as z:
            z.extractall(site)
    shutil.rmtree(wheels)
    for folder in PRUNE:
        shutil.rmtree(site / folder)
    size = folder_mib(args.dest)
    print(f"gpu_carry: {len(requirements)} packages in {site} ({size:.1f} MiB): {' '.join(requirements)}")
    if size > args.max_mib:
        print(f"gpu_carry: {size:.1f} MiB is over --max-mib {args.max_mib:g}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
