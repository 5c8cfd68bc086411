"""Check a dataset directory (posed frames or triple shards) against its schema and manifest.

Checks (`seeu_data.store.dataset_check`, the checks every stage applies to what it reads): the manifest
(JSON shape, known schema and major version, no file or scene listed twice), every listed file
(present, byte size, sha256, row count, its own schema metadata), column names and types against
`schemas/`, finite cameras, orthonormal rotations, positive focal lengths, 0 < near < far, for
posed frames that each scene's rows are where the manifest says and numbered 0..n-1, and every
image's header size equal to the recorded size and under --max-pixels.

Example:
  seeu validate data/posed/clip
"""

from __future__ import annotations

import argparse
import json

from pipelines.cli.config_flags import add_config_flags, config_from_args
from pipelines.cli.options import add_max_pixels, shared_values

SHARED_FLAGS = {"max_pixels": "max_pixels"}  # the shared flags and the ValidateConfig fields they set


def add_arguments(p: argparse.ArgumentParser) -> None:
    from pipelines.validate import ValidateConfig

    add_config_flags(p, ValidateConfig)
    add_max_pixels(p)


def run(args: argparse.Namespace) -> int:
    from pipelines.validate import ValidateConfig, validate_dataset

    cfg = config_from_args(ValidateConfig, args, **shared_values(args, SHARED_FLAGS))
    summary = validate_dataset(cfg.path, check_sha=cfg.check_sha, max_pixels=cfg.max_pixels)
    if cfg.json:
        print(json.dumps(summary, indent=1))
    else:
        scenes = f", {summary['scenes']} scenes" if summary["scenes"] else ""
        print(
            f"OK {summary['path']}: {summary['schema']} v{summary['schema_version']}, {summary['files']} files, "
            f"{summary['rows']} rows{scenes}, {summary['bytes'] / 1e6:.1f} MB"
            + ("" if summary["sha256_checked"] else " (sha256 not checked)")
        )
        ov = summary["overlap"]
        if ov is not None:
            methods = ", ".join(f"{n} from {m}" for m, n in sorted(ov["scenes_by_method"].items()))
            print(f"overlap tables: {ov['files']} files ({methods})")
        elif summary["schema"] == "seeu.posed_frames":
            print(f"note: no overlap table (add one with: seeu overlap {summary['path']})")
        if summary["unlisted_files"]:
            print(f"note: files not in the manifest (ignored): {', '.join(summary['unlisted_files'][:5])}")
    return 0
