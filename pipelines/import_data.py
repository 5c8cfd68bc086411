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

from seeu_data.errors import SeeUError
from seeu_data.importers.colmap import ColmapImportConfig
from seeu_data.importers.dl3dv import Dl3dvImportConfig
from seeu_data.importers.dtu import DtuImportConfig
from seeu_data.importers.nerfstudio import NerfstudioImportConfig
from seeu_data.importers.pixelsplat import PixelSplatImportConfig
from seeu_data.importers.re10k_text import Re10kTextImportConfig
from seeu_data.limits import MAX_WORKERS, check_range
from seeu_data.process_pool import default_workers
from seeu_data.settings import setting
from seeu_data.store.out_lock import locks_output

SourceConfig = (
    PixelSplatImportConfig
    | Re10kTextImportConfig
    | DtuImportConfig
    | ColmapImportConfig
    | NerfstudioImportConfig
    | Dl3dvImportConfig
)

# `seeu import FORMAT` -> (the format's config, whose settings are the subcommand's flags and whose
# `plan()` prepares the import; the one-line help)
IMPORTERS: dict[str, tuple[type, str]] = {
    "pixelsplat": (PixelSplatImportConfig, "RE10K / ACID / DTU pixelSplat chunks"),
    "re10k": (Re10kTextImportConfig, "raw RealEstate10K / ACID text files + frames"),
    "dtu": (DtuImportConfig, "DTU in the MVSNet layout"),
    "colmap": (ColmapImportConfig, "a COLMAP model and its images"),
    "nerfstudio": (NerfstudioImportConfig, "a nerfstudio / NeRF transforms.json"),
    "dl3dv": (Dl3dvImportConfig, "DL3DV-10K scenes (release or benchmark layout)"),
}
FORMATS: dict[type, str] = {cls: name for name, (cls, _) in IMPORTERS.items()}


@dataclass(frozen=True)
class ImportConfig:
    """One `seeu import` run: `source` (a format's config), `out` (the posed-frames directory),
    `strict` (fail on the first bad scene instead of skipping it), `verify` (hash the files a re-run
    keeps), `engine` / `ray_address` / `workers` (where the inputs are read: `importers.read_ahead`), `progress`
    (a bar), `fsync`, `force` (write every posed file anew instead of keeping those a previous run
    completed)."""

    source: SourceConfig
    out: Path
    strict: bool = setting(False, "fail on the first bad scene instead of skipping it")
    verify: bool = setting(
        False,
        "a re-run hashes (sha256) the files it keeps; default: it trusts a file whose size and mtime are "
        "the ones recorded with its sha256 (reads nothing)",
    )
    engine: str = setting(
        "local",
        "local: read and write in this process; ray: read the inputs on a Ray cluster, write here (the same bytes)",
        choices=("local", "ray"),
    )
    ray_address: str | None = setting(None, "Ray cluster address (default: start a local instance)")
    workers: int | None = setting(
        None,
        "local engine: processes that read the inputs, check the scenes and measure their view overlap "
        "(default: one per core, at most 8; one on up to 4 cores)",
    )
    progress: bool = False
    fsync: bool = False
    force: bool = False

    @property
    def format(self) -> str:
        return FORMATS[type(self.source)]

    def check(self) -> None:
        if self.engine not in ("local", "ray"):
            raise SeeUError(f"unknown engine {self.engine!r} (local or ray)")
        if self.workers is not None:
            check_range(self.workers, "--workers", 1, MAX_WORKERS)
        if type(self.source) not in FORMATS:
            raise SeeUError(f"unknown import source {type(self.source).__name__}; one of {', '.join(FORMATS.values())}")


@locks_output(lambda cfg: cfg.out)
def import_dataset(cfg: ImportConfig):
    """Import `cfg.source` into `cfg.out`; returns the `seeu_data.importers.ImportReport` (also in the
    manifest's `report`). Raises SeeUError when the input as a whole is unusable or no scene remains."""
    from seeu_data.importers import ImportReport, write_import
    from seeu_data.importers.common import with_user_masks
    from seeu_data.store.manifest import provenance

    cfg.check()
    job = with_user_masks(cfg.source.plan(), cfg.source)
    report = ImportReport(format=cfg.format)
    write_import(
        job.items,
        cfg.out,
        report,
        params=job.params,
        provenance=provenance(f"import {cfg.format}", job.inputs),
        strict=cfg.strict,
        progress=cfg.progress,
        total=job.total,
        fsync=cfg.fsync,
        force=cfg.force,
        verify=cfg.verify,
        engine=cfg.engine,
        ray_address=cfg.ray_address,
        workers=cfg.workers if cfg.workers is not None else default_workers(),
    )
    return report
