"""Bad inputs thrown at every command: each must end with exit status 0 or 2 and, when
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
import struct
import subprocess
import sys
from pathlib import Path

import cv2  # noqa: F401  (before pycolmap: the other import order breaks OpenCV's PNG encoder)
import numpy as np
import pyarrow as pa
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
case("synth-size-not-HxW")(lambda ws, tmp: ["synth", "--out", str(tmp / "o"), "--size", "big"])
case("synth-zero-frames")(lambda ws, tmp: ["synth", "--out", str(tmp / "o"), "--frames", "0"])
case("synth-out-is-a-file", text="is a file")(
    lambda ws, tmp: _put(tmp / "f", "") or ["synth", "--out", str(tmp / "f" / "x"), "--frames", "2", "--size", "24x32"]
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


# ---- limits ----
# Deeply nested JSON anywhere a JSON document is read, and sizes / counts over their declared limit
# (seeu_data/limits.py): one line, exit 2, before any work.
DEEP = "[" * 100_000 + "]" * 100_000  # past Python's recursion limit
DEEP_OBJ = '{"a": ' * 100 + "1" + "}" * 100  # parses, but nests past MAX_JSON_DEPTH


def _deep_config(tmp, name="deep.json", text=DEEP) -> list[str]:
    _put(tmp / name, text)
    return ["--config", str(tmp / name)]


def _train(ws, tmp, *extra) -> list[str]:
    return ["train", "--data", str(ws["triples"]), "--out", str(tmp / "r"), *extra]


def _render(ws, tmp, *extra) -> list[str]:
    return ["render", "--checkpoint", str(ws["ckpt"]), "--out", str(tmp / "r"), *extra]


case("validate-manifest-deep", text="nests deeper")(
    lambda ws, tmp: _put(_manifest(ws, tmp) / "manifest.json", DEEP) or ["validate", str(tmp / "ds")]
)
case("inspect-manifest-deep-objects", text="nests deeper")(
    lambda ws, tmp: _put(_manifest(ws, tmp) / "manifest.json", DEEP_OBJ) or ["inspect", str(tmp / "ds")]
)
case("train-config-deep", text="nests deeper")(lambda ws, tmp: _train(ws, tmp, *_deep_config(tmp)))
case("train-config-yaml-deep", text="nests deeper")(
    lambda ws, tmp: _train(ws, tmp, *_deep_config(tmp, "deep.yaml", "a: " + "[" * 1000 + "]" * 1000))
)
case("train-override-deep", text="nests deeper")(lambda ws, tmp: _train(ws, tmp, *TRAIN, "model.x=" + DEEP))
case("render-cameras-deep", text="nests deeper")(
    lambda ws, tmp: _put(tmp / "c.json", DEEP) or _render(ws, tmp, "--cameras", str(tmp / "c.json"))
)
case("import-nerfstudio-transforms-deep", text="nests deeper")(
    lambda ws, tmp: _put(tmp / "t.json", DEEP) or ["import", "nerfstudio", str(tmp / "t.json"), "--out", str(tmp / "o")]
)
case("import-pixelsplat-index-deep", text="nests deeper")(lambda ws, tmp: _ps(ws, tmp, index=DEEP_OBJ))
case("build-eval-index-deep", text="nests deeper")(
    lambda ws, tmp: (
        _put(tmp / "i.json", DEEP)
        or ["build", str(ws["posed"]), "--out", str(tmp / "o"), "--mode", "eval", "--index", str(tmp / "i.json")]
    )
)
case("train-batch-size-huge", text="data.batch_size 100000000 is over the limit 1024")(
    lambda ws, tmp: _train(ws, tmp, *TRAIN, "data.batch_size=100000000")
)
case("train-image-size-huge", text="data.image_size 100000 is over the limit 8192")(
    lambda ws, tmp: _train(ws, tmp, *TRAIN, "data.image_size=100000x100000")
)
case("train-num-workers-huge", text="over the limit 256")(
    lambda ws, tmp: _train(ws, tmp, *TRAIN, "data.num_workers=100000")
)
case("train-max-steps-huge", text="--max-steps 10000000000 is over the limit 1000000000")(
    lambda ws, tmp: _train(ws, tmp, "--max-steps", "10000000000")
)
case("train-lr-huge", text="optim.lr must be in (0, 1e+10], got 1e+38")(
    lambda ws, tmp: _train(ws, tmp, *TRAIN, "optim.lr=1e38")
)
case("train-max-pixels-below-the-shards", text="over the 5e-06 MP limit")(
    lambda ws, tmp: _train(ws, tmp, *TRAIN, "data.max_pixels=5")
)
case("eval-max-pixels-below-the-shards", text="over the 5e-06 MP limit")(
    lambda ws, tmp: [
        "eval",
        "--checkpoint",
        str(ws["ckpt"]),
        "--data",
        str(ws["triples"]),
        "--no-lpips",
        "--max-pixels",
        "5",
    ]
)
case("eval-max-pixels-over-the-ceiling", text="--max-pixels 100000000000 is over the limit")(
    lambda ws, tmp: ["eval", "--checkpoint", str(ws["ckpt"]), "--data", str(ws["triples"]), "--max-pixels", "1e11"]
)
case("train-batch-size-zero", text="data.batch_size must be >= 1, got 0")(
    lambda ws, tmp: _train(ws, tmp, *TRAIN, "data.batch_size=0")
)
case("train-config-batch-size-string", text="data.batch_size: expected an integer, got 'eight'")(
    lambda ws, tmp: _train(ws, tmp, *_deep_config(tmp, "c.json", json.dumps({"data": {"batch_size": "eight"}})))
)
case("render-frames-huge", text="--frames 100000000 is over the limit 10000")(
    lambda ws, tmp: _render(ws, tmp, "--cameras", str(tmp / "none.json"), "--frames", "100000000")
)
case("render-image-size-huge", text="over the limit 8192")(
    lambda ws, tmp: _render(ws, tmp, "--cameras", str(tmp / "none.json"), "--image-size", "65536x65536")
)
case("eval-batch-size-huge", text="--batch-size 100000 is over the limit 1024")(
    lambda ws, tmp: ["eval", "--checkpoint", str(ws["ckpt"]), "--data", str(ws["triples"]), "--batch-size", "100000"]
)
case("synth-size-huge", text="--size 100000 is over the limit 4096")(
    lambda ws, tmp: ["synth", "--out", str(tmp / "o"), "--size", "100000x100000"]
)
case("synth-frames-huge", text="over the limit 100000")(
    lambda ws, tmp: ["synth", "--out", str(tmp / "o"), "--frames", "1000000000"]
)
case("synth-size-absurd-digits")(lambda ws, tmp: ["synth", "--out", str(tmp / "o"), "--size", "9" * 5000])
case("export-resize-huge", text="--resize 100000 is over the limit 8192")(
    lambda ws, tmp: ["export", "pixelsplat", str(ws["posed"]), "--out", str(tmp / "o"), "--resize", "100000x100000"]
)
case("export-chunk-mb-inf", text="--chunk-mb")(
    lambda ws, tmp: ["export", "pixelsplat", str(ws["posed"]), "--out", str(tmp / "o"), "--chunk-mb", "inf"]
)
case("ingest-size-huge", text="--size 100000 is over the limit 8192")(
    lambda ws, tmp: ["ingest", str(ws["clip"]), "--out", str(tmp / "o"), "--size", "100000x100000"]
)
case("ingest-workers-huge", text="--workers 100000 is over the limit 256")(
    lambda ws, tmp: ["ingest", str(ws["clip"]), "--out", str(tmp / "o"), "--workers", "100000"]
)
case("ingest-threads-huge", text="--threads 100000 is over the limit 256")(
    lambda ws, tmp: ["ingest", str(ws["clip"]), "--out", str(tmp / "o"), "--threads", "100000"]
)
case("ingest-workers-zero", text="--workers must be >= 1, got 0")(
    lambda ws, tmp: ["ingest", str(ws["clip"]), "--out", str(tmp / "o"), "--workers", "0"]
)
case("build-samples-per-scene-huge", text="--samples-per-scene 1000000000000 is over the limit")(
    lambda ws, tmp: ["build", str(ws["posed"]), "--out", str(tmp / "o"), "--samples-per-scene", "1000000000000"]
)
case("build-num-context-huge", text="--num-context 1000 is over the limit 16")(
    lambda ws, tmp: ["build", str(ws["posed"]), "--out", str(tmp / "o"), "--num-context", "1000"]
)
case("build-num-target-negative", text="--num-target must be >= 1, got -1")(
    lambda ws, tmp: ["build", str(ws["posed"]), "--out", str(tmp / "o"), "--num-target", "-1"]
)
case("build-rows-per-batch-huge", text="--rows-per-batch 100000000 is over the limit")(
    lambda ws, tmp: ["build", str(ws["posed"]), "--out", str(tmp / "o"), "--rows-per-batch", "100000000"]
)
case("demo-size-huge", text="--size 100000 is over the limit 4096")(
    lambda ws, tmp: ["demo", "--out", str(tmp / "o"), "--size", "100000x100000"]
)


# ---- train-guard ----
def _nan_camera_triples(ws, tmp) -> Path:
    """A copy of the workspace triples whose first sample holds one NaN camera value, with the
    manifest's bytes and sha256 of the rewritten shard made to match (the checksum is consistent)."""
    import pyarrow as pa
    import pyarrow.ipc as ipc

    from seeu_data.store.arrow_io import sha256_file

    root = _copy(ws["triples"], tmp, "nan_triples")
    doc = json.loads((root / "manifest.json").read_text())
    entry = doc["files"][0]
    shard = root / entry["path"]
    table = ipc.open_file(pa.BufferReader(shard.read_bytes())).read_all()  # not mapped: rewritten below
    cams = table.column("cam_to_world").to_pylist()
    cams[0][0][3] = float("nan")
    i = table.schema.get_field_index("cam_to_world")
    table = table.set_column(i, table.schema.field(i), pa.array(cams, table.schema.field(i).type))
    with pa.OSFile(str(shard), "wb") as sink, ipc.new_file(sink, table.schema) as writer:
        writer.write_table(table)
    entry["bytes"], entry["sha256"] = shard.stat().st_size, sha256_file(shard)
    (root / "manifest.json").write_text(json.dumps(doc))
    return root


def _all_checkpoints_finite(run: Path):
    def check():
        from seeu_model.training.checkpoint import first_nonfinite

        for p in sorted((run / "checkpoints").glob("*.pt")):
            assert first_nonfinite(torch.load(p, weights_only=True)) is None, f"{p} holds a non-finite tensor"

    return check


def _edited_ckpt(ws, tmp, edit) -> Path:
    """A copy of the workspace run's checkpoint with `edit(ckpt)` applied, its digest made anew (as
    if a run had written those values)."""
    from seeu_model.training.checkpoint import payload_digest

    ck = torch.load(ws["ckpt"], weights_only=True)
    edit(ck)
    ck["digest"] = payload_digest(ck)
    path = tmp / "edited" / ws["ckpt"].name
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save(ck, path)
    return path


def _first_weight(ck: dict) -> str:
    return next(k for k, v in ck["model"].items() if v.is_floating_point() and v.dim() >= 2)


def _nan_weight(ck: dict) -> None:
    ck["model"][_first_weight(ck)].view(-1)[0] = float("nan")


def _wrong_shape(ck: dict) -> None:
    k = _first_weight(ck)
    ck["model"][k] = torch.zeros(ck["model"][k].shape[0] + 1, *ck["model"][k].shape[1:])


def _train_argv(ws, tmp, *extra: str, data: Path | None = None) -> list[str]:
    return ["train", "--data", str(data or ws["triples"]), "--out", str(tmp / "r"), *TRAIN, *extra]


GUARD = ["--max-steps", "4", "checkpoint.every=1", "log.val_every=0"]  # after TRAIN: the later --max-steps wins
NAN_CKPT = "holds NaN or inf values"
case("train-nan-camera-shard-stops")(
    lambda ws, tmp: (
        _train_argv(ws, tmp, *GUARD, data=_nan_camera_triples(ws, tmp)),
        _all_checkpoints_finite(tmp / "r"),
    )
)
case("train-nan-camera-shard-skip-batch", rc=None)(
    lambda ws, tmp: (
        _train_argv(ws, tmp, *GUARD, "--on-nonfinite", "skip-batch", data=_nan_camera_triples(ws, tmp)),
        _all_checkpoints_finite(tmp / "r"),
    )
)
case("train-lr-diverges-without-clipping", text=": step ")(
    lambda ws, tmp: (
        _train_argv(ws, tmp, *GUARD, "optim.lr=1e8", "optim.grad_clip=0"),
        _all_checkpoints_finite(tmp / "r"),
    )
)
case("train-on-nonfinite-unknown")(lambda ws, tmp: _train_argv(ws, tmp, "on_nonfinite=ignore"))
case("train-resume-nan-checkpoint", text=NAN_CKPT)(
    lambda ws, tmp: _train_argv(ws, tmp, "--resume", str(_edited_ckpt(ws, tmp, _nan_weight)))
)
case("train-resume-nan-optimizer-state", text=NAN_CKPT)(
    lambda ws, tmp: _train_argv(
        ws,
        tmp,
        "--resume",
        str(_edited_ckpt(ws, tmp, lambda ck: next(iter(ck["optimizer"]["state"].values()))["exp_avg"].fill_(np.inf))),
    )
)
case("train-init-from-nan-checkpoint", text=NAN_CKPT)(
    lambda ws, tmp: _train_argv(ws, tmp, "--init-from", str(_edited_ckpt(ws, tmp, _nan_weight)))
)
case("train-init-from-wrong-shape", text="has shape")(
    lambda ws, tmp: _train_argv(ws, tmp, "--init-from", str(_edited_ckpt(ws, tmp, _wrong_shape)))
)
case("train-resume-negative-step", text="negative")(
    lambda ws, tmp: _train_argv(ws, tmp, "--resume", str(_edited_ckpt(ws, tmp, lambda ck: ck.update(step=-3))))
)
case("train-resume-step-number", text="not a step number")(lambda ws, tmp: _train_argv(ws, tmp, "--resume", "-1"))


def _eval_ckpt(ws, tmp, ckpt: Path) -> list[str]:
    return ["eval", "--checkpoint", str(ckpt), "--data", str(ws["triples"]), "--no-lpips", "--out", str(tmp / "e")]


def _render_ckpt(ws, tmp, ckpt: Path) -> list[str]:
    return ["render", "--checkpoint", str(ckpt), "--data", str(ws["triples"]), "--out", str(tmp / "r")]


case("eval-nan-checkpoint", text=NAN_CKPT)(lambda ws, tmp: _eval_ckpt(ws, tmp, _edited_ckpt(ws, tmp, _nan_weight)))
case("render-nan-checkpoint", text=NAN_CKPT)(lambda ws, tmp: _render_ckpt(ws, tmp, _edited_ckpt(ws, tmp, _nan_weight)))


def _flipped_bit(ws, tmp) -> Path:
    """A copy of the workspace run's checkpoint with one bit of one weight flipped in the file (as a bad
    disk or copy does): the model still loads, and would be another model."""
    ck = torch.load(ws["ckpt"], weights_only=True)
    weight = ck["model"][_first_weight(ck)].contiguous().numpy().tobytes()
    data = bytearray(ws["ckpt"].read_bytes())
    at = data.index(weight[:64])
    data[at + 5] ^= 0x04
    path = tmp / "flipped" / ws["ckpt"].name
    _put(path, bytes(data))
    return path


FLIPPED = "checkpoint damaged: its contents do not match the digest written with them"
case("eval-checkpoint-flipped-bit", text=FLIPPED)(lambda ws, tmp: _eval_ckpt(ws, tmp, _flipped_bit(ws, tmp)))
case("render-checkpoint-flipped-bit", text=FLIPPED)(lambda ws, tmp: _render_ckpt(ws, tmp, _flipped_bit(ws, tmp)))
case("train-resume-flipped-bit", text=FLIPPED)(
    lambda ws, tmp: (_train_argv(ws, tmp, "--resume", str(_flipped_bit(ws, tmp))), _nothing_written(tmp / "r"))
)


# ---- one dataset validator (dataset_check) ----
def _bomb_jpeg(size: int = 60000) -> bytes:
    """A 25-byte JPEG whose frame header declares `size` x `size` pixels (a header bomb)."""
    sof = b"\xff\xc0" + struct.pack(">HBHHB", 17, 8, size, size, 3) + b"\x01\x22\x00\x02\x11\x01\x03\x11\x01"
    return b"\xff\xd8" + sof + b"\xff\xd9"


def _rewrite(ws, tmp, key, change=None, meta=None, manifest=None) -> Path:
    """A copy of dataset `key` whose first file's table is `change(table)` (and its schema metadata
    updated by `meta`), the manifest's sizes/sha256 kept true, then `manifest(doc)` applied."""
    from seeu_data.store.arrow_io import read_table, write_table

    root = _copy(ws[key], tmp, "ds")
    doc = json.loads((root / "manifest.json").read_text())
    entry = doc["files"][0]
    table = read_table(root / entry["path"]).combine_chunks()
    if change is not None:
        table = change(table)
    if meta is not None:
        table = table.replace_schema_metadata({**table.schema.metadata, **meta})
    entry["bytes"], entry["sha256"] = write_table(root / entry["path"], table)
    if manifest is not None:
        manifest(doc)
    (root / "manifest.json").write_text(json.dumps(doc))
    return root


def _set_column(name, make):
    """change(table): column `name` replaced by `make(table)` (an Arrow array)."""
    return lambda t: t.set_column(t.schema.get_field_index(name), t.schema.field(name), make(t))


def _nan_camera(t):
    c2w = t.column("cam_to_world").combine_chunks().flatten().to_numpy().copy()
    c2w[3] = np.nan
    return pa.FixedSizeListArray.from_arrays(pa.array(c2w), 16)


def _first_image(data: bytes):
    return lambda t: pa.array([data] + t.column("image").to_pylist()[1:], pa.binary())


NAN_CAMERA = _set_column("cam_to_world", _nan_camera)
SAME_FRAME_INDEX = _set_column("frame_index", lambda t: pa.array(np.zeros(t.num_rows, np.int32)))
WIDER = _set_column("width", lambda t: pa.array(t.column("width").to_numpy() + 1))
BOMB = _set_column("image", _first_image(_bomb_jpeg()))
OTHER_VERSION = {b"seeu.schema_version": b"2.0"}


def _distorted_colmap_bomb(ws, tmp) -> list[str]:
    """A COLMAP model with a distorted (OPENCV) camera, one of whose frames is a header bomb: refused
    before the undistortion decodes it."""
    colmap_fixture(tmp / "c", pycolmap.CameraModelId.OPENCV, [90.0, 85.0, 47.0, 33.0, 0.05, -0.01, 0.0, 0.0])
    first = sorted((tmp / "c" / "images").iterdir())[0]
    first.write_bytes(_bomb_jpeg())
    return [
        "import",
        "colmap",
        str(tmp / "c" / "sparse" / "0"),
        "--images",
        str(tmp / "c" / "images"),
        "--out",
        str(tmp / "o"),
    ]


case("import-colmap-distorted-header-bomb", text="over the 64 MP limit")(_distorted_colmap_bomb)


def _build(root: Path, tmp: Path, *more: str) -> list[str]:
    return ["build", str(root), "--out", str(tmp / "o"), "--gap-min", "3", "--gap-max", "5", *more]


def _nothing_written(path: Path):
    def check():
        assert not path.exists(), f"{path} was written"

    return check


case("build-posed-non-finite-camera", text="non-finite camera")(
    lambda ws, tmp: (_build(_rewrite(ws, tmp, "posed", NAN_CAMERA), tmp), _nothing_written(tmp / "o"))
)
case("validate-posed-non-finite-camera", text="non-finite camera")(
    lambda ws, tmp: ["validate", str(_rewrite(ws, tmp, "posed", NAN_CAMERA))]
)
case("build-posed-frame-index-all-equal", text="frame_index repeats")(
    lambda ws, tmp: (_build(_rewrite(ws, tmp, "posed", SAME_FRAME_INDEX), tmp), _nothing_written(tmp / "o"))
)
case("validate-posed-frame-index-all-equal", text="frame_index repeats")(
    lambda ws, tmp: ["validate", str(_rewrite(ws, tmp, "posed", SAME_FRAME_INDEX))]
)
case("build-manifest-claims-more-frames", text="the file holds 12")(
    lambda ws, tmp: _build(_manifest(ws, tmp, "posed", lambda d: d["scenes"][0].update(num_frames=20)), tmp)
)
case("validate-manifest-claims-more-frames", text="the file holds 12")(
    lambda ws, tmp: ["validate", str(_manifest(ws, tmp, "posed", lambda d: d["scenes"][0].update(num_frames=20)))]
)
case("build-manifest-claims-more-rows", text="12 rows, the manifest says 13")(
    lambda ws, tmp: _build(
        _manifest(ws, tmp, "posed", lambda d: d["files"][0].update(rows=13) or d.update(total_rows=13)), tmp
    )
)


def _listed_twice(doc: dict) -> None:
    doc["files"].append(dict(doc["files"][0]))
    doc["total_rows"] *= 2


case("validate-file-listed-twice", text="listed twice")(
    lambda ws, tmp: ["validate", str(_manifest(ws, tmp, change=_listed_twice))]
)
case("train-file-listed-twice", text="listed twice")(
    lambda ws, tmp: ["train", "--data", str(_manifest(ws, tmp, change=_listed_twice)), "--out", str(tmp / "r")] + TRAIN
)
case("build-file-listed-twice", text="listed twice")(
    lambda ws, tmp: _build(_manifest(ws, tmp, "posed", _listed_twice), tmp)
)
case("validate-file-schema-version-2", text="schema version 2.0 is not supported")(
    lambda ws, tmp: ["validate", "--no-sha", str(_rewrite(ws, tmp, "triples", meta=OTHER_VERSION))]
)
case("train-file-schema-version-2", text="schema version 2.0 is not supported")(
    lambda ws, tmp: (
        ["train", "--data", str(_rewrite(ws, tmp, "triples", meta=OTHER_VERSION)), "--out", str(tmp / "r")] + TRAIN
    )
)
case("build-posed-file-names-other-schema", text="names schema 'seeu.triples'")(
    lambda ws, tmp: _build(_rewrite(ws, tmp, "posed", meta={b"seeu.schema": b"seeu.triples"}), tmp)
)
case("build-posed-header-bomb", text="over the 64 MP limit")(
    lambda ws, tmp: (_build(_rewrite(ws, tmp, "posed", BOMB), tmp), _nothing_written(tmp / "o"))
)
case("validate-posed-header-bomb", text="60000x60000")(
    lambda ws, tmp: ["validate", str(_rewrite(ws, tmp, "posed", BOMB))]
)
case("build-posed-header-bomb-max-pixels-raised", text="the row records 32x32")(
    lambda ws, tmp: _build(
        _rewrite(ws, tmp, "posed", _set_column("image", _first_image(_bomb_jpeg(30000)))), tmp, "--max-pixels", "1e9"
    )
)
case("build-posed-header-dims-differ", text="image header declares 32x32, the row records 33x32")(
    lambda ws, tmp: _build(_rewrite(ws, tmp, "posed", WIDER), tmp)
)
case("export-posed-header-bomb", text="over the 64 MP limit")(
    lambda ws, tmp: ["export", "nerfstudio", str(_rewrite(ws, tmp, "posed", BOMB)), "--out", str(tmp / "e")]
)
case("index-posed-header-bomb", text="over the 64 MP limit")(
    lambda ws, tmp: ["index", str(_rewrite(ws, tmp, "posed", BOMB)), "--out", str(tmp / "i.json")]
)
case("validate-triples-over-max-pixels", text="over the 0.0001 MP limit")(
    lambda ws, tmp: ["validate", "--no-sha", str(ws["triples"]), "--max-pixels", "100"]
)
case("validate-max-pixels-not-a-number", text="--max-pixels")(
    lambda ws, tmp: ["validate", str(ws["triples"]), "--max-pixels", "lots"]
)


def _ps_bomb(ws, tmp) -> list[str]:
    """The pixelSplat export with its first frame's JPEG replaced by a header bomb."""
    chunk = torch.load(next((ws["ps"] / "test").glob("*.torch")), weights_only=True)
    chunk[0]["images"][0] = torch.frombuffer(bytearray(_bomb_jpeg()), dtype=torch.uint8)
    return _ps(ws, tmp, chunk=chunk) + ["--strict"]


case("import-pixelsplat-header-bomb", text="over the 64 MP limit")(_ps_bomb)


def _damage_scene_ids(ws, tmp) -> list[str]:
    """A posed file whose scene_id strings are no longer UTF-8 (same size: only the sha256 would see it)."""
    root = _copy(ws["posed"], tmp, "ds")
    path = sorted(root.glob("posed-*.arrow"))[0]
    data = bytearray(path.read_bytes())
    data[data.find(b"syn0syn0") + 4] = 0x82
    path.write_bytes(bytes(data))
    return ["validate", "--no-sha", str(root)]


case("validate-no-sha-damaged-strings", text="corrupt")(_damage_scene_ids)
case("index-gap-no-scene-holds", text="scene 'syn0' has 12 frames, a gap of 40 needs 41")(
    lambda ws, tmp: (
        [
            "index",
            str(ws["posed"]),
            "--out",
            str(tmp / "i.json"),
            "--gap-min",
            "40",
            "--gap-max",
            "45",
            "--pairs",
            "gap",
        ],
        _nothing_written(tmp / "i.json"),
    )
)


_PEAK_RSS = (
    "import resource, subprocess, sys; r = subprocess.run(sys.argv[1:]); "
    "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, r.returncode)"
)


def _png_bomb(side: int = 20000) -> bytes:
    """A valid 1-bit grey PNG of `side` x `side` black pixels (~50 KB): a decoder that trusts it
    allocates side^2 x 3 bytes of BGR (1.2 GB at 20000), then works on them."""
    import zlib

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    row = bytes(1 + -(-side // 8))  # filter byte + the packed bits of one row
    packer = zlib.compressobj(9)
    idat = b"".join(packer.compress(row) for _ in range(side)) + packer.flush()
    ihdr = struct.pack(">IIBBBBB", side, side, 1, 0, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat) + chunk(b"IEND", b"")


def _ingest_folder_bomb(ws, tmp) -> list[str]:
    """An image folder whose second image is a valid PNG declaring 20000x20000 (400 MP)."""
    folder = _folder_with(tmp, ws)
    (folder / "f001.png").write_bytes(_png_bomb())
    return ["ingest", str(folder), "--out", str(tmp / "o"), "--threads", "1"]


def _render_cameras_bomb(ws, tmp) -> list[str]:
    """A cameras file whose first context image is a valid 400 MP PNG."""
    (tmp / "big.png").write_bytes(_png_bomb())
    frames = [_good_frame(tmp), _good_frame(tmp, "b.png")]
    frames[0]["image"] = "big.png"
    return _render(ws, tmp, "--cameras", str(_cameras(tmp, frames)))


def test_header_bomb_refused_in_little_memory(ws, tmp_path):
    """A JPEG declaring 60000x60000 (10.8 GB of pixels) in posed data (build) and in a pixelSplat chunk
    (import), a valid 400 MP PNG in an image folder (ingest) and as a context image of a cameras file
    (render): refused in one line by a real `seeu` process whose peak RSS stays under 1 GB."""
    for d in ("ps", "ing", "ren"):
        (tmp_path / d).mkdir()
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1]), "SEEU_HEARTBEAT_S": "0"}
    for argv in (
        _build(_rewrite(ws, tmp_path, "posed", BOMB), tmp_path),
        _ps_bomb(ws, tmp_path / "ps"),
        _ingest_folder_bomb(ws, tmp_path / "ing"),
        _render_cameras_bomb(ws, tmp_path / "ren"),
    ):
        cmd = [sys.executable, "-c", _PEAK_RSS, sys.executable, "-m", "pipelines.cli", *argv]
        done = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=300)
        peak_kb, rc = (int(v) for v in done.stdout.split()[-2:])
        errors = [ln for ln in done.stderr.splitlines() if ": error: " in ln]
        assert rc == 2 and len(errors) == 1 and "over the 64 MP limit" in errors[0], done.stderr[-600:]
        assert peak_kb < 1 << 20, f"{argv[0]}: peak RSS {peak_kb / 1024:.0f} MB"


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


case("ingest-folder-png-bomb", text="f001.png: image header declares 20000x20000 (400.0 MP) is over the 64 MP limit")(
    _ingest_folder_bomb
)
case("ingest-folder-over-max-pixels", text="f000.jpg: image header declares 64x48 (0.0 MP) is over the 0.003 MP")(
    lambda ws, tmp: ["ingest", str(_folder_with(tmp, ws)), "--out", str(tmp / "o"), "--max-pixels", "3000"]
)
case("ingest-video-over-max-pixels", text="clip.mp4: video frame size 64x48 (0.0 MP) is over the 0.003 MP limit")(
    lambda ws, tmp: ["ingest", str(ws["clip"]), "--out", str(tmp / "o"), "--max-pixels", "3000"]
)
case("render-cameras-png-bomb", text="big.png (frame 0): image header declares 20000x20000")(_render_cameras_bomb)
case("render-cameras-over-max-pixels", text="a.png (frame 0): image header declares 32x32")(
    lambda ws, tmp: _render(
        ws, tmp, "--max-pixels", "1000", "--cameras", str(_cameras(tmp, [_good_frame(tmp), _good_frame(tmp, "b.png")]))
    )
)
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


# ---- check-cameras ----
case("check-cameras-unknown-kind", text="unknown dataset kind")(
    lambda ws, tmp: (tmp / "empty").mkdir() or ["check-cameras", str(tmp / "empty")]
)
case("check-cameras-missing-path", text="not a dataset folder or transforms.json")(
    lambda ws, tmp: ["check-cameras", str(tmp / "nothing")]
)
case("check-cameras-too-small-to-match", text="no scene could be checked")(
    lambda ws, tmp: ["check-cameras", str(ws["posed"])]
)
case("check-cameras-zero-pairs", text="--pairs must be at least 1")(
    lambda ws, tmp: ["check-cameras", str(ws["posed"]), "--pairs", "0"]
)
case("check-cameras-nan-camera", text="non-finite camera")(
    lambda ws, tmp: ["check-cameras", str(_rewrite(ws, tmp, "posed", NAN_CAMERA))]
)


# ---- view ----
def _port_in_use(ws, tmp):
    import socket

    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    sock.listen(1)
    return ["view", str(ws["posed"]), "--port", str(sock.getsockname()[1])], sock.close


case("view-unknown-kind", text="unknown kind")(lambda ws, tmp: (tmp / "empty").mkdir() or ["view", str(tmp / "empty")])
case("view-missing-path", text="not found")(lambda ws, tmp: ["view", str(tmp / "nothing.ply")])
case("view-port-in-use", text="is in use")(_port_in_use)
case("view-not-a-ply", text="not a readable .ply")(
    lambda ws, tmp: _put(tmp / "x.ply", "ply\nformat nonsense\n") or ["view", str(tmp / "x.ply")]
)
case("view-checkpoint-on-gaussians", text="--checkpoint needs posed frames or triple shards")(
    lambda ws, tmp: _put(tmp / "x.ply", "ply") or ["view", str(tmp / "x.ply"), "--checkpoint", str(ws["ckpt"])]
)
case("view-sample-out-of-range", text="no sample 99")(
    lambda ws, tmp: ["view", str(ws["triples"]), "--sample", "99", "--save", str(tmp / "s.viser")]
)


# ---- predict ----
def _predict(ws, tmp, scene_dir, *extra) -> list[str]:
    return ["predict", str(scene_dir), "--checkpoint", str(ws["ckpt"]), "--out", str(tmp / "p"), *extra]


case("predict-context-out-of-range", text="--context frame 12 is not in scene 'syn0' (frames 0..11)")(
    lambda ws, tmp: _predict(ws, tmp, ws["posed"], "--context", "3,12")
)
case("predict-context-same-frame", text="--context frames must differ")(
    lambda ws, tmp: _predict(ws, tmp, ws["posed"], "--context", "4,4")
)
case("predict-context-one-frame", text="context frames in --context")(
    lambda ws, tmp: _predict(ws, tmp, ws["posed"], "--context", "4")
)
case("predict-context-not-indices", text="is not frame indices I,J")(
    lambda ws, tmp: _predict(ws, tmp, ws["posed"], "--context", "2,x")
)
case("predict-unposed-images-folder", text="no manifest.json")(
    lambda ws, tmp: _put(tmp / "imgs" / "a.png", "") or _predict(ws, tmp, tmp / "imgs")
)
case("predict-triples-not-posed", text="expected a seeu.posed_frames dataset")(
    lambda ws, tmp: _predict(ws, tmp, ws["triples"])
)
case("predict-unknown-scene", text="no scene 'nope'")(lambda ws, tmp: _predict(ws, tmp, ws["posed"], "--scene", "nope"))
# ---- dl3dv ----
case("import-dl3dv-no-scene", text="no DL3DV scene found")(
    lambda ws, tmp: (tmp / "empty").mkdir() or ["import", "dl3dv", str(tmp / "empty"), "--out", str(tmp / "o")]
)
case("import-dl3dv-only-wrong-size", text="images_8/frame_00001.png is 48x30, but the intrinsics are for 384x216")(
    lambda ws, tmp: (
        _dl3dv_scene(tmp / "d" / "1K" / ("e" * 64), {"images_8": (48, 30)})
        or ["import", "dl3dv", str(tmp / "d"), "--out", str(tmp / "o")]
    )
)
case("import-dl3dv-missing-root", text="DL3DV root not found")(
    lambda ws, tmp: ["import", "dl3dv", str(tmp / "nothing"), "--out", str(tmp / "o")]
)


def _dl3dv_scene(folder, sizes) -> None:
    from tests.dl3dv_fixtures import make_scene

    make_scene(folder, n=2, sizes=sizes)


# ---- photos ----
case("ingest-matcher-unknown", text="invalid choice: 'vocab'")(
    lambda ws, tmp: ["ingest", str(ws["clip"]), "--out", str(tmp / "o"), "--matcher", "vocab"]
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
    assert len(CASES) >= 190 and commands >= {
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
            lambda ws: ["synth", "--out", "/sys/seeu-bad-input-test", "--frames", "2", "--size", "24x32"],
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
