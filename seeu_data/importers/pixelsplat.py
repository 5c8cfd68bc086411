"""pixelSplat / MVSplat chunk datasets (RealEstate10K, ACID, DTU) -> posed scenes.

Layout: `ROOT/{train,test}/000000.torch ...` and `ROOT/{train,test}/index.json` (scene key -> chunk
file name). A chunk is `torch.save(list_of_examples)`; an example is a dict with `key` (str), `url`
(str), `timestamps` (int64 (N,), microseconds), `cameras` (float32 (N, 18): fx, fy, cx, cy
normalised, two zeros, then the 3x4 world-to-camera row-major) and `images` (N uint8 1-D tensors
holding the encoded JPEG, or PNG for DTU, bytes).

Conversion: intrinsics are kept (already normalised); world-to-camera -> OpenCV camera-to-world with
`cameras.cam_to_world_from_world_to_cam` (what the MVSplat loader's `w2c.inverse()` does); image
bytes are kept as they are; width/height come from the image headers. Scene id = key; the url,
dataset name, stage and chunk name go into the scene's meta. `source_frame` is the frame's position
in the example. Chunks are read one at a time, memory-mapped (`torch_chunk.load_plain`, a restricted
reader that is several times faster than `torch.load` and copies nothing; `torch.load(weights_only
=True)` is the fallback), and each scene's images are copied from the mapping into its record
batch when it is written, so the process holds one chunk in the page cache and one scene's images.

A `seeu_posed.json` next to `index.json` (written by `seeu export pixelsplat`) restores what the
chunk format cannot carry (near/far, source frame numbers and names, meta); peer loaders ignore it.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from seeu_data.cameras import cam_to_world_from_world_to_cam, homogeneous_from_3x4
from seeu_data.errors import SeeUError
from seeu_data.importers.common import ImportJob, ReadSettings, SkippedScene, probe_images, recorded_params
from seeu_data.settings import parse_scene_list, setting
from seeu_data.store.json_file import read_json
from seeu_data.store.paths import contained_path
from seeu_data.store.posed import PosedScene

SIDECAR_NAME = "seeu_posed.json"
# near/far per dataset as MVSplat configures them.
NEAR_FAR = {"re10k": (1.0, 100.0), "acid": (1.0, 100.0), "dtu": (2.125, 4.525)}
EXAMPLE_KEYS = ("url", "timestamps", "cameras", "images", "key")


@dataclass
class PixelSplatImportConfig(ReadSettings):
    """`root`: dataset dir holding `train/` and `test/` (or a stage dir itself); `scenes`: keys to keep
    (None = all); near/far default to the `dataset` preset."""

    root: Path = setting(help="dataset dir holding train/ and test/ (or a stage dir)", positional=True)
    stage: str = setting("train", "which stage's chunks to read", choices=("train", "test"))
    scenes: frozenset[str] | None = setting(
        None, "keep only these scene keys: a,b,c or @file.txt (default: all)", parse=parse_scene_list
    )
    dataset: str = setting(
        "re10k",
        "near/far preset (re10k/acid 1/100, dtu 2.125/4.525) and the name kept in the meta",
        choices=tuple(NEAR_FAR),
    )
    near: float | None = setting(None, "near plane (default: the --dataset preset)")
    far: float | None = setting(None, "far plane (default: the --dataset preset)")

    def near_far(self) -> tuple[float, float]:
        near, far = NEAR_FAR[self.dataset]
        return (near if self.near is None else self.near, far if self.far is None else self.far)

    def plan(self) -> ImportJob:
        found = find_chunks(self)
        near, far = self.near_far()
        params = recorded_params(self, "pixelsplat", near=near, far=far)
        return ImportJob(import_plan(self, found), params, found.total, [str(found.directory)])


def stage_dir(cfg: PixelSplatImportConfig) -> Path:
    """The directory holding the chunks: `root/stage`, or `root` itself when it holds chunks."""
    root = Path(cfg.root)
    if not root.is_dir():
        raise SeeUError("pixelSplat dataset directory not found", root)
    if (root / cfg.stage).is_dir():
        return root / cfg.stage
    if any(root.glob("*.torch")):
        return root
    raise SeeUError(f"no {cfg.stage}/ directory and no *.torch chunks here", root)


def read_index(directory: Path) -> dict[str, str] | None:
    """`index.json` (key -> chunk file name), or None when absent."""
    path = directory / "index.json"
    if not path.exists():
        return None
    index = read_json(path, "index.json")
    if not isinstance(index, dict) or not all(isinstance(k, str) and isinstance(v, str) for k, v in index.items()):
        raise SeeUError("index.json must map scene keys to chunk file names", path)
    return index


@dataclass(frozen=True)
class ChunkList:
    """What an import reads, from one pass over `index.json`: `chunks` in order; `keys` (None without
    an index.json): chunk file name -> the wanted scene keys index.json places in it; `missing`: scenes
    asked for that index.json lacks (or places in a chunk outside the stage directory); `total`: the
    scenes wanted (None: unknown)."""

    directory: Path
    chunks: list[Path]
    keys: dict[str, list[str]] | None
    missing: list[SkippedScene]
    total: int | None


def find_chunks(cfg: PixelSplatImportConfig) -> ChunkList:
    """Which chunks to read, with index.json grouped by chunk once (O(scenes), not scenes x chunks)."""
    directory = stage_dir(cfg)
    index = read_index(directory)
    missing: list[SkippedScene] = []
    if index is None:
        chunks = sorted(directory.glob("*.torch"))
        if not chunks:
            raise SeeUError("no *.torch chunks", directory)
        return ChunkList(directory, chunks, None, missing, len(cfg.scenes) if cfg.scenes else None)
    wanted = sorted(index) if cfg.scenes is None else sorted(cfg.scenes)
    keys: dict[str, list[str]] = {}
    outside: dict[str, str] = {}  # chunk name -> why it is never read
    for key in wanted:
        name = index.get(key)
        if name is None:
            missing.append(SkippedScene(key, "not in index.json"))
            continue
        if name not in keys and name not in outside:
            try:  # a chunk name leading out of the stage directory is never read
                contained_path(directory, name, "index.json entry", directory / "index.json")
                keys[name] = []
            except SeeUError as exc:
                outside[name] = str(exc)
        if name in outside:
            missing.append(SkippedScene(key, outside[name]))
        else:
            keys[name].append(key)
    return ChunkList(directory, [directory / n for n in sorted(keys)], keys, missing, len(wanted))


def load_chunk(path: Path) -> list:
    """Read a chunk: the fast restricted reader (`torch_chunk.load_plain`: numpy views into the
    memory-mapped file), else `torch.load(weights_only=True, mmap=True)`. Either way only plain
    data and tensors are accepted."""
    import pickle
    import zipfile

    from seeu_data.importers.torch_chunk import UnsupportedChunk, load_plain

    if not path.exists():
        raise SeeUError("chunk listed in index.json is missing", path)
    try:
        chunk = load_plain(path)
    except UnsupportedChunk:
        chunk = _torch_load(path)
    except (
        OSError,
        EOFError,
        ValueError,
        TypeError,
        AttributeError,
        IndexError,
        KeyError,
        RecursionError,
        zipfile.BadZipFile,
        pickle.UnpicklingError,
        struct.error,
    ) as exc:
        # TypeError & co.: a pickle calling an allowed global with arguments it does not take
        # (`torch.FloatStorage()`, `OrderedDict(5)`): never code, only an unusable chunk.
        raise SeeUError(
            f"not a readable pixelSplat chunk ({type(exc).__name__}: {str(exc).splitlines()[0][:120]})", path
        ) from None
    if not isinstance(chunk, list):
        raise SeeUError(f"a chunk must hold a list of examples, found {type(chunk).__name__}", path)
    return chunk


def _torch_load(path: Path):
    import zipfile

    import torch

    try:
        # mmap (zip format only): storages stay in the page cache instead of process memory.
        return torch.load(path, map_location="cpu", weights_only=True, mmap=zipfile.is_zipfile(path))
    except Exception as exc:  # corrupt zip, truncated file, pickle of other objects
        raise SeeUError(
            f"not a readable pixelSplat chunk ({type(exc).__name__}: {str(exc).splitlines()[0][:120]})", path
        ) from None


def scene_from_example(example: dict, cfg: PixelSplatImportConfig, chunk_name: str, sidecar: dict | None) -> PosedScene:
    """One chunk example -> PosedScene (SeeUError when the example is malformed).

    The scene's `images` are read-only numpy views into the memory-mapped chunk, not copies (the
    writer copies them into the scene's record batch).
    """
    key = example["key"]
    where = f"{chunk_name}:{key}"
    missing = [k for k in EXAMPLE_KEYS if k not in example]
    if missing:
        raise SeeUError(f"example lacks {', '.join(missing)}", where)
    try:
        cams = np.asarray(example["cameras"], dtype=np.float64)
        timestamps = np.asarray(example["timestamps"], dtype=np.int64).reshape(-1)
    except (TypeError, ValueError):
        raise SeeUError("cameras/timestamps are not numeric tensors", where) from None
    if cams.ndim != 2 or cams.shape[1] != 18:
        raise SeeUError(f"cameras must be an (N, 18) tensor, got shape {cams.shape}", where)
    images = example["images"]
    n = cams.shape[0]
    if not isinstance(images, (list, tuple)):
        raise SeeUError(f"images must be a list of tensors, got {type(images).__name__}", where)
    if len(images) != n or len(timestamps) != n:
        raise SeeUError(f"{len(images)} images, {n} cameras and {len(timestamps)} timestamps disagree", where)
    cam_to_world = cam_to_world_from_world_to_cam(homogeneous_from_3x4(cams[:, 6:].reshape(n, 3, 4)))
    data = image_views(images)
    names = [f"{where}#{i}" for i in range(n)]
    fmt, width, height = probe_images(data, names, cfg.verify_decode, cfg.max_pixels)
    near, far = cfg.near_far()
    meta = {"url": str(example["url"]), "dataset": cfg.dataset, "stage": cfg.stage, "chunk": chunk_name}
    source_frame = np.arange(n, dtype=np.int64)
    source_name: list[str] = []
    scene_id = str(key)
    if sidecar is not None and key in sidecar:
        extra = sidecar[key]
        scene_id = str(extra.get("scene_id", key))  # our export keyed it otherwise (a DL3DV scene's hash)
        near, far = float(extra.get("near", near)), float(extra.get("far", far))
        if len(extra.get("source_frame", [])) == n:
            source_frame = np.asarray(extra["source_frame"], dtype=np.int64)
        if len(extra.get("source_name", [])) == n:
            source_name = [str(s) for s in extra["source_name"]]
        meta.update(extra.get("meta", {}))
        meta.update({"dataset": meta.get("dataset", cfg.dataset), "stage": cfg.stage, "chunk": chunk_name})
    return PosedScene(
        scene_id=scene_id,
        images=data,
        image_format=fmt,
        width=width,
        height=height,
        intrinsics_norm=cams[:, :4].copy(),
        cam_to_world=cam_to_world,
        near=near,
        far=far,
        source_frame=source_frame,
        timestamp_us=timestamps,
        source_name=source_name,
        meta=meta,
    )


def image_views(images: Sequence[Any]) -> list[np.ndarray]:
    """N encoded images (uint8 1-D tensors or arrays) -> numpy uint8 views of them (no copy)."""
    arrays = []
    for t in images:
        a = np.asarray(t)
        if a.dtype != np.uint8 or a.ndim != 1:
            raise SeeUError(f"images must be uint8 1-D tensors of encoded bytes, got {a.dtype} {a.shape}")
        arrays.append(a if a.flags.c_contiguous else np.ascontiguousarray(a))
    if sum(a.size for a in arrays) >= 2**31:
        raise SeeUError("the scene's images total over the 2 GB a scene may hold")
    return arrays


def read_sidecar(directory: Path) -> dict | None:
    path = directory / SIDECAR_NAME
    if not path.exists():
        return None
    return read_json(path, SIDECAR_NAME)


def _chunk_items(
    path: Path, cfg: PixelSplatImportConfig, sidecar: dict | None, keys: list[str] | None, seen: set[str]
) -> Iterator[PosedScene | SkippedScene]:
    """One chunk's scenes (one chunk in memory), its malformed examples as SkippedScene, and the
    scenes index.json places in it (`keys`; None without an index.json) that it does not hold; every
    id yielded is added to `seen`."""
    try:
        chunk = load_chunk(path)
    except SeeUError as exc:
        for key in keys or [path.name]:
            seen.add(key)
            yield SkippedScene(key, str(exc))
        return
    found: set[str] = set()
    for i in range(len(chunk)):
        example, chunk[i] = chunk[i], None  # drop each example once converted: memory ~ one chunk
        if not isinstance(example, dict) or not isinstance(example.get("key"), str):
            yield SkippedScene(f"{path.name}#{i}", "example is not a dict with a string 'key'")
            continue
        if cfg.scenes is not None and example["key"] not in cfg.scenes:
            continue
        found.add(example["key"])
        seen.add(example["key"])
        try:
            yield scene_from_example(example, cfg, path.name, sidecar)
        except SeeUError as exc:
            yield SkippedScene(example["key"], str(exc))
        del example
    del chunk
    for key in keys or []:
        if key not in found:
            seen.add(key)
            yield SkippedScene(key, f"index.json lists it in {path.name}, which does not hold it")


def import_plan(cfg: PixelSplatImportConfig, found: ChunkList | None = None):
    """The import as resumable units (`importers.common.ImportPlan`): one unit per chunk (fingerprint:
    size and mtime), scenes asked for but not in index.json first, and, without an index.json,
    scenes asked for that no chunk held last. index.json and the sidecar are the plan's fingerprint."""
    from functools import partial

    from seeu_data.importers.common import ImportPlan, ImportUnit
    from seeu_data.store.resume import file_fingerprint

    found = found or find_chunks(cfg)
    directory, missing, keys = found.directory, list(found.missing), found.keys
    sidecar = read_sidecar(directory)
    seen: set[str] = {s.scene_id for s in missing}
    units = [ImportUnit(None, "", lambda: iter(missing))] if missing else []
    units += [
        ImportUnit(
            p.name,
            file_fingerprint(p),
            partial(_chunk_items, p, cfg, sidecar, None if keys is None else keys[p.name], seen),
        )
        for p in found.chunks
    ]
    if keys is None and cfg.scenes is not None:

        def not_found():
            return (SkippedScene(k, "not found in any chunk") for k in sorted(set(cfg.scenes) - seen))

        units.append(ImportUnit(None, "", not_found))
    fingerprint = f"{file_fingerprint(directory / 'index.json')}|{file_fingerprint(directory / SIDECAR_NAME)}"
    return ImportPlan(units, seen, fingerprint)


def iter_scenes(cfg: PixelSplatImportConfig, found: ChunkList | None = None) -> Iterator[PosedScene | SkippedScene]:
    """Yield scenes chunk by chunk (one chunk in memory); malformed examples and unreadable chunks
    are yielded as SkippedScene, scenes asked for but missing from index.json first."""
    for unit in import_plan(cfg, found).units:
        yield from unit.read()
