"""Posed frames -> pixelSplat / MVSplat chunks (`OUT/STAGE/000000.torch ...` + `index.json`).

Each chunk is `torch.save(list_of_examples)` with exactly the peer's keys and dtypes: `url` (str),
`timestamps` (int64 (N,)), `cameras` (float32 (N, 18): fx, fy, cx, cy normalised, 0, 0, then the
3x4 world-to-camera row-major), `images` (N uint8 1-D tensors of the encoded bytes, unchanged),
`key` (str). Chunks are filled to about `chunk_bytes` of image data (the peers use 100 MB).

What the format cannot hold (near/far, source frame numbers and names, scene meta) goes into a
sidecar `seeu_posed.json` beside index.json, which `seeu import pixelsplat` reads back and the peer
loaders ignore (they only list `*.torch` and read `index.json`). Files are written atomically;
index.json and the sidecar last, so a stage directory without index.json is an unfinished export.
"""

from __future__ import annotations

import json
import re
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..arrow_io import atomic_path, atomic_write_text
from ..cameras import world_to_cam_from_cam_to_world
from ..errors import SeeUError
from ..posed import PosedDataset, PosedScene

SIDECAR_NAME = "seeu_posed.json"
_CHUNK_NAME = re.compile(r"^\d{6}\.torch$")


@dataclass
class PixelSplatExportConfig:
    """`out`: dataset root (chunks go to `out/stage/`); `scenes`: ids to export (None = all)."""

    out: Path
    stage: str = "test"
    chunk_bytes: int = 100_000_000
    scenes: list[str] | None = None


def example_from_scene(scene: PosedScene) -> dict:
    """PosedScene -> one chunk example dict (the peer's keys and dtypes)."""
    import torch

    n = len(scene)
    w2c = world_to_cam_from_cam_to_world(np.asarray(scene.cam_to_world, dtype=np.float64))
    cameras = np.zeros((n, 18), dtype=np.float64)
    cameras[:, :4] = scene.intrinsics_norm
    cameras[:, 6:] = w2c[:, :3, :].reshape(n, 12)
    return {
        "url": str(scene.meta.get("url", "")),
        "timestamps": torch.tensor(np.asarray(scene.timestamp_us, dtype=np.int64)),
        "cameras": torch.as_tensor(cameras.astype(np.float32)),
        "images": [torch.frombuffer(bytearray(b), dtype=torch.uint8) for b in scene.images],
        "key": scene.scene_id,
    }


def _save_chunk(examples: list[dict], path: Path) -> None:
    import torch

    with atomic_path(path) as tmp:
        torch.save(examples, tmp)


def export_pixelsplat(dataset: PosedDataset, cfg: PixelSplatExportConfig, progress: bool = False) -> dict:
    """Write the chunks, then index.json and the sidecar. Returns a summary dict."""
    from tqdm import tqdm

    scene_ids = cfg.scenes if cfg.scenes is not None else dataset.scene_ids
    unknown = [s for s in scene_ids if s not in set(dataset.scene_ids)]
    if unknown:
        raise SeeUError(f"no scene {unknown[0]!r} in this dataset", dataset.root)
    if not scene_ids:
        raise SeeUError("nothing to export: the dataset has no scenes", dataset.root)
    directory = Path(cfg.out) / cfg.stage
    directory.mkdir(parents=True, exist_ok=True)
    (directory / "index.json").unlink(missing_ok=True)  # being rewritten: not complete
    index: dict[str, str] = {}
    sidecar: dict[str, dict] = {}
    written: list[str] = []
    chunk: list[dict] = []
    size = 0
    not_peer_size = 0

    def flush() -> None:
        nonlocal chunk, size
        name = f"{len(written):06d}.torch"
        _save_chunk(chunk, directory / name)
        for ex in chunk:
            index[ex["key"]] = name
        written.append(name)
        chunk, size = [], 0

    for scene in tqdm(dataset.iter_scenes(scene_ids), total=len(scene_ids), unit="scene",
                      desc="export pixelsplat", file=sys.stderr, disable=not progress):
        chunk.append(example_from_scene(scene))
        size += sum(len(b) for b in scene.images)
        sidecar[scene.scene_id] = {"near": scene.near, "far": scene.far,
                                   "source_frame": np.asarray(scene.source_frame).tolist(),
                                   "source_name": list(scene.source_name), "meta": scene.meta}
        if not ((np.asarray(scene.width) == 640).all() and (np.asarray(scene.height) == 360).all()):
            not_peer_size += 1
        if size >= cfg.chunk_bytes:
            flush()
    if chunk:
        flush()
    for stale in directory.glob("*.torch"):  # chunks of an earlier, larger export into the same place
        if _CHUNK_NAME.match(stale.name) and stale.name not in written:
            stale.unlink()
    atomic_write_text(directory / SIDECAR_NAME, json.dumps(sidecar))
    atomic_write_text(directory / "index.json", json.dumps(index))
    return {"directory": str(directory), "chunks": len(written), "scenes": len(index),
            "scenes_not_360x640": not_peer_size}
