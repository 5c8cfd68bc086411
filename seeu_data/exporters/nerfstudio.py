"""Posed frames -> nerfstudio folders: `OUT/<scene_id>/images/frame_00000.jpg ...` + `transforms.json`.

Images are written as they are stored (JPEG or PNG bytes, no re-encoding). `transforms.json` holds,
per frame, `file_path`, `transform_matrix` (OpenGL camera-to-world, `cameras.opengl_from_opencv`)
and the pinhole intrinsics in pixels `fl_x, fl_y, cx, cy, w, h` (per frame, which nerfstudio's
dataparser accepts), with `camera_model` "OPENCV" and zero distortion. No `applied_transform` is
written: the world frame is the posed dataset's. A `seeu` block (scene id, near/far, meta) and per-
frame `seeu_*` keys (source frame, name, timestamp) make `seeu import nerfstudio` lossless; nerfstudio
ignores unknown keys. Frames with a mask get `mask_path` (`masks/frame_00000.png`) in nerfstudio's
convention, 0 = pixel ignored, 255 = kept (the stored mask inverted), which its dataparser applies to
the loss and `seeu import nerfstudio` reads back. Each transforms.json is written atomically after its
images and masks.
When the posed scene carries SfM points (`meta["points3d"]`, written by `seeu ingest`), they are
copied to `sparse_pc.ply` (x y z + red green blue, in the transforms' world frame) and named in
`ply_file_path`, the key nerfstudio's dataparser reads the splatfacto initial point cloud from.
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seeu_data.cameras import intrinsics_pixels, opengl_from_opencv
from seeu_data.errors import SeeUError
from seeu_data.masks import decode_mask, encode_mask
from seeu_data.settings import parse_scene_ids, setting
from seeu_data.store.arrow_io import atomic_write_bytes, atomic_write_text
from seeu_data.store.image_header import extension_for
from seeu_data.store.out_lock import locks_output
from seeu_data.store.posed import PosedDataset, PosedScene

SPARSE_PLY = "sparse_pc.ply"  # the name nerfstudio's own ns-process-data gives the initial point cloud


@dataclass
class NerfstudioExportConfig:
    out: Path
    scenes: list[str] | None = setting(
        None, "export only these scene ids: a,b,c or @file.txt", parse=parse_scene_ids, metavar="SCENES"
    )


def nerfstudio_mask_name(i: int) -> str:
    """The relative `mask_path` of frame `i` of an exported scene."""
    return f"masks/frame_{i:05d}.png"


def transforms_for_scene(scene: PosedScene) -> tuple[dict, list[str]]:
    """The transforms.json document and the image file names (relative) of a scene."""
    ext = extension_for(scene.image_format)
    c2w_gl = opengl_from_opencv(np.asarray(scene.cam_to_world, dtype=np.float64))
    frames, names = [], []
    for i in range(len(scene)):
        w, h = int(scene.width[i]), int(scene.height[i])
        K = intrinsics_pixels(np.asarray(scene.intrinsics_norm[i], dtype=np.float64), w, h)
        name = f"images/frame_{i:05d}{ext}"
        names.append(name)
        frames.append(
            {
                "file_path": name,
                "transform_matrix": c2w_gl[i].tolist(),
                "fl_x": float(K[0, 0]),
                "fl_y": float(K[1, 1]),
                "cx": float(K[0, 2]),
                "cy": float(K[1, 2]),
                "w": w,
                "h": h,
                "seeu_source_frame": int(scene.source_frame[i]),
                "seeu_source_name": scene.source_name[i] if scene.source_name else "",
                "seeu_timestamp_us": int(scene.timestamp_us[i]),
            }
        )
        if scene.masks is not None and scene.masks[i] is not None:
            frames[-1]["mask_path"] = nerfstudio_mask_name(i)
    doc = {
        "camera_model": "OPENCV",
        "k1": 0.0,
        "k2": 0.0,
        "p1": 0.0,
        "p2": 0.0,
        "frames": frames,
        "seeu": {
            "scene_id": scene.scene_id,
            "near": scene.near,
            "far": scene.far,
            "meta": scene.meta,
            "convention": "transform_matrix: OpenGL camera-to-world in the posed dataset's world",
        },
    }
    return doc, names


def _points_file(root: Path, rel) -> Path | None:
    """The scene's SfM point file when its meta names one that lies inside the dataset directory (a
    scene imported from elsewhere may name a file that did not come with it: then None)."""
    if not isinstance(rel, str) or not rel:
        return None
    src = (Path(root) / rel).resolve()
    if not src.is_relative_to(Path(root).resolve()):
        raise SeeUError(f"SfM point file {rel!r} named in the scene meta lies outside the dataset", root)
    return src if src.is_file() else None


@locks_output(lambda dataset, cfg, *_, **__: cfg.out)
def export_nerfstudio(dataset: PosedDataset, cfg: NerfstudioExportConfig, progress: bool = False) -> dict:
    from tqdm import tqdm

    scene_ids = cfg.scenes if cfg.scenes is not None else dataset.scene_ids
    known = set(dataset.scene_ids)
    for sid in scene_ids:
        if sid not in known:
            raise SeeUError(f"no scene {sid!r} in this dataset", dataset.root)
        if "/" in sid or sid in (".", ".."):
            raise SeeUError(f"scene id {sid!r} cannot be a folder name", dataset.root)
    frames = 0
    for scene in tqdm(
        dataset.iter_scenes(scene_ids),
        total=len(scene_ids),
        unit="scene",
        desc="export nerfstudio",
        file=sys.stderr,
        disable=not progress,
    ):
        folder = Path(cfg.out) / scene.scene_id
        (folder / "transforms.json").unlink(missing_ok=True)  # being rewritten: not complete
        doc, names = transforms_for_scene(scene)
        for name, data in zip(names, scene.images):
            atomic_write_bytes(folder / name, data)
        for i, mask in enumerate(scene.masks or []):
            if mask is not None:  # nerfstudio's convention: nonzero = kept
                atomic_write_bytes(folder / nerfstudio_mask_name(i), encode_mask(~decode_mask(mask)))
        points = _points_file(dataset.root, scene.meta.get("points3d"))
        if points is not None:
            atomic_write_bytes(folder / SPARSE_PLY, points.read_bytes())
            doc["ply_file_path"] = SPARSE_PLY
        atomic_write_text(folder / "transforms.json", json.dumps(doc, indent=1))
        frames += len(scene)
    return {"scenes": len(scene_ids), "frames": frames}
