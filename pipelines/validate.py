"""`seeu validate`: what PATH is, among the layouts the toolkit writes, checked by that layout's own rules.

    posed frames, triple shards   manifest.json      seeu_data.store.dataset_check (the one validator every
                                                     stage applies to what it reads): manifest, sha256, rows,
                                                     columns, cameras, frame order, image headers
    pixelSplat chunks             *.torch + index.json  the pixelSplat importer's reader: every example of every
                                  (OUT/train, OUT/test)  chunk index.json lists, its cameras and image headers;
                                                     noted: scenes the peers' RE10K loaders would skip
    nerfstudio folder             transforms.json    the nerfstudio importer's reader: every frame's image and
                                                     header, its camera
    render directory              render.json, gaussians.ply, cameras.json  the files render.json names, the
                                                     Gaussians (seeu_model.ply.load_ply: 3DGS layout, finite),
                                                     cameras.json's cameras
    .ply file                     *.ply              3DGS Gaussians as above, or a point cloud (finite x y z)
    training run / checkpoints    checkpoints/ckpt-*.pt, a ckpt-*.pt  every checkpoint as every reader loads
                                                     it (seeu_model.training.checkpoint.load_checkpoint: format,
                                                     step, finite tensors) and the run's config.json
    evaluation index              *.json {scene: {context, target}}  the index reader of `seeu build --mode eval`
    a folder of the above         e.g. `seeu ingest --out`, `seeu export nerfstudio --out`, `seeu demo --out`:
                                  each one (what is not one of them is listed as not checked)

A COLMAP model is recognised and named with the command that checks it (`seeu check-cameras`, which
needs its images). Every problem is one SeeUError line naming the file.

Example:
    from pathlib import Path
    from pipelines.validate import ValidateConfig, validate

    summary = validate(ValidateConfig(path=Path("datasets/mine")))   # SeeUError on the first problem
    print(summary["kind"], summary["what"])
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seeu_data.errors import SeeUError
from seeu_data.limits import MAX_PIXELS
from seeu_data.settings import setting
from seeu_data.store.dataset_check import check_dataset

KINDS = {  # kind -> what it is called in the summary line
    "posed": "posed frames",
    "triples": "triple shards",
    "pixelsplat": "pixelSplat chunks",
    "nerfstudio": "nerfstudio folder",
    "render": "render directory",
    "ply": ".ply file",
    "run": "training run",
    "index": "evaluation index",
    "colmap": "COLMAP model",
    "folder": "folder of datasets",
}
FOLDER_DEPTH = 2  # folders of folders: `seeu demo --out` holds posed/ (`seeu ingest --out`), which holds the scenes


@dataclass(frozen=True)
class ValidateConfig:
    """One `seeu validate` run: `path` what to check (its layout detected), `check_sha` (sha256 of every
    file of a manifest dataset), `json` (print the summary as JSON), `max_pixels` (largest image header)."""

    path: Path = setting(
        help="what to check: a dataset (manifest.json), pixelSplat chunks, a nerfstudio folder, a render "
        "directory or .ply, a training run or checkpoint, an evaluation index, or a folder of these",
        positional=True,
    )
    check_sha: bool = setting(True, "skip sha256 checks (faster on large datasets)", flag="--no-sha")
    json: bool = setting(False, "print the summary as JSON")
    max_pixels: int = MAX_PIXELS


def validate_dataset(root: Path, check_sha: bool = True, max_pixels: int = MAX_PIXELS) -> dict:
    """Validate a dataset directory (manifest.json); raise SeeUError on the first problem; return a summary."""
    summary = check_dataset(root, check_sha=check_sha, max_pixels=max_pixels)
    summary.pop("manifest")
    return summary


def detect_layout(path: Path, depth: int = FOLDER_DEPTH) -> str | None:
    """The kind (a key of KINDS) of `path`, or None when it is none of them (a folder: when one of its
    sub-directories, at most `depth` levels down, is one of the others)."""
    path = Path(path)
    if path.is_file():
        if path.suffix.lower() == ".ply":
            return "ply"
        if path.suffix == ".pt":
            return "run"
        if path.name == "transforms.json":
            return "nerfstudio"
        return "index" if path.suffix == ".json" and path.name != "manifest.json" else None
    if not path.is_dir():
        return None
    if (path / "manifest.json").is_file() or any(path.glob("*.arrow")):
        return "posed"  # or triples: check_dataset reads which (and says when the manifest is missing)
    if (path / "render.json").is_file() or ((path / "cameras.json").is_file() and any(path.glob("*.ply"))):
        return "render"
    if (path / "checkpoints").is_dir() or any(path.glob("ckpt-*.pt")):
        return "run"
    if (path / "transforms.json").is_file():
        return "nerfstudio"
    if any((path / f"cameras{ext}").is_file() for ext in (".bin", ".txt")):
        return "colmap"
    if pixelsplat_stages(path):
        return "pixelsplat"
    if depth > 0 and any(detect_layout(child, depth - 1) for child in sorted(path.iterdir()) if child.is_dir()):
        return "folder"
    return None


def pixelsplat_stages(path: Path) -> list[Path]:
    """The directories of pixelSplat chunks at `path`: itself, or its train/ and test/."""
    return [d for d in (path, path / "train", path / "test") if d.is_dir() and any(d.glob("*.torch"))]


def validate(cfg: ValidateConfig) -> dict:
    """Check `cfg.path` by the rules of its layout; SeeUError on the first problem. Returns {"path",
    "kind", "what" (one line), "notes", ...}; a folder's holds "items", the summary of each one in it."""
    path = Path(cfg.path)
    if not path.exists():
        raise SeeUError("not found", path)
    kind = detect_layout(path)
    if kind is None:
        raise SeeUError(
            "not a layout seeu validate knows: expected a dataset (manifest.json), pixelSplat chunks, a nerfstudio "
            "folder (transforms.json), a render directory or .ply, a training run or checkpoint, an evaluation "
            "index, or a folder of these",
            path,
        )
    if kind == "colmap":
        raise SeeUError(
            "a COLMAP model: `seeu check-cameras PATH --images DIR` checks it against its images "
            "(`seeu import colmap` reads it into posed frames, which seeu validate checks)",
            path,
        )
    check = {
        "posed": check_manifest_dataset,
        "pixelsplat": check_pixelsplat,
        "nerfstudio": check_nerfstudio,
        "render": check_render,
        "ply": check_ply,
        "run": check_run,
        "index": check_index,
        "folder": check_folder,
    }[kind]
    return {"path": str(path), "notes": [], **check(path, cfg)}


def check_manifest_dataset(path: Path, cfg: ValidateConfig) -> dict:
    s = validate_dataset(path, check_sha=cfg.check_sha, max_pixels=cfg.max_pixels)
    scenes = f", {s['scenes']} scenes" if s["scenes"] else ""
    kind = "posed" if s["schema"] == "seeu.posed_frames" else "triples"
    notes = [f"files not in the manifest (ignored): {', '.join(s['unlisted_files'][:5])}"] * bool(s["unlisted_files"])
    what = (
        f"{s['schema']} v{s['schema_version']}, {s['files']} files, {s['rows']} rows{scenes}, {s['bytes'] / 1e6:.1f} MB"
        + ("" if s["sha256_checked"] else " (sha256 not checked)")
    )
    ov = s["overlap"]
    if ov is not None:
        methods = ", ".join(f"{n} from {m}" for m, n in sorted(ov["scenes_by_method"].items()))
        what += f"; overlap tables: {ov['files']} files ({methods})"
    elif kind == "posed":
        notes.append(f"no overlap table (add one with: seeu overlap {path})")
    return {**s, "kind": kind, "what": what, "notes": notes}


def scenes_or_first_problem(items, where: Path) -> list:
    """The PosedScenes an importer yields from `where`, each checked (`PosedScene.check`); SeeUError for
    the first scene it skips (a problem here: the layout must read whole) or whose cameras fail."""
    from seeu_data.importers.common import SkippedScene

    scenes = []
    for item in items:
        if isinstance(item, SkippedScene):
            raise SeeUError(f"scene {item.scene_id!r}: {item.reason}", where)
        try:
            item.check()
        except SeeUError as exc:  # "scene ID: problem"
            raise SeeUError(str(exc), where) from None
        scenes.append(item)
    return scenes


def check_pixelsplat(path: Path, cfg: ValidateConfig) -> dict:
    from seeu_data.exporters.pixelsplat import peer_of, peer_skip_reason
    from seeu_data.importers.pixelsplat import PixelSplatImportConfig, iter_scenes, read_index

    stages, notes, frames, scenes = [], [], 0, 0
    for directory in pixelsplat_stages(path):
        index = read_index(directory)
        if index is None:
            raise SeeUError("no index.json beside the chunks: not a finished pixelSplat dataset or export", directory)
        found = scenes_or_first_problem(
            iter_scenes(PixelSplatImportConfig(root=directory, max_pixels=cfg.max_pixels)), directory
        )
        skipped = [(s.scene_id, peer_skip_reason(s.width, s.height, s.intrinsics_norm, peer_of(s.meta))) for s in found]
        skipped = [(sid, why) for sid, why in skipped if why]
        if skipped:
            notes.append(
                f"{directory.name}: {len(skipped)} scene(s) the peers' loaders skip ({skipped[0][0]}: {skipped[0][1]})"
            )
        stray = sorted(p.name for p in directory.glob("*.torch") if p.name not in set(index.values()))
        if stray:
            notes.append(
                f"{directory.name}: chunks index.json does not list (ignored by the loaders): {', '.join(stray[:5])}"
            )
        stages.append(directory.name)
        scenes += len(found)
        frames += sum(len(s) for s in found)
    what = f"{', '.join(stages)}: {scenes} scenes, {frames} frames (read as `seeu import pixelsplat` reads them)"
    return {"kind": "pixelsplat", "what": what, "notes": notes, "stages": stages, "scenes": scenes, "frames": frames}


def check_nerfstudio(path: Path, cfg: ValidateConfig) -> dict:
    from seeu_data.importers.nerfstudio import NerfstudioImportConfig, iter_scenes

    transforms = path if path.is_file() else path / "transforms.json"
    (scene,) = scenes_or_first_problem(
        iter_scenes(NerfstudioImportConfig(transforms=transforms, max_pixels=cfg.max_pixels)), transforms
    )
    dropped = scene.meta.get("skipped_frames") or []
    if dropped:
        raise SeeUError(
            f"{len(dropped)} frame(s) cannot be read, e.g. {dropped[0]['frame']}: {dropped[0]['reason']}", transforms
        )
    what = f"scene {scene.scene_id!r}, {len(scene)} frames (read as `seeu import nerfstudio` reads them)"
    return {"kind": "nerfstudio", "what": what, "scenes": 1, "frames": len(scene)}


def check_ply(path: Path, cfg: ValidateConfig) -> dict:
    """3DGS Gaussians (`load_ply`), or a point cloud (x y z, finite) such as a nerfstudio export's sparse_pc.ply."""
    from plyfile import PlyData, PlyParseError

    try:
        vertex = PlyData.read(str(path))["vertex"]
    except (OSError, KeyError, ValueError, IndexError, PlyParseError) as exc:
        raise SeeUError(f"not a readable .ply with a vertex element ({exc})", path) from None
    if "opacity" in {p.name for p in vertex.properties}:
        from seeu_model.ply import load_ply

        n = int(load_ply(path).means.shape[1])
        return {"kind": "ply", "what": f"{n} Gaussians (3DGS layout)", "gaussians": n}
    xyz = np.stack([np.asarray(vertex[k], np.float64) for k in "xyz"], -1)
    if not np.isfinite(xyz).all():
        raise SeeUError("non-finite point coordinates", path)
    return {"kind": "ply", "what": f"point cloud of {len(xyz)} points", "points": len(xyz)}


def check_render(path: Path, cfg: ValidateConfig) -> dict:
    """What `seeu render` writes (pipelines/render.py), render.json last: the camera paths' MP4s (their
    frame counts) or PNG frames, context.png, gaussians.ply (as many Gaussians as render.json says) and
    cameras.json (rigid poses, positive focal lengths)."""
    import cv2

    from seeu_data.store.dataset_check import check_cameras
    from seeu_data.store.image_header import image_info
    from seeu_data.store.json_file import read_json

    if not (path / "render.json").is_file():
        raise SeeUError("no render.json (written last): the render did not finish", path)
    report = read_json(path / "render.json", "render.json")
    files = [path / "context.png", path / "gaussians.ply", path / "cameras.json"]
    for name in ("interp", "extrap"):
        entry = report.get(name) or {}
        files += (
            [path / f"{name}.mp4"] if "mp4" in entry else [path / "frames" / Path(p).name for p in entry.get("png", [])]
        )
    missing = [f for f in files if not f.is_file()]
    if missing:
        raise SeeUError("missing (render.json names it)", missing[0])
    for f in files:
        if f.suffix == ".png":
            image_info(f.read_bytes(), str(f))
        elif f.suffix == ".mp4":
            video = cv2.VideoCapture(str(f))
            frames = int(video.get(cv2.CAP_PROP_FRAME_COUNT))
            video.release()
            if frames != report[f.stem]["frames"]:
                raise SeeUError(f"{frames} frames, render.json says {report[f.stem]['frames']}", f)
    g = check_ply(path / "gaussians.ply", cfg)
    if g.get("gaussians") != report.get("num_gaussians"):
        raise SeeUError(f"{g['what']}, render.json says {report.get('num_gaussians')}", path / "gaussians.ply")
    cams = read_json(path / "cameras.json", "cameras.json")
    try:
        c2w = np.tile(np.eye(4), (len(cams), 1, 1))
        c2w[:, :3, :3] = [c["rotation"] for c in cams]
        c2w[:, :3, 3] = [c["position"] for c in cams]
        intr = np.array([[c["fx"] / c["width"], c["fy"] / c["height"], 0.5, 0.5] for c in cams], np.float64)
    except (TypeError, KeyError, ValueError, ZeroDivisionError):
        raise SeeUError(
            "every camera needs rotation (3x3), position (3), fx, fy, width, height", path / "cameras.json"
        ) from None
    check_cameras(c2w, intr, np.ones(len(cams)), np.full(len(cams), 2.0), path / "cameras.json")
    what = f"{g['what']}, {len(cams)} cameras, {len(files) - 3} path file(s)"
    return {"kind": "render", "what": what, "cameras": len(cams), "gaussians": g["gaussians"]}


def check_run(path: Path, cfg: ValidateConfig) -> dict:
    from seeu_model.training.checkpoint import list_checkpoints, load_checkpoint
    from seeu_model.training.config import config_from_dict, read_config_file

    if path.is_file():
        files = [path]
    else:
        directory = path / "checkpoints" if (path / "checkpoints").is_dir() else path
        files = list_checkpoints(directory)
        if not files:
            raise SeeUError("no checkpoint (ckpt-*.pt) yet", directory)
    steps = []
    for f in files:
        ckpt = load_checkpoint(f)
        config_from_dict(ckpt["config"])
        steps.append(ckpt["step"])
    notes = []
    if path.is_dir() and (path / "config.json").is_file():
        config_from_dict(read_config_file(path / "config.json"))
        if not (path / "train_summary.json").is_file():
            notes.append("no train_summary.json: the run has not finished (`seeu train --resume` continues it)")
    what = f"{len(files)} checkpoint(s), steps {', '.join(map(str, steps))}"
    return {"kind": "run", "what": what, "notes": notes, "checkpoints": len(files), "steps": steps}


def check_index(path: Path, cfg: ValidateConfig) -> dict:
    from seeu_data.build.eval_index import read_index

    index = read_index(path)
    what = f"{index.format} format, {len(index.entries)} entries, {index.num_null} null"
    return {"kind": "index", "what": what, "entries": len(index.entries)}


def check_folder(path: Path, cfg: ValidateConfig) -> dict:
    from dataclasses import replace

    items, notes = [], []
    for child in sorted(p for p in path.iterdir() if p.is_dir() and not p.name.startswith(".")):
        if detect_layout(child) in (None, "colmap"):
            notes.append(f"not checked (not a layout seeu validate knows): {child.name}")
            continue
        items.append(validate(replace(cfg, path=child)))
    kinds = sorted({KINDS[i["kind"]] for i in items})
    return {"kind": "folder", "what": f"{len(items)} checked: {', '.join(kinds)}", "notes": notes, "items": items}
