"""Structure from motion with pycolmap 4.x, run in a child process.

COLMAP can abort the whole process (SIGABRT, no Python exception; e.g. loop detection without a
vocabulary tree), so `run_sfm` starts `python -m seeu_data.ingest.sfm CONFIG.json` and turns any failure
into a SeeUError. The child runs: the database's camera and images written in frame order ->
SIFT extraction (one camera of `camera_model` per frame size: portrait and landscape photos get one each)
-> matching (`matcher`, see `seeu_data.ingest.match_graph.choose_matcher`): sequential for a video
(`overlap`: frames 1, 2, 4, ..., 2**(overlap-1) apart; loop detection only with a vocabulary-tree file),
exhaustive for an image folder of up to `EXHAUSTIVE_MAX_IMAGES` images, else sequential over
`UNORDERED_OVERLAP` neighbours in name order; verification RANSAC seeded per pair -> keyframes: a video is mapped on every s-th frame (`keyframe_motion`, `seeu_data.ingest.keyframes`)
-> mapping (`mapper`: incremental, or global; possibly several models; re-run with the next seed while
it registers too few keyframes, and mapped twice for the solution check, see `map_with_retries`; when
incremental mapping finds no model, once more with the initial pair allowed to move forward, see
`map_forward_motion`) ->
a last global bundle adjustment of each mapped model with a robust loss (`final_ba_loss`, soft-L1 at
0.5 px by default, `final_bundle_adjustment`) -> the other frames registered into the kept models
(COLMAP's incremental-mapper step) -> undistortion of every model
whose camera has distortion of at least `max_negligible_distortion_px` at the image border (to a
pinhole camera of the same W x H, `seeu_data.undistort`; below that the frames are used as they are
with the camera's pinhole part) -> `result.json` + `points_depth_<k>.npy`. A video's moving content
(`dynamic`, `seeu_data.ingest.motion`) is looked for after matching (mask: its matches dropped before
mapping), on the mapped frames before the final bundle adjustment (mask: its observations dropped; off:
the solution check fails on it) and on every frame after registration (mask: the masks written).

Output directory layout::

    database.db  sfm.log  result.json
    sparse/<k>/             COLMAP binary model k (as mapped, adjusted, the other frames registered)
    undistorted/<k>/images/ the undistorted frames (same size, PINHOLE) when the camera model has distortion
    points_depth_<k>.npy    (M,) depth of every 3D-point observation in its camera, model k
    points3d_<k>.npy        (P, 6) the 3D points of model k: world x y z, colour R G B (0-255)
    masks/<k>/<frame>       --dynamic mask: the frame's mask of moving content (PNG, the frame's size,
                            undistorted as the frame is; none where nothing moves)

`result.json`: {"models": [{"index", "cameras": [{"model", "width", "height", "params",
"fx", "fy", "cx", "cy"}] (one per frame size; used after undistortion), "camera" (the one of most frames), "undistorted": bool,
"camera_distorted" (as mapped, when undistorted; "cameras_distorted": all of them), "image_dir", "images": [{"name",
"world_to_cam" (3x4), "camera" (index into "cameras")}], "num_points3D", "mean_reprojection_error"}], "discarded_models",
"num_keypoints", "num_verified_pairs", "matcher": {"requested", "used", "overlap", "reason"}, "mapping_attempts": [{"seed", "registered", "models", "seconds"[, "disagreement_pct"][, "init": "forward motion"]}],
"solution_check": {"ran", "passed", "disagreement_pct", "kept_seed"[, "reason"], "planar_or_panoramic_pairs",
"verified_pairs"}, "keyframes": {"stride", "count", "motion_px" (median image motion between consecutive
frames, null when not a video), "target_px"[, "registered_after" (frames registered after mapping)]},
"final_ba": [{"index", "loss", "scale_px", "termination", "iterations", "residuals", "used" (false: Ceres'
solution unusable, the model kept as mapped), "reprojection_before_px", "reprojection_after_px"}] (null with `final_ba_loss` none),
"motion": moving content (`dynamic`, seeu_data.ingest.motion; see `_Moving`; with `off`, found in the mapped
frames, it fails "solution_check": "passed" false, "reason" and "moving_content" why),
"timings": {"extract_s", "match_s", "map_s" (every mapping run), "register_s" (with a stride > 1),
"final_ba_s", "undistort_s" (when undistorted), "export_s" (the rest of the export)} in wall seconds, "cpu_timings":
the same in CPU seconds (all threads)} or {"error": "...", "timings", "cpu_timings"}.

Determinism: the same frames give the same database and the same poses whatever `threads`
(tested with 2 threads x 3 runs and 1 thread), with matching and mapping on `map_threads` = 1. COLMAP's parallel extractor would number images in completion
order and each matching thread's RANSAC state would carry over between the pairs it happens to
verify; both are fixed here (`_create_database`, `ransac.random_seed`). Progress comes from COLMAP's
log lines, not from polling the database: a second SQLite connection reading while COLMAP writes can
leave an image's keypoints missing, silently.
"""

from __future__ import annotations

import json
import math
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

from seeu_data.errors import SeeUError
from seeu_data.ingest.match_graph import EXHAUSTIVE_MAX_IMAGES, UNORDERED_OVERLAP
from seeu_data.interrupts import end_process
from seeu_data.limits import MAX_ATTEMPTS, MAX_FEATURES, MAX_FRAMES, MAX_WORKERS, check_range
from seeu_data.settings import setting

CAMERA_MODELS = ("PINHOLE", "SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV")
MAPPERS = ("incremental", "global", "auto")
MATCHERS = ("auto", "exhaustive", "sequential")
FINAL_BA_LOSSES = ("none", "soft_l1", "cauchy", "huber")  # pycolmap.LossFunctionType, upper-cased
DYNAMIC_MODES = ("off", "mask")  # --dynamic: moving content masked, or only looked for (seeu_data.ingest.motion)
# The final bundle adjustment stops when an iteration lowers the cost by less than this fraction
# (Ceres' default; COLMAP sets 0, iterating to the gradient tolerance): 12 iterations instead of 56 on
# a 40-frame clip, the cost within 2e-6 and the focal length within 3e-6 of the 56-iteration result.
FINAL_BA_FUNCTION_TOLERANCE = 1e-6
# --features: (pycolmap FeatureExtractorType, FeatureMatcherType) names; only SIFT needs no ONNX runtime
FEATURES = {"sift": ("SIFT", "SIFT_BRUTEFORCE"), "aliked": ("ALIKED_N16ROT", "ALIKED_LIGHTGLUE")}
_UNDISTORTED_MODELS = ("PINHOLE", "SIMPLE_PINHOLE")
_PROGRESS = "@@seeu"
# COLMAP's log lines for one image done: "Processed file [k/N]" (extraction), "Processing image [k/N]" (matching)
_COLMAP_PROGRESS = re.compile(r"\] Process(?:ed file|ing image) \[(\d+)/\d+\]")
# COLMAP's own defaults for a plausible camera: focal length / image size within [0.1, 10], |extra params| <= 1
_PLAUSIBLE_CAMERA = (0.1, 10.0, 1.0)
# A camera carried straight ahead (a phone video of a walk) gives pairs whose translation lies almost
# along the optical axis and whose rays meet at small angles; COLMAP refuses those as the initial pair
# (|t_z| >= init_max_forward_motion = 0.95, or a median triangulation angle below init_min_tri_angle =
# 16 degrees, relaxed twice to 4) and, when no pair passes, finds no model at all. Incremental mapping
# is then run once more with these initial-pair limits (IncrementalMapperOptions fields;
# `map_forward_motion`): no forward-motion limit, the angle from 8 degrees (relaxed to 4, then 2).
# (The focal length is not the cause: pycolmap 4.2 estimates it per pair from the fundamental matrix
# when no focal is known, so the database camera's prior plays no part in choosing the initial pair.)
FORWARD_MOTION_INIT = {"init_max_forward_motion": 1.0, "init_min_tri_angle": 8.0}


@dataclass(frozen=True)
class SfmConfig:
    """Parameters of the SfM stage (all of them go into the stage stamp)."""

    camera_model: str = setting(
        "SIMPLE_RADIAL", "shared camera model; models with distortion are undistorted", choices=CAMERA_MODELS
    )
    overlap: int = setting(10, "sequential matching overlap in frames")
    # auto: a video sequential; an image folder exhaustive up to EXHAUSTIVE_MAX_IMAGES images, else
    # sequential over UNORDERED_OVERLAP neighbours in name order (seeu_data.ingest.match_graph.choose_matcher)
    matcher: str = setting(
        "auto",
        "which frame pairs are matched: sequential (frames 1, 2, 4, ... apart, --overlap), exhaustive (every "
        "pair), or auto: sequential for a video; for an image folder exhaustive up to "
        f"{EXHAUSTIVE_MAX_IMAGES} images, above that each image with the next {UNORDERED_OVERLAP} in name order "
        "(recorded in report.json)",
        choices=MATCHERS,
    )
    vocab_tree: str | None = setting(None, "vocabulary-tree file: enables loop detection (default: off)")
    min_model_size: int = 10
    max_features: int = setting(8192, "SIFT features per frame")
    threads: int = setting(
        -1,
        "COLMAP threads per scene for feature extraction (default: all cores / workers; 1 with --engine ray, "
        "where each task reserves max(--threads, --map-threads) CPUs); results do not depend on it",
    )
    # Incremental mapping's threads (bundle adjustment of models above 50,000 residuals, and more):
    # with more than one, re-mapping the same database differed in 1 of 15 runs (2 threads, 20-frame
    # clip); with one, never. Matching runs on these threads too; extraction uses `threads` and stays deterministic.
    map_threads: int = setting(
        1,
        "threads for matching and mapping (1: poses identical run after run; more speeds them up on large "
        "inputs, but results then depend on thread timing; -1 = all cores)",
    )
    random_seed: int = 0
    # Incremental mapping is re-run with the next seed (up to this many runs in all) while its usable
    # models register fewer than `retry_below` of the frames; the run registering most is kept.
    sfm_attempts: int = setting(
        3,
        "re-run incremental mapping with the next seed while it registers < 80% of the frames, keeping the "
        "run that registers most (at most this many runs)",
    )
    retry_below: float = 0.8
    # The solution check: map again from the next seed and require two runs whose camera centres agree
    # (Sim(3)-aligned) within this % of the path; see `map_with_retries`. Needs sfm_attempts >= 2.
    sfm_check: bool = setting(
        True,
        "skip the solution check (a second mapping from the next seed whose camera centres must agree within "
        "1% of the path; mapping takes about twice as long with it)",
    )
    max_disagreement_pct: float = 1.0
    # A distorted camera model whose distortion moves no border pixel by more than this is used as a
    # pinhole without resampling the images.
    max_negligible_distortion_px: float = 0.1
    # incremental (COLMAP), global (GLOMAP), or auto: chosen from the match graph (seeu_data.ingest.match_graph)
    mapper: str = setting(
        "incremental",
        "COLMAP incremental mapping, GLOMAP global mapping, or auto: incremental when >= 90% of consecutive "
        "frames match (a video), else global (recorded in report.json)",
        choices=MAPPERS,
    )
    features: str = setting(
        "sift", "feature type (aliked needs a pycolmap built with ONNX, checked up front)", choices=tuple(FEATURES)
    )
    # Keyframes (seeu_data.ingest.keyframes): a video is mapped on every s-th frame, s the largest power of two
    # keeping the median image motion between keyframes <= keyframe_motion pixels and >= min_keyframes
    # of them; the other frames are registered into the model afterwards. 0: map every frame.
    keyframe_motion: float = setting(
        20.0,
        "map a video on keyframes every 2, 4, 8, ... frames, as far apart as keeps the median image motion "
        "between keyframes <= PX pixels (at least 30 keyframes), then register the other frames into the "
        "model; mapping time then grows with the frame count, not its square (0 = map every frame)",
        metavar="PX",
    )
    min_keyframes: int = 30
    # A last global bundle adjustment of every mapped model (a video: its keyframes), with this
    # robust loss (none, soft_l1, cauchy, huber) of scale final_ba_loss_scale pixels; see `final_bundle_adjustment`.
    final_ba_loss: str = setting(
        "soft_l1",
        "a last global bundle adjustment of each model after mapping (a video: of its keyframes), with this "
        "robust loss, so that the few large SIFT residuals pull the camera less (none = off)",
        choices=FINAL_BA_LOSSES,
    )
    final_ba_loss_scale: float = setting(0.5, "scale of --final-ba-loss in pixels", metavar="PX")
    # Moving content of a video (seeu_data.ingest.motion): masked, or only checked for.
    dynamic: str = setting(
        "mask",
        "moving content of a video (people, cars): mask: found from the optical flow between neighbouring "
        "frames (before mapping, then against the SfM cameras), its keypoints left out of mapping and of the "
        "final bundle adjustment, its per-frame masks written with the posed frames; off: not masked, only "
        "looked for (moving content found fails the solution check)",
        choices=DYNAMIC_MODES,
    )

    def check(self) -> None:
        if self.camera_model not in CAMERA_MODELS:
            raise SeeUError(f"--camera-model must be one of {', '.join(CAMERA_MODELS)}, got {self.camera_model!r}")
        check_range(self.sfm_attempts, "--sfm-attempts", 1, MAX_ATTEMPTS)
        check_range(self.map_threads, "--map-threads", -1, MAX_WORKERS)
        if self.map_threads == 0:
            raise SeeUError(f"--map-threads must be >= 1 or -1 (all cores), got {self.map_threads}")
        check_range(self.threads, "--threads", -1, MAX_WORKERS)
        check_range(self.overlap, "--overlap", 1, MAX_FRAMES)
        check_range(self.max_features, "--max-features", 1, MAX_FEATURES)
        if not (self.keyframe_motion >= 0 and math.isfinite(self.keyframe_motion)):
            raise SeeUError(f"--keyframe-motion must be a finite number >= 0, got {self.keyframe_motion}")
        check_range(self.min_keyframes, "min_keyframes", 3, MAX_FRAMES)
        if self.vocab_tree is not None and not Path(self.vocab_tree).is_file():
            raise SeeUError("vocabulary-tree file not found", self.vocab_tree)
        if self.mapper not in MAPPERS:
            raise SeeUError(f"--mapper must be one of {', '.join(MAPPERS)}, got {self.mapper!r}")
        if self.matcher not in MATCHERS:
            raise SeeUError(f"--matcher must be one of {', '.join(MATCHERS)}, got {self.matcher!r}")
        if self.features not in FEATURES:
            raise SeeUError(f"--features must be one of {', '.join(FEATURES)}, got {self.features!r}")
        if self.final_ba_loss not in FINAL_BA_LOSSES:
            raise SeeUError(f"--final-ba-loss must be one of {', '.join(FINAL_BA_LOSSES)}, got {self.final_ba_loss!r}")
        if not (self.final_ba_loss_scale > 0 and math.isfinite(self.final_ba_loss_scale)):
            raise SeeUError(f"--final-ba-loss-scale must be a finite number > 0, got {self.final_ba_loss_scale}")
        if self.dynamic not in DYNAMIC_MODES:
            raise SeeUError(f"--dynamic must be one of {', '.join(DYNAMIC_MODES)}, got {self.dynamic!r}")
        if self.features != "sift":
            _check_features_available(self.features)


def _check_features_available(features: str) -> None:
    """COLMAP aborts the whole process when it cannot run a feature type (ALIKED without its ONNX
    runtime): ask pycolmap here, where that is a Python exception, before any child starts."""
    import pycolmap

    options = pycolmap.FeatureExtractionOptions()
    options.type = getattr(pycolmap.FeatureExtractorType, FEATURES[features][0])
    try:
        pycolmap.FeatureExtractor.create(options)
    except RuntimeError as exc:  # e.g. "ALIKED feature extraction requires ONNX support."
        raise SeeUError(
            f"--features {features} cannot run with this pycolmap ({str(exc).rstrip('.')}); use --features sift"
        ) from None


def run_sfm(
    image_dir: str | Path,
    image_names: list[str],
    out_dir: str | Path,
    config: SfmConfig,
    source: str | Path,
    progress=False,
    video: bool = True,
) -> dict:
    """Run SfM on `image_names` (files in `image_dir`) in a child process; return result.json's dict.

    `video`: the frames come from a video (ordered; `matcher` auto matches them sequentially) rather
    than an image folder. `source` names the user's input in error messages. `progress`: a `StageProgress` (or True for bars
    only) that follows the child: stages `sfm extract` (images), `sfm match` (images), `sfm map`
    (registered images), read from the child's own lines and COLMAP's log lines as they come.
    Raises SeeUError when the child aborts, crashes, or reports that no model could be built.
    """
    from seeu_data.progress import StageProgress

    config.check()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    job = {
        "image_dir": str(Path(image_dir).resolve()),
        "image_names": list(image_names),
        "out_dir": str(out_dir.resolve()),
        "video": bool(video),
        "config": asdict(config),
    }
    (out_dir / "job.json").write_text(json.dumps(job, indent=1))
    log_path = out_dir / "sfm.log"
    env = dict(os.environ, GLOG_minloglevel=os.environ.get("GLOG_minloglevel", "0"))
    own = not isinstance(progress, StageProgress)
    prog = StageProgress("sfm", bar=bool(progress)) if own else progress
    try:
        with open(log_path, "wb") as log:
            # COLMAP's log (stderr) comes through the same pipe: it goes to sfm.log, and its
            # "Processed file [k/N]" / "Processing image [k/N]" lines move the extract and match stages.
            proc = subprocess.Popen(
                [sys.executable, "-m", "seeu_data.ingest.sfm", str(out_dir / "job.json")],
                stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
                env=env,
            )
            assert proc.stdout is not None
            try:
                for raw in proc.stdout:
                    line = raw.decode(errors="replace").strip()
                    if not line.startswith(_PROGRESS):
                        log.write(raw)
                        m = _COLMAP_PROGRESS.search(line)
                        if m and prog.name in ("sfm extract", "sfm match"):
                            prog.set(int(m.group(1)))
                        continue
                    parts = line.split()
                    if parts[1] == "stage":
                        prog.stage(f"sfm {parts[2]}", int(parts[3]) if len(parts) > 3 else None)
                    elif parts[1] == "step":
                        prog.advance()
                rc = proc.wait()
            except BaseException:  # Ctrl-C, SIGTERM (interrupts.Terminated), an error: the child goes too
                end_process(proc)
                raise
    finally:
        if own:
            prog.close()
    result_path = out_dir / "result.json"
    if rc != 0:
        if rc < 0:
            try:
                sig = signal.Signals(-rc).name
            except ValueError:
                sig = f"signal {-rc}"
            what = f"COLMAP aborted the SfM process ({sig})"
        else:
            what = f"the SfM process failed (exit {rc})"
        raise SeeUError(f"{what}; last log line: {_last_log_line(log_path)} (full log: {log_path})", source)
    if not result_path.exists():
        raise SeeUError(f"the SfM process wrote no result (log: {log_path})", source)
    result = json.loads(result_path.read_text())
    if result.get("error"):
        raise SeeUError(result["error"], source)
    return result


def _last_log_line(path: Path) -> str:
    try:
        lines = [ln.strip() for ln in path.read_text(errors="replace").splitlines() if ln.strip()]
    except OSError:
        return "(no log)"
    pick = next(
        (ln for ln in reversed(lines) if ln[:1] in "EF" or "Check failed" in ln or "rror" in ln),
        lines[-1] if lines else "(empty log)",
    )
    pick = re.sub(r"^[IWEF]\d{8} [\d:.]+ +\d+ [\w.]+:\d+\] ", "", pick)  # glog prefix
    return pick if len(pick) <= 200 else pick[:197] + "..."


def _create_database(db_path: Path, image_dir: Path, names: list[str], cfg: SfmConfig) -> None:
    """Write the cameras (one per frame size, in order of first use, each with its rig) and one frame +
    image per name, in frame order, before extraction.

    COLMAP's parallel extractor otherwise assigns image ids in completion order, which changes with the
    thread count and the machine's load; the ids fix the pair ids, the matching order and the mapper's
    tie-breaks. Each camera is the one the extractor would create (`default_focal_length_factor` x the
    longer side, principal point at the centre): a portrait and a landscape photo of one phone get the
    same focal length in pixels, as separate cameras. The extractor then adds the features of these images.
    """
    import pycolmap

    from seeu_data.store.image_header import image_info

    factor = pycolmap.ImageReaderOptions().default_focal_length_factor
    db = pycolmap.Database.open(db_path)
    try:
        cameras: dict[tuple[int, int], tuple[int, int]] = {}  # (width, height) -> (camera id, rig id)
        for name in names:
            path = image_dir / name
            info = image_info(path.read_bytes(), str(path))
            size = (info.width, info.height)
            if size not in cameras:
                focal = factor * max(size)
                camera = pycolmap.Camera.create_from_model_name(len(cameras) + 1, cfg.camera_model, focal, *size)
                camera.camera_id = db.write_camera(camera)
                rig = pycolmap.Rig()
                rig.add_ref_sensor(camera.sensor_id)
                cameras[size] = (camera.camera_id, db.write_rig(rig))
            camera_id, rig_id = cameras[size]
            image = db.read_image(db.write_image(pycolmap.Image(name=name, camera_id=camera_id)))
            frame = pycolmap.Frame()
            frame.rig_id = rig_id
            frame.add_data_id(image.data_id)
            db.write_frame(frame)
    finally:
        db.close()


def map_with_retries(
    map_once, num_frames: int, cfg: SfmConfig, check: bool = False, start=None
) -> tuple[dict, list[dict], list[dict], dict]:
    """Run `map_once(seed)` (incremental mapping: {index: pycolmap.Reconstruction}) for seeds
    cfg.random_seed, +1, ... at most `cfg.sfm_attempts` times, until a run registers enough frames
    and, with `check`, agrees with an earlier such run.

    Registers enough: its usable models register at least `cfg.retry_below` of the `num_frames` frames.
    Usable: at least `min_model_size` registered frames and a camera that passes COLMAP's own
    plausibility test (focal length within 0.1-10x the image size, |extra params| <= 1; a poor initial
    pair can drive a shared radial camera to k = 1.7 and stall registration). A different seed changes
    COLMAP's RANSAC samples and so which initial pair succeeds.

    The solution check (`check`): a wrong model can look clean (every frame registered, sub-pixel
    reprojection) when one plane dominates the scene; a second run from another seed then usually lands
    elsewhere. Two runs agree when their largest models' camera centres, Sim(3)-aligned, differ by at
    most `cfg.max_disagreement_pct` of the path length (`model_disagreement_pct`). The first run of the
    first agreeing pair is kept; when no two runs agree, the run registering most is kept and the check
    fails. Returns (usable models of the kept run, every run's {seed, registered, models, seconds
    (wall, of `map_once`)[, disagreement_pct]}, the kept run's rejected models as {index, registered, reason}, the check's
    {"ran", "passed", "disagreement_pct" (smallest seen), "kept_seed"[, "reason" (a failed check: no two runs
    registered enough frames to compare, or those that did disagree)]}).

    `start(seed)` (optional) begins mapping `seed` in the background; `map_once(seed)` then collects
    it. It is called at once for the runs certainly needed: with the check, the first two (the second
    either checks the first or replaces it). The runs are still judged one by one in seed order, so the
    outcome is the sequential one.
    """
    runs: list[tuple[int, dict, list]] = []  # (registered, usable, rejected)
    attempts: list[dict] = []
    good: list[int] = []  # indices of runs registering enough
    agreed: int | None = None
    smallest = None
    if start is not None:
        for i in range(min(2 if check else 1, cfg.sfm_attempts)):
            start(cfg.random_seed + i)
    for i in range(cfg.sfm_attempts):
        seed = cfg.random_seed + i
        if i:
            _emit("stage", f"map-retry-{i}", num_frames)
        usable, rejected = {}, []
        t0 = time.perf_counter()
        mapped = map_once(seed)
        seconds = time.perf_counter() - t0
        for k, rec in mapped.items():
            n = rec.num_reg_images()
            if n < cfg.min_model_size:  # COLMAP returns leftovers (a pair that failed to grow)
                continue
            bogus = [c for c in _model_cameras(rec) if c.has_bogus_params(*_PLAUSIBLE_CAMERA)]
            if bogus:
                rejected.append(
                    {
                        "index": int(k),
                        "registered": n,
                        "reason": "implausible camera parameters " + ", ".join(f"{p:.3g}" for p in bogus[0].params),
                    }
                )
                continue
            usable[k] = rec
        registered = len({rec.image(j).name for rec in usable.values() for j in rec.reg_image_ids()})
        runs.append((registered, usable, rejected))
        attempts.append({"seed": seed, "registered": registered, "models": len(usable), "seconds": seconds})
        if registered < cfg.retry_below * num_frames:
            continue
        if not check:
            break
        for j in good:
            d = model_disagreement_pct(runs[j][1], usable)
            smallest = d if smallest is None else min(smallest, d)
            attempts[-1].setdefault("disagreement_pct", {})[str(attempts[j]["seed"])] = d
            if d <= cfg.max_disagreement_pct:
                agreed = j
                break
        good.append(i)
        if agreed is not None:
            break
    if agreed is not None:
        keep = agreed
    else:  # the run registering most, the first on ties
        keep = max(range(len(runs)), key=lambda i: (runs[i][0], -i))
    result = {
        "ran": check,
        "passed": (agreed is not None) if check else None,
        "disagreement_pct": smallest,
        "kept_seed": attempts[keep]["seed"],
    }
    if check and agreed is None:
        result["reason"] = _check_failure(len(good), len(runs), cfg.retry_below, smallest)
    return runs[keep][1], attempts, runs[keep][2], result


def _check_failure(enough: int, runs: int, retry_below: float, smallest: float | None) -> str:
    """Why the solution check failed: too few of the `runs` mapping runs registered at least `retry_below`
    of the frames (`enough` did) to compare two, or those that did disagree (closest `smallest` % apart)."""
    if enough < 2:
        who = "no mapping run" if enough == 0 else f"only one of {runs} mapping runs"
        return f"{who} registered enough frames (at least {100 * retry_below:.0f}%) to compare"
    closest = (
        f" (closest {smallest:.2g}% of the path apart)" if smallest is not None and smallest < float("inf") else ""
    )
    return f"the {enough} mapping runs that registered enough frames disagree{closest}"


def _centres_by_name(recs: dict):
    """Camera-to-world poses `{name: (4, 4)}` of the largest model in `recs` ({} when there is none)."""
    import numpy as np

    if not recs:
        return {}
    rec = max(recs.values(), key=lambda r: r.num_reg_images())
    out = {}
    for i in rec.reg_image_ids():
        img = rec.image(i)
        w2c = np.eye(4)
        w2c[:3] = np.asarray(img.cam_from_world().matrix())
        out[img.name] = np.linalg.inv(w2c)
    return out


def model_disagreement_pct(recs_a: dict, recs_b: dict) -> float:
    """How far two mappings of the same frames disagree: centre RMSE of the largest model of `recs_b`,
    Sim(3)-aligned onto the largest of `recs_a` over their common frames (frame-name order), in % of
    the path length of `recs_a`'s centres (`pose_eval.pose_accuracy`). inf when fewer than half of
    either model's frames (or fewer than 3) are common."""
    import numpy as np

    from seeu_data.ingest.pose_eval import pose_accuracy

    a, b = _centres_by_name(recs_a), _centres_by_name(recs_b)
    common = sorted(set(a) & set(b))
    if len(common) < 3 or len(common) < 0.5 * max(len(a), len(b)):
        return float("inf")
    acc = pose_accuracy(np.stack([b[n] for n in common]), np.stack([a[n] for n in common]))
    return float(acc.centre_rmse_pct_path)


def geometry_counts(db_path: str | Path) -> dict:
    """Verified image pairs in a COLMAP database by two-view geometry: {"verified", "planar_or_panoramic"}.

    Planar / panoramic pairs (a homography explains the matches: one dominant plane, or a rotation
    without translation) constrain the relative pose weakly; their fraction is what decides whether
    the solution check maps twice (`SfmConfig.check_planar_fraction`)."""
    import pycolmap

    cfg = pycolmap.TwoViewGeometryConfiguration
    verified = {
        int(c)
        for c in (cfg.CALIBRATED, cfg.UNCALIBRATED, cfg.PLANAR, cfg.PANORAMIC, cfg.PLANAR_OR_PANORAMIC, cfg.MULTIPLE)
    }
    planar = {int(c) for c in (cfg.PLANAR, cfg.PANORAMIC, cfg.PLANAR_OR_PANORAMIC)}
    db = pycolmap.Database.open(db_path)
    try:
        _, geometries = db.read_two_view_geometries()
    finally:
        db.close()
    configs = [int(g.config) for g in geometries]
    return {"verified": sum(c in verified for c in configs), "planar_or_panoramic": sum(c in planar for c in configs)}


# ---------------------------------------------------------------------------------------------
# Child process
# ---------------------------------------------------------------------------------------------


def _emit(*parts) -> None:
    print(_PROGRESS, *parts, flush=True)


class _Clock:
    """Wall and CPU seconds (CPU: every thread of this process and of its finished mapping processes)
    per stage of the child, summed by name.

    `wall` / `cpu`: {"extract_s", "match_s", "map_s", "register_s", "undistort_s", "export_s"}; a machine shared with
    other work stretches the wall times, much less the CPU times."""

    def __init__(self) -> None:
        self.wall: dict[str, float] = {}
        self.cpu: dict[str, float] = {}

    @staticmethod
    def mark() -> tuple[float, float]:
        import resource

        kids = resource.getrusage(resource.RUSAGE_CHILDREN)
        return time.perf_counter(), time.process_time() + kids.ru_utime + kids.ru_stime

    def add(self, name: str, since: tuple[float, float]) -> None:
        wall, cpu = self.mark()
        self.wall[name] = self.wall.get(name, 0.0) + wall - since[0]
        self.cpu[name] = self.cpu.get(name, 0.0) + cpu - since[1]


def _model_cameras(rec) -> list:
    """The cameras of `rec`'s registered images, by camera id (one per frame size)."""
    ids = sorted({rec.image(i).camera_id for i in rec.reg_image_ids()})
    return [rec.cameras[c] for c in ids]


def _camera_dict(camera) -> dict:
    K = camera.calibration_matrix()
    return {
        "model": camera.model.name,
        "width": int(camera.width),
        "height": int(camera.height),
        "params": [float(p) for p in camera.params],
        "fx": float(K[0, 0]),
        "fy": float(K[1, 1]),
        "cx": float(K[0, 2]),
        "cy": float(K[1, 2]),
    }


def _max_distortion_px(camera) -> float:
    """Largest distance (pixels) between where a border pixel is and where the pinhole part of the
    camera alone would put its ray: 0 for pinhole models."""
    import numpy as np

    w, h = float(camera.width), float(camera.height)
    ts = np.linspace(0.0, 1.0, 9)
    border = np.concatenate(
        [
            np.stack([ts * w, np.zeros_like(ts)], 1),
            np.stack([ts * w, np.full_like(ts, h)], 1),
            np.stack([np.zeros_like(ts), ts * h], 1),
            np.stack([np.full_like(ts, w), ts * h], 1),
        ]
    )
    rays = np.asarray(camera.cam_from_img(border), np.float64)
    K = np.asarray(camera.calibration_matrix(), np.float64)
    pinhole = rays @ K[:2, :2].T + K[:2, 2]
    return float(np.linalg.norm(pinhole - border, axis=1).max())


def final_bundle_adjustment(rec, cfg: SfmConfig) -> tuple:
    """One global bundle adjustment of `rec` with the robust loss `cfg.final_ba_loss` of scale
    `cfg.final_ba_loss_scale` px: every registered image, the points, the shared camera's focal
    length and extra parameters (not the principal point), on `cfg.map_threads` threads, until an
    iteration gains less than `FINAL_BA_FUNCTION_TOLERANCE` of the cost (at most 100 iterations;
    NO_CONVERGENCE then keeps the last, better, iterate).

    COLMAP's own global adjustments use a plain squared loss; SIFT's residuals on a video have a heavy
    tail (a few % of observations above 1 px carry most of the squared error), which then pulls the
    focal length and the poses. Returns (the adjusted reconstruction, or `rec` unchanged when Ceres
    calls its solution unusable; {"loss", "scale_px", "termination", "iterations", "residuals", "used",
    "reprojection_before_px", "reprojection_after_px"})."""
    import pycolmap

    before = float(rec.compute_mean_reprojection_error())
    original = rec
    rec = pycolmap.Reconstruction(rec)  # adjusted on a copy: `original` stays when the solve fails
    options = pycolmap.BundleAdjustmentOptions()
    options.print_summary = False
    options.ceres.loss_function_type = getattr(pycolmap.LossFunctionType, cfg.final_ba_loss.upper())
    options.ceres.loss_function_scale = cfg.final_ba_loss_scale
    options.ceres.solver_options.num_threads = cfg.map_threads
    options.ceres.solver_options.function_tolerance = FINAL_BA_FUNCTION_TOLERANCE
    config = pycolmap.BundleAdjustmentConfig()
    for i in sorted(rec.reg_image_ids()):
        config.add_image(i)
    config.fix_gauge(pycolmap.BundleAdjustmentGauge.THREE_POINTS)
    summary = pycolmap.create_default_bundle_adjuster(options, config, rec).solve()
    used = bool(summary.is_solution_usable())
    # the Ceres backend's summary (the default); a plain one when the solve never started (no gauge: a pan)
    ceres = getattr(summary, "ceres_summary", None)
    if used:
        rec.update_point_3d_errors()  # the points' stored errors (what the mean reads) are not updated by the solve
    else:
        rec = original
    return rec, {
        "loss": cfg.final_ba_loss,
        "scale_px": cfg.final_ba_loss_scale,
        "termination": summary.termination_type.name,
        "iterations": 0 if ceres is None else int(ceres.num_successful_steps + ceres.num_unsuccessful_steps),
        "residuals": int(summary.num_residuals),
        "used": used,
        "reprojection_before_px": before,
        "reprojection_after_px": float(rec.compute_mean_reprojection_error()),
    }


def _export_model(rec, index: int, image_dir: str, out: Path, cameras: dict[int, dict], undistorted: bool) -> dict:
    """Cameras (`cameras`: {camera id: dict} of the registered images), poses and point depths of one
    reconstruction, as plain JSON/npy."""
    import numpy as np

    camera_ids = sorted(cameras)
    position = {cid: j for j, cid in enumerate(camera_ids)}
    images, depths = [], []
    points = {pid: p.xyz for pid, p in rec.points3D.items()}
    for iid in sorted(rec.reg_image_ids()):
        img = rec.image(iid)
        w2c = img.cam_from_world().matrix()
        images.append({"name": img.name, "world_to_cam": np.asarray(w2c).tolist(), "camera": position[img.camera_id]})
        pids = [p.point3D_id for p in img.points2D if p.has_point3D()]
        if pids:
            xyz = np.stack([points[p] for p in pids])
            depths.append(xyz @ np.asarray(w2c)[:, :3].T[:, 2] + np.asarray(w2c)[2, 3])
    depth = np.concatenate(depths) if depths else np.zeros(0)
    np.save(out / f"points_depth_{index}.npy", depth.astype(np.float64))
    ids = sorted(points)
    xyz = np.array([points[p] for p in ids], np.float64).reshape(-1, 3)
    rgb = np.array([rec.points3D[p].color for p in ids], np.float64).reshape(-1, 3)
    np.save(out / f"points3d_{index}.npy", np.concatenate([xyz, rgb], 1))  # (M, 6) world xyz + RGB 0-255
    uses = [sum(im["camera"] == j for im in images) for j in range(len(camera_ids))]
    return {
        "index": index,
        "cameras": [cameras[c] for c in camera_ids],
        "camera": cameras[camera_ids[uses.index(max(uses))]],  # the camera of most frames
        "undistorted": undistorted,
        "image_dir": image_dir,
        "images": images,
        "num_points3D": int(rec.num_points3D()),
        "mean_reprojection_error": float(rec.compute_mean_reprojection_error()),
    }


class _Failed(Exception):
    """A result the user can act on (no features, no pairs, no model): result.json's "error"."""


@dataclass
class _Job:
    """What the child works on: job.json's fields, the database path and the stage clock."""

    cfg: SfmConfig
    out: Path
    image_dir: str
    names: list[str]
    db_path: Path
    clock: _Clock
    video: bool = True


@dataclass(frozen=True)
class Matches:
    """The match step's facts: verified pairs, the match graph's statistics, the median image motion
    between consecutive frames (px; None when keyframes are off)."""

    num_pairs: int
    graph: dict
    motion_px: float | None
    matcher: dict


@dataclass(frozen=True)
class Keyframes:
    """The frames mapped: every `stride`-th frame (`names`); `info` is result.json's "keyframes"."""

    stride: int
    names: list[str]
    info: dict


@dataclass(frozen=True)
class Mapped:
    """The kept mapping run: its usable models {index: pycolmap.Reconstruction}, every run's facts, the
    kept run's rejected models, the solution check's facts and the mapper chosen (result.json's fields)."""

    recs: dict
    attempts: list[dict]
    rejected: list[dict]
    check: dict
    mapper_info: dict


def _extract(job: _Job) -> int:
    """The database (camera and images in frame order) and SIFT features; returns the keypoint count."""
    import pycolmap

    cfg, clock = job.cfg, job.clock
    _emit("stage", "extract", len(job.names))
    t0 = clock.mark()
    _create_database(job.db_path, Path(job.image_dir), job.names, cfg)
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = cfg.camera_model
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.sift.max_num_features = cfg.max_features
    extraction.num_threads = cfg.threads
    extraction.type = getattr(pycolmap.FeatureExtractorType, FEATURES[cfg.features][0])
    pycolmap.extract_features(
        job.db_path,
        job.image_dir,
        image_names=job.names,
        camera_mode=pycolmap.CameraMode.AUTO,  # the images' cameras are in the database already
        reader_options=reader,
        extraction_options=extraction,
    )
    clock.add("extract_s", t0)
    db = pycolmap.Database.open(job.db_path)
    num_kp = int(db.num_keypoints())
    db.close()
    if num_kp < 50:
        raise _Failed(
            f"SfM found only {num_kp} image features in {len(job.names)} frames (blank or textureless video?)"
        )
    return num_kp


def _match(job: _Job) -> Matches:
    """Sequential or exhaustive matching (`choose_matcher`) and two-view verification (RANSAC seeded per
    pair), then the facts read back."""
    import pycolmap

    from seeu_data.ingest.keyframes import consecutive_motion_px
    from seeu_data.ingest.match_graph import choose_matcher, match_graph_stats

    cfg, clock = job.cfg, job.clock
    matcher = choose_matcher(cfg.matcher, job.video, len(job.names), cfg.overlap)
    pairing = pycolmap.SequentialPairingOptions()
    pairing.overlap = matcher["overlap"] or cfg.overlap
    # frames 1, 2, 4, ..., 2**(overlap-1) apart (COLMAP's default; the keyframe stride relies on it), or
    # (the fallback for a large image folder) every one of the next `overlap` images
    pairing.quadratic_overlap = matcher["quadratic"]
    pairing.loop_detection = cfg.vocab_tree is not None
    if cfg.vocab_tree is not None:
        pairing.vocab_tree_path = str(cfg.vocab_tree)
    _emit("stage", "match", len(job.names))
    t0 = clock.mark()
    matching = pycolmap.FeatureMatchingOptions()
    # Matching on the mapping threads (default 1): even with a seeded RANSAC per pair, two matching threads
    # can change the database under load; one thread cannot.
    matching.num_threads = cfg.map_threads
    if cfg.features != "sift":
        matching.type = getattr(pycolmap.FeatureMatcherType, FEATURES[cfg.features][1])
    verification = pycolmap.TwoViewGeometryOptions()
    # RANSAC seeded per pair: otherwise each worker thread's random state carries over from the pairs it
    # happened to verify before, and the verified inliers (even the pairs kept) change with the thread count.
    verification.ransac.random_seed = cfg.random_seed
    if matcher["used"] == "exhaustive":
        pycolmap.match_exhaustive(job.db_path, matching_options=matching, verification_options=verification)
    else:
        pycolmap.match_sequential(
            job.db_path, matching_options=matching, pairing_options=pairing, verification_options=verification
        )
    clock.add("match_s", t0)
    t0 = clock.mark()
    db = pycolmap.Database.open(job.db_path)
    num_pairs = int(db.num_verified_image_pairs())
    graph = match_graph_stats(db, job.names)
    # keyframes are for sequentially matched frames (the stride relies on the quadratic overlap)
    keyframes = cfg.keyframe_motion > 0 and matcher["quadratic"]
    motion = consecutive_motion_px(db, job.names) if keyframes else None
    db.close()
    clock.add("map_s", t0)
    return Matches(num_pairs, graph, motion, matcher)


def _keyframes(names: list[str], motion_px: float | None, cfg: SfmConfig) -> Keyframes:
    """The frames to map (`seeu_data.ingest.keyframes`)."""
    from seeu_data.ingest.keyframes import keyframe_names, keyframe_stride

    # keyframes `stride` apart stay matched to each other at 1, 2 and 4 keyframes apart
    stride = keyframe_stride(
        len(names), motion_px, cfg.keyframe_motion, cfg.min_keyframes, 2 ** max(cfg.overlap - 3, 0)
    )
    keys = keyframe_names(names, stride)
    return Keyframes(
        stride, keys, {"stride": stride, "count": len(keys), "motion_px": motion_px, "target_px": cfg.keyframe_motion}
    )


def _map(job: _Job, matches: Matches, kf: Keyframes) -> Mapped:
    """Mapping with retries and the solution check (`map_with_retries`, the runs in `_MapRuns`);
    `sparse/` left empty for the export."""
    from seeu_data.ingest.match_graph import choose_mapper

    cfg, clock = job.cfg, job.clock
    mapper, why = (cfg.mapper, "requested") if cfg.mapper != "auto" else choose_mapper(matches.graph)
    mapper_info = {"requested": cfg.mapper, "used": mapper, "reason": why, "match_graph": matches.graph}
    if matches.num_pairs == 0:
        raise _Failed("SfM could not match any pair of frames (blank, textureless or unrelated frames?)")
    _emit("stage", "map", len(kf.names))
    t0 = clock.mark()
    pairs = geometry_counts(job.db_path)
    runs = _MapRuns(job, mapper, kf.names if kf.stride > 1 else [])
    try:
        recs, attempts, rejected, check = map_with_retries(
            runs.collect, len(kf.names), cfg, check=cfg.sfm_check and cfg.sfm_attempts >= 2, start=runs.start
        )
    finally:
        runs.close()
    for attempt in attempts:  # the run's own wall time (map_with_retries saw only the wait for it)
        attempt["seconds"] = runs.seconds[attempt["seed"]]
    if not recs and mapper == "incremental" and moves_forward_possibly(pairs):
        recs, attempts, rejected, check = map_forward_motion(job, kf, attempts)
    sparse = job.out / "sparse"
    shutil.rmtree(sparse, ignore_errors=True)
    sparse.mkdir()
    check["planar_or_panoramic_pairs"] = pairs["planar_or_panoramic"]
    check["verified_pairs"] = pairs["verified"]
    clock.add("map_s", t0)
    if not recs:
        raise _Failed(
            "SfM found no model: no frame pair with enough parallax "
            "(static camera, blank frames, or too few overlapping frames)"
            + (f"; after {len(attempts)} mapping runs" if len(attempts) > 1 else "")
        )
    return Mapped(recs, attempts, rejected, check, mapper_info)


def moves_forward_possibly(pairs: dict) -> bool:
    """Whether an incremental mapping that found no model is worth the `map_forward_motion` round:
    most verified pairs (`geometry_counts`) have a general two-view geometry, so the camera translates
    (a static or rotating camera gives planar/panoramic pairs, which no init limit can help)."""
    return pairs["verified"] > 0 and pairs["planar_or_panoramic"] < 0.5 * pairs["verified"]


def map_forward_motion(job: _Job, kf: Keyframes, attempts: list[dict]) -> tuple[dict, list[dict], list[dict], dict]:
    """Incremental mapping again, as in `_map` (`map_with_retries` from the same seeds, the solution
    check), with the initial pair allowed to move along the optical axis (`FORWARD_MOTION_INIT`); for
    when the first round found no model. Returns `map_with_retries`' results, its runs appended to
    `attempts`, each marked "init": "forward motion"."""
    cfg = job.cfg
    _emit("stage", "map-forward-motion", len(kf.names))
    runs = _MapRuns(job, "incremental", kf.names if kf.stride > 1 else [], init=FORWARD_MOTION_INIT)
    try:
        recs, more, rejected, check = map_with_retries(
            runs.collect, len(kf.names), cfg, check=cfg.sfm_check and cfg.sfm_attempts >= 2, start=runs.start
        )
    finally:
        runs.close()
    for attempt in more:
        attempt["seconds"] = runs.seconds[attempt["seed"]]
        attempt["init"] = "forward motion"
    return recs, attempts + more, rejected, check


def map_processes(cfg: SfmConfig) -> int:
    """How many mapping runs may go at once: the cores given (`threads`; -1: this process's CPU
    affinity) over each run's `map_threads` (-1: one run at a time)."""
    if cfg.map_threads < 1:
        return 1
    if cfg.threads > 0:
        cores = cfg.threads
    else:
        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    return max(1, cores // cfg.map_threads)


def _copy_database(src: Path, dst: Path) -> None:
    """A consistent copy of the SQLite database `src` (SQLite's backup: pages still in a -wal file included)."""
    import sqlite3

    with sqlite3.connect(src) as a, sqlite3.connect(dst) as b:
        a.backup(b)
    a.close()
    b.close()


class _MapRuns:
    """Mapping runs, each in its own process (`python -m seeu_data.ingest.sfm --map RUN.json`, see
    `_map_run`), at most `map_processes(cfg)` at a time, under <out>/map_runs/<seed>/. Every run, even
    a lone one, is read back from the model files it wrote, so the models do not depend on how many
    ran at once. A run's COLMAP log goes to sfm.log; the run started when none is going reports progress."""

    def __init__(self, job: _Job, mapper: str, image_names: list[str], init: dict | None = None) -> None:
        self.job, self.mapper, self.image_names, self.init = job, mapper, image_names, init or {}
        self.limit = map_processes(job.cfg)
        self.root = job.out / "map_runs"
        shutil.rmtree(self.root, ignore_errors=True)
        self.root.mkdir()
        self.procs: dict[int, subprocess.Popen] = {}
        self.seconds: dict[int, float] = {}

    def _running(self) -> int:
        return sum(p.poll() is None for p in self.procs.values())

    def _launch(self, seed: int) -> None:
        run_dir = self.root / str(seed)
        run_dir.mkdir()
        # Each run maps its own copy of the database: COLMAP opens it for writing (global mapping writes
        # to it), and two runs opening one file at once failed with "database is locked".
        _copy_database(self.job.db_path, run_dir / "database.db")
        run = {
            "parent": os.getpid(),
            "db_path": str(run_dir / "database.db"),
            "image_dir": self.job.image_dir,
            "dir": str(run_dir),
            "mapper": self.mapper,
            "image_names": self.image_names,
            "seed": seed,
            "init": self.init,
            "progress": self._running() == 0,
            "config": asdict(self.job.cfg),
        }
        (run_dir / "run.json").write_text(json.dumps(run))
        self.procs[seed] = subprocess.Popen(
            [sys.executable, "-m", "seeu_data.ingest.sfm", "--map", str(run_dir / "run.json")]
        )

    def start(self, seed: int) -> None:
        """Begin mapping `seed` if a core is free for it."""
        if seed not in self.procs and self._running() < self.limit:
            self._launch(seed)

    def collect(self, seed: int) -> dict:
        """Wait for the run of `seed` (begun now if it was not) and read its models {index: Reconstruction}."""
        import pycolmap

        if seed not in self.procs:
            self._launch(seed)
        rc = self.procs[seed].wait()
        if rc != 0:  # COLMAP aborted the run: this process ends the same way (run_sfm reports it)
            self.close()
            if rc < 0:
                signal.signal(-rc, signal.SIG_DFL)
                os.kill(os.getpid(), -rc)
            sys.exit(rc)
        run_dir = self.root / str(seed)
        done = json.loads((run_dir / "done.json").read_text())
        self.seconds[seed] = done["seconds"]
        return {k: pycolmap.Reconstruction(run_dir / "sparse" / str(k)) for k in done["models"]}

    def close(self) -> None:
        """End the runs still going (those begun but not needed) and remove their files."""
        for proc in self.procs.values():
            end_process(proc)
        shutil.rmtree(self.root, ignore_errors=True)


def _map_run(run_path: str) -> int:
    """One mapping run (a `_MapRuns` child): incremental or global mapping of the database from one
    seed; every model written to <dir>/sparse/<index>/, then done.json {"models": [index], "seconds"}."""
    run = json.loads(Path(run_path).read_text())
    if sys.platform.startswith("linux"):  # end with the SfM child (killed when ingest is interrupted)
        import ctypes

        ctypes.CDLL(None).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    if os.getppid() != run["parent"]:
        return 1
    import pycolmap

    cfg = SfmConfig(**run["config"])
    sparse = Path(run["dir"]) / "sparse"
    sparse.mkdir()
    t0 = time.perf_counter()
    if run["mapper"] == "global":
        global_options = pycolmap.GlobalPipelineOptions()
        global_options.min_model_size = cfg.min_model_size
        global_options.num_threads = cfg.map_threads
        global_options.random_seed = run["seed"]
        global_options.image_names = run["image_names"]
        recs = pycolmap.global_mapping(run["db_path"], run["image_dir"], sparse, options=global_options)
    else:
        options = pycolmap.IncrementalPipelineOptions()
        options.min_model_size = cfg.min_model_size
        options.num_threads = cfg.map_threads
        options.random_seed = run["seed"]
        options.image_names = run["image_names"]
        for name, value in run.get("init", {}).items():  # initial-pair limits (`map_forward_motion`)
            setattr(options.mapper, name, value)
        step = (lambda: _emit("step")) if run["progress"] else (lambda: None)
        recs = pycolmap.incremental_mapping(
            run["db_path"], run["image_dir"], sparse, options=options, next_image_callback=step
        )
    seconds = time.perf_counter() - t0
    for k, rec in recs.items():
        if not (sparse / str(k) / "images.bin").exists():
            (sparse / str(k)).mkdir(exist_ok=True)
            rec.write(sparse / str(k))
    (Path(run["dir"]) / "done.json").write_text(
        json.dumps({"models": sorted(int(k) for k in recs), "seconds": seconds})
    )
    return 0


def _final_ba(job: _Job, recs: dict) -> list[dict] | None:
    """`final_bundle_adjustment` of every model in `recs`, in place; result.json's "final_ba"."""
    if job.cfg.final_ba_loss == "none":
        return None
    # On the mapped (key)frames, before the other frames are registered: a bundle adjustment of
    # every frame costs about the sum of squared track lengths, which grows with the frame rate; the
    # frames registered after are placed against the adjusted points and camera.
    _emit("stage", "final-ba")
    t0 = job.clock.mark()
    facts = []
    for k in sorted(recs):
        recs[k], f = final_bundle_adjustment(recs[k], job.cfg)
        facts.append({"index": int(k), **f})
    job.clock.add("final_ba_s", t0)
    return facts


def _register(job: _Job, recs: dict, kf: Keyframes, seed: int) -> None:
    """The frames between keyframes registered into `recs` (in place); sets kf.info["registered_after"]."""
    from seeu_data.ingest.keyframes import register_frames

    if kf.stride <= 1:
        return
    mapped = {rec.image(i).name for rec in recs.values() for i in rec.reg_image_ids()}
    _emit("stage", "register", len(job.names) - len(mapped))
    t0 = job.clock.mark()
    kf.info["registered_after"] = register_frames(
        job.db_path, recs, job.names, kf.names, seed, job.cfg.map_threads, on_frame=lambda: _emit("step")
    )
    job.clock.add("register_s", t0)


def _keep_models(recs: dict, rejected: list[dict]) -> tuple[list[int], list[dict]]:
    """The model indices to export, largest first, and every discarded model's {index, registered, reason}.

    COLMAP may also build small models that mostly re-register frames of a larger one (often from a
    poor initial pair, with an implausible focal length): only models adding new frames are kept."""
    kept, discarded, seen = [], list(rejected), set[str]()
    for k in sorted(recs, key=lambda k: -recs[k].num_reg_images()):
        names_k = {recs[k].image(i).name for i in recs[k].reg_image_ids()}
        if len(names_k & seen) > 0.5 * len(names_k):
            discarded.append(
                {"index": int(k), "registered": len(names_k), "reason": "mostly re-registers frames of a larger model"}
            )
            continue
        seen |= names_k
        kept.append(k)
    return kept, discarded


def _export(job: _Job, recs: dict, kept: list[int]) -> list[dict]:
    """Each kept model written to sparse/<k>/, undistorted when its distortion matters, and exported;
    returns result.json's "models"."""
    from seeu_data.undistort import undistort_files

    cfg, clock, out, image_dir = job.cfg, job.clock, job.out, job.image_dir
    _emit("stage", "export")
    models = []
    for k in sorted(kept):
        rec = recs[k]
        t0 = clock.mark()
        model_dir = out / "sparse" / str(k)
        model_dir.mkdir(exist_ok=True)
        rec.write(model_dir)
        cameras = {int(c.camera_id): c for c in _model_cameras(rec)}  # one per frame size
        distortion = max(_max_distortion_px(c) for c in cameras.values())
        as_mapped = {cid: _camera_dict(c) for cid, c in cameras.items()}
        pinhole_models = all(c.model.name in _UNDISTORTED_MODELS for c in cameras.values())
        if pinhole_models or distortion < cfg.max_negligible_distortion_px:
            # Pinhole already, or distortion below a fraction of a pixel everywhere: the frames are
            # used as they are (no resampling, no crop, no second JPEG generation).
            models.append(_export_model(rec, k, image_dir, out, as_mapped, undistorted=False))
            models[-1]["distortion_max_px"] = distortion
            clock.add("export_s", t0)
            continue
        # Same-size undistortion (seeu_data.undistort), each camera's frames with it: the frames keep
        # W x H, only the focal changes.
        und = out / "undistorted" / str(k) / "images"
        clock.add("export_s", t0)
        t0 = clock.mark()
        pinholes = {}
        for cid, camera in cameras.items():
            names = sorted(rec.image(i).name for i in rec.reg_image_ids() if rec.image(i).camera_id == cid)
            pinholes[cid] = undistort_files(camera, image_dir, names, und, jpeg_quality=95)
        clock.add("undistort_s", t0)
        t0 = clock.mark()
        model = _export_model(rec, k, str(und), out, {c: p.as_dict() for c, p in pinholes.items()}, undistorted=True)
        primary = next(c for c in cameras if pinholes[c].as_dict() == model["camera"])
        model["camera_distorted"] = as_mapped[primary]
        model["cameras_distorted"] = [as_mapped[c] for c in sorted(cameras)]
        model["distortion_max_px"] = distortion
        model["undistortion"] = {
            "method": "same-size pinhole, focal x scale",
            "scale": pinholes[primary].scale,
            "scales": [pinholes[c].scale for c in sorted(cameras)],
        }
        models.append(model)
        clock.add("export_s", t0)
    return models


# ---------------------------------------------------------------------------------------------
# Moving content (--dynamic; seeu_data.ingest.motion): the SfM child's four hooks
# ---------------------------------------------------------------------------------------------


@dataclass
class _Moving:
    """Moving content found so far: masks {frame name: (h, w) bool, the motion passes' working size} and
    result.json's "motion" {"mode", "judged" (a video: frames in time order), "first_pass", "keyframes"
    (the mapped frames), "frames" (all, after registration), "leave_out" (off), "masked_pct" {name: % of the
    frame}}."""

    masks: dict
    facts: dict


def _motion_first(job: _Job) -> _Moving:
    """--dynamic mask: moving content of a video from the flow alone, its matches dropped before mapping."""
    moving = _Moving({}, {"mode": job.cfg.dynamic, "judged": job.video})
    if job.cfg.dynamic != "mask" or not job.video:
        return moving
    from seeu_data.ingest.motion import drop_matches, first_pass

    _emit("stage", "motion", len(job.names))
    t0 = job.clock.mark()
    moving.masks = first_pass(job.image_dir, job.names, on_frame=lambda: _emit("step"))
    dropped = drop_matches(job.db_path, moving.masks)
    moving.facts["first_pass"] = {"frames_with_motion": len(moving.masks), "matches_dropped": dropped}
    job.clock.add("motion_s", t0)
    return moving


def _motion_keyframes(job: _Job, recs: dict, kf: Keyframes, moving: _Moving, check: dict) -> None:
    """A video's mapped frames against the flow their SfM cameras allow; mask: their observations in moving
    regions dropped before the final bundle adjustment; off: the leave-out test (`_leave_out`), and moving
    content found (`motion.moving_content`) fails the solution `check` (in place; "moving_content" says why)."""
    if not job.video:
        return
    import pycolmap

    from seeu_data.ingest.motion import drop_observations, moving_content

    _emit("stage", "motion-check", len(kf.names))
    t0 = job.clock.mark()
    masks, judged = _model_masks(job, recs, kf.names)
    moving.masks = masks
    moving.facts["keyframes"] = {"judged": judged, "frames_with_motion": len(masks)}
    if job.cfg.dynamic == "mask":
        moving.facts["keyframes"]["observations_dropped"] = sum(drop_observations(r, masks) for r in recs.values())
    elif masks:
        moving.facts["leave_out"] = _leave_out(job, {k: pycolmap.Reconstruction(r) for k, r in recs.items()}, masks)
        found = moving_content(moving.facts)
        if found:
            check["moving_content"] = found
            if check.get("ran"):
                check["passed"], check["reason"] = False, found
    job.clock.add("motion_s", t0)


def _model_masks(job: _Job, recs: dict, names: list[str]) -> tuple[dict, int]:
    """`motion.model_pass` over each model's frames among `names` (in time order): the masks found, and
    how many frames were judged."""
    from seeu_data.ingest.motion import model_pass

    masks: dict = {}
    judged = 0
    for rec in recs.values():
        registered = {rec.image(i).name for i in rec.reg_image_ids()}
        mine = [n for n in names if n in registered]
        masks.update(model_pass(job.image_dir, mine, rec, on_frame=lambda: _emit("step")))
        judged += len(mine)
    return masks, judged


def _leave_out(job: _Job, recs: dict, masks: dict) -> dict:
    """How much the moving regions carry the models `recs` (copies): each adjusted as the final bundle
    adjustment does, with and without their observations in `masks`; {"observations" (left out),
    "centre_change_pct" (`model_disagreement_pct` of the two)}."""
    import pycolmap

    from seeu_data.ingest.motion import drop_observations

    cfg = job.cfg if job.cfg.final_ba_loss != "none" else replace(job.cfg, final_ba_loss="soft_l1")
    with_all = {k: final_bundle_adjustment(pycolmap.Reconstruction(r), cfg)[0] for k, r in recs.items()}
    dropped = sum(drop_observations(r, masks) for r in recs.values())
    without = {k: final_bundle_adjustment(r, cfg)[0] for k, r in recs.items()}
    return {"observations": dropped, "centre_change_pct": model_disagreement_pct(with_all, without)}


def _motion_frames(job: _Job, recs: dict, kf: Keyframes, moving: _Moving) -> None:
    """--dynamic mask, keyframes: every registered frame against the SfM cameras (the final masks), its
    observations in moving regions dropped (registered after the final adjustment: no adjustment follows)."""
    if job.cfg.dynamic != "mask" or not job.video or kf.stride <= 1:
        return
    from seeu_data.ingest.motion import drop_observations

    _emit("stage", "motion-frames", len(job.names))
    t0 = job.clock.mark()
    masks, _ = _model_masks(job, recs, job.names)
    moving.masks = masks
    dropped = sum(drop_observations(rec, masks) for rec in recs.values())
    moving.facts["frames"] = {"frames_with_motion": len(masks), "observations_dropped": dropped}
    job.clock.add("motion_s", t0)


def _motion_export(job: _Job, recs: dict, models: list[dict], moving: _Moving) -> None:
    """--dynamic mask: each exported model's frames' masks as masks/<k>/<name>.png (the frame's size,
    undistorted as the frames are) and their masked share in "masked_pct"."""
    if job.cfg.dynamic != "mask" or not moving.masks:
        return
    from seeu_data.ingest.motion import full_size
    from seeu_data.masks import encode_mask, undistort_mask

    t0 = job.clock.mark()
    pct: dict[str, float] = {}
    for model in models:
        rec = recs[model["index"]]
        out = job.out / "masks" / str(model["index"])
        for iid in rec.reg_image_ids():
            img = rec.image(iid)
            if img.name not in moving.masks:
                continue
            camera = rec.cameras[img.camera_id]
            mask = full_size(moving.masks[img.name], camera.width, camera.height)
            if model["undistorted"]:
                mask = undistort_mask(mask, camera)
            (out / img.name).parent.mkdir(parents=True, exist_ok=True)
            (out / img.name).write_bytes(encode_mask(mask))
            pct[img.name] = 100.0 * float(mask.mean())
    moving.facts["masked_pct"] = pct
    job.clock.add("motion_s", t0)


def _child(job_path: str) -> int:
    """The SfM stage on job.json's frames: extract, match, keyframes, map, final BA, register, export."""
    raw = json.loads(Path(job_path).read_text())
    out = Path(raw["out_dir"])
    db_path = out / "database.db"
    for stale in (db_path, *(db_path.with_name(db_path.name + s) for s in ("-wal", "-shm", "-journal"))):
        stale.unlink(missing_ok=True)  # a leftover -shm of an earlier database makes SQLite fail to open a new one
    job = _Job(
        SfmConfig(**raw["config"]), out, raw["image_dir"], raw["image_names"], db_path, _Clock(), raw.get("video", True)
    )
    try:
        num_kp = _extract(job)
        matches = _match(job)
        moving = _motion_first(job)
        kf = _keyframes(job.names, matches.motion_px, job.cfg)
        mapped = _map(job, matches, kf)
    except _Failed as exc:
        failed = {"error": str(exc), "timings": job.clock.wall, "cpu_timings": job.clock.cpu}
        (out / "result.json").write_text(json.dumps(failed))
        return 0
    recs = mapped.recs
    _motion_keyframes(job, recs, kf, moving, mapped.check)
    final_ba = _final_ba(job, recs)
    _register(job, recs, kf, mapped.check["kept_seed"])
    _motion_frames(job, recs, kf, moving)
    kept, discarded = _keep_models(recs, mapped.rejected)
    models = _export(job, recs, kept)
    _motion_export(job, recs, models, moving)
    result: dict = {
        "models": models,
        "discarded_models": discarded,
        "num_keypoints": num_kp,
        "num_verified_pairs": matches.num_pairs,
        "matcher": matches.matcher,
        "mapping_attempts": mapped.attempts,
        "mapper": mapped.mapper_info,
        "solution_check": mapped.check,
        "keyframes": kf.info,
        "final_ba": final_ba,
        "motion": moving.facts,
        "timings": job.clock.wall,
        "cpu_timings": job.clock.cpu,
    }
    (out / "result.json").write_text(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(_map_run(sys.argv[2]) if sys.argv[1] == "--map" else _child(sys.argv[1]))
