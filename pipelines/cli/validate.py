"""Check what a seeu command wrote, by the rules of its layout (detected).

PATH: posed frames or triple shards (manifest.json), pixelSplat chunks (`seeu export pixelsplat`:
read as `seeu import pixelsplat` reads them), a nerfstudio folder (`seeu export nerfstudio`), a render
directory or a .ply (`seeu render`), a training run or checkpoint (`seeu train`), an evaluation index
(`seeu index`), or a folder of these (each one is checked; e.g. `seeu ingest --out`, `seeu demo --out`).

Datasets with a manifest (`seeu_data.store.dataset_check`, the checks every stage applies to what it
reads): the manifest (JSON shape, known schema and major version, no file or scene listed twice), every listed file
(present, byte size, sha256, row count, its own schema metadata), column names and types against
`schemas/`, finite cameras, orthonormal rotations, positive focal lengths, 0 < near < far, for
posed frames that each scene's rows are where the manifest says and numbered 0..n-1, and every
image's header size equal to the recorded size and under --max-pixels.

Examples:
  seeu validate data/posed/clip
  seeu validate datasets/mine          # a pixelSplat export
  seeu validate out/demo               # everything the demo wrote
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
    from pipelines.validate import KINDS, ValidateConfig, validate

    cfg = config_from_args(ValidateConfig, args, **shared_values(args, SHARED_FLAGS))
    summary = validate(cfg)
    if cfg.json:
        print(json.dumps(summary, indent=1))
        return 0
    for item in flatten(summary):
        print(f"OK {item['path']}: {KINDS[item['kind']]}, {item['what']}")
        for note in item["notes"]:
            print(f"note: {note}")
    return 0


def flatten(summary: dict) -> list[dict]:
    """A folder's summaries (depth first), then its own."""
    return [i for item in summary.get("items", []) for i in flatten(item)] + [summary]
