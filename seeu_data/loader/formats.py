"""Batch layouts the loader can hand out (`LoaderConfig.batch_format`).

* `"seeu"` (default): `types.Batch` (docs/ARCHITECTURE.md "Loader batch").
* `"pixelsplat"`: the layout pixelSplat's and MVSplat's RE10K loaders give their models (their
  `DatasetRE10k` examples through the DataLoader's default collate), so their model code can take our
  batches unchanged. B samples, V context / T target views, H x W the loader's output size:

  ```
  {"context": {"extrinsics": (B, V, 4, 4) float32   OpenCV camera-to-world
               "intrinsics": (B, V, 3, 3) float32   normalised (row 0 / W, row 1 / H)
               "image":      (B, V, 3, H, W) float32 in [0, 1]
               "near", "far": (B, V) float32
               "index":      (B, V) int64           the frames' indices in their scene,
               "mask":       (B, V, H, W) bool      True = excluded pixel; an extra key, only in
                                                    batches where a view has a mask},
   "target":  {... the same with T},
   "scene":   [B scene ids],
   "is_padding": (B,) bool}
  ```

  `is_padding` is the one key the peers' batches lack (their models ignore it): filler samples at the
  end of an epoch (`remainder="pad"`); use `remainder="drop"` to get none. Equal to MVSplat's own
  batch for the same example (tests/fixtures/pixelsplat_batch). Two things the peers' loader does
  differently when it resizes (ours: `transforms.py`): their cx, cy stay as they were after the centre
  crop (ours move by the half pixel an odd crop margin shifts them), and their filter is PIL's Lanczos.
"""

from __future__ import annotations

from typing import Any

from seeu_data.loader.collate import image_to_float
from seeu_data.loader.types import Batch, Views

BATCH_FORMATS = ("seeu", "pixelsplat")


def pixelsplat_views(views: Views) -> dict[str, Any]:
    """One side (context or target) of a loader batch in the peers' keys and order; images float32 in [0, 1]."""
    out = {
        "extrinsics": views["cam_to_world"],
        "intrinsics": views["intrinsics"],
        "image": image_to_float(views["image"]),
        "near": views["near"],
        "far": views["far"],
        "index": views["frame_index"],
    }
    if "mask" in views:
        out["mask"] = views["mask"]
    return out


def to_pixelsplat(batch: Batch) -> dict[str, Any]:
    """A `types.Batch` in the pixelSplat / MVSplat layout (module docstring); tensors are shared, not copied
    (uint8 images are converted)."""
    return {
        "context": pixelsplat_views(batch["context"]),
        "target": pixelsplat_views(batch["target"]),
        "scene": list(batch["scene_id"]),
        "is_padding": batch["is_padding"],
    }
