"""Bad inputs thrown at every command (issue 20): each must end with exit status 0 or 2 and, when
it fails, one line `seeu CMD: error: ...`; never "internal error", never a traceback.

Most cases call `pipelines.cli.main(argv)` in this process (fast); a few run the real `seeu`
process where the process boundary matters (a real EPERM from /sys, a real ENOSPC from /dev/full,
argparse's own exit). Files that would run code if unpickled carelessly create a sentinel file:
the case asserts it does not exist.
"""

from __future__ import annotations

import collections
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import cv2  # noqa: F401  (before pycolmap: the other import order breaks OpenCV's PNG encoder)
import numpy as np
import pycolmap
import pytest
import torch

from pipelines.cli import main as cli_main
from tests.test_import_formats import colmap_fixture

CASES: list = []


def case(name: str, rc: int | None = 2, text: str | None = None):
    """Register `fn(ws, tmp) -> argv` (or `(argv, check)` where `check()` runs after the command)."""

    def deco(fn):
        CASES.append(pytest.param(fn, rc, text, id=name))
        return fn

    return deco


class _Call:
    """Pickles as `fn(*args)`: what a hostile or malformed pickle does on load."""

    def __init__(self, fn, *args):
        self.fn, self.args = fn, args

    def __reduce__(self):
        return self.fn, self.args


def _put(path: Path, data: str | bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data if isinstance(data, bytes) else data.encode())


def _sentinel_check(sentinel: Path):
    def check():
        assert not sentinel.exists(), "code from a file we read ran"

    return check


@pytest.fixture(scope="module")
def ws(workspace, tmp_path_factory):
    """The shared valid inputs (conftest `workspace`), and a pixelSplat export, a COLMAP model and a
    one-step training run; the cases damage copies."""
    root = tmp_path_factory.mktemp("ws")
    tri, posed = workspace["triples"], workspace["posed"]
    assert cli_main(["export", "pixelsplat", str(posed), "--out", str(root / "ps")]) == 0
    colmap_fixture(root / "colmap", pycolmap.CameraModelId.PINHOLE, [90.0, 85.0, 47.0, 33.0])
    assert (
        cli_main(
            [
                "train",
                "--data",
                str(tri),
                "--config",
                "configs/cpu_tiny.json",
                "--out",
                str(root / "run"),
                "--max-steps",
                "1",
                "checkpoint.every=1",
                "log.val_every=0",
            ]
        )
        == 0
    )
    ckpt = sorted((root / "run" / "checkpoints").glob("ckpt-*.pt"))[-1]
    return {**workspace, "ps": root / "ps", "colmap": root / "colmap", "ckpt": ckpt}


def _copy(src: Path, tmp: Path, name: str = "copy") -> Path:
    dst = tmp / name
    shutil.copytree(src, dst) if src.is_dir() else shutil.copy(src, dst)
    return dst


def _ns(ws, tmp, change) -> list[str]:
    """A copy of the nerfstudio export with `change(doc)` applied to its transforms.json."""
    folder = _copy(ws["transforms"].parent, tmp, "ns")
    doc = json.loads((folder / "transforms.json").read_text())
    change(doc)
    (folder / "transforms.json").write_text(json.dumps(doc))
    return ["import", "nerfstudio", str(folder / "transforms.json"), "--out", str(tmp / "out")]


def _ps(ws, tmp, chunk=None, index=None) -> list[str]:
    """A copy of the pixelSplat export whose only chunk is `chunk` (an object to torch.save) and
    whose index.json is `index` (text), when given."""
    root = _copy(ws["ps"], tmp, "ps")
    stage = root / "test"
    if chunk is not None:
        for p in stage.glob("*.torch"):
            p.unlink()
        if isinstance(chunk, bytes):  # raw bytes, not a torch.save file
            (stage / "000000.torch").write_bytes(chunk * 99)
        else:
            torch.save(chunk, stage / "000000.torch")
        keys = list(json.loads((stage / "index.json").read_text()))
        (stage / "index.json").write_text(json.dumps({k: "000000.torch" for k in keys}))
    if index is not None:
        (stage / "index.json").write_text(index)
    return ["import", "pixelsplat", str(root), "--stage", "test", "--out", str(tmp / "out")]


def _manifest(ws, tmp, key="triples", change=None) -> Path:
    root = _copy(ws[key], tmp, "ds")
    if change is not None:
        doc = json.loads((root / "manifest.json").read_text())
        change(doc)
        (root / "manifest.json").write_text(json.dumps(doc))
    return root


def _ckpt_with(tmp, payload) -> Path:
    path = tmp / "ckpt-00000001.pt"
    torch.save(payload, path)
    return path


def _cameras(tmp, frames) -> Path:
    path = tmp / "cams.json"
    path.write_text(json.dumps({"near": 0.5, "far": 10.0, "frames": frames}))
    return path


def _good_frame(tmp, name="a.png", **over) -> dict:
    cv2.imwrite(str(tmp / name), np.full((32, 32, 3), 128, np.uint8))
    return {"image": name, "cam_to_world": np.eye(4).tolist(), "intrinsics_norm": [1.0, 1.0, 0.5, 0.5], **over}


# ------------------------------------------------------------------------------------------ synth
case("synth-size-not-WxH")(lambda ws, tmp: ["synth", "--out", str(tmp / "o"), "--size", "big"])
case("synth-zero-frames")(lambda ws, tmp: ["synth", "--out", str(tmp / "o"), "--frames", "0"])
case("synth-out-is-a-file", text="is a file")(
    lambda ws, tmp: _put(tmp / "f", "") or ["synth", "--out", str(tmp / "f" / "x"), "--frames", "2", "--size", "32x24"]
)

# ------------------------------------------------------------------------------------------ ingest
case("ingest-missing-input")(lambda ws, tmp: ["ingest", str(tmp / "nothing.mp4"), "--out", str(tmp / "o")])
case("ingest-empty-folder")(
    lambda ws, tmp: (tmp / "empty").mkdir() or ["ingest", str(tmp / "empty"), "--out", str(tmp / "o")]
)
case("ingest-garbage-video")(
    lambda ws, tmp: (
        _put(tmp / "v.mp4", os.urandom(4096))
        or ["ingest", str(tmp / "v.mp4"), "--out", str(tmp / "o"), "--threads", "1"]
    )
)
case("ingest-out-is-a-file", text="is a file")(
    lambda ws, tmp: _put(tmp / "f", "") or ["ingest", str(ws["clip"]), "--out", str(tmp / "f")]
)
case("ingest-stride-zero")(lambda ws, tmp: ["ingest", str(ws["clip"]), "--out", str(tmp / "o"), "--stride", "0"])
case("ingest-keyframe-motion-negative", text="--keyframe-motion")(
    lambda ws, tmp: ["ingest", str(ws["clip"]), "--out", str(tmp / "o"), "--keyframe-motion", "-1"]
)
case("ingest-keyframe-motion-nan", text="--keyframe-motion")(
    lambda ws, tmp: ["ingest", str(ws["clip"]), "--out", str(tmp / "o"), "--keyframe-motion", "nan"]
)
case("ingest-final-ba-loss-scale-zero", text="--final-ba-loss-scale")(
    lambda ws, tmp: ["ingest", str(ws["clip"]), "--out", str(tmp / "o"), "--final-ba-loss-scale", "0"]
)

# ------------------------------------------------------------------------------------------ import
case("import-pixelsplat-missing-dir")(
    lambda ws, tmp: ["import", "pixelsplat", str(tmp / "no"), "--out", str(tmp / "o")]
)
case("import-pixelsplat-index-not-json")(lambda ws, tmp: _ps(ws, tmp, index="{not json"))
case("import-pixelsplat-index-a-list")(lambda ws, tmp: _ps(ws, tmp, index="[1, 2]"))
case("import-pixelsplat-index-escapes", text="leads outside")(
    lambda ws, tmp: _ps(ws, tmp, index=json.dumps({"k": "../../elsewhere/x.torch"}))
)
case("import-pixelsplat-index-absolute", text="leads outside")(
    lambda ws, tmp: _ps(ws, tmp, index=json.dumps({"k": "/etc/passwd"}))
)
case("import-pixelsplat-chunk-garbage")(lambda ws, tmp: _ps(ws, tmp, chunk=b"garbage"))
case("import-pixelsplat-chunk-storage-call", text="not a readable pixelSplat chunk")(
    lambda ws, tmp: _ps(ws, tmp, chunk=[_Call(torch.FloatStorage)])
)
case("import-pixelsplat-chunk-ordereddict-5", text="not a readable pixelSplat chunk")(
    lambda ws, tmp: _ps(ws, tmp, chunk=[_Call(collections.OrderedDict, 5)])
)
case("import-pixelsplat-chunk-runs-code")(
    lambda ws, tmp: (_ps(ws, tmp, chunk=[_Call(os.system, f"touch {tmp / 'PWNED'}")]), _sentinel_check(tmp / "PWNED"))
)
case("import-pixelsplat-chunk-a-dict")(lambda ws, tmp: _ps(ws, tmp, chunk={"key": "x"}))
case("import-pixelsplat-chunk-examples-numbers")(lambda ws, tmp: _ps(ws, tmp, chunk=[1, 2, 3]))
case("import-re10k-missing-cameras")(
    lambda ws, tmp: [
        "import",
        "re10k",
        "--cameras",
        str(tmp / "c"),
        "--frames",
        str(tmp / "f"),
        "--out",
        str(tmp / "o"),
    ]
)
case("import-re10k-garbage-camera-file")(
    lambda ws, tmp: (
        [
            (tmp / "c").mkdir(),
            (tmp / "f" / "x").mkdir(parents=True),
            (tmp / "c" / "x.txt").write_text("http://u\n1 2 three\n"),
        ]
        and ["import", "re10k", "--cameras", str(tmp / "c"), "--frames", str(tmp / "f"), "--out", str(tmp / "o")]
    )
)
case("import-dtu-missing")(lambda ws, tmp: ["import", "dtu", str(tmp / "dtu"), "--out", str(tmp / "o")])
case("import-colmap-not-a-model")(
    lambda ws, tmp: ["import", "colmap", str(tmp), "--images", str(tmp), "--out", str(tmp / "o")]
)
case("import-colmap-garbage-binary")(
    lambda ws, tmp: (
        [
            (tmp / "m").mkdir(),
            (tmp / "m" / "cameras.bin").write_bytes(os.urandom(100)),
            (tmp / "m" / "images.bin").write_bytes(os.urandom(100)),
        ]
        and ["import", "colmap", str(tmp / "m"), "--images", str(ws["colmap"] / "images"), "--out", str(tmp / "o")]
    )
)
case("import-nerfstudio-not-json")(
    lambda ws, tmp: _put(tmp / "t.json", "{") or ["import", "nerfstudio", str(tmp / "t.json"), "--out", str(tmp / "o")]
)
case("import-nerfstudio-frames-numbers", text="frames[0] is not an object")(
    lambda ws, tmp: _ns(ws, tmp, lambda d: d.update(frames=[1, 2, 3]))
)
case("import-nerfstudio-fl_x-string", text="fl_x must be a finite number")(
    lambda ws, tmp: _ns(ws, tmp, lambda d: [f.update(fl_x="wide") for f in d["frames"]] and d.update(fl_x="wide"))
)
case("import-nerfstudio-seeu-near-string", text="seeu.near must be a finite number")(
    lambda ws, tmp: _ns(ws, tmp, lambda d: d.update(seeu={"near": "close"}))
)
case("import-nerfstudio-seeu-block-string", text="'seeu' block must be an object")(
    lambda ws, tmp: _ns(ws, tmp, lambda d: d.update(seeu="x"))
)
case("import-nerfstudio-matrix-shape", text="transform_matrix")(
    lambda ws, tmp: _ns(ws, tmp, lambda d: d["frames"][0].update(transform_matrix=[[1, 0], [0, 1]]))
)
case("import-nerfstudio-unknown-camera-model", text="camera_model")(
    lambda ws, tmp: _ns(
        ws,
        tmp,
        lambda d: (
            [f.update(camera_model="EQUIRECTANGULAR") for f in d["frames"]] and d.update(camera_model="EQUIRECTANGULAR")
        ),
    )
)
case("import-nerfstudio-negative-width", text="w must be positive")(
    lambda ws, tmp: _ns(ws, tmp, lambda d: [f.pop("w", None) for f in d["frames"]] and d.update(w=-5))
)
case("import-nerfstudio-missing-image", text="--skip-missing")(
    lambda ws, tmp: _ns(ws, tmp, lambda d: d["frames"][0].update(file_path="images/not_there.jpg"))
)
case("import-nerfstudio-file-path-number", text="file_path must be a non-empty string")(
    lambda ws, tmp: _ns(ws, tmp, lambda d: d["frames"][0].update(file_path=7))
)
case("import-out-is-a-file", text="is a file")(
    lambda ws, tmp: _put(tmp / "f", "") or ["import", "nerfstudio", str(ws["transforms"]), "--out", str(tmp / "f")]
)

# ------------------------------------------------------------------------------------------ export
case("export-missing-dataset")(lambda ws, tmp: ["export", "pixelsplat", str(tmp / "no"), "--out", str(tmp / "o")])
case("export-of-triples", text="expected a seeu.posed_frames dataset")(
    lambda ws, tmp: ["export", "nerfstudio", str(ws["triples"]), "--out", str(tmp / "o")]
)
case("export-out-is-a-file", text="is a file")(
    lambda ws, tmp: _put(tmp / "f", "") or ["export", "pixelsplat", str(ws["posed"]), "--out", str(tmp / "f")]
)

# ------------------------------------------------------------------------------------------ build
case("build-missing-input")(lambda ws, tmp: ["build", str(tmp / "no"), "--out", str(tmp / "o")])
case("build-of-triples")(lambda ws, tmp: ["build", str(ws["triples"]), "--out", str(tmp / "o")])
case("build-eval-without-index")(lambda ws, tmp: ["build", str(ws["posed"]), "--out", str(tmp / "o"), "--mode", "eval"])
case("build-index-not-json")(
    lambda ws, tmp: (
        _put(tmp / "i.json", "[")
        or ["build", str(ws["posed"]), "--out", str(tmp / "o"), "--mode", "eval", "--index", str(tmp / "i.json")]
    )
)
case("build-resize-zero")(lambda ws, tmp: ["build", str(ws["posed"]), "--out", str(tmp / "o"), "--resize", "0x0"])
case("build-manifest-entry-escapes", text="leads outside")(
    lambda ws, tmp: [
        "build",
        str(_manifest(ws, tmp, "posed", lambda d: d["files"][0].update(path="../x.arrow"))),
        "--out",
        str(tmp / "o"),
    ]
)
case("build-out-is-a-file", text="is a file")(
    lambda ws, tmp: (
        _put(tmp / "f", "")
        or ["build", str(ws["posed"]), "--out", str(tmp / "f"), "--gap-min", "3", "--gap-max", "5", "--workers", "1"]
    )
)

# ------------------------------------------------------------------------------------------ index / inspect
case("index-missing-input")(lambda ws, tmp: ["index", str(tmp / "no"), "--out", str(tmp / "i.json")])
case("index-of-triples")(lambda ws, tmp: ["index", str(ws["triples"]), "--out", str(tmp / "i.json")])
case("inspect-missing")(lambda ws, tmp: ["inspect", str(tmp / "no")])
case("inspect-manifest-not-json")(
    lambda ws, tmp: _put(_manifest(ws, tmp) / "manifest.json", "{") or ["inspect", str(tmp / "ds")]
)

# ------------------------------------------------------------------------------------------ validate
case("validate-good", rc=0)(lambda ws, tmp: ["validate", str(ws["triples"])])
case("validate-missing")(lambda ws, tmp: ["validate", str(tmp / "no")])
case("validate-manifest-not-json")(
    lambda ws, tmp: _put(_manifest(ws, tmp) / "manifest.json", "nope") or ["validate", str(tmp / "ds")]
)
case("validate-manifest-no-files")(
    lambda ws, tmp: ["validate", str(_manifest(ws, tmp, change=lambda d: d.pop("files")))]
)
case("validate-entry-escapes", text="leads outside")(
    lambda ws, tmp: ["validate", str(_manifest(ws, tmp, change=lambda d: d["files"][0].update(path="../../x.arrow")))]
)
case("validate-entry-absolute", text="leads outside")(
    lambda ws, tmp: ["validate", str(_manifest(ws, tmp, change=lambda d: d["files"][0].update(path="/etc/passwd")))]
)
case("validate-total-rows-disagree", text="disagrees")(
    lambda ws, tmp: ["validate", str(_manifest(ws, tmp, change=lambda d: d.update(total_rows=d["total_rows"] + 1)))]
)


def _truncate(ws, tmp, no_sha=False):
    root = _manifest(ws, tmp)
    shard = sorted(root.glob("*.arrow"))[0]
    shard.write_bytes(shard.read_bytes()[:-100])
    return ["validate", str(root)] + (["--no-sha"] if no_sha else [])


def _flip_names(ws, tmp):
    """Same size, field names made invalid UTF-8: `--no-sha` cannot see it from size and hash."""
    root = _manifest(ws, tmp)
    shard = sorted(root.glob("*.arrow"))[0]
    data = bytearray(shard.read_bytes())
    i = data.find(b"cam_to_world")
    while i >= 0:
        data[i] = 0xFF
        i = data.find(b"cam_to_world", i + 1)
    shard.write_bytes(bytes(data))
    return ["validate", "--no-sha", str(root)]


case("validate-truncated-shard", text="differs from the manifest")(_truncate)
case("validate-no-sha-corrupt-names", text="corrupt")(_flip_names)

# ------------------------------------------------------------------------------------------ train
TRAIN = ["--config", "configs/cpu_tiny.json", "--max-steps", "1"]
case("train-missing-data")(lambda ws, tmp: ["train", "--data", str(tmp / "no"), "--out", str(tmp / "r")] + TRAIN)
case("train-missing-config")(
    lambda ws, tmp: ["train", "--data", str(ws["triples"]), "--out", str(tmp / "r"), "--config", str(tmp / "no.json")]
)
case("train-unknown-override")(
    lambda ws, tmp: ["train", "--data", str(ws["triples"]), "--out", str(tmp / "r")] + TRAIN + ["optim.nonsense=1"]
)
case("train-data-is-posed-frames")(
    lambda ws, tmp: ["train", "--data", str(ws["posed"]), "--out", str(tmp / "r")] + TRAIN
)
case("train-log-every-zero")(
    lambda ws, tmp: ["train", "--data", str(ws["triples"]), "--out", str(tmp / "r")] + TRAIN + ["log.every=0"]
)
case("train-num-workers-negative")(
    lambda ws, tmp: ["train", "--data", str(ws["triples"]), "--out", str(tmp / "r")] + TRAIN + ["data.num_workers=-1"]
)
case("train-lr-nan")(
    lambda ws, tmp: ["train", "--data", str(ws["triples"]), "--out", str(tmp / "r")] + TRAIN + ["optim.lr=nan"]
)
case("train-resume-garbage")(
    lambda ws, tmp: (
        _put(tmp / "c.pt", b"\x80\x04garbage")
        or ["train", "--data", str(ws["triples"]), "--out", str(tmp / "r"), "--resume", str(tmp / "c.pt")] + TRAIN
    )
)
case("train-resume-runs-code")(
    lambda ws, tmp: (
        [
            "train",
            "--data",
            str(ws["triples"]),
            "--out",
            str(tmp / "r"),
            "--resume",
            str(_ckpt_with(tmp, {"step": 1, "x": _Call(os.system, f"touch {tmp / 'PWNED'}")})),
        ]
        + TRAIN,
        _sentinel_check(tmp / "PWNED"),
    )
)
case("train-out-is-a-file", text="is a file")(
    lambda ws, tmp: _put(tmp / "f", "") or ["train", "--data", str(ws["triples"]), "--out", str(tmp / "f")] + TRAIN
)

# ------------------------------------------------------------------------------------------ eval
case("eval-missing-checkpoint")(
    lambda ws, tmp: ["eval", "--checkpoint", str(tmp / "no.pt"), "--data", str(ws["triples"]), "--no-lpips"]
)
case("eval-garbage-checkpoint")(
    lambda ws, tmp: (
        _put(tmp / "c.pt", os.urandom(300))
        or ["eval", "--checkpoint", str(tmp / "c.pt"), "--data", str(ws["triples"]), "--no-lpips"]
    )
)
case("eval-missing-data")(
    lambda ws, tmp: ["eval", "--checkpoint", str(ws["ckpt"]), "--data", str(tmp / "no"), "--no-lpips"]
)
case("eval-image-size-zero")(
    lambda ws, tmp: [
        "eval",
        "--checkpoint",
        str(ws["ckpt"]),
        "--data",
        str(ws["triples"]),
        "--no-lpips",
        "--image-size",
        "0x0",
        "--out",
        str(tmp / "e"),
    ]
)
case("eval-out-is-a-file", text="is a file")(
    lambda ws, tmp: (
        _put(tmp / "f", "")
        or [
            "eval",
            "--checkpoint",
            str(ws["ckpt"]),
            "--data",
            str(ws["triples"]),
            "--no-lpips",
            "--max-samples",
            "1",
            "--out",
            str(tmp / "f"),
        ]
    )
)
case("eval-checkpoint-runs-code")(
    lambda ws, tmp: (
        [
            "eval",
            "--checkpoint",
            str(_ckpt_with(tmp, _Call(os.system, f"touch {tmp / 'PWNED'}"))),
            "--data",
            str(ws["triples"]),
            "--no-lpips",
        ],
        _sentinel_check(tmp / "PWNED"),
    )
)

# ------------------------------------------------------------------------------------------ render
case("render-missing-checkpoint")(
    lambda ws, tmp: [
        "render",
        "--checkpoint",
        str(tmp / "no.pt"),
        "--data",
        str(ws["triples"]),
        "--out",
        str(tmp / "r"),
    ]
)
case("render-sample-out-of-range")(
    lambda ws, tmp: [
        "render",
        "--checkpoint",
        str(ws["ckpt"]),
        "--data",
        str(ws["triples"]),
        "--sample",
        "999",
        "--out",
        str(tmp / "r"),
        "--frames",
        "2",
    ]
)
case("render-out-is-a-file", text="is a file")(
    lambda ws, tmp: (
        _put(tmp / "f", "")
        or [
            "render",
            "--checkpoint",
            str(ws["ckpt"]),
            "--data",
            str(ws["triples"]),
            "--out",
            str(tmp / "f"),
            "--frames",
            "2",
        ]
    )
)
case("render-cameras-not-json")(
    lambda ws, tmp: (
        _put(tmp / "c.json", "{")
        or ["render", "--checkpoint", str(ws["ckpt"]), "--cameras", str(tmp / "c.json"), "--out", str(tmp / "r")]
    )
)
case("render-camera-frames-strings")(
    lambda ws, tmp: [
        "render",
        "--checkpoint",
        str(ws["ckpt"]),
        "--cameras",
        str(_cameras(tmp, ["a", "b"])),
        "--out",
        str(tmp / "r"),
        "--frames",
        "2",
    ]
)
case("render-camera-nan-pose")(
    lambda ws, tmp: [
        "render",
        "--checkpoint",
        str(ws["ckpt"]),
        "--out",
        str(tmp / "r"),
        "--frames",
        "2",
        "--cameras",
        str(_cameras(tmp, [_good_frame(tmp), _good_frame(tmp, "b.png", cam_to_world=[[float("nan")] * 4] * 4)])),
    ]
)
case("render-camera-negative-focal")(
    lambda ws, tmp: [
        "render",
        "--checkpoint",
        str(ws["ckpt"]),
        "--out",
        str(tmp / "r"),
        "--frames",
        "2",
        "--cameras",
        str(_cameras(tmp, [_good_frame(tmp), _good_frame(tmp, "b.png", intrinsics_norm=[-1, 1, 0.5, 0.5])])),
    ]
)


# ---- locks: image-folder entries that cannot be read as images ----
def _folder_with(tmp: Path, ws, *bad: str) -> Path:
    """An image folder: one real frame (from the workspace clip) and entries named `bad` that are
    not readable images ("pipe.jpg": a FIFO, "dir.png": a directory, anything else: text bytes)."""
    folder = tmp / "images"
    folder.mkdir()
    cap = cv2.VideoCapture(str(ws["clip"]))
    ok, bgr = cap.read()
    cap.release()
    assert ok and cv2.imwrite(str(folder / "f000.jpg"), bgr)
    for name in bad:
        if name.startswith("pipe"):
            os.mkfifo(folder / name)
        elif name.startswith("dir"):
            (folder / name).mkdir()
        else:
            _put(folder / name, "not an image")
    return folder


case("ingest-strict-fifo", text="pipe.jpg: cannot be read as an image: a FIFO (--strict)")(
    lambda ws, tmp: ["ingest", str(_folder_with(tmp, ws, "pipe.jpg")), "--out", str(tmp / "o"), "--strict"]
)
case("ingest-strict-text-as-jpeg", text="notes.jpg: cannot be read as an image: not an image")(
    lambda ws, tmp: ["ingest", str(_folder_with(tmp, ws, "notes.jpg")), "--out", str(tmp / "o"), "--strict"]
)
case("ingest-strict-directory-named-png", text="a directory (--strict)")(
    lambda ws, tmp: ["ingest", str(_folder_with(tmp, ws, "dir.png")), "--out", str(tmp / "o"), "--strict"]
)
case("ingest-only-unreadable-images", text="no readable images (skipped: 2 (dir.png: a directory; pipe.jpg: a FIFO))")(
    lambda ws, tmp: (
        (tmp / "only").mkdir()
        or os.mkfifo(tmp / "only" / "pipe.jpg")
        or (tmp / "only" / "dir.png").mkdir()
        or ["ingest", str(tmp / "only"), "--out", str(tmp / "o")]
    )
)


@pytest.mark.parametrize("make,rc,text", CASES)
def test_bad_input(ws, tmp_path, capsys, make, rc, text):
    made = make(ws, tmp_path)
    argv, check = made if isinstance(made, tuple) else (made, None)
    try:
        code = cli_main(argv)
    except SystemExit as exc:  # argparse rejects the flag itself
        code = exc.code
    err = capsys.readouterr().err
    if check is not None:
        check()
    assert code in (0, 2), f"exit status {code}: {err[-600:]}"
    assert "internal error" not in err and "Traceback" not in err, err[-600:]
    if rc is not None:
        assert code == rc, err[-600:]
    if code == 2:
        errors = [ln for ln in err.splitlines() if ": error: " in ln]
        assert len(errors) == 1, err[-600:]
    if text is not None:
        assert text in err, err[-600:]


def test_enough_cases():
    commands = {p.id.split("-")[0] for p in CASES}
    assert len(CASES) >= 40 and commands >= {
        "ingest",
        "import",
        "export",
        "build",
        "index",
        "inspect",
        "validate",
        "train",
        "eval",
        "render",
        "synth",
    }


# ------------------------------------------------------------------------------------------ real processes


def _seeu(*argv: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    return subprocess.run(
        [sys.executable, "-m", "pipelines.cli", *argv], capture_output=True, text=True, env=env, timeout=300
    )


@pytest.mark.parametrize(
    "argv,expect",
    [
        (lambda ws: ["ingest", str(ws["clip"]), "--out", "/sys/seeu-bad-input-test"], "/sys/seeu-bad-input-test: "),
        (
            lambda ws: ["synth", "--out", "/sys/seeu-bad-input-test", "--frames", "2", "--size", "32x24"],
            "/sys/seeu-bad-input-test: ",
        ),
        (
            lambda ws: ["model-info", "--preset", "tiny", "--json", "/dev/full"],
            "/dev/full: cannot write: no space left",
        ),
        (lambda ws: ["validate", str(ws["triples"]), "--frobnicate"], "unrecognized arguments"),
    ],
    ids=["ingest-out-in-sys", "synth-out-in-sys", "model-info-json-dev-full", "validate-unknown-flag"],
)
def test_bad_input_real_process(ws, argv, expect):
    """The real `seeu` process: a system folder no one may write (EPERM even for root), a device
    that is always full (ENOSPC on every write), an unknown flag (argparse's own exit)."""
    if not Path("/sys").is_dir() or not Path("/dev/full").exists():
        pytest.skip("needs Linux /sys and /dev/full")
    done = _seeu(*argv(ws))
    assert done.returncode == 2 and "internal error" not in done.stderr and "Traceback" not in done.stderr, done.stderr
    assert expect in done.stderr, done.stderr
