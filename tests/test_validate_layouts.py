"""`seeu validate` on the layouts the commands write besides posed frames and shards (those:
tests/test_core.py, tests/test_bad_inputs.py; a training run and a render directory: tests/test_demo.py):
a `seeu export pixelsplat` directory (the command's default, 360x640, and one the peers' loaders would
skip), a `seeu export nerfstudio` folder, a `seeu index` file, a .ply, a folder of these. Each is
recognised and read by its own rules, its counts equal what was written, and a damaged copy is one
error line (exit 2)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from pipelines.cli import main as cli_main
from seeu_data.store.posed import PosedDataset


@pytest.fixture(scope="module")
def written(workspace, tmp_path_factory) -> dict[str, Path]:
    """What the commands write from the workspace's posed frames (12 frames at 32x32, one scene)."""
    root = tmp_path_factory.mktemp("layouts")
    posed = str(workspace["posed"])
    assert cli_main(["export", "pixelsplat", posed, "--out", str(root / "ps"), "--stage", "test"]) == 0
    assert cli_main(["export", "pixelsplat", posed, "--out", str(root / "small"), "--resize", "none"]) == 0
    assert cli_main(["index", posed, "--out", str(root / "index.json"), "--gap-min", "3", "--gap-max", "5"]) == 0
    return {
        "pixelsplat": root / "ps",
        "small": root / "small",
        "nerfstudio": workspace["transforms"].parent.parent,  # `seeu export nerfstudio --out`
        "index": root / "index.json",
    }


def ok_lines(argv: list[str], capsys) -> list[str]:
    assert cli_main(["validate", *argv]) == 0
    return capsys.readouterr().out.splitlines()


def refused(argv: list[str], capsys) -> str:
    assert cli_main(["validate", *argv]) == 2
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("seeu validate: error: "), lines
    return lines[0]


def test_each_layout_is_read_by_its_own_rules(workspace, written, capsys):
    frames = len(PosedDataset(workspace["posed"]).load_scene("syn0"))
    (line,) = ok_lines([str(written["pixelsplat"])], capsys)  # the case: a finished export
    assert line == f"OK {written['pixelsplat']}: pixelSplat chunks, test: 1 scenes, {frames} frames" + (
        " (read as `seeu import pixelsplat` reads them)"
    )
    line, note = ok_lines([str(written["small"])], capsys)
    assert line.startswith(f"OK {written['small']}: pixelSplat chunks, test: 1 scenes, {frames} frames")
    assert note.startswith("note: test: 1 scene(s) the peers' loaders skip (syn0: frames are 32x32")
    scene_line, folder_line = ok_lines([str(written["nerfstudio"])], capsys)
    assert f": nerfstudio folder, scene 'syn0', {frames} frames" in scene_line
    assert folder_line == f"OK {written['nerfstudio']}: folder of datasets, 1 checked: nerfstudio folder"
    doc = json.loads(written["index"].read_text())
    (line,) = ok_lines([str(written["index"])], capsys)
    assert line.endswith(
        f"evaluation index, pixelsplat format, {sum(v is not None for v in doc.values())} entries, 0 null"
    )


def test_a_folder_checks_each_layout_in_it(workspace, written, tmp_path, capsys):
    folder = tmp_path / "out"
    for name in ("pixelsplat", "small", "nerfstudio"):
        shutil.copytree(written[name], folder / name)
    shutil.copytree(workspace["posed"], folder / "posed")
    (folder / "notes").mkdir()
    lines = ok_lines([str(folder)], capsys)
    assert [ln.split(": ")[1].split(",")[0] for ln in lines if ln.startswith("OK ")] == [
        "nerfstudio folder",
        "folder of datasets",
        "pixelSplat chunks",
        "posed frames",
        "pixelSplat chunks",
        "folder of datasets",
    ]
    assert "note: not checked (not a layout seeu validate knows): notes" in lines
    summary = json.loads("\n".join(ok_lines(["--json", str(folder)], capsys)))
    assert [i["kind"] for i in summary["items"]] == ["folder", "pixelsplat", "posed", "pixelsplat"]


def gaussians_ply(path: Path, mean_x: float = 0.0) -> Path:
    import torch

    from seeu_model.gaussians import Gaussians
    from seeu_model.ply import save_ply

    n = 8
    means = torch.zeros(1, n, 3)
    means[0, :, 0] = mean_x
    g = Gaussians(
        means,
        torch.full((1, n, 3), 0.1),
        torch.tensor([1.0, 0, 0, 0]).repeat(1, n, 1),
        torch.full((1, n), 0.5),
        torch.zeros(1, n, 1, 3),
    )
    return save_ply(g, path)


def test_a_ply_file(tmp_path, capsys):
    (line,) = ok_lines([str(gaussians_ply(tmp_path / "g.ply"))], capsys)
    assert line.endswith(": .ply file, 8 Gaussians (3DGS layout)")
    assert "non-finite values in the Gaussians" in refused([str(gaussians_ply(tmp_path / "nan.ply", np.nan))], capsys)


def break_chunk(stage: Path) -> None:
    chunk = next(stage.glob("*.torch"))
    chunk.write_bytes(chunk.read_bytes()[:200])


def drop_image(folder: Path) -> None:
    next((folder / "syn0" / "images").iterdir()).unlink()


def garble_image(folder: Path) -> None:
    next((folder / "syn0" / "images").iterdir()).write_bytes(b"not an image")


def bad_entry(index: Path) -> None:
    index.write_text(json.dumps({"syn0": {"context": [0, 3], "target": ["middle"]}}))


@pytest.mark.parametrize(
    "name,damage,text",
    [
        ("pixelsplat", lambda p: (p / "test" / "index.json").unlink(), "no index.json beside the chunks"),
        ("pixelsplat", lambda p: break_chunk(p / "test"), "not a readable pixelSplat chunk"),
        ("nerfstudio", drop_image, "frame images are missing"),
        ("nerfstudio", garble_image, "syn0/images/"),
        ("index", bad_entry, "entry 'syn0' holds non-integer frame indices"),
    ],
    ids=["no-index-json", "truncated-chunk", "missing-image", "garbled-image", "index-entry"],
)
def test_a_damaged_layout_is_one_line(written, tmp_path, capsys, name, damage, text):
    src = written[name]
    copy = tmp_path / src.name
    (shutil.copytree if src.is_dir() else shutil.copy)(src, copy)
    damage(copy)
    assert text in refused([str(copy)], capsys)


def test_unknown_and_colmap_are_named(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    assert "not a layout seeu validate knows" in refused([str(tmp_path / "empty")], capsys)
    model = tmp_path / "sparse" / "0"
    model.mkdir(parents=True)
    (model / "cameras.txt").write_text("# none\n")
    assert "`seeu check-cameras PATH --images DIR` checks it" in refused([str(model)], capsys)
