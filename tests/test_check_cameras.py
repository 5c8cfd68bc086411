"""`seeu check-cameras`: exact synthetic cameras pass; each common convention mistake written into a
copy of the dataset fails with exit 1 and is named; foreign formats (nerfstudio, COLMAP, pixelSplat)
read through their importers pass too."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

from pipelines.cli import main as cli_main
from seeu_data.cameras import invert_rigid, opencv_from_opengl, quat_wxyz_from_rotmat
from seeu_data.store.arrow_io import read_table, write_table
from seeu_data.store.manifest import provenance
from seeu_data.store.posed import PosedDataset, PosedDatasetWriter
from seeu_data.synthetic import synthetic_posed_scene

H, W = 120, 160


@pytest.fixture(scope="module")
def good(tmp_path_factory) -> Path:
    """A posed dataset of the synthetic corridor with exact cameras, at a size SIFT works on."""
    out = tmp_path_factory.mktemp("check_cameras") / "posed"
    with PosedDatasetWriter(out, {"test": True}, provenance("tests")) as w:
        w.add(synthetic_posed_scene(n_frames=8, height=H, width=W, seed=0, scene_id="syn0"))
    return out


def _check(argv: list[str], capsys) -> tuple[int, str]:
    rc = cli_main(["check-cameras", *argv])
    cap = capsys.readouterr()
    return rc, cap.out + cap.err


def broken_copy(good: Path, tmp: Path, change) -> Path:
    """A copy of `good` whose cameras are `change(cam_to_world (N,4,4), intrinsics_norm (N,4))`,
    written into the Arrow file with the manifest's size and sha256 kept true."""
    root = tmp / "broken"
    shutil.copytree(good, root)
    doc = json.loads((root / "manifest.json").read_text())
    entry = doc["files"][0]
    table = read_table(root / entry["path"]).combine_chunks()
    c2w = table.column("cam_to_world").combine_chunks().values.to_numpy().reshape(-1, 4, 4)
    intr = table.column("intrinsics_norm").combine_chunks().values.to_numpy().reshape(-1, 4)
    c2w, intr = change(c2w.copy(), intr.copy())
    for name, values, k in (("cam_to_world", c2w, 16), ("intrinsics_norm", intr, 4)):
        arr = pa.FixedSizeListArray.from_arrays(pa.array(np.asarray(values, np.float64).reshape(-1)), k)
        table = table.set_column(table.schema.get_field_index(name), table.schema.field(name), arr)
    entry["bytes"], entry["sha256"] = write_table(root / entry["path"], table)
    (root / "manifest.json").write_text(json.dumps(doc))
    return root


def test_exact_cameras_pass_with_figure_and_report(good, tmp_path, capsys):
    rc, out = _check([str(good), "--out", str(tmp_path / "o"), "--pairs", "3"], capsys)
    assert rc == 0, out
    assert (
        "CONSISTENT" in out and "RE10K loader would skip it (frames are 160x120, the RE10K loaders need 640x360" in out
    )
    rep = json.loads((tmp_path / "o" / "check.json").read_text())
    scene = rep["scenes"][0]
    assert rep["verdict"] == "consistent" and rep["kind"] == "posed" and scene["matches"] >= 30
    assert scene["median_error_px"] < 0.5 and rep["median_error_px"] == scene["median_error_px"]
    assert f"median Sampson error {scene['median_error_px']:.2f} px" in out
    png = (tmp_path / "o" / "epipolar.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"


def _transposed(c2w):
    c2w[:, :3, :3] = np.swapaxes(c2w[:, :3, :3], -1, -2).copy()
    return c2w


def _shift_cx(c2w, intr):
    intr[:, 2] += 0.05
    return c2w, intr


BROKEN = {
    "w2c": (lambda c, k: (invert_rigid(c), k), "c2w/w2c swapped"),
    "opengl": (lambda c, k: (opencv_from_opengl(c), k), "OpenGL"),
    "pixel_intrinsics": (lambda c, k: (c, k * np.array([W, H, W, H])), "pixels stored in the normalised field"),
    "principal_point": (_shift_cx, "principal point"),
    "transposed_rotation": (lambda c, k: (_transposed(c), k), "rotations look transposed"),
    "normalised_as_pixels": (lambda c, k: (c, k / np.array([W, H, W, H])), "divided by the size twice"),
}


@pytest.mark.parametrize("variant", sorted(BROKEN))
def test_broken_cameras_fail_and_name_the_cause(good, tmp_path, capsys, variant):
    change, words = BROKEN[variant]
    rc, out = _check([str(broken_copy(good, tmp_path, change)), "--out", str(tmp_path / "o")], capsys)
    assert rc == 1, out
    assert "INCONSISTENT" in out and words in out and "after the fix" in out
    scene = json.loads((tmp_path / "o" / "check.json").read_text())["scenes"][0]
    assert scene["cause"] == variant and scene["hypotheses_median_px"][variant] < 0.5


def test_nerfstudio_export_passes(good, tmp_path, capsys):
    assert cli_main(["export", "nerfstudio", str(good), "--out", str(tmp_path / "ns")]) == 0
    rc, out = _check([str(tmp_path / "ns" / "syn0" / "transforms.json")], capsys)
    assert rc == 0 and "(nerfstudio)" in out, out


def test_pixelsplat_export_passes(good, tmp_path, capsys):
    assert cli_main(["export", "pixelsplat", str(good), "--out", str(tmp_path / "ps")]) == 0
    rc, out = _check([str(tmp_path / "ps")], capsys)
    assert rc == 0 and "(pixelsplat)" in out, out


def test_colmap_text_model_passes(good, tmp_path, capsys):
    """A COLMAP text model (PINHOLE camera, world-to-camera quaternions) written from the exact cameras."""
    scene = PosedDataset(good).load_scene("syn0")
    model, images = tmp_path / "scene" / "sparse" / "0", tmp_path / "scene" / "images"
    model.mkdir(parents=True)
    images.mkdir()
    fx, fy, cx, cy = (float(v) for v in scene.intrinsics_norm[0] * np.array([W, H, W, H]))
    (model / "cameras.txt").write_text(f"1 PINHOLE {W} {H} {fx!r} {fy!r} {cx!r} {cy!r}\n")
    lines = []
    for k, c2w in enumerate(scene.cam_to_world):
        w2c = invert_rigid(c2w)
        q, t = quat_wxyz_from_rotmat(w2c[:3, :3]), w2c[:3, 3]
        numbers = " ".join(repr(float(v)) for v in (*q, *t))
        lines += [f"{k + 1} {numbers} 1 f{k:02d}.jpg", ""]
        (images / f"f{k:02d}.jpg").write_bytes(bytes(scene.images[k]))
    (model / "images.txt").write_text("\n".join(lines) + "\n")
    (model / "points3D.txt").write_text("")
    rc, out = _check([str(model)], capsys)
    assert rc == 0 and "(colmap)" in out, out


def test_near_far_suggested_from_triangulated_matches_and_clipping_flagged(good, tmp_path, capsys):
    """Consistent cameras: near/far suggested from the triangulated matches by ingest's rule (0.4 x p0.1,
    1.5 x p99.9 of the depths) with the RE10K rescale; a stored near beyond the points is flagged."""
    rc, out = _check([str(good), "--out", str(tmp_path / "o")], capsys)
    nf = json.loads((tmp_path / "o" / "check.json").read_text())["scenes"][0]["near_far"]
    assert rc == 0 and nf["source"] == "triangulated_matches" and nf["points"] >= 30, out
    p = nf["depth_percentiles"]
    assert nf["near"] == pytest.approx(0.4 * p["p0.1"]) and nf["far"] == pytest.approx(1.5 * p["p99.9"])
    assert nf["re10k_scale"] == pytest.approx(1.0 / nf["near"])
    scene = PosedDataset(good).load_scene("syn0")  # exact synthetic depths: min/max rendered depth +- 10 %
    assert 0.3 * scene.near < nf["near"] < 3 * scene.near and nf["stored_clips"] is None
    assert f"near/far from {nf['points']} triangulated matches" in out and "warning" not in out
    scene.near = 2 * p["p50"]  # nearer than half the points
    with PosedDatasetWriter(tmp_path / "clipped", {"test": True}, provenance("tests")) as w:
        w.add(scene)
    rc, out = _check([str(tmp_path / "clipped"), "--out", str(tmp_path / "c")], capsys)
    rep = json.loads((tmp_path / "c" / "check.json").read_text())
    assert rc == 0 and rep["near_far_clipped"] == ["syn0"], out
    assert rep["scenes"][0]["near_far"]["points_nearer_than_stored_near_pct"] > 50
    assert "warning: the stored near/far clip the points (near" in out
