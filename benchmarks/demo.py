"""`seeu demo` with its default settings: the figures the README quotes, from the demo's own outputs.

Runs the demo from scratch into `--out` (or reads a finished demo output with `--from`, e.g. the
`out/demo` of your `make demo`), then takes its figures from what the demo wrote: the held-out PSNR
at initialisation and trained (OUT/metrics.json, mean over the held-out sets) and each stage's seconds
(the stage journal, OUT/.stages/stages.jsonl). Prints them next to the README's; `--write` renders
the README's demo paragraph and the `demo` section of RESULTS.md from them (the section keeps the
figures as a JSON record, from which tests/test_readme_figures.py re-renders both and compares).

Example:
  .venv/bin/python benchmarks/demo.py --write              # a fresh run on this machine
  .venv/bin/python benchmarks/demo.py --from out/demo      # your own `make demo` against the README
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.results_md import RESULTS, write_section  # noqa: E402

README = ROOT / "README.md"
RECORD = re.compile(r"<!-- demo record: (\{.*?\}) -->")


def figures_of(out: Path) -> dict:
    """The figures of a finished demo output: {"init_psnr", "trained_psnr" (dB), "stages": {name:
    seconds when it ran}}."""
    from pipelines.demo import STAGES
    from seeu_data.store.resume import STAGES_JOURNAL, Journal

    mean = json.loads((out / "metrics.json").read_text())["mean"]
    seconds = {rec["unit"]: rec["seconds"] for rec in Journal(out / ".stages" / STAGES_JOURNAL).read()}
    return {
        "init_psnr": round(mean["init_psnr"], 2),
        "trained_psnr": round(mean["trained_psnr"], 2),
        "stages": {name: round(seconds[name], 1) for name in STAGES if name in seconds},
    }


def readme_text(record: dict | None) -> str:
    """The README's sentence of demo figures (None: no run recorded since the figures last changed)."""
    if record is None:
        return (
            "The held-out PSNR of a reference run is not recorded for this version yet: "
            "`benchmarks/demo.py --write` measures it (the metrics table of your own report has yours)."
        )
    return (
        f"On the held-out scene the trained model's PSNR rises from {record['init_psnr']:.2f} dB at "
        f"initialisation to {record['trained_psnr']:.2f} dB (`benchmarks/demo.py`; identical run after run "
        "on one machine, other CPUs round differently)."
    )


def results_text(record: dict | None) -> str:
    """RESULTS.md's `demo` section: the figures, the stage times and the record they come from."""
    title = "## `seeu demo` (`benchmarks/demo.py`): default settings"
    if record is None:
        return f"{title}\n\nNot measured for this version yet: `benchmarks/demo.py --write` on an idle 2-core machine."
    rows = [f"| {name} | {s:.1f} |" for name, s in record["stages"].items()]
    total = sum(record["stages"].values())
    return "\n".join(
        [
            title,
            "",
            f"Measured {record['date']} on {record['cores']} cores, load average {record['load']:.1f} at the end."
            f" Held-out PSNR {record['init_psnr']:.2f} dB at initialisation → {record['trained_psnr']:.2f} dB trained"
            f" ({record['trained_psnr'] - record['init_psnr']:+.2f} dB); {total:.0f} s over the stages.",
            "",
            "| stage | seconds |",
            "|---|---|",
            *rows,
            "",
            f"<!-- demo record: {json.dumps(record, sort_keys=True)} -->",
        ]
    )


def recorded(results: str = "") -> dict | None:
    """The record in RESULTS.md's `demo` section (None when there is none)."""
    found = RECORD.search(results or (RESULTS.read_text() if RESULTS.exists() else ""))
    return json.loads(found.group(1)) if found else None


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=Path("out/bench_demo"), help="where the fresh demo run writes")
    ap.add_argument("--from", dest="source", type=Path, help="read this finished demo output instead of running")
    ap.add_argument("--write", action="store_true", help="write the README's figures and RESULTS.md's demo section")
    args = ap.parse_args(argv)

    out = args.source
    if out is None:
        from pipelines.demo import DemoConfig, demo

        shutil.rmtree(args.out, ignore_errors=True)
        demo(DemoConfig(out=args.out))
        out = args.out
    record = {
        **figures_of(out),
        "date": time.strftime("%Y-%m-%d"),
        "cores": os.cpu_count(),
        "load": round(os.getloadavg()[0], 1),
    }
    old = recorded()
    print(f"this demo: {readme_text(record)}")
    print(f"README:    {readme_text(old)}")
    print(results_text(record))
    if args.write:
        write_section("demo", results_text(record))
        write_section("demo", readme_text(record), README)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
