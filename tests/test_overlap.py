"""The view-overlap measure and its stored table: closed forms, the exact overlap of synthetic scenes
(`synthetic.true_overlap`, from rendered depth), SfM tracks from a real ingest, frame-order
detection, the table written by every writer, checked by validate and added by `seeu overlap`."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pyarrow as pa
import pytest

from pipelines.cli import main as cli_main
from seeu_data.overlap import (
    FLOOR,
    camera_overlap_matrix,
    canonical_order,
    frame_order_is_path,
    from_matrix,
    overlap_from_cameras,
    overlap_from_observations,
)
from seeu_data.store.arrow_io import read_table, write_table
from seeu_data.store.overlap_table import OverlapReader
from seeu_data.store.posed import PosedDataset
from seeu_data.synthetic import camera_path
from tests.helpers import look_at_cam_to_world

# The stated tolerances (docs/formats.md, "View overlap"): the cameras measure against the exact
# overlap of the synthetic scenes, median |error| over all pairs; the tracks measure on close pairs
# (exact overlap >= 0.5), median and largest |error|, and nowhere above the truth by more than
# TRACKS_OVER (it counts only what SfM matched, so wider pairs come out lower).
CAMERAS_MEDIAN_TOL = 0.15
TRACKS_MEDIAN_TOL = 0.1
TRACKS_MAX_TOL = 0.25
TRACKS_OVER = 0.1
# exact tracks (`synthetic.exact_observations`: points lifted from every 4th pixel) sample a view's
# content by point density, not by area
EXACT_TRACKS_MEDIAN_TOL = 0.1
EXACT_TRACKS_MAX_TOL = 0.2


def test_tracks_overlap_counts_shared_points():
    # frame 0 sees points 1..4, frame 1 sees 3..8, frame 2 sees 8 only; a repeated observation counts once
    frames = np.array([0, 0, 0, 0, 0, 1, 1, 1, 1, 1, 1, 2])
    points = np.array([1, 2, 3, 4, 4, 3, 4, 5, 6, 7, 8, 8])
    m = overlap_from_observations(3, frames, points, block=2).matrix()
    assert m[0, 1] == pytest.approx(2 / 4) and m[1, 0] == pytest.approx(2 / 6)
    assert m[1, 2] == pytest.approx(1 / 6) and m[2, 1] == 1.0 and m[0, 2] == 0.0
    assert np.allclose(np.diag(m), 1.0)


def test_camera_overlap_closed_forms():
    intr = np.array([1.0, 1.0, 0.5, 0.5])
    a = look_at_cam_to_world(np.array([0.0, 0, 0]), np.array([0.0, 0, 1]))
    back = look_at_cam_to_world(np.array([0.0, 0, 0]), np.array([0.0, 0, -1]))
    far = look_at_cam_to_world(np.array([50.0, 0, 0]), np.array([50.0, 0, 1]))
    m = camera_overlap_matrix(np.stack([a, a, back, far]), np.tile(intr, (4, 1)), 1.0, 10.0)
    assert m[0, 1] == pytest.approx(1.0) and m[0, 2] == 0.0 and m[2, 0] == 0.0 and m[0, 3] == 0.0
    # facing each other across a point: every sample inside both images, but seen from opposite sides
    facing = look_at_cam_to_world(np.array([0.0, 0, 8]), np.array([0.0, 0, 0]))
    m = camera_overlap_matrix(np.stack([a, facing]), np.tile(intr, (2, 1)), 3.0, 5.0, grid=1, depths=1)
    assert m[0, 1] == pytest.approx(0.0, abs=1e-6)


def test_sparse_table_keeps_pairs_above_the_floor():
    m = np.array([[1.0, 0.6, 0.01], [0.3, 1.0, 0.2], [0.02, 0.04, 1.0]])
    t = from_matrix(m, "cameras")
    assert list(zip(t.frame_a, t.frame_b)) == [(0, 1), (1, 2)]  # (0, 2) is below FLOOR both ways
    assert np.allclose(t.matrix(), np.where(np.maximum(m, m.T) >= FLOOR, m, 0.0) + np.eye(3) * (1 - np.diag(m)))
    assert t.pair_scores()[0, 1] == pytest.approx(0.3)
    capped = from_matrix(np.full((10, 10), 0.5), "cameras", max_partners=3)
    partners = np.bincount(np.concatenate([capped.frame_a, capped.frame_b]), minlength=10)
    assert len(capped) <= 10 * 3 and partners.min() >= 3  # each frame keeps 3, so at most N * 3 pairs


def test_camera_overlap_against_the_exact_overlap(overlap_scenes):
    """The cameras measure on the orbit and the wide set vs the overlap from rendered depth (within
    CAMERAS_MEDIAN_TOL), and each frame's best partner among the truth's best three."""
    for name in ("orbit", "wide"):
        scene = PosedDataset(overlap_scenes[name]).load_scene(name)
        est = camera_overlap_matrix(scene.cam_to_world, scene.intrinsics_norm, scene.near, scene.far)
        truth = overlap_scenes[f"truth_{name}"]
        assert np.median(np.abs(est - truth)) < CAMERAS_MEDIAN_TOL, name
        for a in range(len(truth)):
            best = int(np.argmax(np.where(np.eye(len(truth), dtype=bool)[a], -1, est[a])))
            assert best in np.argsort(-np.where(np.arange(len(truth)) == a, -1, truth[a]))[:3], (name, a)


def test_stored_tables_of_the_test_scenes(overlap_scenes):
    """The test scenes' stored tables (from their exact tracks) against the exact overlap, and the
    shuffled orbit's table equal to the orbit's, permuted."""
    for name in ("orbit", "wide"):
        ds = PosedDataset(overlap_scenes[name])
        table = ds.overlap(name)
        err = np.abs(table.matrix() - overlap_scenes[f"truth_{name}"])
        assert (
            table.method == "tracks" and np.median(err) < EXACT_TRACKS_MEDIAN_TOL and err.max() < EXACT_TRACKS_MAX_TOL
        )
    order = overlap_scenes["shuffled_order"]
    orbit = PosedDataset(overlap_scenes["orbit"]).overlap("orbit").matrix()
    assert np.array_equal(
        PosedDataset(overlap_scenes["shuffled"]).overlap("orbit").matrix(), orbit[np.ix_(order, order)]
    )


def test_frame_order_detection(overlap_scenes):
    orbit = PosedDataset(overlap_scenes["orbit"]).load_scene("orbit").cam_to_world
    assert frame_order_is_path(orbit) and frame_order_is_path(camera_path(40))
    assert not frame_order_is_path(orbit[overlap_scenes["shuffled_order"]])
    assert not frame_order_is_path(PosedDataset(overlap_scenes["wide"]).load_scene("wide").cam_to_world)


def test_canonical_order_ignores_numbering(overlap_scenes):
    scene = PosedDataset(overlap_scenes["orbit"]).load_scene("orbit")
    order = overlap_scenes["shuffled_order"]
    a = canonical_order(scene.cam_to_world, scene.intrinsics_norm)
    b = canonical_order(scene.cam_to_world[order], scene.intrinsics_norm[order])
    assert np.array_equal(a, order[b])  # the same cameras in the same canonical order


def test_written_table_is_validated(workspace, tmp_path, capsys):
    root = tmp_path / "posed"
    shutil.copytree(workspace["posed"], root)
    assert cli_main(["validate", str(root)]) == 0
    assert "overlap tables: 1 files (1 from cameras)" in capsys.readouterr().out
    ds = PosedDataset(root)
    (sid,) = ds.scene_ids
    scene = ds.load_scene(sid)
    stored = OverlapReader(root, ds.manifest).table(sid)
    again = overlap_from_cameras(scene.cam_to_world, scene.intrinsics_norm, scene.near, scene.far)
    assert stored is not None and np.array_equal(stored.matrix(), again.matrix())
    # a damaged overlap (out of [0, 1]) written with a true size and sha256: validate refuses it in one line
    doc = json.loads((root / "manifest.json").read_text())
    entry = doc["overlap"]["files"][0]
    table = read_table(root / entry["path"])
    values = table.column("overlap_ab").combine_chunks()
    bad = pa.ListArray.from_arrays(values.offsets, pa.array(np.full(len(values.values), 1.5, np.float32)))
    table = table.set_column(table.schema.get_field_index("overlap_ab"), table.schema.field("overlap_ab"), bad)
    entry["bytes"], entry["sha256"] = write_table(root / entry["path"], table)
    (root / "manifest.json").write_text(json.dumps(doc))
    assert cli_main(["validate", str(root)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "an overlap is not in [0, 1]" in err and entry["path"] in err


def test_seeu_overlap_adds_the_table_to_old_data(workspace, tmp_path, capsys):
    root = tmp_path / "old"
    shutil.copytree(workspace["posed"], root)
    doc = json.loads((root / "manifest.json").read_text())
    (sid,) = [s["scene_id"] for s in doc["scenes"]]
    written = OverlapReader(root, doc).table(sid)
    for f in doc.pop("overlap")["files"]:  # as written before overlap tables existed
        (root / f["path"]).unlink()
    (root / "manifest.json").write_text(json.dumps(doc))
    assert cli_main(["validate", str(root)]) == 0
    assert "no overlap table (add one with: seeu overlap" in capsys.readouterr().out
    assert cli_main(["overlap", str(root)]) == 0
    assert "1 scenes measured" in capsys.readouterr().out
    ds = PosedDataset(root)
    added = OverlapReader(root, ds.manifest).table(sid)
    assert added is not None and written is not None and np.array_equal(added.matrix(), written.matrix())
    assert cli_main(["validate", str(root)]) == 0
    assert cli_main(["overlap", str(root)]) == 0 and "already has its overlap tables" in capsys.readouterr().out


@pytest.mark.slow
def test_ingest_stores_the_overlap_of_its_tracks(overlap_scenes, tmp_path):
    """A real ingest of the orbit's photos: the stored table is measured from the SfM tracks and matches
    the exact overlap on close pairs (TRACKS_*_TOL), is never much above it (TRACKS_OVER), and ranks
    each frame's best partner among the truth's best two."""
    images = tmp_path / "photos"
    images.mkdir()
    scene = PosedDataset(overlap_scenes["orbit"]).load_scene("orbit")
    for k, data in enumerate(scene.images):
        (images / f"img_{k:02d}.jpg").write_bytes(bytes(data))
    assert cli_main(["ingest", str(images), "--out", str(tmp_path / "posed"), "--no-progress"]) == 0
    root = next((tmp_path / "posed").glob("*/manifest.json")).parent
    ds = PosedDataset(root)
    (sid,) = ds.scene_ids
    table = OverlapReader(root, ds.manifest).table(sid)
    ingested = ds.load_scene(sid)
    assert table is not None and table.method == "tracks" and len(ingested) == 24
    rows = [int(name[4:6]) for name in ingested.source_name]  # each posed frame's orbit view
    truth = overlap_scenes["truth_orbit"][np.ix_(rows, rows)]
    est = table.matrix()
    close = (truth >= 0.5) & ~np.eye(24, dtype=bool)
    err = np.abs(est - truth)[close]
    assert close.sum() >= 48 and np.median(err) < TRACKS_MEDIAN_TOL and err.max() < TRACKS_MAX_TOL
    assert (est <= truth + TRACKS_OVER).all()
    for a in range(24):
        others = np.arange(24) != a
        best = np.flatnonzero(others)[np.argmax(est[a, others])]
        assert best in np.argsort(-np.where(others, truth[a], -1))[:2]


def test_the_camera_overlap_runs_on_one_blas_thread(monkeypatch):
    """Its 3-column products only wait with more BLAS threads (2.5x the CPU with 2, 3.5x the import's time
    on a 16-core node): inside, BLAS has one thread; outside, the process's count is back."""
    from threadpoolctl import threadpool_info

    from seeu_data import overlap as ov

    def blas_threads() -> list[int]:
        return [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]

    seen = []
    inner = ov._camera_overlap_matrix

    def spy(*args):
        seen.append(blas_threads())
        return inner(*args)

    monkeypatch.setattr(ov, "_camera_overlap_matrix", spy)
    before = blas_threads()
    c2w = np.tile(np.eye(4), (6, 1, 1))
    c2w[:, 0, 3] = np.arange(6) * 0.1
    m = ov.camera_overlap_matrix(c2w, np.tile([0.8, 1.4, 0.5, 0.5], (6, 1)), 0.5, 20.0)
    assert m.shape == (6, 6) and seen and all(n == [1] * len(n) for n in seen) and seen[0]
    assert blas_threads() == before
