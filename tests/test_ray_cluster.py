"""`--engine ray` for `seeu import` and `seeu build` on a Ray cluster of two nodes started on this machine
(`ray start --head`, then `ray start --address` for the second node, one CPU each): the bytes of the
local engine, and a node killed in the middle of a task loses nothing (Ray runs the task again on
the node left). The kill is the task's own doing, so it always happens mid-task: the first task to run
on the second node (the only one whose environment names a marker file) kills that node's raylet, its
parent process, and waits to die with it.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from functools import partial
from pathlib import Path

import numpy as np
import pytest

from seeu_data.importers import ImportReport, write_import
from seeu_data.importers import pixelsplat as ps
from tests.test_import_pixelsplat import make_example, write_chunks

ray = pytest.importorskip("ray")
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[1]
RAY = str(Path(sys.executable).parent / "ray")
MARKER_ENV = "SEEU_TEST_KILL_MARKER"


def die_once_on_the_marked_node() -> None:
    """Run in a Ray worker: on the node whose environment names a marker file not yet written, write it
    and SIGKILL this node's raylet (the worker's parent), then wait for the node's end."""
    marker = os.environ.get(MARKER_ENV)
    if marker and not os.path.exists(marker):
        Path(marker).write_text(str(os.getpid()))
        os.kill(os.getppid(), signal.SIGKILL)
        time.sleep(300)


def read_dying(read):
    die_once_on_the_marked_node()
    return read()


def build_task_dying(row: dict) -> dict:
    from seeu_data.build.ray_build import ray_task

    die_once_on_the_marked_node()
    return ray_task(row)


class Cluster:
    """A head node and a second node on this machine, in a session directory of its own; every process
    of the session is ended (by its pid) at the close."""

    def __init__(self) -> None:
        self.temp = Path(tempfile.mkdtemp(prefix="seeu-ray-", dir="/tmp"))  # short: Ray's socket paths
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        self.address = f"127.0.0.1:{port}"
        self.env = {
            **os.environ,
            "RAY_AUTH_MODE": "token",  # Ray 2.60's `ray start` turns token authentication on
            "RAY_USAGE_STATS_ENABLED": "0",
            "RAY_health_check_period_ms": "500",  # a dead node noticed within seconds
            "RAY_health_check_failure_threshold": "4",
            "RAY_health_check_initial_delay_ms": "0",
            "PYTHONPATH": str(ROOT),
        }
        try:
            self._start("--head", f"--port={port}", "--include-dashboard=false", f"--temp-dir={self.temp}")
        except BaseException:
            self.close()
            raise

    def _start(self, *args: str, env: dict | None = None) -> None:
        cmd = [RAY, "start", *args, "--num-cpus=1", "--disable-usage-stats"]
        res = subprocess.run(cmd, env=env or self.env, capture_output=True, text=True, timeout=240)
        assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-2000:]

    def add_dying_node(self, marker: Path) -> None:
        """A second node whose first task of the tests' kind kills it (marker: that it happened)."""
        self._start(f"--address={self.address}", env={**self.env, MARKER_ENV: str(marker)})

    def close(self) -> None:
        for pid in [int(p.name) for p in Path("/proc").iterdir() if p.name.isdigit()]:
            try:
                cmdline = (Path("/proc") / str(pid) / "cmdline").read_bytes()
            except OSError:
                continue
            if str(self.temp).encode() in cmdline and pid != os.getpid():
                try:
                    os.kill(pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
        shutil.rmtree(self.temp, ignore_errors=True)


@pytest.fixture(scope="module")
def cluster():
    c = Cluster()
    yield c
    c.close()


def alive_nodes(expect: int = 1, wait_s: float = 30.0) -> int:
    """The nodes alive, polled until `expect` or `wait_s` (the head notices a killed raylet within its
    health check's 2 s, which a short job can finish inside)."""
    deadline = time.monotonic() + wait_s
    while True:
        alive = sum(1 for n in ray.nodes() if n["Alive"])
        if alive <= expect or time.monotonic() > deadline:
            return alive
        time.sleep(0.25)


def drive_import(ds: str, out: str, address: str | None) -> None:
    """The import of the chunks in `ds` into `out` (posed files of ~40 kB: several), on the cluster at
    `address` or locally (None), every unit read through `read_dying`."""
    plan = ps.import_plan(ps.PixelSplatImportConfig(root=Path(ds)))
    plan.units[:] = [replace(u, read=partial(read_dying, u.read)) for u in plan.units]
    engine = {"engine": "ray", "ray_address": address} if address else {}
    write_import(plan, Path(out), ImportReport("pixelsplat"), {}, {}, target_file_bytes=40_000, **engine)
    if address:
        print("RESULT", json.dumps({"alive": alive_nodes()}), flush=True)


def drive_build(posed: str, out: str, address: str | None) -> None:
    """An interp build of `posed` into `out` (shards of ~30 kB), on the cluster through `build_task_dying`
    or locally (None)."""
    from pipelines.build import BuildConfig, build
    from seeu_data.build import ray_build
    from seeu_data.build.sampling import SamplingConfig

    sampling = SamplingConfig(gap_min=8, gap_max=14, samples_per_scene=4)
    engine = {"engine": "ray", "ray_address": address} if address else {"workers": 1}
    ray_build.ray_task = build_task_dying  # what Ray Data maps (pickled by reference: this module's)
    build(BuildConfig(inputs=(posed,), out=out, sampling=sampling, shard_bytes=30_000, seed=5, **engine))
    if address:
        print("RESULT", json.dumps({"alive": alive_nodes()}), flush=True)


def run_driver(cluster: Cluster, fn: str, *args: str) -> dict:
    """`fn(*args, cluster.address)` of this module in a driver process of its own (RAY_AUTH_MODE is read
    when ray is imported: the driver's must say token, as `ray start`'s did)."""
    call = f"from tests.test_ray_cluster import {fn}; {fn}(*{list(args)!r}, {cluster.address!r})"
    res = subprocess.run([sys.executable, "-c", call], env=cluster.env, capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-3000:]
    return json.loads(next(ln for ln in res.stdout.splitlines() if ln.startswith("RESULT "))[len("RESULT ") :])


def _outputs(out: Path) -> tuple[dict[str, bytes], dict]:
    doc = json.loads((out / "manifest.json").read_text())
    return {p.name: p.read_bytes() for p in sorted(out.glob("*.arrow"))}, {k: doc.get(k) for k in ("files", "scenes")}


def test_import_on_two_nodes_is_the_local_import_and_survives_a_node_killed(cluster, tmp_path):
    rng = np.random.default_rng(21)
    write_chunks(tmp_path / "ds", "train", [[make_example(f"c{c}s{i}", 4, rng) for i in range(2)] for c in range(6)])
    drive_import(str(tmp_path / "ds"), str(tmp_path / "local"), None)
    marker = tmp_path / "killed"
    cluster.add_dying_node(marker)
    after = run_driver(cluster, "drive_import", str(tmp_path / "ds"), str(tmp_path / "ray"))
    assert marker.exists(), "no task ran on the second node"
    assert after["alive"] == 1  # the second node is gone; its task ran again on the head
    local, remote = _outputs(tmp_path / "local"), _outputs(tmp_path / "ray")
    assert len(local[0]) >= 3 and remote == local


def test_build_on_two_nodes_is_the_local_build_and_survives_a_node_killed(cluster, tmp_path):
    from seeu_data.store.posed import PosedDatasetWriter
    from tests.helpers import make_posed_scene

    posed = tmp_path / "posed"
    with PosedDatasetWriter(posed, params={}, provenance={}) as w:
        for i, n in enumerate((26, 33, 40)):
            w.add(make_posed_scene(f"scene{i}", n=n, height=24, width=32, seed=i))
    drive_build(str(posed), str(tmp_path / "local"), None)
    marker = tmp_path / "killed"
    cluster.add_dying_node(marker)
    after = run_driver(cluster, "drive_build", str(posed), str(tmp_path / "ray"))
    assert marker.exists(), "no task ran on the second node"
    assert after["alive"] == 1
    local, remote = _outputs(tmp_path / "local"), _outputs(tmp_path / "ray")
    assert len(local[0]) > 2 and remote[0] == local[0] and remote[1]["files"] == local[1]["files"]
