"""`seeu validate`: the dataset checks of `seeu_data.store.dataset_check` (the one validator every stage
uses), run over a whole dataset directory (posed frames or triple shards).

Example:
    from pathlib import Path
    from pipelines.validate import validate_dataset

    summary = validate_dataset(Path("data/posed/clip"))   # SeeUError on the first problem
    print(summary["rows"], summary["files"])
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from seeu_data.limits import MAX_PIXELS
from seeu_data.settings import setting
from seeu_data.store.dataset_check import check_dataset


@dataclass(frozen=True)
class ValidateConfig:
    """One `seeu validate` run: `path` the dataset directory, `check_sha` (sha256 of every file),
    `json` (print the summary as JSON), `max_pixels` (largest image header)."""

    path: Path = setting(help="dataset directory (holds manifest.json)", positional=True)
    check_sha: bool = setting(True, "skip sha256 checks (faster on large datasets)", flag="--no-sha")
    json: bool = setting(False, "print the summary as JSON")
    max_pixels: int = MAX_PIXELS


def validate_dataset(root: Path, check_sha: bool = True, max_pixels: int = MAX_PIXELS) -> dict:
    """Validate a dataset directory; raise SeeUError on the first problem; return a summary."""
    summary = check_dataset(root, check_sha=check_sha, max_pixels=max_pixels)
    summary.pop("manifest")
    return summary
