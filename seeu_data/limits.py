"""Upper bounds on the sizes and counts a user gives, and the one check that applies them.

Every size or count taken from a flag or a config file is checked with `check_range` where it is
parsed (the flag parsers in pipelines/cli/options.py, the stage configs' `check()`, the training
config's `validate`), so a value that would allocate without end or run forever is one line
(`data.batch_size 100000000 is over the limit 1024`), not a MemoryError or a run that never ends.
Each limit is declared once, here; docs/limits.md lists them.

Example:
    from seeu_data.limits import MAX_WORKERS, check_range
    check_range(cfg.workers, "--workers", 1, MAX_WORKERS)
"""

from __future__ import annotations

import numbers
from pathlib import Path
from typing import Any

from seeu_data.errors import SeeUError

MAX_PIXELS = 64_000_000  # pixels (width x height) of an image any stage reads; --max-pixels raises it
MAX_PIXELS_CEILING = (
    1 << 30
)  # the most --max-pixels / data.max_pixels may raise it to (OpenCV decodes no more: CV_IO_MAX_IMAGE_PIXELS)
MAX_IMAGE_SIDE = 8192  # px: image sides of training, evaluation, render, ingest --size/--max-size, --resize
MAX_VIDEO_SIDE = 4096  # px: the frame sides of a synthetic video (seeu synth / demo --size)
MAX_VIDEO_FRAMES = 100_000  # frames of a synthetic video (seeu synth / demo --frames)
MAX_RENDER_FRAMES = 10_000  # frames per rendered camera path (render --frames, demo --render-frames)
MAX_BATCH_SIZE = 1024  # examples per batch (data.batch_size, data.val_batch_size, eval --batch-size)
MAX_CONTEXT_VIEWS = 16  # context views per example (build --num-context)
MAX_TARGET_VIEWS = 64  # target views per example (build --num-target)
MAX_SAMPLES = 10_000_000  # examples drawn or evaluated (--samples-per-scene, --max-samples, demo samples, ...)
MAX_FRAMES = 10_000_000  # frame counts and frame distances (--stride, --target-frames, --gap-max, --overlap, ...)
MAX_WORKERS = 256  # worker processes and threads (--workers, --threads, --map-threads, data.num_workers)
MAX_STEPS = 10**9  # training steps and step intervals (optim.max_steps, checkpoint.every, demo --steps, ...)
MAX_FEATURES = 1_000_000  # SIFT features per frame (ingest --max-features)
MAX_CHUNK_BYTES = 1 << 30  # bytes of one exported pixelSplat chunk, held in memory (export --chunk-mb)
MAX_ROWS_PER_BATCH = 65_536  # rows per Arrow record batch (build --rows-per-batch)
MAX_ATTEMPTS = 100  # repeated mapping runs (ingest --sfm-attempts)
MAX_LEARNING_RATE = 1e10  # optim.lr: far above any useful rate; a diverging run then reaches the non-finite guard (AdamW itself overflows from ~3e37)
MAX_SEED = 2**63 - 1  # random seeds (--seed, data.seed, seed)

# (what, limit) for docs/limits.md; tests/test_limits.py checks the page lists them.
LIMITS = {
    "pixels per image read (default of --max-pixels)": MAX_PIXELS,
    "--max-pixels, data.max_pixels": MAX_PIXELS_CEILING,
    "image side (px)": MAX_IMAGE_SIDE,
    "synthetic video side (px)": MAX_VIDEO_SIDE,
    "synthetic video frames": MAX_VIDEO_FRAMES,
    "rendered frames per path": MAX_RENDER_FRAMES,
    "batch size": MAX_BATCH_SIZE,
    "context views": MAX_CONTEXT_VIEWS,
    "target views": MAX_TARGET_VIEWS,
    "samples": MAX_SAMPLES,
    "frame counts and distances": MAX_FRAMES,
    "workers and threads": MAX_WORKERS,
    "training steps": MAX_STEPS,
    "features per frame": MAX_FEATURES,
    "rows per record batch": MAX_ROWS_PER_BATCH,
    "pixelSplat chunk bytes": MAX_CHUNK_BYTES,
    "SfM attempts": MAX_ATTEMPTS,
    "random seeds": MAX_SEED,
    "learning rate": MAX_LEARNING_RATE,
}


def check_range(value: Any, name: str, lo: int, hi: int, path: str | Path | None = None) -> int:
    """`value` as an int in lo..hi, else SeeUError naming `name` (a flag or a config key), the bound and
    the file `path` the value came from, when given.

    Wrong type: `NAME: expected an integer, got 'x'`; too small: `NAME must be >= LO, got V`; too
    large: `NAME V is over the limit HI`.
    """
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise SeeUError(f"{name}: expected an integer, got {value!r}", path)
    value = int(value)
    if value < lo:
        raise SeeUError(f"{name} must be >= {lo}, got {value}", path)
    if value > hi:
        raise SeeUError(f"{name} {value} is over the limit {hi}", path)
    return value
