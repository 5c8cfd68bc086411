"""benchmarks/ingest_scaling.py: the pure functions its figures rest on (no ingest runs, no timings)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from benchmarks.ingest_scaling import STAGES, growth_exponent, stage_seconds, tables


def test_growth_exponent_recovers_a_power_law_and_fits_only_its_range():
    n = [50, 100, 200, 400]
    assert growth_exponent(n, [3.0 * v**1.7 for v in n]) == pytest.approx(1.7, abs=1e-12)
    assert growth_exponent(n, [0.2 * v for v in n]) == pytest.approx(1.0, abs=1e-12)
    # the 50-frame run lies off the law: outside the default 100..400 range it must not count
    off = [1e6, *(3.0 * v**1.2 for v in n[1:])]
    assert growth_exponent(n, off) == pytest.approx(1.2, abs=1e-12)
    assert abs(growth_exponent(n, off, lo=50) - 1.2) > 0.5


def test_growth_exponent_is_the_least_squares_log_log_slope():
    rng = np.random.default_rng(0)
    n = [100, 100, 200, 300, 400]
    t = [5.0 * v**1.4 * float(rng.uniform(0.8, 1.25)) for v in n]
    expected = np.polyfit(np.log(n), np.log(t), 1)[0]  # independent: numpy's least-squares line
    assert growth_exponent(n, t) == pytest.approx(expected, rel=1e-12)


def test_growth_exponent_needs_two_frame_counts_and_positive_times():
    assert math.isnan(growth_exponent([50, 100], [1.0, 2.0]))  # one count in 100..400
    assert math.isnan(growth_exponent([100, 100], [1.0, 2.0]))
    assert math.isnan(growth_exponent([100, 400], [0.0, 2.0]))
    assert math.isnan(growth_exponent([100, 400], [float("nan"), 2.0]))


def _report(map_runs: list[float], undistort: float | None = 0.4) -> dict:
    sfm = {
        "extract_s": 10.0,
        "match_s": 8.0,
        "map_s": sum(map_runs) + 0.3,
        "register_s": 0.7,
        "final_ba_s": 0.6,
        "export_s": 0.2,
    }
    if undistort is not None:
        sfm["undistort_s"] = undistort
    inside = 10.0 + 8.0 + sfm["map_s"] + 0.7 + 0.6 + (undistort or 0.0)
    return {
        "timings_s": {
            "decode": 2.0,
            "select": 0.1,
            "sfm": inside + 0.2 + 1.3,
            "chunks": 0.05,
            "write": 0.9,
            "total": 0.0,
        },
        "sfm": {"timings_s": sfm, "mapping_attempts": [{"seed": i, "seconds": s} for i, s in enumerate(map_runs)]},
    }


def test_stage_seconds_split_the_sfm_stage_and_add_up_to_the_run():
    r = _report([20.0, 22.0])
    r["timings_s"]["total"] = sum(v for k, v in r["timings_s"].items() if k != "total")
    s = stage_seconds(r)
    assert set(s) == {k for k, _ in STAGES} | {"total"}
    assert s["decode"] == pytest.approx(2.1)
    assert s["map_first"] == 20.0
    assert s["map_check"] == pytest.approx(22.3)  # the second run + the agreement test around it
    assert s["undistort"] == 0.4 and s["register"] == 0.7 and s["final_ba"] == 0.6
    assert s["sfm_other"] == pytest.approx(1.3 + 0.2)  # start-up and database reads, model export
    assert s["write"] == pytest.approx(0.95)
    assert sum(s[k] for k, _ in STAGES) == pytest.approx(s["total"])
    # no undistortion (pinhole camera), one mapping run (no solution check)
    s = stage_seconds(_report([20.0], undistort=None))
    assert s["undistort"] == 0.0 and s["map_check"] == pytest.approx(0.3)


def test_tables_give_one_row_per_run_and_an_exponent_per_mapper():
    rows = []
    for mapper, k in (("incremental", 1.5), ("global", 1.1)):
        for n in (50, 100, 200, 400):
            stages = {key: 0.01 * n**k for key, _ in STAGES}
            stages["total"] = sum(stages.values())
            rows.append(
                {
                    "mapper": mapper,
                    "frames": n,
                    "stages_s": stages,
                    "cpu_s": 2 * stages["total"],
                    "sfm_cpu_s": {"map_s": stages["map_first"]},
                    "registered_pct": 100.0,
                    "centre_rmse_pct_path": 0.03,
                    "keyframes": {"count": 51, "stride": n // 50},
                }
            )
    lines = tables(rows, 100, 400)
    assert sum(line.startswith("| incremental |") for line in lines) == 5  # 4 runs + the exponent row
    assert "| incremental | 400 | 51 (every 8) |" in "\n".join(lines)
    exp = {line.split("|")[1].strip(): line for line in lines[-2:]}
    assert "**1.50**" in exp["incremental"] and "**1.10**" in exp["global"]
