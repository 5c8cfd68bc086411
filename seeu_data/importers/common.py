"""Shared importer machinery: skipped-scene records, image probing, the streaming writer loop."""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from ..errors import SeeUError
from ..image_header import decode_check, image_info
from ..posed import PosedDatasetWriter, PosedScene
from .prefetch import prefetch


@dataclass(frozen=True)
class SkippedScene:
    """A scene an importer leaves out, with the one-line reason (shown to the user, kept in the report)."""

    scene_id: str
    reason: str


@dataclass
class ImportReport:
    """What an import did; stored as the manifest's `report` and summarised on one line."""

    format: str
    scenes: int = 0
    frames: int = 0
    skipped: list[SkippedScene] = field(default_factory=list)
    notes: dict = field(default_factory=dict)

    def as_dict(self) -> dict:
        return {"format": self.format, "imported_scenes": self.scenes, "imported_frames": self.frames,
                "skipped_scenes": len(self.skipped),
                "skipped": [{"scene_id": s.scene_id, "reason": s.reason} for s in self.skipped],
                **self.notes}

    def summary_line(self, out_dir: Path | str) -> str:
        line = f"imported {self.scenes} scenes ({self.frames} frames) from {self.format} into {out_dir}"
        if self.skipped:
            names = ", ".join(s.scene_id for s in self.skipped[:5]) + (", ..." if len(self.skipped) > 5 else "")
            line += f"; skipped {len(self.skipped)} scenes ({names}): see the manifest's report"
        return line


def probe_images(images: Sequence[bytes], names: Sequence[str], verify_decode: bool = False
                 ) -> tuple[str, np.ndarray, np.ndarray]:
    """Format and sizes of a scene's encoded frames: `(format, width (N,), height (N,))`.

    Header parse plus trailer check per image (see `seeu_data.image_header`); a full OpenCV decode
    when `verify_decode`. Raises SeeUError naming the frame when one fails, or when a scene mixes
    JPEG and PNG (a posed scene holds one format).
    """
    check = decode_check if verify_decode else image_info
    n = len(images)
    width = np.empty(n, dtype=np.int32)
    height = np.empty(n, dtype=np.int32)
    fmt = None
    for i, (data, name) in enumerate(zip(images, names)):
        info = check(data, name)
        if fmt is None:
            fmt = info.format
        elif info.format != fmt:
            raise SeeUError(f"scene mixes {fmt} and {info.format} images", name)
        width[i], height[i] = info.width, info.height
    if fmt is None:
        raise SeeUError("scene has no frames")
    return fmt, width, height


def write_import(items: Iterable[PosedScene | SkippedScene], out_dir: str | Path, report: ImportReport,
                 params: dict, provenance: dict, strict: bool = False, progress: bool = False,
                 total: int | None = None) -> ImportReport:
    """Stream importer output into a posed-frames directory; the manifest (with the report) goes last.

    The importer runs in a background thread a few scenes ahead (`prefetch.prefetch`), so reading
    the input overlaps with writing and hashing the output. A scene whose cameras fail `PosedScene.check` (non-finite, non-orthonormal, bad near/far) is
    skipped like the importer's own skips. `strict` turns the first skip into an error. Raises
    SeeUError, leaving no manifest, when nothing usable remains.
    """
    from tqdm import tqdm

    out_dir = Path(out_dir)
    writer = PosedDatasetWriter(out_dir, params=params, provenance=provenance)
    bar = tqdm(total=total, unit="scene", desc=f"import {report.format}", file=sys.stderr,
               disable=not progress, dynamic_ncols=True)
    try:
        for item in prefetch(items):
            bar.update(1)
            if isinstance(item, PosedScene):
                try:
                    writer.add(item)
                except SeeUError as exc:
                    item = SkippedScene(item.scene_id, str(exc))
                else:
                    report.scenes += 1
                    report.frames += len(item)
                    continue
            if strict:
                raise SeeUError(f"scene {item.scene_id}: {item.reason} (--strict)")
            report.skipped.append(item)
            bar.set_postfix(skipped=len(report.skipped))
        if report.scenes == 0:
            reasons = "; ".join(f"{s.scene_id}: {s.reason}" for s in report.skipped[:3])
            raise SeeUError("no usable scene to import" + (f" ({len(report.skipped)} skipped; {reasons})"
                                                          if report.skipped else ""))
        writer.report = report.as_dict()
    except BaseException as exc:
        writer.__exit__(type(exc), exc, None)
        raise
    finally:
        bar.close()
    writer.close()
    return report
