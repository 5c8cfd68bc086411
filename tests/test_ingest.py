"""`seeu ingest` end to end on a small synthetic clip (accuracy against the exact ground truth), resume,
frame selection, chunking, and ingest's bad inputs (one line, exit 2, nothing that looks complete)."""

from __future__ import annotations

import json
import shutil
import tempfile
from pathlib import Path

import cv2
import numpy as np
import pytest

from pipelines.cli import main as cli_main
from pipelines.validate import validate_dataset
from seeu_data import cameras as cam
from seeu_data.ingest.chunks import ChunkConfig, plan_chunks
from seeu_data.ingest.frame_select import SelectConfig, drop_blurriest_per_window, evenly_spaced, select_frames
from seeu_data.ingest.pose_eval import pose_accuracy, umeyama
from seeu_data.ingest.report import summary_line
from seeu_data.ingest.scale import ScaleConfig
from seeu_data.ingest.video import discover_sources, iter_frames, sharpness
from seeu_data.store.posed import PosedDataset
from seeu_data.synthetic import (
    camera_path,
    default_intrinsics_norm,
    ingest_accuracy,
    load_ground_truth,
    make_scene,
    mask_accuracy,
    render_view,
    write_clip,
)

W, H, N = 320, 180, 36
# A synthetic walk (scene seed 0) that COLMAP's default initial-pair limits cannot map (forward motion):
# no mapping run finds a model at 10 frames of 360x640 or of 450x800, nor at 12 of 360x640. Which
# walks fail is a matter of small margins (the first round maps 12 frames of 450x800, scene seeds 1 and
# 2 at 12 frames of 360x640, and 16 frames of 450x800 from its second mapping seed), so a change to
# extraction, pair choice or motion masking may need another walk here: the test then fails at its
# first assertion.
FORWARD_SIZE, FORWARD_FRAMES = (360, 640), 10


pytestmark = pytest.mark.usefixtures("no_heartbeat")  # conftest: one-line error checks


@pytest.fixture(scope="module")
def clip(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("clip")
    write_clip(root / "walk.mp4", n_frames=N, size=(H, W), seed=0)
    return root / "walk.mp4"


@pytest.fixture(scope="module")
def ingested(clip, tmp_path_factory):
    """One ingest shared by the tests: first run, then the same command again (resume). Every core (results
    do not depend on the thread count; the --force re-run below must give bit-identical poses)."""
    out = tmp_path_factory.mktemp("posed")
    argv = ["ingest", str(clip), "--out", str(out)]
    assert cli_main(argv) == 0
    report1 = json.loads((out / "walk" / "report.json").read_text())
    stages1 = _stage_files(out)
    assert cli_main(argv) == 0
    report2 = json.loads((out / "walk" / "report.json").read_text())
    return {"out": out, "argv": argv, "report1": report1, "report2": report2, "stages": (stages1, _stage_files(out))}


def _stage_files(out: Path) -> dict[str, int]:
    """The files the decode and SfM stages wrote under OUT/.work/walk, with their mtime_ns."""
    work = out / ".work" / "walk"
    files = [p for stage in ("decode", "sfm") for p in (work / stage).rglob("*") if p.is_file()]
    return {str(p.relative_to(work)): p.stat().st_mtime_ns for p in files}


def _expect_failure(argv, capsys, *needles) -> str:
    assert cli_main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0, err  # one line
    for needle in needles:
        assert needle in err, err
    return err


def _no_complete_output(out: Path) -> None:
    assert not list(out.glob("*/manifest.json")), list(out.glob("*/manifest.json"))


# ---------------------------------------------------------------------------------------------
# End to end
# ---------------------------------------------------------------------------------------------


def test_a_known_focal_length_is_held_through_sfm(clip, tmp_path, capsys):
    """`--focal F`: the shared camera starts at F x the longer side as a known prior, and mapping and the final
    adjustment keep it (the model's camera, before undistortion, holds it exactly; the distortion is still
    estimated); at the renderer's own focal length the cameras are as accurate as estimated ones. Outside
    0.1-10, a one-line error."""
    import pycolmap

    gt = load_ground_truth(clip)
    truth = float(gt["intrinsics_norm"][0][0])  # fx over the width: the longer side of a 320x180 frame
    for focal in (truth, 1.1 * truth):
        out = tmp_path / f"posed-{focal:.4f}"
        assert cli_main(["ingest", str(clip), "--out", str(out), "--focal", f"{focal!r}"]) == 0
        sparse = sorted((out / ".work" / "walk" / "sfm" / "sparse").iterdir())
        for model in sparse:
            (camera,) = pycolmap.Reconstruction(model).cameras.values()
            assert camera.params[0] == pytest.approx(focal * W, rel=1e-9), (focal, camera.params)
        if focal == truth:
            scene = PosedDataset(out / "walk").load_scene("walk_c0")
            rows = [int(np.nonzero(gt["frame"] == f)[0][0]) for f in scene.source_frame]
            assert pose_accuracy(scene.cam_to_world, gt["cam_to_world"][rows]).centre_rmse_pct_path <= 0.5
    for bad in ("0", "11", "nan"):
        _expect_failure(["ingest", str(clip), "--out", str(tmp_path / "bad"), "--focal", bad], capsys, "--focal")
    _no_complete_output(tmp_path / "bad")


def test_end_to_end_registration_and_accuracy(ingested, clip, capsys):
    out = ingested["out"] / "walk"
    summary = validate_dataset(out)
    report = ingested["report1"]
    assert report["frames_selected"] == N and report["registered"] / N >= 0.95
    assert report["mean_reprojection_error_px"] < 1.0
    ds = PosedDataset(out, verify=True)
    assert ds.scene_ids == ["walk_c0"] and summary["rows"] >= 0.95 * N
    scene = ds.load_scene("walk_c0")
    # Independent check against the ground-truth JSON, matched through source_frame.
    gt = load_ground_truth(clip)
    rows = [int(np.nonzero(gt["frame"] == f)[0][0]) for f in scene.source_frame]
    assert list(scene.source_frame) == sorted(scene.source_frame)
    assert np.allclose(scene.timestamp_us, np.asarray(rows) * 1e6 / 30.0, atol=1)
    acc = pose_accuracy(scene.cam_to_world, gt["cam_to_world"][rows])
    assert acc.centre_rmse_pct_path <= 0.5, acc
    assert acc.rel_rot_err_mean_deg <= 0.2, acc
    # The stored pinhole focal (pixels, after undistortion's crop) matches the true one within 2 % at 320x180.
    fx_px = scene.intrinsics_norm[0, 0] * scene.width[0]
    assert fx_px == pytest.approx(gt["intrinsics_norm"][0, 0] * W, rel=0.02)
    assert abs(scene.intrinsics_norm[0, 2] - 0.5) < 0.02 and abs(scene.intrinsics_norm[0, 3] - 0.5) < 0.02
    img = cv2.imdecode(np.frombuffer(scene.images[0], np.uint8), cv2.IMREAD_COLOR)
    assert img.shape == (scene.height[0], scene.width[0], 3)
    # Scale: first camera at the identity, median depth of the scene ~1, so true depths map inside near/far.
    assert np.allclose(scene.cam_to_world[0], np.eye(4), atol=1e-9)
    scene_gt = make_scene(0)
    for k in (5, 30):
        _, depth = render_view(scene_gt, gt["cam_to_world"][rows[k]], gt["intrinsics_norm"][0], W, H)
        chunk_depths = depth[np.isfinite(depth)] / acc.alignment_scale  # metres -> chunk units
        assert scene.near < np.percentile(chunk_depths, 1) and np.percentile(chunk_depths, 99) < scene.far
    # The report's own ground-truth section agrees with this computation; trajectory plot exists.
    rep_gt = ingest_accuracy(out, clip, report["registered"], report["frames_selected"])["chunks"][0]
    assert rep_gt["centre_rmse"] == pytest.approx(acc.centre_rmse, rel=1e-6)
    assert rep_gt["focal_err_pct"] < 2.0
    png = cv2.imread(str(out / "trajectory.png"))
    assert png is not None and png.shape[0] > 200
    assert ds.manifest["report"]["registered"] == report["registered"]
    # the solution check passed and is recorded with the chunk; a walk of 7 m has ample parallax
    assert scene.meta["sfm_solution_check"] == "passed" and report["warnings"] == []
    assert report["chunks"][0]["baseline_over_depth"] == pytest.approx(scene.meta["baseline_over_depth"])
    assert scene.meta["baseline_over_depth"] > 0.1 and scene.meta["degeneracy"] is None
    # nothing moves in the walk: --dynamic mask (the default) masks at most a stated share of its pixels
    assert report["motion"]["mode"] == "mask" and mask_accuracy(out, clip)["false_positive_pct"] < 0.5


def test_check_cameras_on_ingested_scene(ingested, tmp_path, capsys):
    """`seeu check-cameras` passes the ingested walk (median Sampson error stated) and suggests near/far
    from the SfM points ingest kept, by ingest's own rule: its re10k near/far (1 / 100) clip nothing."""
    capsys.readouterr()
    assert cli_main(["check-cameras", str(ingested["out"] / "walk"), "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    rep = json.loads((tmp_path / "check.json").read_text())
    nf = rep["scenes"][0]["near_far"]
    assert rep["verdict"] == "consistent" and rep["median_error_px"] < 1.0, out
    assert f"median Sampson error {rep['median_error_px']:.2f} px" in out
    assert nf["source"] == "sfm_points" and nf["stored"] == [1.0, 100.0] and nf["stored_clips"] is None, nf
    assert 0.5 < nf["near"] < 2.0 and nf["re10k_points_farther_than_far_pct"] == 0.0


def test_resume_reuses_stages_and_force_redoes(ingested, capsys):
    r1, r2 = ingested["report1"], ingested["report2"]
    assert r1["reused"] == {"decode": False, "sfm": False}
    assert r2["reused"] == {"decode": True, "sfm": True}
    stages1, stages2 = ingested["stages"]  # the resume rewrote none of the stages' files
    assert any(name.startswith("sfm/") for name in stages1) and stages2 == stages1
    assert r2["chunks"] == r1["chunks"]
    out = ingested["out"]
    poses_before = PosedDataset(out / "walk").load_scene("walk_c0").cam_to_world
    assert cli_main(ingested["argv"] + ["--force"]) == 0
    r3 = json.loads((out / "walk" / "report.json").read_text())
    assert r3["reused"] == {"decode": False, "sfm": False}
    stages3 = _stage_files(out)  # --force wrote every one again
    assert stages3.keys() == stages1.keys() and all(stages3[k] != stages1[k] for k in stages1)
    assert r3["registered"] == r1["registered"]
    # COLMAP redone from scratch gives bit-identical poses
    assert np.array_equal(PosedDataset(out / "walk").load_scene("walk_c0").cam_to_world, poses_before)
    # A changed parameter redoes only the stages downstream of it (decode is reused).
    assert cli_main(ingested["argv"] + ["--target-frames", "30"]) == 0
    r4 = json.loads((out / "walk" / "report.json").read_text())
    assert r4["reused"] == {"decode": True, "sfm": False} and r4["frames_selected"] == 30
    assert len(r4["dropped_frames"]) == N - 30 + (30 - r4["frames_in_chunks"])
    validate_dataset(out / "walk")


# ---------------------------------------------------------------------------------------------
# Units: decoding, selection, chunks, alignment
# ---------------------------------------------------------------------------------------------


def test_decode_stride_keeps_source_frames(clip):
    (src,) = discover_sources([clip])
    frames = list(iter_frames(src, stride=4))
    assert [f.source_frame for f in frames] == list(range(0, N, 4))
    cap = cv2.VideoCapture(str(clip))
    for _ in range(9):
        ok, bgr = cap.read()
        assert ok
    assert np.array_equal(frames[2].rgb, cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))  # frame 8


def test_sharpness_filter_drops_the_blurred_frame():
    scene = make_scene(1)
    poses = camera_path(8)
    intr = default_intrinsics_norm(160, 96)
    imgs = [render_view(scene, p, intr, 160, 96)[0] for p in poses]
    imgs[5] = cv2.GaussianBlur(imgs[5], (0, 0), 2.0)
    scores = [sharpness(i) for i in imgs]
    kept, dropped = drop_blurriest_per_window(np.array(scores), 4)
    assert 5 in dropped and len(dropped) == 2 and len(kept) == 6
    source = np.arange(8) * 3  # as if decoded with --stride 3
    keep, dropped_info = select_frames(scores, source, SelectConfig(stride=3, sharpness_window=4, target_frames=4))
    assert len(keep) == 4 and 5 not in keep
    assert {d["source_frame"] for d in dropped_info} == set(source) - set(source[keep])
    assert list(evenly_spaced(10, 4)) == [0, 3, 6, 9]


def test_umeyama_recovers_a_known_similarity():
    rng = np.random.default_rng(0)
    src = rng.normal(size=(20, 3))
    rot = cam.rotmat_from_quat_wxyz(rng.normal(size=4))
    dst = 2.5 * src @ rot.T + np.array([1.0, -2.0, 0.5])
    sim = umeyama(src, dst)
    assert sim.scale == pytest.approx(2.5) and np.allclose(sim.rotation, rot) and np.allclose(sim.apply(src), dst)


def _fake_model(index, names, poses, depth_scale, out: Path):
    np.save(out / f"points_depth_{index}.npy", depth_scale * np.linspace(0.5, 1.5, 101))
    w2c = cam.world_to_cam_from_cam_to_world(poses)
    return {
        "index": index,
        "undistorted": False,
        "image_dir": str(out),
        "mean_reprojection_error": 0.5,
        "camera": {
            "model": "PINHOLE",
            "width": 100,
            "height": 50,
            "params": [80, 80, 50, 25],
            "fx": 80.0,
            "fy": 80.0,
            "cx": 50.0,
            "cy": 25.0,
        },
        "images": [{"name": n, "world_to_cam": w[:3].tolist()} for n, w in zip(names, w2c)],
    }


def test_chunks_split_runs_claim_frames_and_normalise_scale(tmp_path):
    names = [f"{i:06d}.jpg" for i in range(30)]
    poses = camera_path(30)
    poses_scaled = poses.copy()
    poses_scaled[:, :3, 3] *= 3.0  # model 0 is in another scale: depths 3x
    # model 0: frames 0-13 and 15-29 (frame 14 unregistered: splits the run); model 1 overlaps 20-29 + 3 extra
    m0 = [i for i in range(30) if i != 14]
    m1 = list(range(20, 30))
    res = {
        "models": [
            _fake_model(0, [names[i] for i in m0], poses_scaled[m0], 3.0, tmp_path),
            _fake_model(1, [names[i] for i in m1], poses[m1], 1.0, tmp_path),
        ]
    }
    chunks, dropped = plan_chunks(
        "s", names, res, tmp_path, ChunkConfig(min_chunk_frames=15, scale=ScaleConfig("median-depth"))
    )
    # run 0-13 (14 frames) is too short; 15-29 kept from the larger model; model 1's frames are claimed
    assert [c.scene_id for c in chunks] == ["s_c0"] and chunks[0].frame_positions == list(range(15, 30))
    assert {d["position"] for d in dropped} == set(range(15))
    assert any("not registered" in d["reason"] for d in dropped if d["position"] == 14)
    c = chunks[0]
    # scale: median depth 3.0 -> 1; poses relative to the first camera, so they equal the truth up to scale 1/3 * 3
    expected = cam.invert_rigid(poses[15]) @ poses[15:]
    assert np.allclose(c.cam_to_world, expected, atol=1e-9)
    assert c.near == pytest.approx(0.4 * np.percentile(np.linspace(0.5, 1.5, 101), 0.1))
    assert c.far == pytest.approx(1.5 * np.percentile(np.linspace(0.5, 1.5, 101), 99.9))
    assert np.allclose(c.intrinsics_norm, [0.8, 1.6, 0.5, 0.5])


# ---------------------------------------------------------------------------------------------
# Bad input: one line naming the input, exit 2, no output that looks complete
# ---------------------------------------------------------------------------------------------


def _write_video(path: Path, frames: list[np.ndarray]) -> Path:
    h, w = frames[0].shape[:2]
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*"mp4v"), 30, (w, h))
    for f in frames:
        vw.write(cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
    vw.release()
    return path


def test_missing_path(tmp_path, capsys):
    _expect_failure(
        ["ingest", str(tmp_path / "nope.mp4"), "--out", str(tmp_path / "out")], capsys, "nope.mp4", "no such file"
    )
    _no_complete_output(tmp_path / "out")


def test_not_a_video(tmp_path, capsys):
    (tmp_path / "notes.txt").write_text("hello")
    _expect_failure(
        ["ingest", str(tmp_path / "notes.txt"), "--out", str(tmp_path / "out")], capsys, "notes.txt", "not a video"
    )
    (tmp_path / "fake.mp4").write_text("hello, not a video\n")
    _expect_failure(
        ["ingest", str(tmp_path / "fake.mp4"), "--out", str(tmp_path / "out")],
        capsys,
        "fake.mp4",
        "cannot be opened as a video",
    )
    _no_complete_output(tmp_path / "out")


def test_truncated_and_corrupt_mp4(clip, tmp_path, capsys):
    data = clip.read_bytes()
    (tmp_path / "trunc.mp4").write_bytes(data[: len(data) // 2])
    _expect_failure(
        ["ingest", str(tmp_path / "trunc.mp4"), "--out", str(tmp_path / "out")], capsys, "trunc.mp4", "truncated"
    )
    corrupt = bytearray(data)
    corrupt[len(data) // 3 : len(data) // 3 + 20000] = bytes(20000)
    (tmp_path / "corrupt.mp4").write_bytes(bytes(corrupt))
    _expect_failure(
        ["ingest", str(tmp_path / "corrupt.mp4"), "--out", str(tmp_path / "out")], capsys, "corrupt.mp4", "corrupt"
    )
    _no_complete_output(tmp_path / "out")


def test_too_few_frames(tmp_path, capsys):
    write_clip(tmp_path / "short.mp4", n_frames=5, size=(96, 160), seed=0)
    _expect_failure(
        ["ingest", str(tmp_path / "short.mp4"), "--out", str(tmp_path / "out")],
        capsys,
        "short.mp4",
        "only 5 usable frame",
    )
    _no_complete_output(tmp_path / "out")


def test_static_camera_no_model(tmp_path, capsys):
    scene = make_scene(0)
    rgb, _ = render_view(scene, camera_path(30)[10], default_intrinsics_norm(W, H), W, H)
    _write_video(tmp_path / "static.mp4", [rgb] * 12)
    _expect_failure(
        ["ingest", str(tmp_path / "static.mp4"), "--out", str(tmp_path / "out")],
        capsys,
        "static.mp4",
        "no model",
        "after 3 mapping runs",
    )
    _no_complete_output(tmp_path / "out")


def test_blank_clip_and_workers(tmp_path, capsys):
    """Two bad scenes in a folder of videos, processed by two workers: one line each, exit 2."""
    vids = tmp_path / "videos"
    vids.mkdir()
    _write_video(vids / "blank.mp4", [np.full((96, 160, 3), 128, np.uint8)] * 12)
    shutil.copy(vids / "blank.mp4", vids / "blank2.mp4")
    _expect_failure(
        ["ingest", str(vids / "blank.mp4"), "--out", str(tmp_path / "out")], capsys, "blank.mp4", "blank or textureless"
    )
    assert cli_main(["ingest", str(vids), "--out", str(tmp_path / "out"), "--workers", "2"]) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 2 and all("blank or textureless" in ln for ln in lines)
    assert "0/2 scenes ingested" in captured.out
    _no_complete_output(tmp_path / "out")


def test_failed_rerun_invalidates_previous_output(ingested, tmp_path, capsys):
    """A scene whose re-run fails must not keep an old manifest that looks like this run's result (the
    re-run's input is another file, so it takes --force to replace the scene)."""
    out = tmp_path / "out"
    shutil.copytree(ingested["out"] / "walk", out / "walk")
    assert (out / "walk" / "manifest.json").exists()
    vid = tmp_path / "walk.mp4"
    _write_video(vid, [np.full((96, 160, 3), 128, np.uint8)] * 12)
    _expect_failure(["ingest", str(vid), "--out", str(out)], capsys, "another input")
    assert (out / "walk" / "manifest.json").exists()
    _expect_failure(["ingest", str(vid), "--out", str(out), "--force"], capsys, "walk.mp4")
    _no_complete_output(out)


def test_image_folders_and_folder_of_videos(tmp_path, clip):
    imgs = tmp_path / "photos"
    imgs.mkdir()
    (src,) = discover_sources([clip])
    for fr in iter_frames(src, stride=3):
        cv2.imwrite(str(imgs / f"img{fr.source_frame}.png"), cv2.cvtColor(fr.rgb, cv2.COLOR_RGB2BGR))
    (folder,) = discover_sources([imgs])
    assert folder.kind == "images" and folder.name == "photos"
    frames = list(iter_frames(folder, stride=2))
    # natural order (img3 before img12), source_frame = position in the folder, names kept
    assert [f.source_name for f in frames] == [f"img{i}.png" for i in range(0, N, 6)]
    assert [f.source_frame for f in frames] == list(range(0, N // 3, 2))
    vids = tmp_path / "videos"
    vids.mkdir()
    shutil.copy(clip, vids / "a.mp4")
    shutil.copy(clip, vids / "b.mov")
    assert [(s.name, s.kind) for s in discover_sources([vids])] == [("a", "video"), ("b", "video")]
    # frames of different sizes each get a camera of their size (tests/test_photo_folders.py), no refusal


def test_colmap_abort_in_child_is_one_line(clip, tmp_path, capsys):
    """An invalid vocabulary tree makes COLMAP abort (SIGABRT): only the child dies; the user gets one line."""
    bogus = tmp_path / "vocab.bin"
    bogus.write_bytes(b"not a vocabulary tree")
    _expect_failure(
        [
            "ingest",
            str(clip),
            "--out",
            str(tmp_path / "out"),
            "--target-frames",
            "8",
            "--min-chunk-frames",
            "3",
            "--vocab-tree",
            str(bogus),
        ],
        capsys,
        "walk.mp4",
        "COLMAP aborted",
    )
    _expect_failure(
        ["ingest", str(clip), "--out", str(tmp_path / "out"), "--vocab-tree", str(tmp_path / "none.bin")],
        capsys,
        "none.bin",
        "vocabulary-tree file not found",
    )
    _no_complete_output(tmp_path / "out")


def test_split_clip_gives_two_chunks_and_reports_dropped_frames(tmp_path, fsyncs):
    """Frames 16-21 of a 38-frame walk are blank: SfM cannot register them, the run splits into two
    chunks, each accurate against the ground truth, and the report names the dropped frames. Run
    with --fsync: the posed file, the manifest, the report and the stage journal's records are
    fsynced (before their renames, the journal as each record is written)."""
    n, blank = 38, range(16, 22)
    scene = make_scene(0)
    poses = camera_path(n)
    intr = default_intrinsics_norm(W, H)
    frames = [
        np.full((H, W, 3), 128, np.uint8) if i in blank else render_view(scene, poses[i], intr, W, H)[0]
        for i in range(n)
    ]
    vid = _write_video(tmp_path / "split.mp4", frames)
    assert cli_main(["ingest", str(vid), "--out", str(tmp_path / "out"), "--fsync"]) == 0
    synced = [Path(p).name for kind, p in fsyncs if kind == "fsync"]
    for name in ("posed-00000.arrow", "manifest.json", "report.json"):
        assert any(n.startswith(f".{name}.") for n in synced), (name, synced)
    assert "stages.jsonl" in synced, synced
    report = json.loads((tmp_path / "out" / "split" / "report.json").read_text())
    assert [c["scene_id"] for c in report["chunks"]] == ["split_c0", "split_c1"]
    assert report["chunks"][0]["source_frames"][1] < 16 and report["chunks"][1]["source_frames"][0] > 21
    dropped = {d["source_frame"]: d["reason"] for d in report["dropped_frames"]}
    assert set(blank) <= set(dropped) and all("not registered" in dropped[i] for i in blank)
    ds = PosedDataset(tmp_path / "out" / "split", verify=True)
    for sid in ds.scene_ids:
        s = ds.load_scene(sid)
        acc = pose_accuracy(s.cam_to_world, poses[s.source_frame])
        assert acc.centre_rmse_pct_path < 0.5 and acc.rel_rot_err_mean_deg < 0.2, (sid, acc)


def test_mapping_is_retried_with_the_next_seed_and_implausible_cameras_are_rejected(ingested, tmp_path):
    """A first mapping run whose shared camera ends implausible (k = 1.7, as a poor initial pair can
    leave it) registers nothing usable: the next seed is mapped and kept; a run that registers every
    frame ends the retries; when every run fails, nothing is returned."""
    import pycolmap

    from seeu_data.ingest.sfm import SfmConfig
    from seeu_data.ingest.solution_check import map_with_retries

    sfm_dir = ingested["out"] / ".work" / "walk" / "sfm"
    job = json.loads((sfm_dir / "job.json").read_text())
    seeds = []

    def map_once(seed):
        seeds.append(seed)
        options = pycolmap.IncrementalPipelineOptions()
        options.num_threads, options.random_seed, options.min_model_size = 1, seed, 10
        out = Path(tempfile.mkdtemp(dir=tmp_path))
        recs = pycolmap.incremental_mapping(sfm_dir / "database.db", job["image_dir"], out, options=options)
        if seed == 5:
            for rec in recs.values():
                camera = rec.camera(next(iter(rec.cameras)))
                params = camera.params.copy()
                params[3] = 1.7
                camera.params = params
        return recs

    n = len(job["image_names"])
    models, attempts, rejected, _ = map_with_retries(map_once, n, SfmConfig(random_seed=5, threads=1))
    assert seeds == [5, 6]
    assert all(a.pop("seconds") > 0 for a in attempts)  # each run's duration, for the scaling benchmark
    assert attempts[0] == {"seed": 5, "registered": 0, "models": 0}
    assert attempts[1] == {"seed": 6, "registered": n, "models": 1}
    assert all("implausible camera parameters" in r["reason"] for r in rejected)
    assert sum(rec.num_reg_images() for rec in models.values()) == n

    seeds.clear()
    models, attempts, rejected, _ = map_with_retries(map_once, n, SfmConfig(random_seed=5, sfm_attempts=1))
    assert seeds == [5] and models == {} and len(attempts) == 1
    assert max(r["registered"] for r in rejected) == n
    assert all("implausible camera parameters" in r["reason"] and ", 1.7" in r["reason"] for r in rejected)

    calls = []
    models, attempts, _, _ = map_with_retries(lambda seed: calls.append(seed) or {}, n, SfmConfig(random_seed=0))
    assert calls == [0, 1, 2] and models == {} and [a["registered"] for a in attempts] == [0, 0, 0]
    report = ingested["report1"]
    # the solution check maps twice; two agreeing runs are no retry
    first, second = report["sfm"]["mapping_attempts"]
    assert first.pop("seconds") > 0 and first == {"seed": 0, "registered": N, "models": 1}
    assert second["seed"] == 1 and second["registered"] == N and second["disagreement_pct"]["0"] < 1.0
    assert report["sfm"]["solution_check"]["state"] == "passed"
    assert "mapping runs" not in summary_line(report)
    retried = {**report, "sfm": {**report["sfm"], "mapping_attempts": attempts[:2], "solution_check": {"ran": False}}}
    assert f"{N}/{N} frames registered (100.0% after 2 mapping runs)" in summary_line(retried)


def test_a_run_of_frames_taken_out_registers_again_from_its_end_when_each_triangulates(ingested):
    """`register_frames` with `triangulate` (the moving-content trial): the first third of the walk's frames,
    taken out of its model, registers again nearest the rest first, each frame's new points triangulated for
    the next: every frame placed where it was, within 0.3 % of the path, and closer than without (then each
    frame has only the points the rest holds: on this walk 0.56 % against 0.10 %; on the 90-frame orbit of
    benchmarks/footage.py, 10 of its first 22 frames placed against 22)."""
    import pycolmap

    from seeu_data.ingest.keyframes import register_frames

    sfm_dir = ingested["out"] / ".work" / "walk" / "sfm"
    worst = {}
    for triangulate in (False, True):
        rec = pycolmap.Reconstruction(next((sfm_dir / "sparse").iterdir()))  # the model kept
        centres = {rec.image(i).name: rec.image(i).projection_center() for i in rec.reg_image_ids()}
        names = sorted(centres)
        run = names[: len(names) // 3]
        for i in list(rec.reg_image_ids()):
            if rec.image(i).name in run:
                rec.deregister_frame(rec.image(i).frame_id)
        placed = register_frames(sfm_dir / "database.db", {0: rec}, names, names, 0, 1, triangulate=triangulate)
        back = {rec.image(i).name: rec.image(i).projection_center() for i in rec.reg_image_ids()}
        path = sum(np.linalg.norm(centres[b] - centres[a]) for a, b in zip(names, names[1:]))
        worst[triangulate] = max(np.linalg.norm(back[n] - centres[n]) / path for n in run if n in back)
        if triangulate:
            assert placed == len(run) and all(n in back for n in run)
    assert worst[True] < 0.003 and worst[True] < worst[False], worst


def test_forward_walk_maps_with_forward_motion_allowed(tmp_path):
    """A short synthetic walk (FORWARD_*): its frame pairs move mostly along the optical axis with small
    triangulation angles, so COLMAP's initial-pair limits find no model in any run; each run's retry with
    forward motion allowed (`mapping.forward_below`) poses every frame, accurately, and the two runs agree.
    A static camera (planar/panoramic pairs) gets no retry: test_static_camera_no_model."""
    from seeu_data.ingest.mapping import forward_below, moves_forward_possibly
    from seeu_data.ingest.sfm import SfmConfig

    clip = tmp_path / "fwd.mp4"
    write_clip(clip, n_frames=FORWARD_FRAMES, size=FORWARD_SIZE, seed=0)
    out = tmp_path / "out"
    assert cli_main(["ingest", str(clip), "--out", str(out)]) == 0
    report = json.loads((out / "fwd" / "report.json").read_text())
    attempts = report["sfm"]["mapping_attempts"]
    # every run, the check's two and a third when they disagree, placed every frame once forward motion was allowed
    assert [a["seed"] for a in attempts[:2]] == [0, 1], attempts
    assert {(a["registered"], a.get("init")) for a in attempts} == {(FORWARD_FRAMES, "forward motion")}, attempts
    assert report["sfm"]["solution_check"]["state"] == "passed"
    assert report["sfm"]["solution_check"]["init"] == "forward motion"
    assert "forward motion allowed for the initial pair)" in summary_line(report)
    acc = ingest_accuracy(out / "fwd", clip, report["registered"], report["frames_selected"])
    assert acc["registered_pct"] >= 95 and acc["largest"]["centre_rmse_pct_path"] <= 1.0, acc
    pairs = report["sfm"]["solution_check"]
    assert moves_forward_possibly(
        {"verified": pairs["verified_pairs"], "planar_or_panoramic": pairs["planar_or_panoramic_pairs"]}
    )
    assert not moves_forward_possibly({"verified": 10, "planar_or_panoramic": 5})
    assert not moves_forward_possibly({"verified": 0, "planar_or_panoramic": 0})
    cfg = SfmConfig()
    assert forward_below(cfg, "incremental", {"verified": 10, "planar_or_panoramic": 2}, FORWARD_FRAMES) == 8
    assert forward_below(cfg, "global", {"verified": 10, "planar_or_panoramic": 2}, FORWARD_FRAMES) == 0
    assert forward_below(cfg, "incremental", {"verified": 10, "planar_or_panoramic": 5}, FORWARD_FRAMES) == 0


def test_forward_walk_at_a_high_frame_rate_maps_its_keyframes_with_forward_motion_allowed(tmp_path):
    """The forward walk of the test above, sampled 8 times as densely (73 frames on the same path) and mapped
    on every 8th frame (`min_keyframes` 10, `keyframe_motion` 200 px): the keyframes are the 10 views COLMAP's
    initial-pair limits cannot map. The frames between them, a few pixels apart, give pairs a homography
    explains; counted with them, the planar/panoramic share looked like a camera turning in place, no
    forward-motion retry ran and SfM found no model (the 400-frame walk of benchmarks/footage.py too). Counted
    among the keyframes, every run retries and poses every frame."""
    from pipelines.ingest import IngestConfig, ingest_scene
    from seeu_data.ingest.sfm import SfmConfig
    from seeu_data.ingest.solution_check import geometry_counts

    clip = tmp_path / "fwd73.mp4"
    write_clip(clip, n_frames=8 * (FORWARD_FRAMES - 1) + 1, size=FORWARD_SIZE, seed=0)
    (source,) = discover_sources([clip])
    sfm = SfmConfig(min_keyframes=FORWARD_FRAMES, keyframe_motion=200.0)  # 12 px a frame: a stride of 8
    cfg = IngestConfig(out=tmp_path / "out", inputs=(clip,), sfm=sfm)
    report = ingest_scene(source, cfg)
    keyframes, check = report["sfm"]["keyframes"], report["sfm"]["solution_check"]
    assert keyframes["stride"] == 8 and keyframes["count"] == FORWARD_FRAMES, keyframes
    attempts = report["sfm"]["mapping_attempts"]
    assert {a.get("init") for a in attempts} == {"forward motion"}, attempts
    assert check["state"] == "passed" and check["init"] == "forward motion"
    acc = ingest_accuracy(tmp_path / "out" / "fwd73", clip, report["registered"], report["frames_selected"])
    assert acc["registered_pct"] >= 95 and acc["largest"]["centre_rmse_pct_path"] <= 1.0, acc
    db = tmp_path / "out" / ".work" / "fwd73" / "sfm" / "database.db"
    keys = {f"{i:06d}.jpg" for i in range(0, 73, 8)}
    every, mapped = geometry_counts(db), geometry_counts(db, keys)
    assert mapped["verified"] < every["verified"] and mapped["verified"] >= FORWARD_FRAMES - 1
    assert mapped["planar_or_panoramic"] < 0.5 * mapped["verified"]


def test_lens_distortion_is_estimated_and_undistorted(tmp_path):
    """Frames rendered through a radial lens (k1 = -0.1, OpenCV's model = COLMAP's SIMPLE_RADIAL):
    SfM estimates k, the output images are undistorted, and a stored frame equals a fresh pinhole
    render of the true pose with the stored intrinsics."""
    n, k1 = 30, -0.1
    scene = make_scene(0)
    poses = camera_path(n)
    intr = default_intrinsics_norm(W, H)
    K = cam.intrinsics_pixels(intr, W, H)
    # distorted pixel -> where its ray lands in the pinhole image (pixel centres at +0.5)
    grid = np.stack(np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5), -1).reshape(-1, 1, 2)
    und = cv2.undistortPoints(grid, K, np.array([k1, 0, 0, 0.0])).reshape(H, W, 2)
    map_x = (und[..., 0] * K[0, 0] + K[0, 2] - 0.5).astype(np.float32)
    map_y = (und[..., 1] * K[1, 1] + K[1, 2] - 0.5).astype(np.float32)
    frames = [cv2.remap(render_view(scene, p, intr, W, H)[0], map_x, map_y, cv2.INTER_LINEAR) for p in poses]
    vid = _write_video(tmp_path / "lens.mp4", frames)
    assert cli_main(["ingest", str(vid), "--out", str(tmp_path / "out")]) == 0
    report = json.loads((tmp_path / "out" / "lens" / "report.json").read_text())
    (model,) = report["sfm"]["models"]
    assert model["undistorted"] and model["distortion_max_px"] > 5
    s = PosedDataset(tmp_path / "out" / "lens", verify=True).load_scene("lens_c0")
    assert s.meta["camera_as_mapped"]["params"][3] == pytest.approx(k1, abs=0.01)
    assert s.meta["camera_as_mapped"]["params"][0] == pytest.approx(K[0, 0], rel=0.02)
    acc = pose_accuracy(s.cam_to_world, poses[s.source_frame])
    assert acc.centre_rmse_pct_path < 0.5 and acc.rel_rot_err_mean_deg < 0.2, acc
    # The undistorted frames keep the original size (what the peers' loaders need); the focal changes.
    assert (s.width == W).all() and (s.height == H).all()
    assert model["camera"]["model"] == "PINHOLE" and (model["camera"]["width"], model["camera"]["height"]) == (W, H)
    w2, h2 = W, H
    i = len(s) // 2
    stored = cv2.cvtColor(cv2.imdecode(np.frombuffer(s.images[i], np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    assert stored.shape == (h2, w2, 3)
    truth, _ = render_view(scene, poses[s.source_frame[i]], s.intrinsics_norm[i], w2, h2)
    distorted = frames[s.source_frame[i]]
    m = 2  # same-size undistortion leaves no blank border

    def psnr(a, b):  # on slightly blurred crops: geometry, not mp4/JPEG noise
        return cv2.PSNR(cv2.GaussianBlur(a[m:-m, m:-m], (0, 0), 1.5), cv2.GaussianBlur(b[m:-m, m:-m], (0, 0), 1.5))

    assert psnr(stored, truth) > 28  # measured ~31.7
    assert psnr(stored, truth) > psnr(distorted, truth) + 4  # measured ~25.4 for the distorted frame
    # ... and the pixelSplat export of it keeps the original frame size too (--resize none)
    assert (
        cli_main(
            ["export", "pixelsplat", str(tmp_path / "out" / "lens"), "--out", str(tmp_path / "ps"), "--resize", "none"]
        )
        == 0
    )
    import torch

    (ex,) = torch.load(tmp_path / "ps" / "test" / "000000.torch", weights_only=True)
    assert {cv2.imdecode(im.numpy(), cv2.IMREAD_COLOR).shape for im in ex["images"]} == {(H, W, 3)}
