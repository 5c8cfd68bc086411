"""DL3DV-10K -> posed scenes, one per scene hash (scene key `dl3dv_<hash>`).

Layouts found under ROOT (any mix; a hash found twice is an error):

* release (DL3DV-ALL-480P / -960P / -4K, `download.py`): `ROOT/<subset>/<hash>/transforms.json`
  (subset `1K`, `2K`, ...) or, for one subset, `ROOT/<hash>/transforms.json`, with the frames in
  `images_8/` (480p), `images_4/` (960p) or `images/` (full resolution) beside it;
* benchmark (DL3DV-10K-Benchmark, 140 scenes): `ROOT/<hash>/nerfstudio/transforms.json` with the same
  `images_*` folders.

transforms.json is nerfstudio's (read with `importers.nerfstudio`: intrinsics `fl_x, fl_y, cx, cy`
for the image size `w, h`, OpenGL camera-to-world `transform_matrix`, `applied_transform` undone).
Its `file_path` names `images/frame_XXXXX.png` for every resolution: the frame is read from the
chosen resolution's folder under the same file name (`RESOLUTIONS`, as DepthSplat's converter does
with `images_8` / `images_4`). Each frame's real size (header only, `image_header.file_image_size`)
must be the intrinsics' size scaled by one factor (W / w, H / h within a pixel); a scene that breaks
this (a frame of another size or aspect) is skipped with the sizes in the reason. The intrinsics are
scaled to the frame (normalised intrinsics: fl_x / w, cx / w, ... as DepthSplat's converter stores
them). DL3DV's `k1, k2, p1, p2` are ignored by default, as DepthSplat does (the values are kept in
the scene's meta); `undistort` undistorts the frames instead (`importers.nerfstudio`).

`exclude` drops hashes (e.g. the 140 benchmark scenes from a training import: DL3DV publishes them as
the scene folders of the DL3DV-10K-Benchmark dataset, huggingface.co/datasets/DL3DV/DL3DV-10K-Benchmark,
and DepthSplat's `assets/dl3dv_*.json` evaluation indices are keyed by them). Resume: one unit per
scene (transforms.json and its frames fingerprinted).
"""

from __future__ import annotations

import copy
from collections.abc import Iterator
from dataclasses import dataclass
from functools import partial
from pathlib import Path, PurePosixPath

from seeu_data.errors import SeeUError
from seeu_data.importers.common import ImportJob, ReadSettings, SkippedScene, recorded_params
from seeu_data.importers.nerfstudio import NerfstudioImportConfig, load_transforms, scene_from_doc
from seeu_data.settings import parse_scene_list, setting
from seeu_data.store.image_header import file_image_size
from seeu_data.store.posed import PosedScene

RESOLUTIONS = {"480p": "images_8", "960p": "images_4", "full": "images"}  # --resolution -> frame folder
DEFAULT_RESOLUTION = "480p"
DL3DV_NEAR_FAR = (0.5, 200.0)  # DepthSplat's DL3DV experiment (config/experiment/dl3dv.yaml)
SCENE_PREFIX = "dl3dv_"
_SCALED_KEYS = {"fl_x": 0, "cx": 0, "fl_y": 1, "cy": 1}  # key -> axis (0: x, 1: y)
_DISTORTION = ("k1", "k2", "k3", "k4", "p1", "p2")


@dataclass
class Dl3dvImportConfig(ReadSettings):
    """`seeu import dl3dv ROOT`: every scene under `root` (see the module docstring) at `resolution`,
    except the hashes in `exclude`."""

    root: Path = setting(help="folder of <subset>/<hash>/transforms.json or <hash>/nerfstudio/", positional=True)
    resolution: str = setting(
        DEFAULT_RESOLUTION,
        "frames read: " + ", ".join(f"{k} = {v}/" for k, v in RESOLUTIONS.items()),
        choices=tuple(RESOLUTIONS),
    )
    exclude: frozenset[str] | None = setting(
        None,
        "scene hashes left out: a,b,c or @file.txt (one per line), e.g. the 140 DL3DV-Benchmark hashes (default: none)",
        parse=parse_scene_list,
    )
    near: float = setting(DL3DV_NEAR_FAR[0], "near plane")
    far: float = setting(DL3DV_NEAR_FAR[1], "far plane")
    undistort: bool = setting(
        False, "undistort the frames with transforms.json's k1, k2, p1, p2 (default: ignored, as DepthSplat)"
    )

    def plan(self) -> ImportJob:
        scenes = selected_scenes(self)
        params = recorded_params(self, "dl3dv")
        return ImportJob(import_plan(self, scenes), params, len(scenes), [str(self.root)])

    def check(self) -> None:
        if self.resolution not in RESOLUTIONS:
            raise SeeUError(f"--resolution {self.resolution!r}: one of {', '.join(RESOLUTIONS)}")
        if not Path(self.root).is_dir():
            raise SeeUError("DL3DV root not found (a folder of <subset>/<hash>/ or <hash>/nerfstudio/)", self.root)


@dataclass(frozen=True)
class Dl3dvScene:
    hash: str
    transforms: Path
    layout: str  # "release" | "benchmark"

    @property
    def key(self) -> str:
        return SCENE_PREFIX + self.hash


def find_scenes(root: Path) -> list[Dl3dvScene]:
    """Every scene's transforms.json under `root`, sorted by hash; SeeUError for a hash found twice."""
    root = Path(root)
    found: dict[str, Dl3dvScene] = {}
    patterns = [("*/nerfstudio/transforms.json", "benchmark"), ("*/*/transforms.json", "release")]
    patterns += [("*/transforms.json", "release"), ("nerfstudio/transforms.json", "benchmark")]
    for pattern, layout in patterns:
        for t in sorted(root.glob(pattern)):
            folder = t.parent.parent if layout == "benchmark" else t.parent
            if layout == "release" and folder.name == "nerfstudio":
                continue  # a benchmark scene, found by its own pattern
            name = folder.resolve().name
            scene = Dl3dvScene(name, t, layout)
            other = found.get(name)
            if other is not None and other.transforms != t:
                raise SeeUError(f"scene {name} found twice: {other.transforms} and {t}", root)
            found[name] = scene
    return [found[k] for k in sorted(found)]


def selected_scenes(cfg: Dl3dvImportConfig) -> list[Dl3dvScene]:
    cfg.check()
    scenes = find_scenes(cfg.root)
    if not scenes:
        raise SeeUError(
            "no DL3DV scene found (expected <subset>/<hash>/transforms.json or <hash>/nerfstudio/transforms.json)",
            cfg.root,
        )
    drop = {h.removeprefix(SCENE_PREFIX) for h in cfg.exclude or ()}
    return [s for s in scenes if s.hash not in drop]


def frame_files(scene: Dl3dvScene, doc: dict, resolution: str) -> list[Path]:
    """Each frame's image in the resolution's folder (doc order): its `file_path`'s file name there."""
    folder = scene.transforms.parent / RESOLUTIONS[resolution]
    return [folder / PurePosixPath(f["file_path"]).name for f in doc["frames"]]


def _scaled_doc(doc: dict, folder: str, size: tuple[int, int], where: Path) -> dict:
    """`doc` with the intrinsics scaled to frames of `size` (w, h) and file_paths in `folder`."""
    out = copy.deepcopy(doc)
    w, h = out.get("w"), out.get("h")
    if not isinstance(w, (int, float)) or not isinstance(h, (int, float)) or w <= 0 or h <= 0:
        raise SeeUError("transforms.json has no image size (w, h)", where)
    scale = (size[0] / float(w), size[1] / float(h))
    for block in [out, *out["frames"]]:
        for key, axis in _SCALED_KEYS.items():
            if isinstance(block.get(key), (int, float)) and not isinstance(block.get(key), bool):
                block[key] = block[key] * scale[axis]
    out["w"], out["h"] = size
    for f in out["frames"]:
        f["file_path"] = f"{folder}/{PurePosixPath(f['file_path']).name}"
    return out


def check_sizes(files: list[Path], doc: dict, where: Path) -> tuple[int, int]:
    """The frames' common size (w, h), read from their headers; SeeUError when a frame is missing or
    its size is not transforms.json's (w, h) scaled by one factor (within a pixel) or differs from
    the first frame's."""
    w, h = doc.get("w"), doc.get("h")
    if not isinstance(w, (int, float)) or not isinstance(h, (int, float)) or w <= 0 or h <= 0:
        raise SeeUError("transforms.json has no image size (w, h)", where)
    missing = [p for p in files if not p.is_file()]
    if missing:
        raise SeeUError(f"{len(missing)} of {len(files)} frame images are missing (first: {missing[0]})", where)
    first: tuple[int, int] | None = None
    for p in files:
        size = file_image_size(p)
        if first is None:
            first = size
            expect_h = h * size[0] / w
            if abs(size[1] - expect_h) > 1.0:
                raise SeeUError(
                    f"frame {p.parent.name}/{p.name} is {size[0]}x{size[1]}, but the intrinsics are for "
                    f"{w:g}x{h:g} (at width {size[0]} that is {size[0]}x{expect_h:.1f})",
                    where,
                )
        elif size != first:
            raise SeeUError(
                f"frame {p.parent.name}/{p.name} is {size[0]}x{size[1]}, the scene's first frame {first[0]}x{first[1]}",
                where,
            )
    assert first is not None
    return first


def iter_scene(cfg: Dl3dvImportConfig, scene: Dl3dvScene) -> Iterator[PosedScene | SkippedScene]:
    """One DL3DV scene (the nerfstudio importer's reading, frames from the resolution's folder)."""
    path = scene.transforms
    try:
        doc = load_transforms(path)
        files = frame_files(scene, doc, cfg.resolution)
        size = check_sizes(files, doc, path)
        scaled = _scaled_doc(doc, RESOLUTIONS[cfg.resolution], size, path)
    except SeeUError as exc:
        yield SkippedScene(scene.key, str(exc))
        return
    meta: dict[str, object] = {
        "dataset": "dl3dv",
        "dl3dv_hash": scene.hash,
        "layout": scene.layout,
        "resolution": cfg.resolution,
        "intrinsics_scale": [size[0] / float(doc["w"]), size[1] / float(doc["h"])],
    }
    dist = {k: scaled.pop(k) for k in _DISTORTION if k in scaled}
    if not cfg.undistort and any(v for v in dist.values()):
        meta["distortion_ignored"] = dist  # as DepthSplat's converter: the frames are used as they are
    elif cfg.undistort:
        scaled.update(dist)
    ns = NerfstudioImportConfig(
        transforms=path,
        scene_id=scene.key,
        near=cfg.near,
        far=cfg.far,
        verify_decode=cfg.verify_decode,
        max_pixels=cfg.max_pixels,
        undistort=cfg.undistort,
    )
    paths: list[Path | None] = list(files)
    yield from scene_from_doc(ns, scaled, scene.key, paths, {}, meta)


def import_plan(cfg: Dl3dvImportConfig, scenes: list[Dl3dvScene]):
    """The import as resumable units (`importers.common.ImportPlan`): one per scene, its fingerprint
    covering transforms.json and the frame folder's files."""
    from seeu_data.importers.common import ImportPlan, ImportUnit
    from seeu_data.store.resume import files_fingerprint

    units = []
    for s in scenes:
        folder = s.transforms.parent / RESOLUTIONS[cfg.resolution]
        frames = sorted(folder.iterdir()) if folder.is_dir() else []
        units.append(ImportUnit(s.key, files_fingerprint([s.transforms, *frames]), partial(iter_scene, cfg, s)))
    return ImportPlan(units)
