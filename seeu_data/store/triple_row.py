"""One stored triple (a row of `schemas/triples.v1.json`) as Python values: `TripleRow`.

The one row type of the triples format, on both sides: `TripleRow.to_pydict` gives a row as the
schema's columns (for `pa.Table.from_pylist` with `schema.arrow_schema("seeu.triples")`), and the
readers give rows back as `TripleRow`s (`triples.TripleShards.iter_rows` over whole shards, the
loader's `ShardReader.sample` one row at a time, its images zero-copy views into the shard).
`seeu build` writes the same columns straight from its sample plan (`triples.build_shard_table`).

L = V + T views per row, the V = `num_context` context views first, then the T targets.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# The columns holding one value per view (L per row, list columns of equal lengths); frame_index first.
PER_VIEW_COLUMNS = (
    "frame_index",
    "source_frame",
    "image",
    "width",
    "height",
    "intrinsics_norm",
    "cam_to_world",
    "near",
    "far",
)


@dataclass
class TripleRow:
    """One context-target example; images stay encoded.

    sample_id: '{scene_id}/{mode}/{k}'; mode: 'interp' | 'extrap' | 'eval'; num_context: V;
    frame_index, source_frame: (L,) int64 (the view's frame in the scene, and in its source video);
    images: L encoded JPEG/PNG images, bytes-like (`bytes(im)`, `np.frombuffer(im, np.uint8)`);
    image_format: 'jpeg' | 'png'; width, height: (L,) int32 pixels; intrinsics_norm: (L, 4) float64
    (fx/W, fy/H, cx/W, cy/H); cam_to_world: (L, 4, 4) float64 (OpenCV axes); near, far: (L,)
    float32; gap: max minus min context frame_index; target_offset: (T,) int64 frames outside the
    context range (0 inside, negative before, positive after); masks: None (no view has a mask) or L
    entries, each a view's mask as PNG bytes-like (nonzero = excluded pixel; `seeu_data.masks`) or None.
    """

    sample_id: str
    scene_id: str
    mode: str
    num_context: int
    frame_index: np.ndarray
    source_frame: np.ndarray
    images: list[memoryview]
    image_format: str
    width: np.ndarray
    height: np.ndarray
    intrinsics_norm: np.ndarray
    cam_to_world: np.ndarray
    near: np.ndarray
    far: np.ndarray
    gap: int
    target_offset: np.ndarray
    masks: list[memoryview | None] | None = None

    @property
    def context(self) -> list[int]:
        """The V context frame indices."""
        return self.frame_index[: self.num_context].tolist()

    @property
    def target(self) -> list[int]:
        """The T target frame indices."""
        return self.frame_index[self.num_context :].tolist()

    @classmethod
    def from_pydict(cls, d: dict) -> TripleRow:
        """A row as `pa.Table.to_pylist` gives it (column names of the schema)."""
        return cls(
            sample_id=d["sample_id"],
            scene_id=d["scene_id"],
            mode=d["mode"],
            num_context=int(d["num_context"]),
            frame_index=np.asarray(d["frame_index"], np.int64),
            source_frame=np.asarray(d["source_frame"], np.int64),
            images=[memoryview(b) for b in d["image"]],
            image_format=d["image_format"],
            width=np.asarray(d["width"], np.int32),
            height=np.asarray(d["height"], np.int32),
            intrinsics_norm=np.asarray(d["intrinsics_norm"], np.float64).reshape(-1, 4),
            cam_to_world=np.asarray(d["cam_to_world"], np.float64).reshape(-1, 4, 4),
            near=np.asarray(d["near"], np.float32),
            far=np.asarray(d["far"], np.float32),
            gap=int(d["gap"]),
            target_offset=np.asarray(d["target_offset"], np.int64),
            masks=[None if m is None else memoryview(m) for m in d["mask"]] if any(d.get("mask") or []) else None,
        )

    def to_pydict(self) -> dict:
        """The row as the schema's columns (plain Python values), for `pa.Table.from_pylist`."""
        return {
            "sample_id": self.sample_id,
            "scene_id": self.scene_id,
            "mode": self.mode,
            "num_context": int(self.num_context),
            "frame_index": np.asarray(self.frame_index).tolist(),
            "source_frame": np.asarray(self.source_frame).tolist(),
            "image": [bytes(im) for im in self.images],
            "image_format": self.image_format,
            "width": np.asarray(self.width).tolist(),
            "height": np.asarray(self.height).tolist(),
            "intrinsics_norm": np.asarray(self.intrinsics_norm, np.float64).reshape(-1, 4).tolist(),
            "cam_to_world": np.asarray(self.cam_to_world, np.float64).reshape(-1, 16).tolist(),
            "near": np.asarray(self.near).tolist(),
            "far": np.asarray(self.far).tolist(),
            "gap": int(self.gap),
            "target_offset": np.asarray(self.target_offset).tolist(),
            "mask": [None if m is None else bytes(m) for m in self.masks or [None] * len(self.images)],
        }
