"""seeu_data/limits.py: `check_range` wording, and docs/limits.md listing every declared limit."""

from __future__ import annotations

from pathlib import Path

import pytest

from seeu_data.errors import SeeUError
from seeu_data.limits import LIMITS, MAX_BATCH_SIZE, check_range
from seeu_data.store.json_file import MAX_JSON_BYTES, MAX_JSON_DEPTH


def test_check_range_messages():
    assert check_range(8, "data.batch_size", 1, MAX_BATCH_SIZE) == 8
    with pytest.raises(SeeUError, match=r"^data.batch_size 100000000 is over the limit 1024$"):
        check_range(100_000_000, "data.batch_size", 1, MAX_BATCH_SIZE)
    with pytest.raises(SeeUError, match=r"^--workers must be >= 1, got 0$"):
        check_range(0, "--workers", 1, 256)
    for bad in ("8", 8.0, True, None):
        with pytest.raises(SeeUError, match="expected an integer"):
            check_range(bad, "data.batch_size", 1, MAX_BATCH_SIZE)
    with pytest.raises(SeeUError, match=r"^c.json: n 9 is over the limit 4$"):
        check_range(9, "n", 0, 4, "c.json")


def test_limits_page_lists_every_limit():
    page = (Path(__file__).resolve().parents[1] / "docs" / "limits.md").read_text()
    section = page[page.index("| what | at most |") :][:3000]
    for what, limit in {**LIMITS, "JSON bytes": MAX_JSON_BYTES, "JSON depth": MAX_JSON_DEPTH}.items():
        assert f"| {what} | {limit} |" in section, what
