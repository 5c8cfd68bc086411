"""Mapping: the runs of incremental or global mapping (each in its own process, `python -m
seeu_data.ingest.mapping RUN.json`), judged by the solution check; the forward-motion retry; the last
robust bundle adjustment; the frames between keyframes registered; the models kept (steps of the SfM
child, `seeu_data.ingest.sfm_child`)."""

from __future__ import annotations

import json
import math
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path

from seeu_data.ingest.features import Matches, copy_database
from seeu_data.ingest.keyframes import Keyframes
from seeu_data.ingest.sfm import Failed, Job, SfmConfig, emit
from seeu_data.ingest.solution_check import (
    FOCAL_STEP,
    geometry_counts,
    map_with_retries,
    registered_frames,
    registered_names,
    usable_models,
)
from seeu_data.interrupts import end_process, end_with_parent

# The final bundle adjustment stops when an iteration lowers the cost by less than this fraction
# (Ceres' default; COLMAP sets 0, iterating to the gradient tolerance): 12 iterations instead of 56 on
# a 40-frame clip, the cost within 2e-6 and the focal length within 3e-6 of the 56-iteration result.
FINAL_BA_FUNCTION_TOLERANCE = 1e-6
# Incremental mapping adjusts the whole model again once it has this many times the frames (or points)
# of the last global adjustment: COLMAP's 1.1. 1.3 saved 18 % of a mapping run's CPU on the 60-frame street
# walk of benchmarks/footage.py with the same final accuracy, but the runs the solution check compares drift
# apart (the demo's 36-frame clip: 1.1 % of the path, a failed check, against 0.26 %): kept at 1.1.
GLOBAL_BA_GROWTH = 1.1
# A final adjustment whose mean reprojection error ends above this many times the start's (or 1 px) diverged.
DIVERGED_FACTOR = 10.0
# Whether the footage determines the focal length (`focal_hold`): the model adjusted again with the focal length
# held `solution_check.FOCAL_STEP` lower and higher, the poses, points and distortion free, for at most
# FOCAL_HOLD_ITERATIONS iterations (10 come within 6 % of the converged rise on the final models of the 640x360
# clips of benchmarks/dynamic.py, at 1-2 s each against 12-28 s to converge; 5 left a camera that never turns,
# where the rise converges to 0.025, at 0.053).
FOCAL_HOLD_ITERATIONS = 10
# A camera carried straight ahead (a phone video of a walk) gives pairs whose translation lies almost
# along the optical axis and whose rays meet at small angles; COLMAP refuses those as the initial pair
# (|t_z| >= init_max_forward_motion = 0.95, or a median triangulation angle below init_min_tri_angle =
# 16 degrees, relaxed twice to 4) and, when no pair passes, finds no model at all. A run that registers
# too few frames then maps again at once, in its own process, with these initial-pair limits
# (IncrementalMapperOptions fields; `forward_below`): no forward-motion limit, the angle from 8 degrees
# (relaxed to 4, then 2).
# (The focal length is not the cause: pycolmap 4.2 estimates it per pair from the fundamental matrix
# when no focal is known, so the database camera's prior plays no part in choosing the initial pair.)
FORWARD_MOTION_INIT = {"init_max_forward_motion": 1.0, "init_min_tri_angle": 8.0}


@dataclass(frozen=True)
class Mapped:
    """The kept mapping run: its usable models {index: pycolmap.Reconstruction}, every run's facts, the
    kept run's rejected models, the solution check's facts and the mapper chosen (result.json's fields)."""

    recs: dict
    attempts: list[dict]
    rejected: list[dict]
    check: dict
    mapper_info: dict


def map_frames(job: Job, matches: Matches, kf: Keyframes) -> Mapped:
    """Mapping with retries and the solution check (`map_with_retries`, the runs in `_MapRuns`);
    `sparse/` left empty for the export."""
    from seeu_data.ingest.match_graph import choose_mapper

    cfg, clock = job.cfg, job.clock
    mapper, why = (cfg.mapper, "requested") if cfg.mapper != "auto" else choose_mapper(matches.graph)
    mapper_info = {"requested": cfg.mapper, "used": mapper, "reason": why, "match_graph": matches.graph}
    if matches.num_pairs == 0:
        raise Failed("SfM could not match any pair of frames (blank, textureless or unrelated frames?)")
    emit("stage", "map", len(kf.names), "registered")
    t0 = clock.mark()
    pairs = geometry_counts(job.db_path, set(kf.names))  # the mapped frames' pairs
    runs = _MapRuns(job, mapper, kf, forward_below(job.cfg, mapper, pairs, len(kf.names)))
    try:
        recs, attempts, rejected, check = map_with_retries(
            runs.collect, len(kf.names), cfg, check=cfg.sfm_check and cfg.sfm_attempts >= 2, start=runs.start
        )
    finally:
        runs.close()
    job.resumed["map_runs"] = runs.kept
    for attempt in attempts:  # the run's own wall time (map_with_retries saw only the wait for it)
        attempt["seconds"] = runs.seconds[attempt["seed"]]
        if runs.inits[attempt["seed"]]:
            attempt["init"] = runs.inits[attempt["seed"]]
    if runs.inits.get(check["kept_seed"]):
        check["init"] = runs.inits[check["kept_seed"]]  # the model kept came from a forward-motion retry
    if mapper == "incremental":  # the runs leave the points' colours out: the kept one's frames read once here
        for rec in recs.values():
            rec.extract_colors_for_all_images(job.image_dir, 1)
    sparse = job.out / "sparse"
    shutil.rmtree(sparse, ignore_errors=True)
    sparse.mkdir()
    check["planar_or_panoramic_pairs"] = pairs["planar_or_panoramic"]
    check["verified_pairs"] = pairs["verified"]
    clock.add("map_s", t0)
    if not recs:
        raise Failed(
            "SfM found no model: no frame pair with enough parallax "
            "(static camera, blank frames, too few overlapping frames, or a large moving object filling the view)"
            + (f"; after {len(attempts)} mapping runs" if len(attempts) > 1 else "")
        )
    return Mapped(recs, attempts, rejected, check, mapper_info)


def moves_forward_possibly(pairs: dict) -> bool:
    """Whether an incremental mapping run that registered too few frames is worth its forward-motion retry:
    most verified pairs (`geometry_counts`) have a general two-view geometry, so the camera translates
    (a static or rotating camera gives planar/panoramic pairs, which no init limit can help)."""
    return pairs["verified"] > 0 and pairs["planar_or_panoramic"] < 0.5 * pairs["verified"]


def forward_below(cfg: SfmConfig, mapper: str, pairs: dict, num_frames: int) -> int:
    """Registered frames under which an incremental mapping run maps again, in the same process, with
    the initial pair allowed to move along the optical axis (`FORWARD_MOTION_INIT`), keeping whichever
    try registers more: `map_with_retries`' line for a run that registers enough (`retry_below` of the
    frames), where the camera moves (`moves_forward_possibly`); 0 (never) otherwise. A forward walk's
    runs whose initial pair COLMAP refused: the 50-frame walk of benchmarks/footage.py found a model from
    seed 0 only; a retry in each failing run, beside the others, costs no round of its own."""
    if mapper != "incremental" or not moves_forward_possibly(pairs):
        return 0
    return math.ceil(cfg.retry_below * num_frames)


def map_processes(cfg: SfmConfig) -> int:
    """How many mapping runs may go at once: the cores given (`threads`; -1: this process's CPU
    affinity) over each run's `map_threads` (-1: one run at a time)."""
    if cfg.map_threads < 1:
        return 1
    return max(1, cfg.cores() // cfg.map_threads)


class _MapRuns:
    """Mapping runs, each in its own process (`python -m seeu_data.ingest.mapping RUN.json`, see
    `_map_run`), at most `map_processes(cfg)` at a time, under <out>/<job.map_runs>/run-<seed>/. Every run,
    even a lone one, is read back from the model files it wrote, so the models do not depend on how many
    ran at once, nor on whether a run was made by an earlier, interrupted SfM child: a finished run
    (done.json) made with the same settings is kept, not run again (counted in `kept`). A run's COLMAP
    log goes to sfm.log; the run started when none is going reports its registered frames."""

    def __init__(self, job: Job, mapper: str, kf: Keyframes, forward_below: int = 0) -> None:
        self.job, self.mapper, self.kf, self.forward_below = job, mapper, kf, forward_below
        self.limit = map_processes(job.cfg)
        self.root = job.out / job.map_runs
        self.root.mkdir(exist_ok=True)
        self.procs: dict[int, subprocess.Popen | None] = {}  # None: a finished run kept
        self.seconds: dict[int, float] = {}
        self.inits: dict[int, str | None] = {}  # "forward motion": the run's models came from its retry
        self.kept = 0

    def _dir(self, seed: int) -> Path:
        return self.root / f"run-{seed}"

    def _running(self) -> int:
        return sum(p is not None and p.poll() is None for p in self.procs.values())

    def _launch(self, seed: int) -> None:
        run_dir = self._dir(seed)
        run = {
            "db_path": str(run_dir / "database.db"),
            "image_dir": self.job.image_dir,
            "dir": str(run_dir),
            "mapper": self.mapper,
            "image_names": self.kf.names if self.kf.stride > 1 else [],  # [] every frame in the database
            "num_frames": len(self.kf.names),
            "seed": seed,
            "forward_below": self.forward_below,
            "config": asdict(self.job.cfg),
        }
        try:
            earlier = json.loads((run_dir / "run.json").read_text())
            if (run_dir / "done.json").exists() and {k: earlier.get(k) for k in run} == run:
                self.procs[seed] = None
                self.kept += 1
                return
        except (OSError, ValueError):
            pass
        shutil.rmtree(run_dir, ignore_errors=True)
        run_dir.mkdir()
        # Each run maps its own copy of the database: COLMAP opens it for writing (global mapping writes
        # to it), and two runs opening one file at once failed with "database is locked".
        copy_database(self.job.db_path, run_dir / "database.db")
        (run_dir / "run.json").write_text(json.dumps({**run, "parent": os.getpid(), "progress": self._running() == 0}))
        self.procs[seed] = subprocess.Popen(
            [sys.executable, "-m", "seeu_data.ingest.mapping", str(run_dir / "run.json")]
        )

    def start(self, seed: int) -> None:
        """Begin mapping `seed` if a core is free for it (or keep its finished run)."""
        if seed not in self.procs and self._running() < self.limit:
            self._launch(seed)

    def collect(self, seed: int) -> dict:
        """Wait for the run of `seed` (begun now if it was not) and read its models {index: Reconstruction}."""
        import pycolmap

        if seed not in self.procs:
            self._launch(seed)
        proc = self.procs[seed]
        rc = 0 if proc is None else proc.wait()
        if rc != 0:  # COLMAP aborted the run: this process ends the same way (run_sfm reports it)
            self.close()
            if rc < 0:
                signal.signal(-rc, signal.SIG_DFL)
                os.kill(os.getpid(), -rc)
            sys.exit(rc)
        run_dir = self._dir(seed)
        done = json.loads((run_dir / "done.json").read_text())
        self.seconds[seed] = done["seconds"]
        self.inits[seed] = done.get("init")
        return {k: pycolmap.Reconstruction(run_dir / "sparse" / str(k)) for k in done["models"]}

    def close(self) -> None:
        """End the runs still going (those begun but not needed); the finished ones stay for a re-run of
        an interrupted SfM child (`sfm_child` removes map_runs/ once it is done)."""
        for proc in self.procs.values():
            if proc is not None:
                end_process(proc)
        for seed in self.procs:
            if not (self._dir(seed) / "done.json").exists():
                shutil.rmtree(self._dir(seed), ignore_errors=True)


def _map_run(run_path: str) -> int:
    """One mapping run (a `_MapRuns` child): incremental or global mapping of the database from one
    seed (incremental: again with `FORWARD_MOTION_INIT` when it registers fewer than run["forward_below"]
    frames, the try registering more kept); every model written to <dir>/sparse/<index>/, the database
    copy removed, then done.json {"models": [index], "seconds", "init" (null, or "forward motion": the
    retry's models)}."""
    run = json.loads(Path(run_path).read_text())
    end_with_parent()  # with the SfM child (killed when ingest is interrupted)
    if os.getppid() != run["parent"]:
        return 1
    import pycolmap

    cfg = SfmConfig(**run["config"])
    sparse = Path(run["dir"]) / "sparse"
    sparse.mkdir()
    t0 = time.perf_counter()
    init = None
    if run["mapper"] == "global":
        global_options = pycolmap.GlobalPipelineOptions()
        global_options.min_model_size = cfg.min_model_size
        global_options.num_threads = cfg.map_threads
        global_options.random_seed = run["seed"]
        global_options.image_names = run["image_names"]
        global_options.mapper.bundle_adjustment.refine_focal_length = cfg.focal is None
        recs = pycolmap.global_mapping(run["db_path"], run["image_dir"], sparse, options=global_options)
    else:
        recs = _incremental(run, cfg, {})
        registered = registered_frames(usable_models(recs, cfg, run["num_frames"])[0])
        if registered < run["forward_below"]:  # as `map_with_retries` counts them
            again = _incremental(run, cfg, FORWARD_MOTION_INIT)
            if registered_frames(usable_models(again, cfg, run["num_frames"])[0]) > registered:
                recs, init = again, "forward motion"
    seconds = time.perf_counter() - t0
    for k, rec in recs.items():
        if not (sparse / str(k) / "images.bin").exists():
            (sparse / str(k)).mkdir(exist_ok=True)
            rec.write(sparse / str(k))
    Path(run["db_path"]).unlink(missing_ok=True)
    (Path(run["dir"]) / "done.json").write_text(
        json.dumps({"models": sorted(int(k) for k in recs), "seconds": seconds, "init": init})
    )
    return 0


def _incremental(run: dict, cfg: SfmConfig, init: dict) -> dict:
    """pycolmap.incremental_mapping's own steps for a `_map_run`, with initial-pair limits `init`
    (IncrementalMapperOptions fields) and the reconstructions at hand for the progress (the run started
    when none was going reports the frames registered so far, in every model it holds, after each one):
    {index: pycolmap.Reconstruction}."""
    import pycolmap

    options = pycolmap.IncrementalPipelineOptions()
    options.min_model_size = cfg.min_model_size
    options.num_threads = cfg.map_threads
    options.random_seed = run["seed"]
    options.image_names = run["image_names"]
    options.image_path = run["image_dir"]
    options.extract_colors = False  # read once, for the kept run only (`map_frames`)
    options.ba_global_frames_ratio = options.ba_global_points_ratio = GLOBAL_BA_GROWTH
    options.ba_refine_focal_length = options.mapper.abs_pose_refine_focal_length = cfg.focal is None
    for name, value in init.items():
        setattr(options.mapper, name, value)
    manager = pycolmap.ReconstructionManager()
    db = pycolmap.Database.open(run["db_path"])
    try:
        pipeline = pycolmap.IncrementalPipeline(options, db, manager)
        if run["progress"]:
            for event in ("INITIAL_IMAGE_PAIR_REG_CALLBACK", "NEXT_IMAGE_REG_CALLBACK"):
                pipeline.add_callback(
                    getattr(pycolmap.IncrementalPipelineCallback, event),
                    lambda: emit("done", sum(manager.get(i).num_reg_images() for i in range(manager.size()))),
                )
        pipeline.run()
    finally:
        db.close()
    return {i: manager.get(i) for i in range(manager.size())}


def _ba_options(cfg: SfmConfig):
    """Bundle adjustment options of the final adjustment: `cfg.final_ba_loss` of scale `cfg.final_ba_loss_scale`
    px on `cfg.map_threads` threads, the focal length refined unless --focal holds it."""
    import pycolmap

    options = pycolmap.BundleAdjustmentOptions()
    options.print_summary = False
    options.ceres.loss_function_type = getattr(pycolmap.LossFunctionType, cfg.final_ba_loss.upper())
    options.ceres.loss_function_scale = cfg.final_ba_loss_scale
    options.ceres.solver_options.num_threads = cfg.map_threads
    options.ceres.solver_options.function_tolerance = FINAL_BA_FUNCTION_TOLERANCE
    options.refine_focal_length = cfg.focal is None
    return options


def _adjust(rec, options):
    """One global bundle adjustment of every registered image of `rec` (in place), the gauge fixed by three
    points; the solver's summary."""
    import pycolmap

    config = pycolmap.BundleAdjustmentConfig()
    for i in sorted(rec.reg_image_ids()):
        config.add_image(i)
    config.fix_gauge(pycolmap.BundleAdjustmentGauge.THREE_POINTS)
    return pycolmap.create_default_bundle_adjuster(options, config, rec).solve()


def focal_hold(rec, cfg: SfmConfig, cost: float, residuals: int) -> float:
    """How firmly the footage holds the focal length of `rec`'s camera (one camera: a video's), `rec` just adjusted
    by `final_bundle_adjustment` to the robust `cost` over `residuals` residuals: the model adjusted again
    (`FOCAL_HOLD_ITERATIONS`) with the focal length held `FOCAL_STEP` lower and higher; the smaller of the two
    rises in cost, as the RMS reprojection change it amounts to (sqrt(2 rise / residuals)), in px per 1000 px
    of the image's longer side (comparable across image sizes).

    Where the camera turns little (a tripod pan, a walk straight ahead) the distortion and the poses absorb a
    wrong focal length almost in full, and a moving object can then carry the camera to one."""
    import numpy as np
    import pycolmap

    options = _ba_options(replace(cfg, focal=1.0))  # the focal length held
    options.ceres.solver_options.max_num_iterations = FOCAL_HOLD_ITERATIONS
    camera = next(iter(rec.cameras.values()))
    rises = []
    for scale in (1 - FOCAL_STEP, 1 + FOCAL_STEP):
        moved = pycolmap.Reconstruction(rec)
        for cam in moved.cameras.values():
            params = np.array(cam.params)
            params[list(cam.focal_length_idxs())] *= scale
            cam.params = params.tolist()
        summary = _adjust(moved, options)
        rises.append(max(0.0, summary.ceres_summary.final_cost - cost))
    return 1000 * math.sqrt(2 * min(rises) / max(residuals, 1)) / max(camera.width, camera.height)


def final_bundle_adjustment(rec, cfg: SfmConfig) -> tuple:
    """One global bundle adjustment of `rec` with the robust loss `cfg.final_ba_loss` of scale
    `cfg.final_ba_loss_scale` px: every registered image, the points, the shared camera's focal
    length (unless --focal holds it) and extra parameters (not the principal point), on `cfg.map_threads`
    threads, until an iteration gains less than `FINAL_BA_FUNCTION_TOLERANCE` of the cost (at most 100
    iterations; NO_CONVERGENCE then keeps the last, better, iterate).

    COLMAP's own global adjustments use a plain squared loss; SIFT's residuals on a video have a heavy
    tail (a few % of observations above 1 px carry most of the squared error), which then pulls the
    focal length and the poses. Returns (the adjusted reconstruction, or `rec` unchanged when Ceres
    calls its solution unusable or it diverged (`DIVERGED_FACTOR`, once the observations it left behind their camera
    are dropped); {"loss", "scale_px", "termination", "iterations", "residuals", "used",
    "reprojection_before_px", "reprojection_after_px", "cost" (the robust cost reached; None unless used)})."""
    import pycolmap

    before = float(rec.compute_mean_reprojection_error())
    original = rec
    rec = pycolmap.Reconstruction(rec)  # adjusted on a copy: `original` stays when the solve fails
    summary = _adjust(rec, _ba_options(cfg))
    used = bool(summary.is_solution_usable())
    if used:  # a solve that diverged (its mean reprojection error far over the start's) is no solution either;
        # but first, as COLMAP's mapper does after each global adjustment, the observations of points the solve
        # moved behind a camera that sees them are dropped: such a point has no reprojection (COLMAP's error
        # 1.3e154 px), and 3 of 2,090 (tracks of 2-6 frames) had made a sound solve look diverged (the mover
        # crossing far ahead, `benchmarks/dynamic.py --seed 1`, 320x180: unadjusted, the checks that need the
        # adjustment did not run, and the check passed with cameras 1.1 % of the path off; adjusted, 0.094 %)
        pycolmap.ObservationManager(rec).filter_observations_with_negative_depth()
        rec.update_point_3d_errors()
        after = float(rec.compute_mean_reprojection_error())
        used = math.isfinite(after) and after <= DIVERGED_FACTOR * max(before, 1.0)
    # the Ceres backend's summary (the default); a plain one when the solve never started (no gauge: a pan)
    ceres = getattr(summary, "ceres_summary", None)
    if not used:
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
        "cost": float(ceres.final_cost) if used and ceres is not None else None,
    }


def final_ba(job: Job, recs: dict) -> list[dict] | None:
    """`final_bundle_adjustment` of every model in `recs`, in place; result.json's "final_ba", with a video's
    `focal_hold` ("focal_hold") unless --focal gives the focal length."""
    if job.cfg.final_ba_loss == "none":
        return None
    # On the mapped (key)frames, before the other frames are registered: a bundle adjustment of
    # every frame costs about the sum of squared track lengths, which grows with the frame rate; the
    # frames registered after are placed against the adjusted points and camera.
    emit("stage", "final-ba")
    t0 = job.clock.mark()
    facts = []
    for k in sorted(recs):
        recs[k], f = final_bundle_adjustment(recs[k], job.cfg)
        if job.video and job.cfg.focal is None and f["cost"] is not None:
            f["focal_hold"] = focal_hold(recs[k], job.cfg, f["cost"], f["residuals"])
        facts.append({"index": int(k), **f})
    job.clock.add("final_ba_s", t0)
    return facts


def register_rest(
    job: Job, recs: dict, kf: Keyframes, seed: int, leave_out: Sequence[str] = (), again: Sequence[str] = ()
) -> None:
    """The frames between keyframes, and keyframes the mapper could not register, registered into `recs`
    (in place), but those of `leave_out`; with `again` (mapped frames taken out: `sfm_motion.astray_plan`)
    also when every frame is a keyframe. Sets kf.info["registered_after"]."""
    from seeu_data.ingest.keyframes import register_frames

    if kf.stride <= 1 and not again:
        return
    mapped = registered_names(*recs.values())
    emit("stage", "register", len(job.names) - len(mapped), "frames")
    t0 = job.clock.mark()
    tried = iter(range(1, len(job.names) + 1))
    names = [n for n in job.names if n not in leave_out]
    kf.info["registered_after"] = register_frames(
        job.db_path, recs, names, kf.names, seed, job.cfg.map_threads, on_frame=lambda: emit("done", next(tried))
    )
    job.clock.add("register_s", t0)


def keep_models(recs: dict, rejected: list[dict]) -> tuple[list[int], list[dict]]:
    """The model indices to export, largest first, and every discarded model's {index, registered, reason}.

    COLMAP may also build small models that mostly re-register frames of a larger one (often from a
    poor initial pair, with an implausible focal length): only models adding new frames are kept."""
    kept, discarded, seen = [], list(rejected), set[str]()
    for k in sorted(recs, key=lambda k: -recs[k].num_reg_images()):
        names_k = registered_names(recs[k])
        if len(names_k & seen) > 0.5 * len(names_k):
            discarded.append(
                {"index": int(k), "registered": len(names_k), "reason": "mostly re-registers frames of a larger model"}
            )
            continue
        seen |= names_k
        kept.append(k)
    return kept, discarded


if __name__ == "__main__":
    sys.exit(_map_run(sys.argv[1]))
