"""The SfM child process (`python -m seeu_data.ingest.sfm_child JOB.json`, started by
`seeu_data.ingest.sfm.run_sfm`): its steps in turn, result.json last.

    database, extract, match with the keyframes chosen on the way (features.py, pairs.py, keyframes.py)
    -> map, final BA, register the rest, keep models (mapping.py, solution_check.py; a video's models must agree on
    one focal length, `solution_check.one_camera`, which the footage must hold, `focal_held`, without a
    pincushion making up for it, `no_pincushion`) -> export (sfm_export.py),
    with moving content looked for on the way (sfm_motion.py, `--dynamic`); with mask, mapped first without
    the matches on moving content (`sfm_motion.static_job`), that try kept unless its solution check fails; else
    mapped so again with that try's focal length held where its camera passed (`sfm_motion.held_job`), then on
    every match

A child started on a directory where an interrupted one of the same job worked (`run_sfm` keeps it)
continues from what that one finished: the database (its journal entry), each image's features, each
verified pair, each finished mapping run. result.json's "resumed" says how much was kept.
"""

from __future__ import annotations

import json
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path

from seeu_data.ingest.features import Matches, extract, match, open_database
from seeu_data.ingest.keyframes import Keyframes
from seeu_data.ingest.mapping import Mapped, final_ba, keep_models, map_frames, register_rest
from seeu_data.ingest.sfm import Clock, Failed, Job, SfmConfig
from seeu_data.ingest.sfm_export import export_models
from seeu_data.ingest.sfm_motion import (
    Moving,
    astray_plan,
    held_job,
    motion_export,
    motion_frames,
    motion_keyframes,
    motion_rigid,
    motion_start,
    static_job,
)
from seeu_data.ingest.solution_check import (
    camera_plausible,
    focal_held,
    focal_lengths,
    no_pincushion,
    one_camera,
)


def main(job_path: str) -> int:
    """The SfM stage on job.json's frames: extract, match, keyframes, map, final BA, register, export."""
    raw = json.loads(Path(job_path).read_text())
    out = Path(raw["out_dir"])
    job = Job(
        SfmConfig(**raw["config"]),
        out,
        raw["image_dir"],
        raw["image_names"],
        out / "database.db",
        Clock(),
        raw.get("video", True),
        raw.get("mask_dir"),
    )
    try:
        open_database(job)
        num_kp = extract(job)
        matches = match(job)
        kf = matches.keyframes
        posed = _posed(job, matches, kf)
    except Failed as exc:
        failed = {"error": str(exc), "timings": job.clock.wall, "cpu_timings": job.clock.cpu, "resumed": job.resumed}
        (out / "result.json").write_text(json.dumps(failed))
        return 0
    mapped, moving, recs = posed.mapped, posed.moving, posed.mapped.recs
    kept, discarded = keep_models(recs, mapped.rejected)
    models = export_models(job, recs, kept)
    motion_export(job, recs, models, moving)
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
        "final_ba": posed.final_ba,
        "motion": moving.facts,
        "timings": job.clock.wall,
        "cpu_timings": job.clock.cpu,
        "resumed": job.resumed,
    }
    (out / "result.json").write_text(json.dumps(result))
    for runs in ("map_runs", "static_map_runs", "held_runs", "static_held_runs"):  # kept for a re-run of an
        shutil.rmtree(out / runs, ignore_errors=True)  # interrupted child only
    for db in ("static-database.db", "held.db", "static-held.db"):
        (out / db).unlink(missing_ok=True)
    return 0


@dataclass
class Posed:
    """One try at the poses: the mapping kept (`Mapped`, its models adjusted and completed in place), the moving
    content found on the way, the final bundle adjustment's facts."""

    mapped: Mapped
    moving: Moving
    final_ba: list[dict] | None


def _pose(job: Job, matches: Matches, kf: Keyframes, moving: Moving) -> Posed:
    """Map, look for moving content, adjust, register the rest, look again (the steps after matching)."""
    mapped = map_frames(job, matches, kf)
    recs = mapped.recs
    motion_keyframes(job, recs, kf, moving, mapped.check)
    facts = final_ba(job, recs)
    register_rest(job, recs, kf, mapped.check["kept_seed"], *astray_plan(job, moving))
    motion_frames(job, recs, kf, moving, mapped.check)
    motion_rigid(job, recs, kf, moving, mapped.check)
    if job.video:
        one_camera(recs, mapped.check)
        focal_held(facts, mapped.check)
        no_pincushion(recs, mapped.check)
    return Posed(mapped, moving, facts)


def _posed(job: Job, matches: Matches, kf: Keyframes) -> Posed:
    """The poses: with `static_job`'s database (without the matches on moving content) first, that try kept when
    its solution check does not fail; else, where its camera passed its tests (`solution_check.camera_plausible`) and no --focal
    is given, `_held_try` (its focal length held), kept when that check does not fail; else (or without a first
    try) on every verified match.
    "static_first" in the kept try's motion facts says whether the first was kept ("kept"), why not ("reason"), its
    models' focal lengths over the image's longer side ("focal") and the one held ("focal_held")."""
    moving = motion_start(job)
    static = static_job(job, moving)
    if static is None:
        return _pose(job, matches, kf, moving)
    facts = moving.facts["static_first"]
    try:
        first = _pose(static, matches, kf, moving)
    except Failed as exc:
        facts.update(kept=False, reason=str(exc))
    else:
        check = first.mapped.check
        facts["focal"] = focal_lengths(first.mapped.recs)
        facts["kept"] = check.get("passed") is not False
        if facts["kept"]:
            return first
        facts["reason"] = check.get("reason")
        if camera_plausible(check) and job.cfg.focal is None:  # mapped again with its focal length held
            largest = max(first.mapped.recs.values(), key=lambda rec: rec.num_reg_images())
            facts["focal_held"] = focal_lengths({0: largest})[0]
            held = _held_try(job, matches, kf, moving, facts)
            if held is not None:
                return held
    second = _pose(job, matches, kf, motion_start(job, moving.memo))
    second.moving.facts["static_first"] = facts
    return second


def _held_try(job: Job, matches: Matches, kf: Keyframes, moving: Moving, facts: dict) -> Posed | None:
    """The try with the first try's focal length (`facts["focal_held"]`) held (`held_job`), without the matches on
    moving content (`static_job` on its database): kept (returned) unless its solution check fails. Its facts
    into `facts["held"]` {"frames_masked", "matches_dropped", "kept", "reason"}."""
    retry = motion_start(job, moving.memo)
    held_all = held_job(job, facts["focal_held"])
    held_static = static_job(held_all, retry) or held_all
    facts["held"] = retry.facts.pop("static_first", {})
    try:
        held = _pose(held_static, matches, kf, retry)
    except Failed as exc:
        facts["held"].update(kept=False, reason=str(exc))
        return None
    facts["held"]["kept"] = held.mapped.check.get("passed") is not False
    if facts["held"]["kept"]:
        held.moving.facts["static_first"] = facts
        return held
    facts["held"]["reason"] = held.mapped.check.get("reason")
    return None


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
