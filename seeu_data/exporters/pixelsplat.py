"""Posed frames -> pixelSplat / MVSplat chunks (`OUT/STAGE/000000.torch ...` + `index.json`).

Each chunk is `torch.save(list_of_examples)` with exactly the peer's keys and dtypes: `url` (str),
`timestamps` (int64 (N,)), `cameras` (float32 (N, 18): fx, fy, cx, cy normalised, 0, 0, then the
3x4 world-to-camera row-major), `images` (N uint8 1-D tensors of the encoded bytes, unchanged),
`key` (str). Chunks are filled to about `chunk_bytes` of image data (the peers use 100 MB).

The peers' RE10K loaders (pixelSplat, MVSplat: `src/dataset/dataset_re10k.py`) skip an example
whose frames are not 360x640 (H x W) or whose field of view exceeds `max_fov` = 100 degrees on either
axis (the angle between the rays through the middles of opposite frame edges). `peer_skip_reason`
applies that rule. `resize` (H, W), by default the peers' `PEER_HW`, resizes every frame to cover H x W
and crops the centre, as the peers' own crop shim does (`seeu_data.resize.resize_scene`: intrinsics
updated, JPEG re-encoded at `jpeg_quality`), so posed data of any size is loader-ready; a scene whose
frames are already H x W is kept as stored (bytes unchanged); None keeps every frame as stored. `size_check`
"warn" (default: count the scenes the loaders would skip, the CLI prints one line) or "refuse"
(raise SeeUError at the first such scene, before index.json is written).

What the format cannot hold (near/far, source frame numbers and names, scene meta) goes into a
sidecar `seeu_posed.json` beside index.json, which `seeu import pixelsplat` reads back and the peer
loaders ignore (they only list `*.torch` and read `index.json`). Files are written atomically;
index.json and the sidecar last, so a stage directory without index.json is an unfinished export.
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seeu_data.cameras import world_to_cam_from_cam_to_world
from seeu_data.errors import SeeUError
from seeu_data.limits import MAX_CHUNK_BYTES, MAX_IMAGE_SIDE, check_range
from seeu_data.resize import resize_scene
from seeu_data.settings import parse_dims_or_none, parse_megabytes, parse_scene_ids, setting
from seeu_data.store.arrow_io import atomic_path, atomic_write_text
from seeu_data.store.out_lock import locks_output
from seeu_data.store.posed import PosedDataset, PosedScene
from seeu_data.store.resume import sweep

SIDECAR_NAME = "seeu_posed.json"
CHUNK_FILES = "[0-9]" * 6 + ".torch"  # glob of the chunk files (000000.torch, ...)


PEER_HW = (360, 640)
PEER_MAX_FOV_DEG = 100.0
SIZE_CHECKS = ("warn", "refuse")


@dataclass
class PixelSplatExportConfig:
    """`out`: dataset root (chunks go to `out/stage/`); `scenes`: ids to export (None = all);
    `resize`: (H, W) to resize + centre-crop every frame to (default the peers' 360x640; None = as
    stored; frames already that size are kept as stored); `size_check`: what to
    do with a scene the peers' loaders would skip ("warn" | "refuse")."""

    out: Path
    stage: str = setting("test", "the split written (OUT/STAGE/)", choices=("train", "test"))
    chunk_bytes: int = setting(
        100_000_000,
        f"image megabytes per chunk (default: 100, the peers'; at most {MAX_CHUNK_BYTES / 1e6:g})",
        flag="--chunk-mb",
        parse=parse_megabytes,
        metavar="CHUNK_MB",
    )
    scenes: list[str] | None = setting(
        None, "export only these scene ids: a,b,c or @file.txt", parse=parse_scene_ids, metavar="SCENES"
    )
    resize: tuple[int, int] | None = setting(
        PEER_HW,
        "resize every frame to cover HxW and crop the centre (the peers' crop, intrinsics updated, JPEG re-encoded; "
        "frames already HxW kept as stored); 'none' keeps every frame as stored",
        parse=parse_dims_or_none,
        metavar="HxW|none",
    )
    size_check: str = setting(
        "warn",
        "scenes the peers' RE10K loaders would skip (frames not 360x640, field of view > 100 deg): "
        "warn in one line or refuse the export (exit 2)",
        choices=SIZE_CHECKS,
    )
    jpeg_quality: int = 95

    def check(self) -> None:
        if self.size_check not in SIZE_CHECKS:
            raise SeeUError(f"--size-check must be one of {', '.join(SIZE_CHECKS)}, got {self.size_check!r}")
        for side in self.resize or ():
            check_range(side, "--resize", 1, MAX_IMAGE_SIDE)
        check_range(self.chunk_bytes, "--chunk-mb in bytes", 1, MAX_CHUNK_BYTES)
        check_range(self.jpeg_quality, "JPEG quality", 1, 100)


def peer_fov_deg(intrinsics_norm: np.ndarray) -> np.ndarray:
    """(N, 4) normalised fx, fy, cx, cy -> (N, 2) horizontal and vertical field of view in degrees, as
    the peers measure it: the angle between the rays through the normalised points (0, 0.5) and
    (1, 0.5), and through (0.5, 0) and (0.5, 1)."""
    k = np.asarray(intrinsics_norm, np.float64).reshape(-1, 4)
    fx, fy, cx, cy = k.T

    def ray(x, y):
        r = np.stack([(x - cx) / fx, (y - cy) / fy, np.ones_like(fx)], -1)
        return r / np.linalg.norm(r, axis=-1, keepdims=True)

    def angle(a, b):
        return np.degrees(np.arccos(np.clip((a * b).sum(-1), -1.0, 1.0)))

    zero, half, one = np.zeros_like(fx), np.full_like(fx, 0.5), np.ones_like(fx)
    return np.stack([angle(ray(zero, half), ray(one, half)), angle(ray(half, zero), ray(half, one))], -1)


def peer_skip_reason(width: np.ndarray, height: np.ndarray, intrinsics_norm: np.ndarray) -> str | None:
    """Why the peers' RE10K loaders would skip a scene with these (N,) frame sizes and (N, 4)
    intrinsics, or None when they accept it."""
    w, h = np.asarray(width), np.asarray(height)
    if not ((h == PEER_HW[0]).all() and (w == PEER_HW[1]).all()):
        bad = int(np.nonzero((h != PEER_HW[0]) | (w != PEER_HW[1]))[0][0])
        return (
            f"frames are {int(w[bad])}x{int(h[bad])}, the RE10K loaders need 640x360 "
            "(seeu export pixelsplat resizes to it unless given --resize none)"
        )
    fov = peer_fov_deg(intrinsics_norm)
    if (fov > PEER_MAX_FOV_DEG).any():
        return f"field of view {fov.max():.1f} deg > {PEER_MAX_FOV_DEG:.0f} deg, which the RE10K loaders skip"
    return None


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


@locks_output(lambda dataset, cfg, *_, **__: cfg.out)
def export_pixelsplat(dataset: PosedDataset, cfg: PixelSplatExportConfig, progress: bool = False) -> dict:
    """Write the chunks, then index.json and the sidecar. Returns a summary dict."""
    from tqdm import tqdm

    cfg.check()
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
    skipped_by_peers: list[str] = []

    def flush() -> None:
        nonlocal chunk, size
        name = f"{len(written):06d}.torch"
        _save_chunk(chunk, directory / name)
        for ex in chunk:
            index[ex["key"]] = name
        written.append(name)
        chunk, size = [], 0

    for scene in tqdm(
        dataset.iter_scenes(scene_ids),
        total=len(scene_ids),
        unit="scene",
        desc="export pixelsplat",
        file=sys.stderr,
        disable=not progress,
    ):
        if cfg.resize is not None and not (
            (np.asarray(scene.height) == cfg.resize[0]).all() and (np.asarray(scene.width) == cfg.resize[1]).all()
        ):
            scene = resize_scene(scene, cfg.resize, cfg.jpeg_quality)
        reason = peer_skip_reason(scene.width, scene.height, scene.intrinsics_norm)
        if reason is not None:
            if cfg.size_check == "refuse":
                raise SeeUError(
                    f"scene {scene.scene_id!r}: {reason}; nothing exported (index.json not written)", dataset.root
                )
            skipped_by_peers.append(f"{scene.scene_id}: {reason}")
        chunk.append(example_from_scene(scene))
        size += sum(len(b) for b in scene.images)
        sidecar[scene.scene_id] = {
            "near": scene.near,
            "far": scene.far,
            "source_frame": np.asarray(scene.source_frame).tolist(),
            "source_name": list(scene.source_name),
            "meta": scene.meta,
        }
        if size >= cfg.chunk_bytes:
            flush()
    if chunk:
        flush()
    sweep(directory, CHUNK_FILES, keep=written)  # chunks of an earlier, larger export into the same place
    atomic_write_text(directory / SIDECAR_NAME, json.dumps(sidecar))
    atomic_write_text(directory / "index.json", json.dumps(index))
    return {
        "directory": str(directory),
        "chunks": len(written),
        "scenes": len(index),
        "scenes_peers_skip": len(skipped_by_peers),
        "peers_skip": skipped_by_peers,
    }
