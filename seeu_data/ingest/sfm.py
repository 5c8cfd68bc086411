"""Structure from motion with pycolmap 4.x, run in a child process: the stage's config (`SfmConfig`),
`run_sfm` (the parent's side), and what the child's steps share (`Job`, `Clock`, `emit`, `Failed`).

COLMAP can abort the whole process (SIGABRT, no Python exception; e.g. loop detection without a
vocabulary tree), so `run_sfm` starts `python -m seeu_data.ingest.sfm_child JOB.json` and turns any failure
into a SeeUError. The child's steps live in modules named for them: `features` (database, extraction,
matching), `keyframes`, `mapping` (mapping runs, final BA, registration of the other frames),
`solution_check`, `sfm_export`. The child runs: the database's camera and images written in frame order ->
SIFT extraction (one camera of `camera_model` per frame size: portrait and landscape photos get one each;
on the frames downscaled to `feature_size`, at most `max_features` each) -> matching (`matcher`, see
`seeu_data.ingest.match_graph.choose_matcher`; the pairs: `seeu_data.ingest.pairs`): in frame order for
a video (neighbours; then the keyframes, every s-th frame, s from the neighbours' image motion
(`keyframe_motion`, `seeu_data.ingest.keyframes`), 1, 2, 4, ..., 2**(overlap-1) keyframes apart while
they still overlap; the other frames with the keyframes around them; loop detection only with a
vocabulary-tree file), exhaustive for an image folder of up to `EXHAUSTIVE_MAX_IMAGES` images, else
each with the next `UNORDERED_OVERLAP` in name order; verification RANSAC seeded per pair -> mapping (`mapper`: incremental, or global; possibly several models; re-run with the next seed while
it registers too few keyframes, and mapped twice for the solution check, see `map_with_retries`; an
incremental run that registers too few maps once more with the initial pair allowed to move forward, see
`forward_below`) ->
a last global bundle adjustment of each mapped model with a robust loss (`final_ba_loss`, soft-L1 at
0.5 px by default, `final_bundle_adjustment`) -> the other frames registered into the kept models
(COLMAP's incremental-mapper step) -> undistortion of every model
whose camera has distortion of at least `max_negligible_distortion_px` at the image border (to a
pinhole camera of the same W x H, `seeu_data.undistort`; below that the frames are used as they are
with the camera's pinhole part) -> `result.json` + `points_depth_<k>.npy`. A video's moving content
(`dynamic`, `seeu_data.ingest.motion`) is looked for on the mapped frames before the final bundle
adjustment (mask: its observations dropped; off: the solution check fails on it) and on every frame after
registration (mask: the masks written); a user's masks (`mask_dir`) keep features out from the start.

Output directory layout::

    database.db  sfm.log  result.json  job.json  steps.jsonl (the child's finished steps)
    map_runs/run-<seed>/    a mapping run (kept for a re-run of an interrupted child; removed at the end)
    static-database.db, static_map_runs/
                            --dynamic mask, moving content found: the database without the matches on it, and
                            the mapping runs of the try on it (`sfm_motion.static_job`; removed at the end)
    held.db, held_runs/, static-held.db, static_held_runs/
                            the same with the first try's focal length held (`sfm_motion.held_job`; removed)
    sparse/<k>/             COLMAP binary model k (as mapped, adjusted, the other frames registered)
    undistorted/<k>/images/ the undistorted frames (same size, PINHOLE) when the camera model has distortion
    points_depth_<k>.npy    (M,) depth of every 3D-point observation in its camera, model k
    points3d_<k>.npy        (P, 6) the 3D points of model k: world x y z, colour R G B (0-255)
    observations_<k>.npz    names (I,) the registered images; obs (M, 2) int64: image position in
                            names, 3D point id of every observation (the tracks, for the view overlap)
    masks/<k>/<frame>       --dynamic mask: the frame's mask of moving content (PNG, the frame's size,
                            undistorted as the frame is; none where nothing moves)

`result.json`: {"models": [{"index", "cameras": [{"model", "width", "height", "params",
"fx", "fy", "cx", "cy"}] (one per frame size; used after undistortion), "camera" (the one of most frames), "undistorted": bool,
"camera_distorted" (as mapped, when undistorted; "cameras_distorted": all of them), "image_dir", "images": [{"name",
"world_to_cam" (3x4), "camera" (index into "cameras")}], "num_points3D", "mean_reprojection_error"}], "discarded_models",
"num_keypoints", "num_verified_pairs", "matcher": {"requested", "used", "overlap", "reason", "pairs_matched"}, "mapping_attempts": [{"seed", "registered", "models", "seconds"[, "disagreement_pct"][, "init": "forward motion"]}],
"solution_check": {"ran", "passed", "disagreement_pct", "kept_seed"[, "reason"], "planar_or_panoramic_pairs",
"verified_pairs"[, a video's "focal_spread_pct", "focal_hold", "corner_pincushion_pct" (solution_check.py)]}, "keyframes": {"stride", "count", "motion_px" (median image motion between consecutive
frames, null when not a video), "target_px"[, "registered_after" (frames registered after mapping)]},
"final_ba": [{"index", "loss", "scale_px", "termination", "iterations", "residuals", "used" (false: Ceres'
solution unusable, the model kept as mapped), "reprojection_before_px", "reprojection_after_px", "cost" (the robust
cost reached, null unless used)[, "focal_hold" (a video without `focal`: `mapping.focal_hold`)]}] (null with
`final_ba_loss` none),
"motion": moving content (`dynamic`, seeu_data.ingest.sfm_motion.Moving; with `off`, found in the mapped
frames, it fails "solution_check": "passed" false, "reason" and "moving_content" why),
"timings": {"extract_s", "match_s", "map_s" (every mapping run), "register_s" (with a stride > 1),
"final_ba_s", "undistort_s" (when undistorted), "export_s" (the rest of the export)} in wall seconds, "cpu_timings":
the same in CPU seconds (all threads), "resumed": {"images", "pairs", "map_runs"} (what was kept of an
interrupted run of the same job)} or {"error": "...", "timings", "cpu_timings", "resumed"}.

Determinism: the same frames give the same database and the same poses whatever `threads`
(tested with 2 threads x 3 runs and 1 thread), with matching and mapping on `map_threads` = 1. COLMAP's parallel extractor would number images in completion
order and each matching thread's RANSAC state would carry over between the pairs it happens to
verify; both are fixed here (`create_database`, `ransac.random_seed`). Progress comes from COLMAP's
log lines (extraction) and the child's own lines (matching batches, mapping callbacks), not from polling
the database: a second SQLite connection reading while COLMAP writes can leave an image's keypoints
missing, silently.
"""

from __future__ import annotations

import json
import math
import os
import re
import signal
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

from seeu_data.errors import SeeUError
from seeu_data.ingest.match_graph import EXHAUSTIVE_MAX_IMAGES, UNORDERED_OVERLAP
from seeu_data.interrupts import end_process
from seeu_data.limits import MAX_ATTEMPTS, MAX_FEATURES, MAX_FRAMES, MAX_IMAGE_SIDE, MAX_WORKERS, check_range
from seeu_data.settings import setting
from seeu_data.store.resume import Journal, claim_dir, stamp_of

CAMERA_MODELS = ("PINHOLE", "SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV")
MAPPERS = ("incremental", "global", "auto")
MATCHERS = ("auto", "exhaustive", "sequential")
FINAL_BA_LOSSES = ("none", "soft_l1", "cauchy", "huber")  # pycolmap.LossFunctionType, upper-cased
DYNAMIC_MODES = ("off", "mask")  # --dynamic: moving content masked, or only looked for (seeu_data.ingest.motion)
# --features: (pycolmap FeatureExtractorType, FeatureMatcherType) names; only SIFT needs no ONNX runtime
FEATURES = {"sift": ("SIFT", "SIFT_BRUTEFORCE"), "aliked": ("ALIKED_N16ROT", "ALIKED_LIGHTGLUE")}
_PROGRESS = "@@seeu"
# COLMAP's log line for one image's features done: "Processed file [k/N]"
_COLMAP_PROGRESS = re.compile(r"\] Processed file \[(\d+)/\d+\]")


@dataclass(frozen=True)
class SfmConfig:
    """Parameters of the SfM stage (all of them go into the stage stamp)."""

    camera_model: str = setting(
        "SIMPLE_RADIAL", "shared camera model; models with distortion are undistorted", choices=CAMERA_MODELS
    )
    # A video's focal length is poorly observable when the camera turns little, and a moving object can carry SfM
    # to another one while every test agrees with the cameras (docs/ingest.md, "Moving content").
    focal: float | None = setting(
        None,
        "the camera's known focal length over the image's longer side (the 35 mm-equivalent focal length / 36: "
        "0.72 for a phone's 26 mm main camera), held fixed in SfM (the distortion is still estimated); "
        "default: estimated",
        metavar="F",
    )
    overlap: int = setting(10, "sequential matching: keyframes up to 2**(N-1) keyframes apart", metavar="N")
    # auto: a video sequential; an image folder exhaustive up to EXHAUSTIVE_MAX_IMAGES images, else
    # sequential over UNORDERED_OVERLAP neighbours in name order (seeu_data.ingest.match_graph.choose_matcher)
    matcher: str = setting(
        "auto",
        "which frame pairs are matched: sequential (in frame order: neighbours, keyframes 1, 2, 4, ... apart "
        "while they still overlap, --overlap), exhaustive (every pair), or auto: sequential for a video; for "
        "an image folder exhaustive up to "
        f"{EXHAUSTIVE_MAX_IMAGES} images, above that each image with the next {UNORDERED_OVERLAP} in name order "
        "(recorded in report.json)",
        choices=MATCHERS,
    )
    vocab_tree: str | None = setting(None, "vocabulary-tree file: enables loop detection (default: off)")
    min_model_size: int = 10
    max_features: int = setting(
        4096,
        "most SIFT features per frame (COLMAP uses 8192; the mapping uses a few thousand, and matching "
        "costs the square of the count; a 640x360 frame has about 2,000)",
    )
    feature_size: int = setting(
        1600,
        "extract features on the frames downscaled so the longer side is at most PX pixels (COLMAP: 3200), "
        "keypoints mapped back to the full frame",
        metavar="PX",
    )
    threads: int = setting(
        -1,
        "COLMAP threads per scene for feature extraction, and single-threaded matching processes (default: all "
        "cores / workers; 1 with --engine ray, where each task reserves max(--threads, --map-threads) CPUs); "
        "results do not depend on it",
    )
    # Incremental mapping's threads (bundle adjustment of models above 50,000 residuals, and more):
    # with more than one, re-mapping the same database differed in 1 of 15 runs (2 threads, 20-frame
    # clip); with one, never. Extraction and matching use `threads` and stay deterministic.
    map_threads: int = setting(
        1,
        "threads of each mapping run (1: poses identical run after run; more speeds up large inputs, but "
        "results then depend on thread timing; -1 = all cores)",
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
    # of them; the other frames are registered into the model afterwards. 0: map every frame. 40 px (6 % of a
    # 640 px frame): the orbit of benchmarks/footage.py (16.7 px a frame, 90 frames at 640x360) then maps every
    # second frame, 33.5 s instead of 57.2 s, at the same accuracy (0.013 vs 0.012 % of the path); the walk and
    # the pan there keep their stride (30 keyframes at least), as the project's short test clips do.
    keyframe_motion: float = setting(
        40.0,
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

    def cores(self) -> int:
        """The cores SfM may use: `threads`, or with -1 this process's CPU affinity."""
        if self.threads > 0:
            return self.threads
        return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1

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
        check_range(self.feature_size, "--feature-size", 16, MAX_IMAGE_SIDE)
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
        if self.focal is not None and not (math.isfinite(self.focal) and 0.1 <= self.focal <= 10):
            raise SeeUError(f"--focal must be a focal length over the image's longer side, 0.1-10, got {self.focal}")
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
    resume: bool = True,
    mask_dir: str | Path | None = None,
) -> dict:
    """Run SfM on `image_names` (files in `image_dir`) in a child process; return result.json's dict.

    `video`: the frames come from a video (ordered; `matcher` auto matches them sequentially) rather
    than an image folder. `source` names the user's input in error messages. `progress`: a `StageProgress`
    (or True for bars only) that follows the child, stage by stage in its own unit: `sfm extract` (images),
    `sfm match` (image pairs), `sfm map` (registered frames), `sfm register` (frames), read from the
    child's own lines and COLMAP's extraction log lines as they come.
    `resume`: `out_dir` keeps what an interrupted run of the same job (frames, settings; not `threads`)
    finished there: the database with its features and verified pairs, the finished mapping runs; the
    child continues from there (`claim_dir`; anything else there is removed first).
    `mask_dir`: masks of what SfM must leave out, as COLMAP reads them (<name>.png, 0: no features there;
    `ImageReaderOptions.mask_path`), for the frames that have one.
    Raises SeeUError when the child aborts, crashes, or reports that no model could be built.
    """
    from seeu_data.progress import StageProgress

    config.check()
    out_dir = Path(out_dir)
    job = {
        "image_dir": str(Path(image_dir).resolve()),
        "image_names": list(image_names),
        "out_dir": str(out_dir.resolve()),
        "video": bool(video),
        "mask_dir": None if mask_dir is None else str(Path(mask_dir).resolve()),
        "config": asdict(config),
    }
    # what the work depends on: not the thread count (image ids and RANSAC seeds are fixed by the frames)
    made_from = {**job, "out_dir": None, "config": {**asdict(config), "threads": None}}
    claim_dir(out_dir, stamp_of(made_from), not resume)
    (out_dir / "job.json").write_text(json.dumps(job, indent=1))
    log_path = out_dir / "sfm.log"
    env = dict(os.environ, GLOG_minloglevel=os.environ.get("GLOG_minloglevel", "0"))
    own = not isinstance(progress, StageProgress)
    prog = StageProgress("sfm", bar=bool(progress)) if own else progress
    base = 0  # extraction: the images done before COLMAP's "Processed file [k/N]" count starts
    try:
        with open(log_path, "ab") as log:
            # COLMAP's log (stderr) comes through the same pipe: it goes to sfm.log, and its
            # "Processed file [k/N]" lines move the extract stage.
            proc = subprocess.Popen(
                [sys.executable, "-m", "seeu_data.ingest.sfm_child", str(out_dir / "job.json")],
                stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
                env=env,
                start_new_session=True,  # its own process group: `end_process` ends its mapping processes too
            )
            assert proc.stdout is not None
            try:
                for raw in proc.stdout:
                    line = raw.decode(errors="replace").strip()
                    if not line.startswith(_PROGRESS):
                        log.write(raw)
                        m = _COLMAP_PROGRESS.search(line)
                        if m and prog.name == "sfm extract":
                            prog.set(base + int(m.group(1)))
                        continue
                    parts = line.split()
                    try:
                        if parts[1] == "stage":
                            total = int(parts[3]) if len(parts) > 3 and parts[3] != "None" else None
                            prog.stage(f"sfm {parts[2]}", total, parts[4] if len(parts) > 4 else "")
                        elif parts[1] == "done":
                            base = int(parts[2])
                            prog.set(base)
                        elif parts[1] == "total":
                            prog.set_total(int(parts[2]))
                    except (IndexError, ValueError):  # a line another writer broke into: progress only
                        log.write(raw)
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


# ---------------------------------------------------------------------------------------------
# What the child's steps share (seeu_data.ingest.sfm_child and its step modules)
# ---------------------------------------------------------------------------------------------


def emit(*parts) -> None:
    """One progress line to the parent, in one write: under PYTHONUNBUFFERED, print() writes each piece
    on its own, and COLMAP's threads logging to the same pipe got in between ("done 30I2026...")."""
    sys.stdout.flush()
    os.write(sys.stdout.fileno(), (" ".join(map(str, (_PROGRESS, *parts))) + "\n").encode())


class Clock:
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


def model_cameras(rec) -> list:
    """The cameras of `rec`'s registered images, by camera id (one per frame size)."""
    ids = sorted({rec.image(i).camera_id for i in rec.reg_image_ids()})
    return [rec.cameras[c] for c in ids]


class Failed(Exception):
    """A result the user can act on (no features, no pairs, no model): result.json's "error"."""


@dataclass
class Job:
    """What the child works on: job.json's fields, the database path, the stage clock, the journal of
    the steps finished (`steps.jsonl` in `out`, kept by a resumed run) and what was kept of an earlier
    run (result.json's "resumed": {"images" with features, verified "pairs", "map_runs"})."""

    cfg: SfmConfig
    out: Path
    image_dir: str
    names: list[str]
    db_path: Path
    clock: Clock
    video: bool = True
    mask_dir: str | None = None  # masks of what SfM leaves out (`run_sfm`)
    map_runs: str = "map_runs"  # the mapping runs' folder in `out` (`mapping._MapRuns`)
    journal: Journal = field(init=False)
    resumed: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.journal = Journal(self.out / "steps.jsonl")

    def finished(self, step: str) -> bool:
        """Whether `step` is in the journal (finished by this run or an earlier one of the same job)."""
        return any(r["unit"] == step for r in self.journal.read())
