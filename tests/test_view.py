"""`seeu view` in a real browser: the command serves, headless chromium (software WebGL) opens the
page, the server logs the client (viser's on_client_connect) and the screenshot's canvas is not
blank; `--screenshot` shoots once the scene is drawn, run after run. Chromium is required: a missing
one fails these tests (`make test` installs it: scripts/system-deps.sh)."""

from __future__ import annotations

import os
import queue
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from benchmarks.view_screenshot import Drawn, magenta_posed
from pipelines.chromium import Chromium
from pipelines.cli import main as cli_main

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module", autouse=True)
def chromium() -> None:
    if shutil.which("chromium") is None and shutil.which("chromium-browser") is None:
        pytest.fail("chromium is not installed: `make system-deps` (run by `make test`) installs it")


def canvas_spread(png: Path) -> float:
    """Standard deviation of the pixels left of viser's panel and below its notification."""
    import cv2

    img = cv2.imread(str(png))
    assert img is not None, png
    return float(img[170:640, 60:640].astype(np.float64).std())


class Served:
    """`seeu view PATH --port 0` as a process; its stdout lines in a queue."""

    def __init__(self, *argv: str):
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "pipelines.cli", "view", *argv, "--port", "0"],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            env=env,
        )
        self.lines: queue.Queue[str] = queue.Queue()
        self.seen: list[str] = []
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.put(line.rstrip("\n"))

    def wait_for(self, text: str, timeout: float = 60.0) -> str:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            try:
                line = self.lines.get(timeout=0.2)
            except queue.Empty:
                assert self.proc.poll() is None, "\n".join(self.seen[-20:])
                continue
            self.seen.append(line)
            if text in line:
                return line
        raise AssertionError(f"no {text!r} in: " + "\n".join(self.seen[-20:]))

    def saw(self, text: str) -> bool:
        """Whether `text` is in a line printed so far (without waiting)."""
        while not self.lines.empty():
            self.seen.append(self.lines.get())
        return any(text in line for line in self.seen)

    def stop(self) -> int:
        self.proc.send_signal(signal.SIGINT)
        return self.proc.wait(timeout=30)


def _look(path: Path, tmp_path: Path) -> None:
    served = Served(str(path))
    try:
        url = served.wait_for(" at http://").split(" at ")[1].split()[0]
        png = tmp_path / "page.png"
        with Chromium((1000, 700)) as browser:
            browser.shoot(url, png, drawn=lambda seconds: served.wait_for("connected", seconds))
        assert canvas_spread(png) > 10.0, "the 3D canvas looks blank"
    finally:
        rc = served.stop()
    assert rc == 0, "\n".join(served.seen[-20:])


def test_view_posed_frames_in_browser(workspace, tmp_path):
    _look(workspace["posed"], tmp_path)


def test_view_triple_shards_in_browser(workspace, tmp_path):
    _look(workspace["triples"], tmp_path)


def test_screenshot_waits_until_drawn(tmp_path, capsys):
    """`--screenshot` run after run (benchmarks/view_screenshot.py does 20): each PNG shows the
    thumbnails (the images' own magenta), a filled control panel and no browser notice (the top left
    is background), and all are the same picture."""
    posed = magenta_posed(tmp_path / "posed", frames=12, hw=(32, 32))
    shots = [tmp_path / f"shot_{k}.png" for k in range(2)]
    for png in shots:
        assert cli_main(["view", str(posed), "--screenshot", str(png)]) == 0
        drawn = Drawn.of(png)
        assert drawn.complete(), (png.name, drawn)
        assert (read_rgb(png)[15:150, 15:310] >= 250).all(), "a notice is shown at the top left"
    assert all(np.array_equal(read_rgb(shots[0]), read_rgb(png)) for png in shots[1:])
    assert capsys.readouterr().out.count("(posed)") == len(shots)


def read_rgb(png: Path) -> np.ndarray:
    import cv2

    img = cv2.imread(str(png))
    assert img is not None, png
    return img[:, :, ::-1]


def gaussians_dir(root: Path, n: int = 2000) -> Path:
    """A render-like directory: a blob of n coloured Gaussians (gaussians.ply) and two cameras."""
    import torch

    from seeu_model.gaussians import Gaussians
    from seeu_model.ply import save_ply_bundle

    rng = np.random.default_rng(0)
    g = Gaussians(
        means=torch.tensor(rng.normal(size=(1, n, 3)) * [1.0, 0.5, 0.5] + [0, 0, 4], dtype=torch.float32),
        scales=torch.full((1, n, 3), 0.05),
        rotations=torch.tensor([1.0, 0, 0, 0]).expand(1, n, 4).clone(),
        opacities=torch.full((1, n), 0.8),
        sh=torch.tensor(rng.normal(size=(1, n, 1, 3)), dtype=torch.float32),
    )
    c2w = np.stack([np.eye(4)] * 2)
    c2w[1, 0, 3] = 0.5
    save_ply_bundle(g, root, c2w, np.array([[1.0, 1.0, 0.5, 0.5]] * 2), 64, 48, ["context_0", "target_0"])
    return root


def test_view_ply_screenshot(tmp_path, capsys):
    """`--screenshot` (docs/view.md's command): serve, chromium, PNG, exit; the client was logged."""
    ply = gaussians_dir(tmp_path / "render") / "gaussians.ply"
    png = tmp_path / "shot.png"
    assert cli_main(["view", str(ply), "--screenshot", str(png)]) == 0
    out = capsys.readouterr().out
    assert "connected" in out and f"wrote {png} (ply)" in out, out
    assert "(viser)" not in out and "╭" not in out, out  # viser's own banner and stop line are quiet
    assert canvas_spread(png) > 10.0


def test_view_save_scene_file(workspace, tmp_path, capsys):
    """`--save` writes viser's scene file (with the frustums' thumbnails) and serves nothing."""
    out = tmp_path / "scene.viser"
    assert cli_main(["view", str(workspace["posed"]), "--save", str(out)]) == 0
    assert "wrote" in capsys.readouterr().out
    kinds = [m[1]["type"] for m in read_viser_file(out)["messages"]]
    assert kinds.count("CameraFrustumMessage") == 12 + 1  # every frame, and the slider's frame
    assert "LineSegmentsMessage" in kinds  # the trajectory


def read_viser_file(path: Path) -> dict:
    """The msgpack header of a .viser file (viser's StateSerializer: 8-byte size, zstd of
    [8-byte msgpack length, msgpack, binary buffers])."""
    import msgspec
    import zstandard

    data = path.read_bytes()
    inner = zstandard.ZstdDecompressor().decompress(data[8:], max_output_size=int.from_bytes(data[:8], "little"))
    n = int.from_bytes(inner[:8], "little")
    return msgspec.msgpack.decode(inner[8 : 8 + n])


@pytest.fixture(scope="module")
def checkpoint(workspace, tmp_path_factory) -> Path:
    """A tiny SeeU checkpoint after one training step on the workspace's shards (32x32)."""
    from pipelines.train import TrainRunConfig, train

    run = tmp_path_factory.mktemp("view_ckpt") / "run"
    overrides = ["model.preset=tiny", "data.batch_size=2", "data.num_workers=0", "data.image_size=[32,32]"]
    overrides += ["optim.max_steps=1", "loss.lpips_weight=0", "precision=fp32", "rasterizer=torch", "log.every=1"]
    train(TrainRunConfig(data=str(workspace["triples"]), out=run, overrides=overrides))
    return run / "checkpoints"


def test_live_render_follows_viser_camera(workspace, checkpoint, capsys):
    """The live render of a viser camera (OpenCV c2w as wxyz/position, vertical fov, aspect) is our
    render of the same camera, and a viewer camera behind the scene looking at it sees Gaussians."""
    import viser.transforms as vtf

    from pipelines.render import render_views, shard_sample
    from pipelines.view import Notes, Prediction, ViewConfig, build_scene, look_at_wxyz, stop_server

    server, _ = build_scene(ViewConfig(path=workspace["triples"], port=0))
    try:
        pred = Prediction(server, checkpoint, None, Notes())
        pred.predict(shard_sample(str(workspace["triples"]), "0", pred.hw)["context"])
        assert float(np.asarray(pred.image.image).std()) > 5.0, "the panel's first image (start view) is blank"
        c2w = np.eye(4)
        c2w[:3, :3] = vtf.SO3(look_at_wxyz([0.3, -0.5, -2.0], [0.0, 0.0, 3.0])).as_matrix()
        c2w[:3, 3] = [0.3, -0.5, -2.0]
        fov, aspect = 1.0, 1.5
        fy = 0.5 / np.tan(fov / 2)
        live = pred.render_camera(vtf.SO3.from_matrix(c2w[:3, :3]).wxyz, c2w[:3, 3], fov, aspect, width=48)
        k = np.array([[fy * 32 / 48, 0, 0.5], [0, fy, 0.5], [0, 0, 1]])
        ours, _ = render_views(pred.model, {}, c2w[None], k[None], (32, 48), "torch", pred.g)
        assert live.shape == (32, 48, 3) and np.array_equal(live, ours[0])
        assert live.std() > 10.0 and (live.max(-1) > 40).mean() > 0.2, "the viewer camera sees no Gaussians"
        flipped = pred.render_camera(vtf.SO3.from_matrix(c2w[:3, :3] * [1, -1, -1]).wxyz, c2w[:3, 3], fov, aspect, 48)
        assert not np.array_equal(flipped, live)  # an OpenGL reading of the same pose looks elsewhere
    finally:
        stop_server(server)


def test_server_url_brackets_ipv6():
    from pipelines.view import server_url

    assert server_url("::1", 8080) == "http://[::1]:8080" and server_url("127.0.0.1", 80) == "http://127.0.0.1:80"
