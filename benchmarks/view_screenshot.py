"""`seeu view --screenshot`, run after run: does every screenshot show the scene drawn?

Writes a posed-frames dataset whose images are all plain magenta (FRAMES frames on the synthetic
corridor's camera path; nothing else on viser's page is magenta), then runs the real command,
`seeu view PATH --screenshot shot_K.png`, `--runs` times in a row (a fresh process, server and
chromium each time). A screenshot is complete when its thumbnails are drawn (magenta pixels, the
images' own colour) and the control panel is filled (dark text pixels under its title: the scene and
frame pickers, the frame's caption), and it is pixel-identical to the first one (software WebGL
draws the same page the same way: a screenshot taken half-way differs). Prints one line per run and
the count of complete ones; `--write` puts the table in RESULTS.md.

Example:
  .venv/bin/python benchmarks/view_screenshot.py --runs 20 --write
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.results_md import write_section  # noqa: E402

FRAMES, HEIGHT, WIDTH = 30, 180, 320
MAGENTA = (255, 0, 255)  # RGB of every image
PANEL_BOX = (slice(60, 160), slice(665, 985))  # rows, columns of viser's control panel under its title (1000x700 page)


def magenta_posed(out: Path, frames: int = FRAMES, hw: tuple[int, int] = (HEIGHT, WIDTH)) -> Path:
    """A posed-frames dataset at `out` (one scene, 'magenta'): the synthetic corridor's cameras, every
    image plain magenta (PNG, so the colour is exact)."""
    import cv2

    from seeu_data.store.manifest import provenance
    from seeu_data.store.posed import PosedDatasetWriter
    from seeu_data.synthetic import synthetic_posed_scene

    scene = synthetic_posed_scene(frames, hw[0], hw[1], scene_id="magenta")
    png = cv2.imencode(".png", np.full((*hw, 3), MAGENTA[::-1], np.uint8))[1].tobytes()
    with PosedDatasetWriter(out, {"magenta": True}, provenance("benchmarks/view_screenshot.py")) as writer:
        writer.add(replace(scene, images=[png] * frames, image_format="png"))
    return out


@dataclass(frozen=True)
class Drawn:
    """What one screenshot shows: thumbnail pixels (magenta) and panel text pixels (dark)."""

    thumbnails: int
    panel: int

    @classmethod
    def of(cls, png: Path) -> Drawn:
        import cv2

        bgr = cv2.imread(str(png))
        if bgr is None:
            return cls(0, 0)
        rgb = bgr[:, :, ::-1].astype(np.int16)
        magenta = (rgb[..., 0] > 200) & (rgb[..., 1] < 80) & (rgb[..., 2] > 200)
        return cls(int(magenta.sum()), int((rgb[PANEL_BOX].max(-1) < 120).sum()))

    def complete(self) -> bool:
        """Thumbnails and a filled panel (a blank panel has 0 text pixels there, a filled one ~600)."""
        return self.thumbnails > 1000 and self.panel > 200


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=20, help="screenshots in a row (default 20)")
    ap.add_argument("--out", type=Path, default=Path("out/bench_view_screenshot"))
    ap.add_argument("--write", action="store_true", help="write the view_screenshot section of RESULTS.md")
    args = ap.parse_args(argv)

    shutil.rmtree(args.out, ignore_errors=True)
    posed = magenta_posed(args.out / "posed")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    rows, first = [], None
    for k in range(args.runs):
        png = args.out / f"shot_{k:02d}.png"
        t0 = time.perf_counter()
        done = subprocess.run(
            [sys.executable, "-m", "pipelines.cli", "view", str(posed), "--screenshot", str(png)],
            env=env,
            capture_output=True,
            text=True,
        )
        seconds = time.perf_counter() - t0
        drawn = Drawn.of(png)
        pixels = png.read_bytes() if png.is_file() else b""
        first = pixels if first is None else first
        same = bool(pixels) and pixels == first
        ok = done.returncode == 0 and drawn.complete() and same
        rows.append((k, seconds, drawn, same, ok))
        note = "" if done.returncode == 0 else f"  exit {done.returncode}: {done.stdout.strip()[-200:]}"
        print(
            f"run {k:2d}: {seconds:5.1f} s, thumbnails {drawn.thumbnails} px, panel {drawn.panel} px, "
            f"same as run 0: {same}, complete: {ok}{note}",
            flush=True,
        )
    complete = sum(r[-1] for r in rows)
    secs = sorted(r[1] for r in rows)
    text = "\n".join(
        [
            f"## `seeu view --screenshot`, run after run (`benchmarks/view_screenshot.py --runs {args.runs}`)",
            "",
            f"Measured {time.strftime('%Y-%m-%d')} on {os.cpu_count()} cores, load average "
            f"{os.getloadavg()[0]:.1f} at the end. {FRAMES} posed frames {WIDTH}x{HEIGHT}, every image plain magenta;",
            "each run is the whole command (a fresh process, server and headless chromium). Complete: the",
            "thumbnails drawn (magenta pixels), the control panel filled, the PNG identical to the first run's.",
            "",
            "| runs | complete | seconds per run (median, max) |",
            "|---|---|---|",
            f"| {args.runs} | {complete} | {secs[len(secs) // 2]:.1f}, {secs[-1]:.1f} |",
        ]
    )
    print(text)
    if args.write:
        write_section("view_screenshot", text)
    return 0 if complete == args.runs else 1


if __name__ == "__main__":
    raise SystemExit(main())
