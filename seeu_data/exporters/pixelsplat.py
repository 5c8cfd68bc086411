"""Posed frames -> pixelSplat / MVSplat chunks (`OUT/STAGE/000000.torch ...` + `index.json`).

Each chunk is `torch.save(list_of_examples)` with exactly the peer's keys and dtypes: `url` (str),
`timestamps` (int64 (N,)), `cameras` (float32 (N, 18): fx, fy, cx, cy normalised, 0, 0, then the
3x4 world-to-camera row-major), `images` (N uint8 1-D tensors of the encoded bytes, unchanged),
`key` (str). Chunks are filled to about `chunk_bytes` of image data (the peers use 100 MB).

The peers' loaders skip an example whose frames are not their one configured size or whose field of
view exceeds `max_fov` = 100 degrees on either axis (the angle between the rays through the middles of
opposite frame edges): the RE10K loaders (pixelSplat, MVSplat, DepthSplat: `src/dataset/dataset_re10k.py`)
need 360x640 (H x W); DepthSplat's DL3DV loader (`src/dataset/dataset_dl3dv.py`) needs its
`ori_image_shape`, 270x480 in its config (540x960 for its 960p runs). `PEERS` holds these per dataset;
a scene's `dataset` meta ("dl3dv" from `seeu import dl3dv`) picks its peer, any other scene is RE10K's
(`peer_of`). `peer_skip_reason` applies the rule. `resize` "auto" (the default) resizes every frame to
cover its peer's size and crops the centre, as the peers' own crop shim does (`seeu_data.resize.
resize_scene`: intrinsics updated, JPEG re-encoded at `jpeg_quality`); (H, W) does so to that size for
every scene; a scene whose frames are already the target size is kept as stored (bytes unchanged); None
keeps every frame as stored. `size_check` "warn" (default: count the scenes the loaders would skip, the
CLI prints one line) or "refuse" (raise SeeUError at the first such scene, before index.json is
written). One export directory is read by one loader with one size: export DL3DV and RE10K-style
scenes to separate `--out` roots.

Keys: an example's `key` is the scene id, except for a scene imported from DL3DV, whose key is its bare
scene hash (meta `dl3dv_hash`), as DepthSplat's converter writes it and its evaluation indices
(`assets/dl3dv_*.json`) name it (`export_key`).

What the format cannot hold (near/far, source frame numbers and names, scene meta) goes into a
sidecar `seeu_posed.json` beside index.json, which `seeu import pixelsplat` reads back and the peer
loaders ignore (they only list `*.torch` and read `index.json`). Files are written atomically;
index.json and the sidecar last, so a stage directory without index.json is an unfinished export.
The sidecar is keyed like index.json; an entry whose key is not the scene id holds `scene_id`.
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
from seeu_data.settings import parse_dims, parse_megabytes, parse_scene_ids, setting
from seeu_data.store.arrow_io import atomic_path, atomic_write_text
from seeu_data.store.out_lock import locks_output
from seeu_data.store.posed import PosedDataset, PosedScene
from seeu_data.store.resume import sweep

SIDECAR_NAME = "seeu_posed.json"
CHUNK_FILES = "[0-9]" * 6 + ".torch"  # glob of the chunk files (000000.torch, ...)


@dataclass(frozen=True)
class Peer:
    """A peer loader's frame rule: `sizes` (H, W) it accepts (the first is its default config's, the size
    `resize="auto"` makes); `loader` names it in messages, `verb` agrees with it ("need" | "needs")."""

    loader: str
    verb: str
    sizes: tuple[tuple[int, int], ...]

    @property
    def hw(self) -> tuple[int, int]:
        return self.sizes[0]


PEERS = {
    "re10k": Peer("the RE10K loaders", "need", ((360, 640),)),  # pixelSplat, MVSplat, DepthSplat
    "dl3dv": Peer("DepthSplat's DL3DV loader", "needs", ((270, 480), (540, 960))),  # its ori_image_shape
}
PEER_HW = PEERS["re10k"].hw
PEER_MAX_FOV_DEG = 100.0
SIZE_CHECKS = ("warn", "refuse")
RESIZE_AUTO = "auto"  # `resize`: each scene to its peer's size (`peer_of`)


def parse_resize(text: str, flag: str = "--resize") -> tuple[int, int] | str | None:
    """`--resize`: "none" -> None (frames as stored), "auto" -> RESIZE_AUTO, "HxW" -> (H, W)."""
    word = str(text).strip().lower()
    if word in ("none", RESIZE_AUTO):
        return None if word == "none" else RESIZE_AUTO
    return parse_dims(text, flag)


DL3DV_HASH_META = "dl3dv_hash"  # scene meta written by `seeu import dl3dv`: the example key


def peer_of(meta: dict) -> str:
    """The peer dataset ("re10k" | "dl3dv") a scene with this meta is exported for."""
    return "dl3dv" if meta.get("dataset") == "dl3dv" else "re10k"


def export_key(scene_id: str, meta: dict) -> str:
    """The example key: the bare DL3DV hash for a scene imported from DL3DV, else the scene id."""
    value = meta.get(DL3DV_HASH_META)
    return value if peer_of(meta) == "dl3dv" and isinstance(value, str) and value else scene_id


@dataclass
class PixelSplatExportConfig:
    """`out`: dataset root (chunks go to `out/stage/`); `scenes`: ids to export (None = all);
    `resize`: "auto" (each scene to its peer's size, `PEERS`), (H, W) to resize + centre-crop every
    frame to, or None (as stored); frames already the target size are kept as stored; `size_check`: what
    to do with a scene the peers' loaders would skip ("warn" | "refuse")."""

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
    resize: tuple[int, int] | str | None = setting(
        RESIZE_AUTO,
        "resize every frame to cover HxW and crop the centre (the peers' crop, intrinsics updated, JPEG re-encoded; "
        f"frames already that size kept as stored); {RESIZE_AUTO}: each scene to its peer's size, "
        f"{PEERS['dl3dv'].hw[0]}x{PEERS['dl3dv'].hw[1]} (DepthSplat) for scenes from seeu import dl3dv, else "
        f"{PEERS['re10k'].hw[0]}x{PEERS['re10k'].hw[1]} (the RE10K peers); 'none' keeps every frame as stored",
        parse=parse_resize,
        metavar="HxW|auto|none",
    )
    size_check: str = setting(
        "warn",
        "scenes the peers' loaders would skip (frames not their size, "
        + ", ".join(f"{p}: " + " or ".join(f"{h}x{w}" for h, w in r.sizes) for p, r in PEERS.items())
        + f"; field of view > {PEER_MAX_FOV_DEG:g} deg): warn in one line or refuse the export (exit 2)",
        choices=SIZE_CHECKS,
    )
    jpeg_quality: int = 95

    def check(self) -> None:
        if self.size_check not in SIZE_CHECKS:
            raise SeeUError(f"--size-check must be one of {', '.join(SIZE_CHECKS)}, got {self.size_check!r}")
        if isinstance(self.resize, str):
            if self.resize != RESIZE_AUTO:
                raise SeeUError(f"--resize must be HxW, {RESIZE_AUTO} or none, got {self.resize!r}")
        else:
            for side in self.resize or ():
                check_range(side, "--resize", 1, MAX_IMAGE_SIDE)
        check_range(self.chunk_bytes, "--chunk-mb in bytes", 1, MAX_CHUNK_BYTES)
        check_range(self.jpeg_quality, "JPEG quality", 1, 100)

    def target_hw(self, meta: dict) -> tuple[int, int] | None:
        """The (H, W) a scene with this meta is resized to (None: as stored)."""
        if isinstance(self.resize, str):
            return PEERS[peer_of(meta)].hw
        return self.resize


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


def peer_skip_reason(
    width: np.ndarray, height: np.ndarray, intrinsics_norm: np.ndarray, peer: str = "re10k"
) -> str | None:
    """Why the `peer` dataset's loader (`PEERS`) would skip a scene with these (N,) frame sizes and
    (N, 4) intrinsics, or None when it accepts it."""
    rule = PEERS[peer]
    w, h = np.asarray(width), np.asarray(height)
    for sh, sw in rule.sizes:
        if (h == sh).all() and (w == sw).all():
            break
    else:
        bad = int(np.nonzero((h != rule.hw[0]) | (w != rule.hw[1]))[0][0])
        sizes = " or ".join(f"{sw}x{sh}" for sh, sw in rule.sizes)
        return (
            f"frames are {int(w[bad])}x{int(h[bad])}, {rule.loader} {rule.verb} {sizes} "
            "(seeu export pixelsplat resizes to it unless given --resize none or another size)"
        )
    fov = peer_fov_deg(intrinsics_norm)
    if (fov > PEER_MAX_FOV_DEG).any():
        return f"field of view {fov.max():.1f} deg > {PEER_MAX_FOV_DEG:.0f} deg, which {rule.loader} {rule.verb.replace('need', 'skip')}"
    return None


def example_from_scene(scene: PosedScene, key: str | None = None) -> dict:
    """PosedScene -> one chunk example dict (the peer's keys and dtypes); `key` defaults to the scene id."""
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
        "key": scene.scene_id if key is None else key,
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
        hw = cfg.target_hw(scene.meta)
        if hw is not None and not (
            (np.asarray(scene.height) == hw[0]).all() and (np.asarray(scene.width) == hw[1]).all()
        ):
            scene = resize_scene(scene, hw, cfg.jpeg_quality)
        reason = peer_skip_reason(scene.width, scene.height, scene.intrinsics_norm, peer_of(scene.meta))
        if reason is not None:
            if cfg.size_check == "refuse":
                raise SeeUError(
                    f"scene {scene.scene_id!r}: {reason}; nothing exported (index.json not written)", dataset.root
                )
            skipped_by_peers.append(f"{scene.scene_id}: {reason}")
        key = export_key(scene.scene_id, scene.meta)
        if key in sidecar:
            other = sidecar[key].get("scene_id", key)
            raise SeeUError(f"scenes {other!r} and {scene.scene_id!r} both have the example key {key!r}", dataset.root)
        chunk.append(example_from_scene(scene, key))
        size += sum(len(b) for b in scene.images)
        sidecar[key] = {
            "near": scene.near,
            "far": scene.far,
            "source_frame": np.asarray(scene.source_frame).tolist(),
            "source_name": list(scene.source_name),
            "meta": scene.meta,
            **({"scene_id": scene.scene_id} if key != scene.scene_id else {}),
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
