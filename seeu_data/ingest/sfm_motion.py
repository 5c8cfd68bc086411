"""Moving content in the SfM child (`--dynamic`, `seeu_data.ingest.motion`): its hooks, in the
order `sfm_child.main` calls them.

    before mapping:            static_job       (mask: the database without the matches on what the best
                                                 rigid motion of the flow leaves unexplained, mapped first;
                                                 that try kept unless its solution check fails; else
                                                 mapped so again with its focal length held where its
                                                 camera passed (held_job), then the steps from mapping
                                                 run again on every verified match)
                               motion_start     (the moving content found on the way, empty)
    after mapping:             motion_keyframes (frames whose camera alone is astray taken out; the
                                                 mapped frames against their SfM cameras; frames with
                                                 moving content placed again on trial; mask: frames a
                                                 large mover carried taken out too, the others' moving
                                                 observations dropped before the final BA, and fail the
                                                 solution check when leaving them out moves the cameras
                                                 past its line; off: moving content found fails it;
                                                 either: frames mostly unexplained by the cameras fail it)
    registration:              astray_plan      (mask: the frames taken out registered again against the
                                                 static points; off: left out)
    after registration:        motion_frames    (mask: every registered frame, the final masks; frames
                                                 astray again taken out for good; carried frames still
                                                 mostly unexplained fail the solution check)
    then:                      motion_rigid     (either: the mapped frames' final cameras against the best
                                                 rigid motion of each pair; carried frames that do not fit
                                                 taken out, other pairs that do not fail the solution check)
    after export:              motion_export    (mask: masks/<k>/<frame>.png, undistorted as the frames)
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

from seeu_data.ingest.keyframes import Keyframes
from seeu_data.ingest.mapping import final_bundle_adjustment
from seeu_data.ingest.sfm import Job, emit
from seeu_data.ingest.solution_check import model_disagreement_pct, registered_names

if TYPE_CHECKING:
    from seeu_data.ingest.motion import FlowMemo


@dataclass
class Moving:
    """Moving content found so far: masks {frame name: (h, w) bool, the motion passes' working size} and
    result.json's "motion" {"mode", "judged" (a video: frames in time order), "keyframes"
    (the mapped frames), "frames" (all, after registration), "leave_out", "static_first" (`static_job`), "masked_pct"
    {name: % of the frame}, "astray" [mapped frames taken out: `_leave_astray`], "carried" [mapped frames a mover
    carried: `motion.carried_frames`]}; `astray`: the frames of both, registered again with mask; `memo`: the frames and
    flows the passes share (`motion.FlowMemo`)."""

    masks: dict
    facts: dict
    memo: FlowMemo
    astray: list[str] = field(default_factory=list)


class _Counter:
    """Progress of one motion stage, frame by frame (the parent's `done N` line)."""

    def __init__(self) -> None:
        self.done = 0

    def __call__(self) -> None:
        self.done += 1
        emit("done", self.done)


def motion_start(job: Job, memo: FlowMemo | None = None) -> Moving:
    """Nothing found yet, the frames and flows of `memo` (a try before: `static_job`) or none read."""
    from seeu_data.ingest.motion import FlowMemo

    return Moving({}, {"mode": job.cfg.dynamic, "judged": job.video}, memo or FlowMemo(job.image_dir))


def motion_keyframes(job: Job, recs: dict, kf: Keyframes, moving: Moving, check: dict) -> None:
    """A video's mapped frames against the flow their SfM cameras allow. mask: frames a large mover carried
    (`motion.carried_frames`) taken out, to be registered again against the static points (`astray_plan`),
    the others' observations in moving regions dropped before the final bundle adjustment. Both modes: the
    leave-out test (`_leave_out`); mask: the cameras moving past the solution check's line without them fail it
    (`motion.masked_content_carried`); off: moving content found (`motion.moving_content`) or frames a mover
    carried fail the solution `check`. Either mode: a trial (`_placed_on_trial`) looks for frames a mover carried
    unseen, and frames left mostly unexplained by the cameras (`motion.cameras_disagree`) fail the check (in place;
    "moving_content" says why)."""
    if not job.video:
        return
    import pycolmap

    from seeu_data.ingest.motion import (
        cameras_disagree,
        carried_frames,
        drop_observations,
        masked_content_carried,
        moving_content,
    )

    emit("stage", "motion-check", len(kf.names), "frames")
    t0 = job.clock.mark()
    moving.astray = _leave_astray(moving.memo, recs, kf.names)
    masks, judged = _model_masks(moving.memo, recs, kf.names)
    moving.facts["keyframes"] = {"judged": judged, "frames_with_motion": len(masks)}
    if moving.astray:
        moving.facts["astray"] = list(moving.astray)
    found = None
    carried = carried_frames(masks, kf.names)
    if not carried:
        carried = _placed_on_trial(job, recs, kf, masks, check["kept_seed"], moving)
        found = carried_unseen(moving.facts.get("trials", []), bool(carried), job.cfg.dynamic)
    if carried and job.cfg.dynamic == "mask":
        _take_out(recs.values(), carried)
        masks = {n: m for n, m in masks.items() if n not in carried}
        moving.astray += carried
        moving.facts["carried"] = carried
    moving.masks = masks
    if masks:
        moving.facts["leave_out"] = _leave_out(job, {k: pycolmap.Reconstruction(r) for k, r in recs.items()}, masks)
    if job.cfg.dynamic == "mask":
        moving.facts["keyframes"]["observations_dropped"] = sum(drop_observations(r, masks) for r in recs.values())
        found = found or masked_content_carried(moving.facts, job.cfg.max_disagreement_pct)
    elif masks:
        found = found or moving_content(moving.facts)
    found = cameras_disagree(masks, kf.names) or found
    if found:
        _fail(check, found)
    job.clock.add("motion_s", t0)


def motion_rigid(job: Job, recs: dict, kf: Keyframes, moving: Moving, check: dict) -> None:
    """A video's mapped frames, their final cameras against the best rigid motion of each pair of neighbours
    (`motion.rigid_gaps`, with the masks found): carried frames (`motion_keyframes`) of pairs over the line are
    taken out for good (registered again, they did not fit); the other pairs over it fail the solution `check`
    (`motion.cameras_unlike_rigid`; in place), unless it failed already (moving content: not judged). result.json's "motion" "rigid_gap"
    {"max", "pairs_judged", "pairs_over", "taken_out"}."""
    if not job.video or check.get("moving_content"):
        return
    from seeu_data.ingest.motion import RIGID_GAP, cameras_unlike_rigid, rigid_gaps

    t0 = job.clock.mark()
    gaps: list[float] = []
    over: list[tuple[str, str, float]] = []  # the pairs over the line
    for rec in recs.values():
        registered = registered_names(rec)
        mine = [n for n in kf.names if n in registered]
        found = rigid_gaps(moving.memo, mine, rec, moving.masks) if len(mine) > 1 else []
        gaps += [g for *_, g in found]
        over += [(mine[i], mine[j], g) for i, j, g in found if g > RIGID_GAP]
    carried = set(moving.facts.get("carried", ()))
    taken = sorted({n for a, b, _ in over for n in (a, b)} & carried)
    _take_out(recs.values(), taken)
    judged = [g for g in gaps if g == g]  # not NaN
    moving.facts["rigid_gap"] = {
        "max": max(judged, default=0.0),
        "pairs_judged": len(judged),
        "pairs_over": len(over),
        "taken_out": taken,
    }
    why = cameras_unlike_rigid([p for p in over if not {p[0], p[1]} & carried], len(judged))
    if why and check.get("passed") is not False:  # a check failed already keeps its reason
        _fail(check, why)
    job.clock.add("motion_s", t0)


def static_job(job: Job, moving: Moving) -> Job | None:
    """--dynamic mask, a video: the job to map first, on a copy of the database (static-<its name>) without the
    verified matches that touch what the best rigid motion of the flow leaves unexplained (`motion.rigid_pass` over
    every frame, no cameras needed; in frames where it finds none, those matched to it: `drop_matches`), its mapping
    runs in static_<its runs>/; None when not wanted, or when that finds moving content in fewer than
    MIN_MOVING_FRAMES frames (every match is then mapped). moving.facts["static_first"]: {"frames_masked"[, "matches_dropped"]}.

    A mover's matches make COLMAP follow it (cameras 15 % of the path off, the mapping runs agreeing) or try model
    after model (300 s on a 90-frame 320x180 clip that maps in 3 s without it); without them it maps as the
    static scene does. The caller (`sfm_child`) keeps that try unless its own solution check fails, else maps
    every match: where the mover fills much of the view, the best rigid motion of the flow is its own."""
    from seeu_data.ingest.motion import MIN_MOVING_FRAMES, rigid_pass

    if job.cfg.dynamic != "mask" or not job.video:
        return None
    emit("stage", "motion-static", len(job.names), "frames")
    t0 = job.clock.mark()
    masks = rigid_pass(moving.memo, job.names, on_frame=_Counter())
    facts = moving.facts["static_first"] = {"frames_masked": len(masks)}
    static = replace(
        job, db_path=job.db_path.with_name(f"static-{job.db_path.name}"), map_runs=f"static_{job.map_runs}"
    )
    if len(masks) >= MIN_MOVING_FRAMES:
        facts["matches_dropped"] = drop_matches(job.db_path, static.db_path, masks)
    job.clock.add("motion_s", t0)
    return static if "matches_dropped" in facts else None


def held_job(job: Job, focal: float) -> Job:
    """The job to map again with the focal length `focal` (over the image's longer side) that the try without the
    matches on moving content found (`static_job`): a copy of the database (held.db) whose cameras start there as a
    known prior, held as `--focal` holds one, and every pair's matches verified again against it (an essential
    matrix where the focal length is known); its mapping runs in held_runs/.

    With the focal length known, verification keeps other matches, and the try on them maps as a user's `--focal`
    does: `person_x` at 320x180 failed its first try (the focal length 0.716, the truth 0.714; the cameras carried
    over frames 8-23) and mapped with every match 3.2 % of the path off at 0.760; held, 0.065 % with the check
    passed. Held on the first try's verified matches instead, it failed as the first."""
    import pycolmap

    from seeu_data.ingest.features import copy_database, set_focal, verify_again

    dst = job.out / "held.db"
    dst.unlink(missing_ok=True)
    copy_database(job.db_path, dst)
    db = pycolmap.Database.open(dst)
    try:
        for camera in db.read_all_cameras():
            set_focal(camera, focal, known=True)
            db.update_camera(camera)
    finally:
        db.close()
    held = replace(job, cfg=replace(job.cfg, focal=focal), db_path=dst, map_runs="held_runs")
    verify_again(held)
    return held


def drop_matches(src: Path, dst: Path, masks: dict) -> int:
    """A copy of the SfM database `src` at `dst` without the verified matches (two-view geometries' inliers)
    that touch moving content: a keypoint in its frame's moving `masks` {name: (h, w) bool, working size}, or, in
    a frame where they found none, one matched to such a keypoint in another frame, up to MATCH_HOPS matches away
    (`motion.grown_moving`: the same moving point, missed there); returns how many went. COLMAP's correspondence
    graph then leaves out pairs left with too few."""
    import numpy as np
    import pycolmap

    from seeu_data.ingest.features import copy_database
    from seeu_data.ingest.motion import grown_moving, moving_keypoints

    dst.unlink(missing_ok=True)
    copy_database(src, dst)
    db = pycolmap.Database.open(dst)
    dropped = 0
    try:
        moving: dict[int, np.ndarray] = {}
        for image in db.read_all_images():
            xy = np.asarray(db.read_keypoints(image.image_id))[:, :2]
            moving[image.image_id] = np.zeros(len(xy), bool)
            if image.name in masks:
                camera = db.read_camera(image.camera_id)
                moving[image.image_id] = moving_keypoints(xy, masks[image.name], camera.width, camera.height)
        verified = [
            (pycolmap.pair_id_to_image_pair(pair_id), geometry, np.asarray(geometry.inlier_matches).reshape(-1, 2))
            for pair_id, geometry in zip(*db.read_two_view_geometries())
        ]
        moving = grown_moving(moving, [(a, b, pairs) for (a, b), _, pairs in verified])
        for (a, b), geometry, pairs in verified:
            out = moving[a][pairs[:, 0]] | moving[b][pairs[:, 1]]
            if out.any():
                geometry.inlier_matches = pairs[~out]
                db.update_two_view_geometry(a, b, geometry)
                dropped += int(out.sum())
    finally:
        db.close()
    return dropped


def _placed_on_trial(job: Job, recs: dict, kf: Keyframes, masks: dict, seed: int, moving: Moving) -> list[str]:
    """Nothing carried (`motion.carried_frames`): the mapped frames with moving content (`masks`) placed again
    against the rest on trial (`motion.trial_frames`: taken out of copies of `recs`, the rest adjusted, they
    registered again, their new points triangulated as they go), widened by REPAIR_MARGIN frames, then twice,
    four times ... as many while the trial leaves more than a quarter of them unregistered or mostly unexplained
    by the flow (`motion.cameras_disagree`). The frames of the first trial that places them well are carried
    when it moved the cameras more than TRIAL_SHIFT_PCT of the path (their own points carried them: with mask
    they are repaired, with off the solution check fails); else none. Each trial in `moving.facts["trials"]`
    (in place)."""
    import pycolmap

    from seeu_data.ingest.keyframes import register_frames
    from seeu_data.ingest.motion import REPAIR_MARGIN, TRIAL_SHIFT_PCT, cameras_disagree, trial_frames

    margin = REPAIR_MARGIN
    while names := trial_frames(masks, kf.names, margin):
        emit("stage", "motion-trial", len(names), "frames")
        trial = {k: pycolmap.Reconstruction(r) for k, r in recs.items()}
        _take_out(trial.values(), names)
        trial = _adjusted(job, trial)
        register_frames(job.db_path, trial, kf.names, kf.names, seed, job.cfg.map_threads, triangulate=True)
        lo, hi = kf.names.index(names[0]), kf.names.index(names[-1])
        judged = kf.names[max(0, lo - REPAIR_MARGIN) : hi + REPAIR_MARGIN + 1]  # with neighbours on both sides
        found, _ = _model_masks(moving.memo, trial, judged)
        placed = registered_names(*trial.values()) & set(names)
        shift = model_disagreement_pct(recs, trial)
        unexplained = cameras_disagree({n: m for n, m in found.items() if n in names}, names)
        moving.facts.setdefault("trials", []).append(
            {
                "frames": [names[0], names[-1]],
                "count": len(names),
                "placed": len(placed),
                "shift_pct": shift if shift < float("inf") else None,  # None: most ended outside the model
                "unexplained": unexplained is not None,
            }
        )
        if 4 * len(placed) >= 3 * len(names) and unexplained is None:
            return names if shift > TRIAL_SHIFT_PCT else []
        margin *= 2
    return []


def carried_unseen(trials: list[dict], carried: bool, mode: str) -> str | None:
    """Why the solution check fails after the `trials` (`_placed_on_trial`'s facts): with --dynamic off, frames
    they found `carried`; in either mode, none found while every trial moved the frames placed again more than
    TRIAL_SHIFT_PCT of the path or left most of them outside the model (shift None), the flow confirming no
    placement; None otherwise."""
    from seeu_data.ingest.motion import TRIAL_SHIFT_PCT

    if not trials or (carried and mode == "mask"):
        return None
    first, last = trials[-1]["frames"]
    shift = trials[-1]["shift_pct"]
    moved = f"placed again against the rest, mapped frames {first} to {last} " + (
        f"move {shift:.2g}% of the path" if shift is not None else "mostly end outside the model"
    )
    if carried:
        return f"{moved}: a moving object carried their cameras (--dynamic off); re-run with --dynamic mask"
    if all(t["shift_pct"] is None or t["shift_pct"] > TRIAL_SHIFT_PCT for t in trials):
        return (
            f"{moved}, and the optical flow confirms neither placement: a moving object carried SfM, or the poses "
            "are wrong there"
        )
    return None


def _adjusted(job: Job, recs: dict) -> dict:
    """Copies of the models `recs`, each adjusted as the final bundle adjustment does (with soft-L1 when
    --final-ba-loss is none)."""
    import pycolmap

    cfg = job.cfg if job.cfg.final_ba_loss != "none" else replace(job.cfg, final_ba_loss="soft_l1")
    return {k: final_bundle_adjustment(pycolmap.Reconstruction(r), cfg)[0] for k, r in recs.items()}


def _fail(check: dict, why: str) -> None:
    """The solution `check` (result.json's) failed, in place, for `why` (moving content)."""
    check["moving_content"] = why
    if check.get("ran"):
        check["passed"], check["reason"] = False, why


def astray_plan(job: Job, moving: Moving) -> tuple[list[str], list[str]]:
    """The astray frames (`_leave_astray`) that registration leaves out, and those it tries again: with
    mask, all are tried again once the moving content's observations are gone (a frame registered through
    a mover then goes through the static points); with off, none."""
    return ([], moving.astray) if job.cfg.dynamic == "mask" else (moving.astray, [])


def _leave_astray(memo: FlowMemo, recs: dict, names: list[str]) -> list[str]:
    """The mapped frames whose camera alone disagrees with the flow (`motion.astray_frames`), taken out of
    their models (in place: their observations go, and points left with fewer than two); their names."""
    from seeu_data.ingest.motion import astray_frames

    out: list[str] = []
    for rec in recs.values():
        registered = registered_names(rec)
        found = astray_frames(memo, [n for n in names if n in registered], rec)
        _take_out([rec], found)
        out += found
    return out


def _take_out(recs: Iterable, names: list[str]) -> None:
    """Deregister the frames `names` from the models `recs` (in place: their observations go, and points left
    with fewer than two)."""
    for rec in recs:
        for i in list(rec.reg_image_ids()):
            if rec.image(i).name in names:
                rec.deregister_frame(rec.image(i).frame_id)


def _model_masks(memo: FlowMemo, recs: dict, names: list[str], reach: int = 1) -> tuple[dict, int]:
    """`motion.model_pass` over each model's frames among `names` (in time order; `reach` of it): the masks found,
    and how many frames were judged."""
    from seeu_data.ingest.motion import model_pass

    masks: dict = {}
    judged = 0
    count = _Counter()
    for rec in recs.values():
        registered = registered_names(rec)
        mine = [n for n in names if n in registered]
        if mine:  # a model of other frames (a trial can leave one so)
            masks.update(model_pass(memo, mine, rec, count, reach))
            judged += len(mine)
    return masks, judged


def _leave_out(job: Job, recs: dict, masks: dict) -> dict:
    """How much the moving regions carry the models `recs` (copies): each adjusted as the final bundle
    adjustment does, with and without their observations in `masks`; {"observations" (left out), "total"
    (the models' observations), "centre_change_pct" (`model_disagreement_pct` of the two)}."""
    from seeu_data.ingest.motion import drop_observations

    total = sum(r.compute_num_observations() for r in recs.values())
    with_all = _adjusted(job, recs)
    dropped = sum(drop_observations(r, masks) for r in recs.values())
    without = _adjusted(job, recs)
    return {"observations": dropped, "total": total, "centre_change_pct": model_disagreement_pct(with_all, without)}


def motion_frames(job: Job, recs: dict, kf: Keyframes, moving: Moving, check: dict) -> None:
    """--dynamic mask, keyframes or frames registered again (`astray_plan`): every registered frame against the
    SfM cameras, to neighbours `MODEL_REACH` times as far as before (the final masks; a clip mapped on every frame
    keeps the keyframe pass's: reaching as far on the 30-frame box clip of the tests, 1.6 % of its static pixels
    were masked), its observations in moving regions dropped (registered after the final
    adjustment: no adjustment follows); frames astray now, and frames mostly unexplained (`motion.unexplained_frames`:
    not most of the clip, nor much of the stretch a mover carried, `motion_keyframes`) are taken out for good.
    Frames mostly unexplained otherwise fail the solution `check` (in place)."""
    if job.cfg.dynamic != "mask" or not job.video or (kf.stride <= 1 and not moving.astray):
        return
    from seeu_data.ingest.motion import MODEL_REACH, cameras_disagree, drop_observations, unexplained_frames

    emit("stage", "motion-frames", len(job.names), "frames")
    t0 = job.clock.mark()
    astray = _leave_astray(moving.memo, recs, job.names)  # registered astray, or again so
    masks, _ = _model_masks(moving.memo, recs, job.names, MODEL_REACH)
    registered = registered_names(*recs.values())
    judged = [n for n in job.names if n in registered]
    gone = unexplained_frames(masks, judged, moving.facts.get("carried", ()))
    _take_out(recs.values(), gone)
    moving.masks = {n: m for n, m in masks.items() if n not in gone}
    dropped = sum(drop_observations(rec, moving.masks) for rec in recs.values())
    moving.facts["frames"] = {
        "frames_with_motion": len(masks),
        "observations_dropped": dropped,
        "astray": astray,
        "unexplained": gone,
    }
    why = None if gone else cameras_disagree(masks, judged)
    if why:
        _fail(check, why)
    job.clock.add("motion_s", t0)


def motion_export(job: Job, recs: dict, models: list[dict], moving: Moving) -> None:
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
