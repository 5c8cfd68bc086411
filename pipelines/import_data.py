"""The import stage: a public dataset or your own posed scenes -> a posed-frames directory.

`import_dataset(ImportConfig(source=..., out=...))` takes one format's config from
`seeu_data.importers` (`PixelSplatImportConfig`, `Re10kTextImportConfig`, `DtuImportConfig`,
`ColmapImportConfig`, `NerfstudioImportConfig`, `Dl3dvImportConfig`), plans the import (a re-run keeps the output files
already complete for the same options and unchanged inputs), streams the scenes into OUT with
`write_import` (bad scenes skipped and counted, manifest last) and returns the `ImportReport`.

Example:
    from pathlib import Path
    from pipelines.import_data import ImportConfig, import_dataset
    from seeu_data.importers.colmap import ColmapImportConfig
from seeu_data.importers.dl3dv import Dl3dvImportConfig

    source = ColmapImportConfig(model_dir=Path("scene/sparse/0"), images_dir=Path("scene/images"))
    report = import_dataset(ImportConfig(source=source, out=Path("data/posed/scene")))
    print(report.summary_line(Path("data/posed/scene")))
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from seeu_data.errors import SeeUError
from seeu_data.importers.colmap import ColmapImportConfig
from seeu_data.importers.dl3dv import Dl3dvImportConfig
from seeu_data.importers.dtu import DtuImportConfig
from seeu_data.importers.nerfstudio import NerfstudioImportConfig
from seeu_data.importers.pixelsplat import PixelSplatImportConfig
from seeu_data.importers.re10k_text import Re10kTextImportConfig
from seeu_data.out_lock import locks_output

SourceConfig = (
    PixelSplatImportConfig
    | Re10kTextImportConfig
    | DtuImportConfig
    | ColmapImportConfig
    | NerfstudioImportConfig
    | Dl3dvImportConfig
)

# format name (the `seeu import FORMAT`) of each source config
FORMATS: dict[type, str] = {
    PixelSplatImportConfig: "pixelsplat",
    Re10kTextImportConfig: "re10k",
    DtuImportConfig: "dtu",
    ColmapImportConfig: "colmap",
    NerfstudioImportConfig: "nerfstudio",
    Dl3dvImportConfig: "dl3dv",
}


@dataclass(frozen=True)
class ImportConfig:
    """One `seeu import` run: `source` (a format's config), `out` (the posed-frames directory),
    `strict` (fail on the first bad scene instead of skipping it), `progress` (a bar), `fsync`."""

    source: SourceConfig
    out: Path
    strict: bool = False
    progress: bool = False
    fsync: bool = False

    @property
    def format(self) -> str:
        return FORMATS[type(self.source)]

    def check(self) -> None:
        if type(self.source) not in FORMATS:
            raise SeeUError(f"unknown import source {type(self.source).__name__}; one of {', '.join(FORMATS.values())}")


# Each planner: the source config -> (items or ImportPlan, params recorded in the manifest, number of
# units for the progress bar, inputs named in the provenance).


def _plan_pixelsplat(cfg: PixelSplatImportConfig) -> tuple[Any, dict, int | None, list[str]]:
    from seeu_data.importers import pixelsplat as m

    directory, chunks, missing, total = m.plan(cfg)
    near, far = cfg.near_far()
    params = {
        "format": "pixelsplat",
        "root": str(cfg.root),
        "stage": cfg.stage,
        "dataset": cfg.dataset,
        "near": near,
        "far": far,
        "scenes": sorted(cfg.scenes) if cfg.scenes else None,
        "verify_decode": cfg.verify_decode,
    }
    return m.import_plan(cfg, chunks, directory, missing), params, total, [str(directory)]


def _plan_re10k(cfg: Re10kTextImportConfig) -> tuple[Any, dict, int | None, list[str]]:
    from seeu_data.importers import re10k_text as m

    files = m.camera_files(cfg)
    params = {
        "format": "re10k",
        "cameras": str(cfg.cameras_dir),
        "frames": str(cfg.frames_dir),
        "dataset": cfg.dataset,
        "near": cfg.near,
        "far": cfg.far,
        "allow_missing_frames": cfg.allow_missing_frames,
        "verify_decode": cfg.verify_decode,
    }
    return m.import_plan(cfg, files), params, len(files), [str(cfg.cameras_dir), str(cfg.frames_dir)]


def _plan_dtu(cfg: DtuImportConfig) -> tuple[Any, dict, int | None, list[str]]:
    from seeu_data.importers import dtu as m

    found = m.scan_list(cfg)
    params = {
        "format": "dtu",
        "root": str(cfg.root),
        "scans": found,
        "lighting": cfg.lighting,
        "scale": cfg.scale,
        "near": cfg.near,
        "far": cfg.far,
        "verify_decode": cfg.verify_decode,
    }
    return m.import_plan(cfg, found), params, len(found), [str(cfg.root)]


def _plan_colmap(cfg: ColmapImportConfig) -> tuple[Any, dict, int | None, list[str]]:
    from seeu_data.importers import colmap as m

    params = {
        "format": "colmap",
        "model": str(cfg.model_dir),
        "images": str(cfg.images_dir),
        "undistort": cfg.undistort,
        "near": cfg.near,
        "far": cfg.far,
        "scene_id": cfg.scene_id,
        "verify_decode": cfg.verify_decode,
        "allow_outside_paths": cfg.allow_outside_paths,
    }
    return m.import_plan(cfg), params, 1, [str(cfg.model_dir), str(cfg.images_dir)]


def _plan_nerfstudio(cfg: NerfstudioImportConfig) -> tuple[Any, dict, int | None, list[str]]:
    from seeu_data.importers import nerfstudio as m

    params = {
        "format": "nerfstudio",
        "transforms": str(cfg.transforms),
        "undo_applied_transform": cfg.undo_applied_transform,
        "near": cfg.near,
        "far": cfg.far,
        "scene_id": cfg.scene_id,
        "verify_decode": cfg.verify_decode,
        "undistort": cfg.undistort,
        "skip_missing": cfg.skip_missing,
        "allow_outside_paths": cfg.allow_outside_paths,
    }
    return m.import_plan(cfg), params, 1, [str(cfg.transforms)]


def _plan_dl3dv(cfg: Dl3dvImportConfig) -> tuple[Any, dict, int | None, list[str]]:
    from dataclasses import asdict

    from seeu_data.importers import dl3dv as m

    scenes = m.selected_scenes(cfg)
    params = {"format": "dl3dv", **asdict(cfg), "root": str(cfg.root), "exclude": sorted(cfg.exclude or ())}
    params.pop("max_pixels")
    return m.import_plan(cfg, scenes), params, len(scenes), [str(cfg.root)]


_PLANNERS = {
    "pixelsplat": _plan_pixelsplat,
    "re10k": _plan_re10k,
    "dtu": _plan_dtu,
    "colmap": _plan_colmap,
    "nerfstudio": _plan_nerfstudio,
    "dl3dv": _plan_dl3dv,
}


@locks_output(lambda cfg: cfg.out)
def import_dataset(cfg: ImportConfig):
    """Import `cfg.source` into `cfg.out`; returns the `seeu_data.importers.ImportReport` (also in the
    manifest's `report`). Raises SeeUError when the input as a whole is unusable or no scene remains."""
    from seeu_data.importers import ImportReport, write_import
    from seeu_data.manifest import provenance

    cfg.check()
    items, params, total, inputs = _PLANNERS[cfg.format](cfg.source)  # type: ignore[operator]
    report = ImportReport(format=cfg.format)
    write_import(
        items,
        cfg.out,
        report,
        params=params,
        provenance=provenance(f"import {cfg.format}", inputs),
        strict=cfg.strict,
        progress=cfg.progress,
        total=total,
        fsync=cfg.fsync,
    )
    return report
