"""Every figure the README states comes from a command whose output it is compared with here:

- the demo's held-out PSNR: the README paragraph between `<!-- demo:begin -->` and `<!-- demo:end -->`
  is what `benchmarks/demo.py --write` renders from the record it keeps in RESULTS.md's `demo` section
  (the figures of one real `seeu demo` run, read from its metrics.json and stage journal), or, with no
  record, the sentence saying none is recorded;
- `seeu model-info`'s parameter counts (paper config, MVSplat's total);
- the demo's training steps and image size (configs/demo.json, DemoConfig), the pixelSplat export's
  default size (the exporter's), the count of bad inputs tests/test_bad_inputs.py throws.

The README screenshot is made by the command printed under it (tests/test_view.py runs that command
path; docs/view.md gives the whole recipe)."""

from __future__ import annotations

import json
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()


def section(text: str, name: str) -> str:
    begin, end = f"<!-- {name}:begin -->\n", f"\n<!-- {name}:end -->"
    assert begin in text and end in text, name
    return text[text.index(begin) + len(begin) : text.index(end)]


def test_demo_figures_are_the_recorded_run():
    from benchmarks.demo import readme_text, recorded, results_text
    from benchmarks.results_md import RESULTS

    results = RESULTS.read_text()
    record = recorded(results)  # None: not measured for this version yet, and both pages say so
    assert section(README, "demo") == readme_text(record)
    assert section(results, "demo") == results_text(record)
    assert record is None or record["trained_psnr"] > record["init_psnr"]


def test_demo_settings_in_the_readme():
    from pipelines.demo import DemoConfig
    from seeu_data.exporters.pixelsplat import PEER_HW

    steps = json.loads((ROOT / "configs" / "demo.json").read_text())["optim"]["max_steps"]
    h, w = DemoConfig().image_size
    assert f"at {h}×{w}, trains the small SeeU of `configs/demo.json` for {steps} steps" in " ".join(README.split())
    assert f"Posed frames → pixelSplat chunks ({PEER_HW[0]}×{PEER_HW[1]} by default" in README


def test_model_info_figures():
    from pipelines.model_info import ModelInfoConfig, model_info

    info = model_info(ModelInfoConfig(preset="paper"))
    trainable, frozen = info["total_trainable"] / 1e6, info["total_frozen"] / 1e6
    figures = f"(paper config: {trainable:.1f} M + {frozen:.1f} M frozen; MVSplat {info['mvsplat_total'] / 1e6:.1f} M)"
    assert figures in README


def test_bad_input_count():
    from tests.test_bad_inputs import CASES

    (claimed,) = re.findall(r"throws over (\d+) bad inputs", README)
    assert len(CASES) > int(claimed)


def test_a_record_round_trips():
    """What `benchmarks/demo.py --write` writes into RESULTS.md reads back as the same record."""
    from benchmarks.demo import recorded, results_text

    record = {
        "cores": 2,
        "date": "2026-01-01",
        "init_psnr": 20.15,
        "load": 0.3,
        "stages": {"synth": 9.5},
        "trained_psnr": 24.72,
    }
    assert recorded(results_text(record)) == record
    assert recorded(results_text(None)) is None
