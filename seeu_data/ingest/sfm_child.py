"""The SfM child process (`python -m seeu_data.ingest.sfm_child JOB.json`, started by
`seeu_data.ingest.sfm.run_sfm`): its steps in turn, result.json last.

    database, extract, match with the keyframes chosen on the way (features.py, pairs.py, keyframes.py)
    -> map, final BA, register the rest, keep models (mapping.py, solution_check.py) -> export (sfm_export.py),
    with moving content looked for on the way (sfm_motion.py, `--dynamic`)

A child started on a directory where an interrupted one of the same job worked (`run_sfm` keeps it)
continues from what that one finished: the database (its journal entry), each image's features, each
verified pair, each finished mapping run. result.json's "resumed" says how much was kept.
"""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

from seeu_data.ingest.features import extract, match, open_database
from seeu_data.ingest.mapping import final_ba, keep_models, map_frames, register_rest
from seeu_data.ingest.sfm import Clock, Failed, Job, SfmConfig
from seeu_data.ingest.sfm_export import export_models
from seeu_data.ingest.sfm_motion import (
    astray_plan,
    motion_export,
    motion_frames,
    motion_keyframes,
    motion_rigid,
    motion_start,
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
        moving = motion_start(job)
        mapped = map_frames(job, matches, kf)
    except Failed as exc:
        failed = {"error": str(exc), "timings": job.clock.wall, "cpu_timings": job.clock.cpu, "resumed": job.resumed}
        (out / "result.json").write_text(json.dumps(failed))
        return 0
    recs = mapped.recs
    motion_keyframes(job, recs, kf, moving, mapped.check)
    final_ba_facts = final_ba(job, recs)
    register_rest(job, recs, kf, mapped.check["kept_seed"], *astray_plan(job, moving))
    motion_frames(job, recs, kf, moving, mapped.check)
    motion_rigid(job, recs, kf, moving, mapped.check)
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
        "final_ba": final_ba_facts,
        "motion": moving.facts,
        "timings": job.clock.wall,
        "cpu_timings": job.clock.cpu,
        "resumed": job.resumed,
    }
    (out / "result.json").write_text(json.dumps(result))
    shutil.rmtree(out / "map_runs", ignore_errors=True)  # kept only for a re-run of an interrupted child
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
