"""Ingest results to trust: SfM results that do not depend on the thread count, the solution check, scene naming
without silent overwrites, the low-parallax warning, parallax judged on the SfM model as mapped (the same under
every --scale), a camera rotating in place flagged, why a solution check failed, and progress/heartbeat while
SfM works."""

from __future__ import annotations

import io
import json
import sqlite3
import time
from pathlib import Path

import numpy as np
import pytest

from pipelines.cli import main as cli_main
from seeu_data.ingest.pose_eval import pose_accuracy
from seeu_data.ingest.report import (
    LOW_PARALLAX,
    ROTATES_IN_PLACE,
    baseline_over_depth,
    degeneracy,
    scene_warnings,
    summary_line,
    weak_geometry,
)
from seeu_data.ingest.sfm import SfmConfig, run_sfm
from seeu_data.ingest.solution_check import map_with_retries, model_disagreement_pct
from seeu_data.ingest.video import SceneSource, discover_sources, unique_scene_names
from seeu_data.progress import StageProgress
from seeu_data.store.posed import PosedDataset
from seeu_data.synthetic import (
    default_intrinsics_norm,
    load_ground_truth,
    make_planar_scene,
    planar_camera_path,
    render_view,
    write_clip,
)

W, H = 320, 180


pytestmark = pytest.mark.usefixtures("no_heartbeat")  # conftest: one-line error checks


# ---------------------------------------------------------------------------------------------
# Determinism and progress (COLMAP)
# ---------------------------------------------------------------------------------------------


class _Recorder(StageProgress):
    """A StageProgress that keeps every (stage, done) it is told."""

    def __init__(self):
        super().__init__("test")
        self.events: list[tuple[str, int]] = []

    def stage(self, name, total=None, unit=""):
        super().stage(name, total, unit)
        self.events.append((name, 0))

    def set(self, done):
        super().set(done)
        self.events.append((self.name, done))


def _db_rows(db: Path) -> dict:
    con = sqlite3.connect(db)
    try:
        return {
            "images": con.execute("SELECT image_id, name FROM images ORDER BY image_id").fetchall(),
            "matches": con.execute("SELECT pair_id, data FROM matches ORDER BY pair_id").fetchall(),
            "geometries": con.execute(
                "SELECT pair_id, config, data FROM two_view_geometries ORDER BY pair_id"
            ).fetchall(),
        }
    finally:
        con.close()


@pytest.mark.slow
def test_sfm_is_identical_run_after_run_with_two_threads(tmp_path):
    """The planar clip, 2 COLMAP threads and 2 matching processes, 2 runs, then 1 thread and one process:
    the same database (image ids in frame order, the same matches and verified geometries) and
    bit-identical poses, every frame registered and accurate against the ground truth. Before the fix,
    image ids followed extraction completion order and such runs gave different poses. The extract and
    match stages report progress while they work."""
    n = 20
    frames = tmp_path / "frames"
    frames.mkdir()
    poses = planar_camera_path(n)
    scene = make_planar_scene(0)
    intr = default_intrinsics_norm(W, H)
    import cv2

    for i in range(n):
        rgb, _ = render_view(scene, poses[i], intr, W, H)
        cv2.imwrite(str(frames / f"{i:06d}.jpg"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    names = [f"{i:06d}.jpg" for i in range(n)]
    results, dbs = [], []
    rec = _Recorder()
    for r, threads in enumerate((2, 2, 1)):
        out = tmp_path / f"sfm{r}"
        # every pair (190): enough to be matched by `threads` worker processes, each into a database copy
        cfg = SfmConfig(threads=threads, sfm_check=False, min_model_size=5, matcher="exhaustive")
        results.append(run_sfm(frames, names, out, cfg, frames, progress=rec if r == 0 else False))
        dbs.append(_db_rows(out / "database.db"))
    assert dbs[0]["images"] == [(i + 1, name) for i, name in enumerate(names)]
    assert all(db == dbs[0] for db in dbs[1:])
    models = [[(im["name"], im["world_to_cam"]) for m in res["models"] for im in m["images"]] for res in results]
    assert all(m == models[0] for m in models[1:])
    assert len(models[0]) == n
    c2w = np.linalg.inv(
        np.concatenate([np.asarray([w for _, w in models[0]]), np.tile([[[0, 0, 0, 1.0]]], (n, 1, 1))], axis=1)
    )
    assert pose_accuracy(c2w, poses).centre_rmse_pct_path <= 0.5
    # progress moved inside the extract and match stages (values strictly between 0 and the end), in their
    # units: images (n), pairs (all n (n - 1) / 2 matched)
    for stage, total in (("sfm extract", n), ("sfm match", n * (n - 1) // 2)):
        seen = [d for s, d in rec.events if s == stage]
        assert any(0 < d < total for d in seen) and max(seen) <= total, (stage, seen)
    assert [s for s, _ in rec.events if s.startswith("sfm map")]


# ---------------------------------------------------------------------------------------------
# Solution check (closed-form cases on stand-in reconstructions)
# ---------------------------------------------------------------------------------------------


class _Pose:
    def __init__(self, w2c):
        self.w2c = w2c

    def matrix(self):
        return self.w2c[:3]


class _Image:
    camera_id = 1

    def __init__(self, name, w2c):
        self.name, self._pose = name, _Pose(w2c)

    def cam_from_world(self):
        return self._pose


class _Camera:
    def __init__(self, focal=300.0, width=320, height=180):
        self.params, self.width, self.height = np.array([focal, width / 2, height / 2, 0.0]), width, height

    def has_bogus_params(self, *args):
        return False

    def mean_focal_length(self):
        return float(self.params[0])


class _Rec:
    """The parts of pycolmap.Reconstruction the solution check reads; `c2w (N, 4, 4)`."""

    def __init__(self, c2w, camera=None):
        self.images = {i + 1: _Image(f"{i:06d}.jpg", np.linalg.inv(m)) for i, m in enumerate(c2w)}
        self.cameras = {1: camera or _Camera()}

    def num_reg_images(self):
        return len(self.images)

    def reg_image_ids(self):
        return list(self.images)

    def image(self, i):
        return self.images[i]


def _similar(c2w, scale, angle, shift):
    """The same poses in another world frame: x -> scale * R x + shift."""
    c, s = np.cos(angle), np.sin(angle)
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    out = c2w.copy()
    out[:, :3, :3] = R @ c2w[:, :3, :3]
    out[:, :3, 3] = scale * c2w[:, :3, 3] @ R.T + shift
    return out


def test_model_disagreement_is_zero_up_to_similarity_and_measures_a_bent_path():
    truth = planar_camera_path(30)
    same = _similar(truth, 2.5, 0.7, np.array([1.0, -2, 3]))
    assert model_disagreement_pct({0: _Rec(truth)}, {0: _Rec(same)}) == pytest.approx(0.0, abs=1e-9)
    bent = truth.copy()
    bent[15:, 2, 3] += 0.7  # the second half 0.7 m off (10 % of the 7 m path)
    d = model_disagreement_pct({0: _Rec(truth)}, {0: _Rec(bent)})
    # independent: the aligned RMSE of the same point sets, from the pose-accuracy code path on raw arrays
    assert d == pytest.approx(pose_accuracy(bent, truth).centre_rmse_pct_path, rel=1e-9)
    assert 2.0 < d < 10.0
    # too few common frames: no agreement possible
    assert model_disagreement_pct({0: _Rec(truth)}, {0: _Rec(truth[:10])}) == float("inf")


def test_solution_check_maps_again_until_two_runs_agree_and_flags_when_none_do():
    truth = planar_camera_path(30)
    wrong = truth.copy()
    wrong[15:, 0, 3] *= 1.5
    runs = {0: truth, 1: wrong, 2: _similar(truth, 0.5, 0.2, np.zeros(3))}
    seeds = []

    def map_once(seed):
        seeds.append(seed)
        return {0: _Rec(runs[seed])}

    cfg = SfmConfig(sfm_attempts=3)
    models, attempts, _, check = map_with_retries(map_once, 30, cfg, check=True)
    assert seeds == [0, 1, 2]
    assert check["passed"] is True and check["kept_seed"] == 0
    assert attempts[1]["disagreement_pct"]["0"] > cfg.max_disagreement_pct
    assert attempts[2]["disagreement_pct"]["0"] == pytest.approx(0.0, abs=1e-9)
    # two clean runs agree at once: two runs
    seeds.clear()
    runs[1] = _similar(truth, 3.0, -0.4, np.ones(3))
    _, attempts, _, check = map_with_retries(map_once, 30, cfg, check=True)
    assert seeds == [0, 1] and check["passed"] and len(attempts) == 2
    # no two runs agree: the check fails, the run registering most is kept
    seeds.clear()
    runs[1], runs[2] = wrong, truth.copy()
    runs[2][:10, 1, 3] += 2.0
    models, attempts, _, check = map_with_retries(map_once, 30, cfg, check=True)
    assert seeds == [0, 1, 2] and check["passed"] is False and check["kept_seed"] == 0
    assert check["reason"].startswith("the 3 mapping runs that registered enough frames disagree (closest ")
    # without the check one registering run is enough
    seeds.clear()
    _, _, _, check = map_with_retries(map_once, 30, cfg, check=False)
    assert seeds == [0] and check["ran"] is False and check["passed"] is None and "reason" not in check
    # a small photo set: 9 of 11 frames is a model (COLMAP's min(min_model_size, int(80 %)) = 8), 7 of 11 is not
    small = {seed: truth[:11] for seed in range(3)}
    small[0] = truth[:9]
    runs.update(small)
    seeds.clear()
    models, attempts, _, _ = map_with_retries(map_once, 11, SfmConfig(sfm_attempts=1), check=False)
    assert seeds == [0] and attempts[0]["registered"] == 9 and models[0].num_reg_images() == 9
    runs[0] = truth[:7]
    seeds.clear()
    models, attempts, _, _ = map_with_retries(map_once, 11, SfmConfig(sfm_attempts=1), check=False)
    assert models == {} and attempts[0]["registered"] == 0
    # too few frames registered to compare: said so, not "the runs disagree"
    for short, who in (
        ({0: truth[:12], 1: truth[:12], 2: truth[:12]}, "no mapping run"),
        ({0: truth[:12], 1: truth, 2: truth[:12]}, "only one of 3 mapping runs"),
    ):
        runs.update(short)
        _, _, _, check = map_with_retries(map_once, 30, cfg, check=True)
        assert check["passed"] is False and check["disagreement_pct"] is None
        assert check["reason"] == f"{who} registered enough frames (at least 80%) to compare"
        warning = scene_warnings({"sfm": {"solution_check": {**check, "state": "failed"}}, "chunks": []})[0]
        assert (
            warning
            == f"SfM solution check failed: {who} registered enough frames (at least 80%) to compare; the poses may be wrong"
        )


def test_solution_check_starts_at_once_only_the_runs_it_certainly_needs():
    """`start(seed)` begins a run in the background (the SfM child: a process per run): with the check
    the first two runs are started together (the second either checks or replaces the first), a third
    only once the two disagree; without it, one. The outcome is the sequential one."""
    truth = planar_camera_path(30)
    wrong = truth.copy()
    wrong[15:, 0, 3] *= 1.5
    cfg = SfmConfig(sfm_attempts=3)
    for runs, check in (({0: truth, 1: wrong, 2: truth}, True), ({0: truth, 1: truth}, True), ({0: truth}, False)):
        events: list[tuple[str, int]] = []

        def map_once(seed, runs=runs, events=events):
            events.append(("collect", seed))
            return {0: _Rec(runs[seed])}

        got = map_with_retries(map_once, 30, cfg, check=check, start=lambda seed, ev=events: ev.append(("start", seed)))
        sequential = map_with_retries(lambda seed, runs=runs: {0: _Rec(runs[seed])}, 30, cfg, check=check)
        for attempt in got[1] + sequential[1]:
            attempt.pop("seconds")  # wall time: differs between any two runs
        assert got[1:] == sequential[1:] and got[0].keys() == sequential[0].keys()
        started = [s for e, s in events if e == "start"]
        assert started == ([0, 1] if check else [0]), events
        assert [s for e, s in events if e == "collect"] == sorted(runs)


def test_failed_check_names_the_weak_geometry_and_chunks_are_warned_otherwise():
    """A failed solution check is warned with its likely causes, each from its own figure: low parallax
    (the smallest chunk baseline/depth), a dominant plane (planar/panoramic share of the verified pairs),
    too few matches (median inliers, matched frames per frame); without a failed check, chunks whose
    camera rotates in place and low-parallax chunks are warned each."""
    reason = "the 3 mapping runs that registered enough frames disagree (closest 28% of the path apart)"
    check = {
        "ran": True,
        "passed": False,
        "state": "failed",
        "disagreement_pct": 27.9,
        "reason": reason,
        "planar_or_panoramic_pairs": 60,
        "verified_pairs": 64,
    }
    base = {
        "scene": "s",
        "registered": 30,
        "frames_selected": 30,
        "registration_rate": 1.0,
        "frames_in_chunks": 30,
        "mean_reprojection_error_px": 0.3,
        "timings_s": {"total": 1.0},
        "output": "out/s",
        "sfm": {
            "mapping_attempts": [{}, {}, {}],
            "solution_check": check,
            "mapper": {"match_graph": {"median_inliers": 31.0, "mean_degree": 5.2}},
        },
        "chunks": [
            {"scene_id": "s_c0", "baseline_over_depth": 0.04, "degeneracy": ROTATES_IN_PLACE},
            {"scene_id": "s_c1", "baseline_over_depth": 0.5, "degeneracy": None},
            {"scene_id": "s_c2", "baseline_over_depth": 0.07},  # a report without degeneracy
        ],
    }
    causes = weak_geometry(base)
    assert causes == [
        "low parallax (baseline/depth 0.040 < 0.1)",
        "a dominant plane or a camera turning in place (60/64 verified pairs planar or panoramic)",
        "too few matches (median 31 inliers per verified pair, each frame matched to 5.2 others)",
    ]
    failed = {**base, "sfm": {**base["sfm"], "solution_check": {**check, "weak_geometry": causes}}}
    (warning,) = scene_warnings(failed)
    assert warning == f"SfM solution check failed: {reason}; likely owed to {', '.join(causes)}; the poses may be wrong"
    line = summary_line({**failed, "warnings": [warning]})
    assert line.count("WARNING") == 1 and "\n" not in line and "after 3 mapping runs" in line
    assert "low parallax" in line and "dominant plane" in line and "too few matches" in line
    # each cause only from its own figure
    wide = {**base, "chunks": [{"scene_id": "s_c0", "baseline_over_depth": 0.5}]}
    many = {"mapper": {"match_graph": {"median_inliers": 400.0, "mean_degree": 5.0}}}
    general = {**check, "planar_or_panoramic_pairs": 10}
    assert weak_geometry({**wide, "sfm": {**base["sfm"], **many, "solution_check": general}}) == []
    none_found = {**wide, "sfm": {**many, "solution_check": {**general, "weak_geometry": []}}}
    assert scene_warnings(none_found)[0].endswith(
        "; no sign of low parallax, a dominant plane or too few matches; the poses may be wrong"
    )
    # the check did not fail: the chunks are warned one by one
    passed = {**base, "sfm": {**base["sfm"], "solution_check": {**check, "state": "passed", "passed": True}}}
    warnings = scene_warnings(passed)
    assert warnings[0] == f"{ROTATES_IN_PLACE} in s_c0 (baseline/depth 0.040, 60/64 verified pairs planar or panoramic)"
    assert warnings[1] == "low parallax: baseline/depth 0.070 < 0.1 in s_c2 (geometry weakly constrained)"
    assert len(warnings) == 2
    assert "camera mostly rotates in place: depth is unreliable" in summary_line({**passed, "warnings": warnings})
    # an SfM result from before the reason was recorded: the old wording
    old = {**base, "sfm": {"solution_check": {"state": "failed", "disagreement_pct": 27.9}}}
    assert (
        scene_warnings(old)[0]
        == "SfM solution check failed: no two mapping runs agree (closest 28% of the path apart); the poses may be wrong"
    )
    ok = {
        **base,
        "sfm": {
            "mapping_attempts": [{}, {}],
            "solution_check": {"ran": True, "passed": True, "state": "passed", "disagreement_pct": 0.02},
        },
        "chunks": [{"scene_id": "s_c0", "baseline_over_depth": 0.5, "degeneracy": None}],
    }
    assert scene_warnings(ok) == []
    assert "mapping runs" not in summary_line(ok) and "solution check passed" in summary_line(ok)


def test_baseline_over_depth_on_the_model_as_mapped_is_scale_free():
    """A pan in place has no baseline; cameras on a 0.3-long segment over points at median depth 2 give 0.15,
    and the same cameras and points in any other unit (what a --scale convention does) give the same figure."""
    c2w = np.tile(np.eye(4), (5, 1, 1))
    c2w[:, :3, :3] = [
        [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]] for a in np.linspace(-0.5, 0.5, 5)
    ]
    depths = np.array([1.0, 2.0, 2.0, 3.0, 50.0, np.nan, -1.0])  # invalid depths ignored: median 2
    assert baseline_over_depth(np.linalg.inv(c2w)[:, :3], depths) == 0.0 < LOW_PARALLAX
    c2w[:, 0, 3] = np.linspace(0, 0.3, 5)
    c2w[2, 1, 3] = 0.05
    w2c = np.linalg.inv(c2w)
    assert baseline_over_depth(w2c, depths) == pytest.approx(0.15)
    assert baseline_over_depth(w2c[:, :3], depths) == pytest.approx(0.15)  # (N, 3, 4) as in result.json
    for s in (1 / 0.4, 7.3e-3, 1e4):  # the re10k and median-depth factors are such numbers
        scaled = w2c.copy()
        scaled[:, :3, 3] *= s
        assert baseline_over_depth(scaled, depths * s) == pytest.approx(0.15, rel=1e-12)
    assert np.isnan(baseline_over_depth(w2c, np.array([np.nan])))


def test_rotation_in_place_needs_planar_pairs_and_low_parallax():
    """Flagged only when both hold: a walk along a wall (planar pairs, wide baseline) and a low-parallax
    scene with 3D structure in its pairs are not."""
    check = {"planar_or_panoramic_pairs": 67, "verified_pairs": 69}
    assert degeneracy(check, 0.05) == ROTATES_IN_PLACE
    assert degeneracy(check, 0.8) is None
    assert degeneracy({"planar_or_panoramic_pairs": 20, "verified_pairs": 69}, 0.05) is None
    assert degeneracy({}, 0.05) is None  # nothing counted (an old result): not flagged


@pytest.mark.slow
def test_tripod_pan_is_flagged_under_default_options_and_the_figure_ignores_scale(tmp_path, capsys):
    """A synthetic tripod pan (the head turns 60 deg, the camera 0.3 m in front of its axis, 3 cm of
    wobble) through the default `seeu ingest` (--scale re10k): the camera rotating in place is warned in
    the summary line, report.json and the chunk meta. Then --scale median-depth (the SfM stage reused):
    the same baseline/depth, to the bit, while the poses' scale differs. The walking clip of
    tests/test_ingest.py is not warned (test_end_to_end_registration_and_accuracy)."""
    clip = tmp_path / "pan.mp4"
    write_clip(clip, n_frames=20, size=(H, W), scene="pan")
    out = tmp_path / "out"
    figures, scales = [], []
    for extra in ([], ["--scale", "median-depth"]):
        assert cli_main(["ingest", str(clip), "--out", str(out), *extra]) == 0
        line = capsys.readouterr().out
        report = json.loads((out / "pan" / "report.json").read_text())
        (chunk,) = report["chunks"]
        assert chunk["baseline_over_depth"] < LOW_PARALLAX and chunk["degeneracy"] == ROTATES_IN_PLACE
        assert any(w.startswith(ROTATES_IN_PLACE) for w in report["warnings"]), report["warnings"]
        # what a failed check would name, computed whether or not it failed
        causes = report["sfm"]["solution_check"]["weak_geometry"]
        assert causes[0].startswith("low parallax") and causes[1].startswith("a dominant plane"), causes
        assert f"WARNING: {ROTATES_IN_PLACE}" in line
        meta = PosedDataset(out / "pan").load_scene("pan_c0").meta
        assert meta["degeneracy"] == ROTATES_IN_PLACE and meta["baseline_over_depth"] == chunk["baseline_over_depth"]
        figures.append(chunk["baseline_over_depth"])
        scales.append(meta["scale_factor"])
    assert report["reused"]["sfm"] and figures[0] == figures[1]
    assert scales[0] != pytest.approx(scales[1], rel=0.1)
    # the true figure of the clip's path: widest baseline 0.30 m over a median depth of about 4.7 m
    assert 0.02 < figures[0] < 0.1


def test_final_bundle_adjustment_keeps_a_model_it_cannot_fix_the_gauge_of():
    """A model without 3D points (what mapping a pure rotation can leave): Ceres never starts, pycolmap
    returns a summary without a Ceres part; the model is kept as mapped (once a crash of the SfM child)."""
    import pycolmap

    from seeu_data.ingest.mapping import final_bundle_adjustment

    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(
        pycolmap.Camera.create_from_model_id(1, pycolmap.CameraModelId.SIMPLE_RADIAL, 200.0, W, H)
    )
    for i in (1, 2):
        points = pycolmap.Point2DList([pycolmap.Point2D(np.array([10.0 * i, 20.0]))])
        image = pycolmap.Image(name=f"{i}.jpg", camera_id=1, image_id=i, points2D=points)
        rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(pycolmap.Rotation3d(), np.array([0.1 * i, 0, 0])))
    kept, info = final_bundle_adjustment(rec, SfmConfig())
    assert kept is rec and info["used"] is False and info["iterations"] == 0


def test_planar_scene_is_dominated_by_one_plane():
    """More than 80 % of every view of the planar clip sees the wall (the plane z = 4)."""
    scene = make_planar_scene(0)
    poses = planar_camera_path(12)
    intr = default_intrinsics_norm(W, H)
    K = np.array([[intr[0] * W, 0, intr[2] * W], [0, intr[1] * H, intr[3] * H], [0, 0, 1]])
    for pose in poses[::3]:
        _, depth = render_view(scene, pose, intr, W, H)
        u, v = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
        rays = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(K).T
        world_z = (rays * depth[..., None]) @ pose[:3, :3].T[:, 2] + pose[2, 3]
        assert np.mean(np.abs(world_z - 4.0) < 1e-3) > 0.8


# ---------------------------------------------------------------------------------------------
# Scene names and overwrites
# ---------------------------------------------------------------------------------------------


def test_unique_scene_names_rule(tmp_path):
    def src(p):
        return SceneSource(Path(p).name, Path(p), "images")

    names = [s.name for s in unique_scene_names([src("/x/a/images"), src("/x/b/images"), src("/x/clip")])]
    assert names == ["a-images", "b-images", "clip"]
    names = [s.name for s in unique_scene_names([src("/x/a/images"), src("/y/a/images")])]
    assert names == ["a-images", "a-images-2"]
    for d in ("a/images", "b/images"):
        (tmp_path / d).mkdir(parents=True)
        (tmp_path / d / "0.png").write_bytes(b"\x89PNG\r\n\x1a\n")  # an image by its signature
    assert [s.name for s in discover_sources([tmp_path / "a/images", tmp_path / "b/images"])] == [
        "a-images",
        "b-images",
    ]
    from seeu_data.errors import SeeUError

    with pytest.raises(SeeUError, match="same input is given twice"):
        discover_sources([tmp_path / "a/images", tmp_path / "a" / ".." / "a/images"])


def _one_line_error(argv, capsys, *needles):
    assert cli_main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0, err
    for needle in needles:
        assert needle in err, err
    return err


@pytest.mark.slow
def test_another_inputs_scene_is_never_overwritten(tmp_path, capsys):
    """a/walk.mp4 is ingested as `walk`; b/walk.mp4 (another clip) into the same --out is refused with one
    line and leaves the scene untouched; --name puts it beside it (with a heartbeat on stderr); re-running
    the first input resumes; --force replaces."""
    write_clip(tmp_path / "a" / "walk.mp4", n_frames=14, size=(H, W), seed=0, path_length_m=3.0)
    write_clip(tmp_path / "b" / "walk.mp4", n_frames=14, size=(H, W), seed=1, path_length_m=3.0)
    out = tmp_path / "out"
    common = ["--out", str(out), "--min-chunk-frames", "5", "--no-sfm-check"]
    assert cli_main(["ingest", str(tmp_path / "a" / "walk.mp4"), *common]) == 0
    capsys.readouterr()
    manifest = (out / "walk" / "manifest.json").read_bytes()
    report = json.loads((out / "walk" / "report.json").read_text())
    assert report["input_identity"]["path"] == str((tmp_path / "a" / "walk.mp4").resolve())
    _one_line_error(
        ["ingest", str(tmp_path / "b" / "walk.mp4"), *common], capsys, str(out / "walk"), "another input", "--force"
    )
    assert (out / "walk" / "manifest.json").read_bytes() == manifest
    _one_line_error(
        ["ingest", str(tmp_path / "a" / "walk.mp4"), str(tmp_path / "b" / "walk.mp4"), "--name", "x", *common],
        capsys,
        "--name names one scene",
    )
    assert (
        cli_main(["ingest", str(tmp_path / "b" / "walk.mp4"), "--name", "walk-b", "--heartbeat", "0.5", *common]) == 0
    )
    err = capsys.readouterr().err
    assert "seeu ingest: walk-b: sfm " in err
    gt = load_ground_truth(tmp_path / "b" / "walk.mp4")
    assert json.loads((out / "walk-b" / "report.json").read_text())["input"] == str(tmp_path / "b" / "walk.mp4")
    assert gt["frame"].size == 14
    assert cli_main(["ingest", str(tmp_path / "a" / "walk.mp4"), *common]) == 0
    assert all(json.loads((out / "walk" / "report.json").read_text())["reused"].values())
    assert cli_main(["ingest", str(tmp_path / "b" / "walk.mp4"), "--force", *common]) == 0
    assert json.loads((out / "walk" / "report.json").read_text())["input"] == str(tmp_path / "b" / "walk.mp4")


def test_heartbeat_line(tmp_path):
    stream = io.StringIO()
    with StageProgress("seeu ingest: walk", heartbeat_s=0.02, stream=stream) as prog:
        prog.stage("sfm extract", 36)
        prog.set(12)
        deadline = time.monotonic() + 10
        while "sfm extract 12/36" not in stream.getvalue() and time.monotonic() < deadline:
            time.sleep(0.01)
    assert "seeu ingest: walk: sfm extract 12/36, " in stream.getvalue()
    assert all(line.startswith("seeu ingest: walk: ") for line in stream.getvalue().splitlines())


def test_progress_lines_stay_whole_while_colmap_logs_to_the_same_pipe(tmp_path):
    """The SfM child's progress lines (`emit`) and COLMAP's log share one pipe. Under PYTHONUNBUFFERED
    (set on CI machines) print() wrote each piece on its own and a log line landed inside ours
    ("done 30I2026..."), an internal error in the parent. Two threads in a real child: every progress
    line arrives whole."""
    import os
    import subprocess
    import sys

    code = (
        "import os, threading\n"
        "from seeu_data.ingest.sfm import emit\n"
        "def log():\n"
        "    for _ in range(3000): os.write(2, b'I20261126 12:00:00.000 mapper.cc:1] Registering image\\n')\n"
        "t = threading.Thread(target=log); t.start()\n"
        "for i in range(3000): emit('done', i)\n"
        "t.join()\n"
    )
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    out = subprocess.run([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=env)
    assert out.returncode == 0, out.stdout[-2000:]
    log = "I20261126 12:00:00.000 mapper.cc:1] Registering image"
    lines = out.stdout.decode().splitlines()
    assert lines.count(log) == 3000
    assert [ln for ln in lines if ln != log] == [f"@@seeu done {i}" for i in range(3000)]  # the child's marker


def _observed(turn_deg: float):
    """`_observed_model(turn_deg)` adjusted by `final_bundle_adjustment` (and its facts)."""
    from seeu_data.ingest.mapping import final_bundle_adjustment

    return final_bundle_adjustment(_observed_model(turn_deg), SfmConfig())


def _observed_model(turn_deg: float):
    """A pycolmap Reconstruction: 20 frames of a SIMPLE_RADIAL camera (focal length 0.714 x W, no distortion) on a
    path 1.5 m sideways and 2 m ahead, turning `turn_deg` degrees from end to end, that see 600 points 3-9 m ahead
    through 0.3 px of noise."""
    import cv2
    import pycolmap

    rng = np.random.default_rng(0)
    f = 0.714 * W
    points = rng.uniform([-4, -2, 3], [4, 2, 9], (600, 3))
    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(
        pycolmap.Camera.create_from_model_id(1, pycolmap.CameraModelId.SIMPLE_RADIAL, f, W, H)
    )
    seen: dict[int, list] = {j: [] for j in range(len(points))}
    for i, t in enumerate(np.linspace(0, 1, 20)):
        R = cv2.Rodrigues(np.array([0.0, np.radians(turn_deg) * (t - 0.5), 0.0]))[0]  # world to camera
        t_w = -R @ np.array([1.5 * t, 0.1 * np.sin(4 * t), 2.0 * t])
        x = points @ R.T + t_w
        uv = f * x[:, :2] / x[:, 2:] + [W / 2, H / 2] + rng.normal(0, 0.3, (len(points), 2))
        inside = np.flatnonzero((x[:, 2] > 0.5) & (uv > 0).all(1) & (uv < [W, H]).all(1))
        image = pycolmap.Image(
            name=f"{i:06d}.jpg",
            camera_id=1,
            image_id=i + 1,
            points2D=pycolmap.Point2DList([pycolmap.Point2D(p) for p in uv[inside]]),
        )
        rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(pycolmap.Rotation3d(R), t_w))
        for k, j in enumerate(inside):
            seen[j].append((i + 1, k))
    for j, observations in seen.items():
        if len(observations) >= 2:
            track = pycolmap.Track()
            for image_id, k in observations:
                track.add_element(image_id, k)
            rec.add_point3D(points[j], track)
    rec.update_point_3d_errors()
    return rec


@pytest.mark.parametrize("moved", ["behind a camera", "far off"])
def test_a_final_adjustment_that_leaves_a_point_behind_a_camera_is_used_one_that_sends_it_far_off_is_not(
    monkeypatch, moved
):
    """`final_bundle_adjustment` on `_observed_model(30)`, points moved after the solve: one behind the first camera
    that sees it (COLMAP's reprojection error then 1.3e154 px), its observations are dropped and the solution is used
    (the other points kept); every point 3 m to the side (errors of about 100 px, in front of the cameras), the solve
    diverged and the model is kept as it was."""
    import pycolmap

    from seeu_data.ingest import mapping

    model = _observed_model(30.0)
    pid = min(model.points3D)
    first = min(el.image_id for el in model.points3D[pid].track.elements)
    adjust = mapping._adjust

    def adjust_and_move(rec, options):
        summary = adjust(rec, options)
        cam_from_world = rec.image(first).cam_from_world()
        centre = cam_from_world.inverse().translation
        axis = cam_from_world.rotation.matrix()[2]  # the camera's optical axis in the world
        if moved == "behind a camera":
            rec.point3D(pid).xyz = centre - 2.0 * axis
        else:
            for point in rec.points3D.values():
                point.xyz = point.xyz + 3.0 * cam_from_world.rotation.matrix()[0]
        return summary

    monkeypatch.setattr(mapping, "_adjust", adjust_and_move)
    kept, facts = mapping.final_bundle_adjustment(pycolmap.Reconstruction(model), SfmConfig())
    if moved == "behind a camera":
        assert facts["used"] and facts["reprojection_after_px"] < 1.0, facts
        assert pid not in kept.points3D or all(el.image_id != first for el in kept.points3D[pid].track.elements)
        assert kept.num_points3D() >= model.num_points3D() - 1
    else:
        assert not facts["used"] and facts["cost"] is None, facts
        assert kept.point3D(pid).xyz.tolist() == model.point3D(pid).xyz.tolist()


def test_a_camera_that_never_turns_leaves_its_focal_length_unheld():
    """`mapping.focal_hold` against the closed form: a camera that only moves (never turns) leaves its focal length
    undetermined (the points (X/s, Y/s, Z) under focal length s f project as (X, Y, Z) under f; only the gauge's
    three fixed points resist): the hold is under FOCAL_HOLD_MIN and `focal_held` fails the check; the same path
    turning 30 degrees holds it over ten times as firmly and passes."""
    from seeu_data.ingest.mapping import focal_hold
    from seeu_data.ingest.solution_check import FOCAL_HOLD_MIN, focal_held

    holds = []
    for turn in (0.0, 30.0):
        rec, facts = _observed(turn)
        assert facts["used"] and rec.cameras[1].params[0] == pytest.approx(0.714 * W, rel=0.02)
        holds.append(focal_hold(rec, SfmConfig(), facts["cost"], facts["residuals"]))
    assert holds[0] < FOCAL_HOLD_MIN < holds[1] and holds[1] > 10 * holds[0], holds
    slide, turning = ({"ran": True, "passed": True} for _ in range(2))
    focal_held([{"focal_hold": holds[0]}], slide)
    focal_held([{"focal_hold": holds[1]}, {"focal_hold": None}], turning)
    assert slide["passed"] is False and slide["reason"].startswith("the footage hardly determines the camera's focal")
    assert "held 15% off" in slide["reason"] and slide["camera_failed"] == ["focal_hold"]
    assert turning == {"ran": True, "passed": True, "focal_hold": holds[1]}


def test_a_fitted_pincushion_fails_a_videos_check():
    """`corner_pincushion_pct` against the closed form of SIMPLE_RADIAL (a corner at distorted radius r_d from the
    principal point, in focal lengths, lies at r_u with r_u + k r_u^3 = r_d), the same for RADIAL and OPENCV, none
    for PINHOLE, barrel negative; `no_pincushion` fails the check of the tripod pan's camera (k 0.254 at focal
    length 1.076 of the longer side: 6.4 %), passes a camera within a % of it, keeps an earlier failure's reason
    while it lists the camera as failed (`camera_plausible`)."""
    import pycolmap

    from seeu_data.ingest.solution_check import (
        PINCUSHION_MAX_PCT,
        camera_plausible,
        corner_pincushion_pct,
        no_pincushion,
    )

    r_d = np.hypot(320, 180) / 500
    expected = {}
    for k in (0.2, -0.2):
        r_u = min(r.real for r in np.roots([k, 0, 1, -r_d]) if abs(r.imag) < 1e-9 and r.real > 0)
        expected[k] = 100 * (r_d / r_u - 1)
        simple = pycolmap.Camera(model="SIMPLE_RADIAL", width=640, height=360, params=[500, 320, 180, k])
        assert corner_pincushion_pct(simple) == pytest.approx(expected[k], rel=1e-6)
    assert expected[0.2] > 0 > expected[-0.2]
    for model, params in (("RADIAL", [500, 320, 180, 0.2, 0.0]), ("OPENCV", [500, 500, 320, 180, 0.2, 0, 0, 0])):
        camera = pycolmap.Camera(model=model, width=640, height=360, params=params)
        assert corner_pincushion_pct(camera) == pytest.approx(expected[0.2], rel=1e-6)
    pinhole = pycolmap.Camera(model="PINHOLE", width=640, height=360, params=[500, 500, 320, 180])
    assert corner_pincushion_pct(pinhole) == pytest.approx(0.0, abs=1e-9)

    path = planar_camera_path(6)
    pan = pycolmap.Camera(model="SIMPLE_RADIAL", width=640, height=360, params=[1.076 * 640, 320, 180, 0.254])
    walk = pycolmap.Camera(model="SIMPLE_RADIAL", width=640, height=360, params=[0.806 * 640, 320, 180, 0.020])
    check = {"ran": True, "passed": True}
    no_pincushion({0: _Rec(path, pan)}, check)
    assert check["passed"] is False and check["corner_pincushion_pct"] == pytest.approx(6.4, abs=0.1)
    assert check["reason"].startswith("the camera's fitted distortion pushes the image's corners 6.4% outwards")
    check = {"ran": True, "passed": True}
    no_pincushion({0: _Rec(path, walk)}, check)
    assert check["passed"] is True and check["corner_pincushion_pct"] < PINCUSHION_MAX_PCT / 2
    failed = {"ran": True, "passed": False, "reason": "the runs disagree"}
    no_pincushion({0: _Rec(path, pan)}, failed)
    assert failed["reason"] == "the runs disagree"
    assert failed["camera_failed"] == ["corner_pincushion_pct"] and not camera_plausible(failed)
    assert camera_plausible(check)


def test_the_models_of_one_video_must_agree_on_its_focal_length():
    """`solution_check.one_camera`: a video's models over FOCAL_SPREAD_PCT apart in focal length fail the check
    (the `train` clip's two models: 0.93 and 0.71 of the longer side), within it they pass; a failed check keeps
    its reason; one model, or the check not run, judges nothing."""
    from seeu_data.ingest.solution_check import FOCAL_SPREAD_PCT, focal_spread_pct, one_camera

    path = planar_camera_path(12)
    train = {0: _Rec(path[:6], _Camera(0.933 * 320, 320, 180)), 1: _Rec(path[6:], _Camera(0.712 * 320, 320, 180))}
    assert focal_spread_pct(train) == pytest.approx(100 * (0.933 / 0.712 - 1))
    check = {"ran": True, "passed": True}
    one_camera(train, check)
    assert check["passed"] is False and check["focal_spread_pct"] > FOCAL_SPREAD_PCT
    assert check["reason"].startswith("the 2 models of one video give its camera focal lengths 31% apart")
    # the same camera turned (portrait frames): focal over the longer side, 5 % apart, passes
    near = {0: _Rec(path[:6], _Camera(0.75 * 640, 640, 360)), 1: _Rec(path[6:], _Camera(0.7875 * 640, 360, 640))}
    check = {"ran": True, "passed": True}
    one_camera(near, check)
    assert check == {"ran": True, "passed": True, "focal_spread_pct": pytest.approx(5.0)}
    failed = {"ran": True, "passed": False, "reason": "the runs disagree"}
    one_camera(train, failed)
    assert failed["reason"] == "the runs disagree" and failed["focal_spread_pct"] > FOCAL_SPREAD_PCT
    for models, check in (({0: train[0]}, {"ran": True, "passed": True}), (train, {"ran": False, "passed": None})):
        one_camera(models, check)
        assert check["passed"] in (True, None) and "reason" not in check
