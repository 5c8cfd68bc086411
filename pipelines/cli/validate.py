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
from pathlib import Path

from pipelines.cli.options import add_max_pixels, max_pixels


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("path", type=Path, help="dataset directory (holds manifest.json)")
    p.add_argument("--no-sha", action="store_true", help="skip sha256 checks (faster on large datasets)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    add_max_pixels(p)


def run(args: argparse.Namespace) -> int:
    from pipelines.validate import validate_dataset

    summary = validate_dataset(args.path, check_sha=not args.no_sha, max_pixels=max_pixels(args))
    if args.json:
        print(json.dumps(summary, indent=1))
    else:
        scenes = f", {summary['scenes']} scenes" if summary["scenes"] else ""
        print(
            f"OK {summary['path']}: {summary['schema']} v{summary['schema_version']}, {summary['files']} files, "
            f"{summary['rows']} rows{scenes}, {summary['bytes'] / 1e6:.1f} MB"
            + ("" if summary["sha256_checked"] else " (sha256 not checked)")
        )
        if summary["unlisted_files"]:
            print(f"note: files not in the manifest (ignored): {', '.join(summary['unlisted_files'][:5])}")
    return 0
