"""Paths read from dataset files stay inside their dataset.

Each case puts a real, intact file outside the dataset and points a dataset file at it (`../x`, an
absolute path, a symbolic link): without the containment rule the file would be read and accepted
(sizes and sha256 match), so every assertion here fails if the rule is missing.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2  # noqa: F401  (before pycolmap: the other import order breaks OpenCV's PNG encoder)
import numpy as np
import pyarrow.fs as pafs
import pycolmap
import pytest

from pipelines.cli import main as cli_main
from pipelines.validate import validate_dataset
from seeu_data.errors import SeeUError
from seeu_data.loader import ShardSource, make_loader
from seeu_data.store.paths import OutsidePathError, contained_key, contained_path
from seeu_data.store.posed import PosedDataset
from tests.loader_fixtures import write_triples
from tests.test_import_formats import colmap_fixture, nerfstudio_from_colmap
from tests.test_import_pixelsplat import make_example, write_chunks


def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "internal error" not in err, err
    return err


def _move_out(root: Path, name: str, how: str) -> str:
    """Move `root/name` out of the dataset; return the manifest path that reaches it (`how`:
    relative `..`, absolute, or a symbolic link inside the dataset)."""
    outside = root.parent / "outside"
    outside.mkdir(exist_ok=True)
    shutil.move(root / name, outside / name)
    if how == "dotdot":
        return f"../outside/{name}"
    if how == "absolute":
        return str((outside / name).resolve())
    (root / name).symlink_to(outside / name)
    return name


def _rewrite(manifest: Path, old: str, new: str, scenes: bool = False) -> None:
    doc = json.loads(manifest.read_text())
    for f in doc["files"]:
        if f["path"] == old:
            f["path"] = new
    for s in doc.get("scenes", []) if scenes else []:
        if s["file"] == old:
            s["file"] = new
    manifest.write_text(json.dumps(doc))


def test_contained_path_rule(tmp_path):
    (tmp_path / "d" / "sub").mkdir(parents=True)
    (tmp_path / "x").write_text("")
    assert contained_path(tmp_path / "d", "sub/../a.arrow", "entry") == tmp_path / "d" / "sub/../a.arrow"
    for bad in ("../x", str(tmp_path / "x"), "sub/../../x"):
        with pytest.raises(OutsidePathError, match="leads outside"):
            contained_path(tmp_path / "d", bad, "entry")
    assert contained_path(tmp_path / "d", "../x", "entry", allow_outside=True) == tmp_path / "d" / "../x"
    assert contained_key("a/b.arrow", "entry", "s3://b/ds") == "a/b.arrow"
    for bad in ("../b.arrow", "/b.arrow", "a/../../b.arrow", "s3://other/b.arrow"):
        with pytest.raises(OutsidePathError):
            contained_key(bad, "entry", "s3://b/ds")


@pytest.mark.parametrize("how", ["dotdot", "absolute", "symlink"])
def test_validate_refuses_a_triples_manifest_entry_outside_its_directory(tmp_path, capsys, how):
    root = write_triples(tmp_path / "ds", [3, 2], hw=(8, 8))
    validate_dataset(root)  # intact before
    _rewrite(root / "manifest.json", "shard-00001.arrow", _move_out(root, "shard-00001.arrow", how))
    assert cli_main(["validate", str(root)]) == 2
    assert "leads outside" in _one_error_line(capsys)


def test_validate_refuses_a_total_row_count_that_disagrees(tmp_path, capsys):
    root = write_triples(tmp_path / "ds", [3, 2], hw=(8, 8))
    doc = json.loads((root / "manifest.json").read_text())
    doc["total_rows"] = 6
    (root / "manifest.json").write_text(json.dumps(doc))
    assert cli_main(["validate", str(root), "--no-sha"]) == 2
    assert "total_rows 6 disagrees with the 5 rows" in _one_error_line(capsys)


def test_loader_refuses_a_manifest_entry_outside_its_directory(tmp_path):
    root = write_triples(tmp_path / "ds", [3, 2], hw=(8, 8))
    assert len(list(make_loader(root, 1, image_hw=(8, 8), cache_dir=str(tmp_path / "c")))) == 5
    _rewrite(root / "manifest.json", "shard-00000.arrow", _move_out(root, "shard-00000.arrow", "dotdot"))
    with pytest.raises(SeeUError, match=r"manifest entry '\.\./outside/shard-00000\.arrow' leads outside"):
        make_loader(root, 1, image_hw=(8, 8), cache_dir=str(tmp_path / "c"))


def test_loader_refuses_an_object_key_outside_its_prefix(tmp_path):
    """Object storage (here pyarrow's local file system behind the remote code path): a key with
    `..` would read another prefix of the bucket; refused before anything is downloaded."""
    root = write_triples(tmp_path / "bucket" / "ds", [3, 2], hw=(8, 8))
    fs = pafs.LocalFileSystem()
    src = ShardSource(f"mem://{root}", cache_dir=tmp_path / "c", filesystem=fs)
    assert src.local_path(1).is_file()
    shutil.copy(root / "shard-00001.arrow", tmp_path / "bucket" / "other.arrow")
    _rewrite(root / "manifest.json", "shard-00001.arrow", "../other.arrow")
    with pytest.raises(SeeUError, match="leads outside"):
        ShardSource(f"mem://{root}", cache_dir=tmp_path / "c2", filesystem=fs)
    assert not (tmp_path / "c2" / "objects").exists()


def test_build_refuses_a_posed_manifest_entry_outside_its_directory(tmp_path, capsys):
    from tests.training_fixtures import synthetic_posed

    posed = synthetic_posed(tmp_path, n_frames=8, hw=(16, 16))
    name = json.loads((posed / "manifest.json").read_text())["files"][0]["path"]
    _rewrite(posed / "manifest.json", name, _move_out(posed, name, "dotdot"), scenes=True)
    rc = cli_main(["build", str(posed), "--out", str(tmp_path / "tri"), "--mode", "interp", "--workers", "1"])
    assert rc == 2 and "leads outside" in _one_error_line(capsys)
    assert not (tmp_path / "tri" / "manifest.json").exists()
    with pytest.raises(SeeUError, match="leads outside"):
        PosedDataset(posed)


@pytest.mark.parametrize("entry", ["../../elsewhere/000000.torch", "ABSOLUTE"])
def test_pixelsplat_index_entry_outside_the_stage_is_skipped(tmp_path, capsys, entry):
    rng = np.random.default_rng(0)
    stage = write_chunks(tmp_path / "ds", "test", [[make_example("inside", 3, rng)]])
    elsewhere = write_chunks(tmp_path, "elsewhere", [[make_example("evil", 3, rng)]])  # a valid chunk
    index = json.loads((stage / "index.json").read_text())
    index["evil"] = str(elsewhere / "000000.torch") if entry == "ABSOLUTE" else entry
    (stage / "index.json").write_text(json.dumps(index))
    assert (
        cli_main(["import", "pixelsplat", str(tmp_path / "ds"), "--stage", "test", "--out", str(tmp_path / "out")]) == 0
    )
    assert "skipped 1 scenes (evil)" in capsys.readouterr().out
    report = json.loads((tmp_path / "out" / "manifest.json").read_text())["report"]
    assert report["skipped_scenes"] == 1 and "leads outside" in report["skipped"][0]["reason"]
    assert PosedDataset(tmp_path / "out").scene_ids == ["inside"]


@pytest.mark.parametrize("how", ["dotdot", "absolute", "symlink"])
def test_nerfstudio_file_path_outside_its_folder_is_dropped(tmp_path, capsys, how):
    rec = colmap_fixture(tmp_path / "scene", pycolmap.CameraModelId.PINHOLE, [90.0, 85.0, 47.0, 33.0])
    tj = nerfstudio_from_colmap(rec, tmp_path / "ns", tmp_path / "scene" / "images")
    doc = json.loads(tj.read_text())
    first = sorted(doc["frames"], key=lambda f: f["file_path"])[0]
    name = Path(first["file_path"]).name
    (tmp_path / "outside").mkdir()
    shutil.move(tmp_path / "ns" / "images" / name, tmp_path / "outside" / name)
    if how == "dotdot":
        first["file_path"] = f"../outside/{name}"
    elif how == "absolute":
        first["file_path"] = str(tmp_path / "outside" / name)
    else:
        (tmp_path / "ns" / "images" / name).symlink_to(tmp_path / "outside" / name)
    tj.write_text(json.dumps(doc))
    assert cli_main(["import", "nerfstudio", str(tj), "--out", str(tmp_path / "o")]) == 0
    assert "dropped 1 frames" in capsys.readouterr().out
    scene = PosedDataset(tmp_path / "o").load_scene("ns")
    assert len(scene) == len(doc["frames"]) - 1 and first["file_path"] not in scene.source_name
    assert "leads outside" in scene.meta["skipped_frames"][0]["reason"]
    assert json.loads((tmp_path / "o" / "manifest.json").read_text())["report"]["skipped_frames"] == 1
    # Where that is intended, the flag reads it.
    assert cli_main(["import", "nerfstudio", str(tj), "--allow-outside-paths", "--out", str(tmp_path / "o2")]) == 0
    assert len(PosedDataset(tmp_path / "o2").load_scene("ns")) == len(doc["frames"])


def test_colmap_image_name_outside_the_image_folder_is_dropped(tmp_path, capsys):
    colmap_fixture(tmp_path / "scene", pycolmap.CameraModelId.PINHOLE, [90.0, 85.0, 47.0, 33.0])
    model = tmp_path / "scene" / "sparse" / "0"
    rec = pycolmap.Reconstruction(str(model))
    txt = tmp_path / "txt"
    txt.mkdir()
    rec.write_text(str(txt))
    name = sorted(im.name for im in rec.images.values())[0]
    shutil.move(tmp_path / "scene" / "images" / name, tmp_path / "scene" / name)  # beside images/: ../name
    text = (txt / "images.txt").read_text()
    (txt / "images.txt").write_text(text.replace(f" {name}\n", f" ../{name}\n"))
    args = ["import", "colmap", str(txt), "--images", str(tmp_path / "scene" / "images"), "--scene-id", "s"]
    assert cli_main(args + ["--out", str(tmp_path / "o")]) == 0
    assert "dropped 1 frames" in capsys.readouterr().out
    scene = PosedDataset(tmp_path / "o").load_scene("s")
    assert len(scene) == len(rec.images) - 1 and f"../{name}" not in scene.source_name
    assert scene.meta["skipped_frames"][0]["frame"] == f"../{name}"
    assert cli_main(args + ["--allow-outside-paths", "--out", str(tmp_path / "o2")]) == 0
    assert f"../{name}" in PosedDataset(tmp_path / "o2").load_scene("s").source_name
