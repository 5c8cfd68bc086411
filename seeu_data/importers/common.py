"""Shared importer machinery: skipped-scene records, image probing, the streaming writer loop and its resume."""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import asdict, dataclass, field, fields, replace
from functools import partial
from itertools import takewhile
from pathlib import Path

import numpy as np

from seeu_data.errors import SeeUError
from seeu_data.importers.prefetch import prefetch
from seeu_data.limits import MAX_PIXELS
from seeu_data.masks import MASK_CONVENTIONS, masks_from_folder
from seeu_data.settings import parse_pixels, setting
from seeu_data.store.arrow_io import BytesLike
from seeu_data.store.dataset_check import check_image
from seeu_data.store.image_header import decode_check
from seeu_data.store.manifest import FileEntry, read_manifest
from seeu_data.store.overlap_table import OVERLAP_FILES
from seeu_data.store.posed import POSED_FILES, PosedDatasetWriter, PosedScene, scene_overlap
from seeu_data.store.resume import Journal, file_intact, file_stat, files_fingerprint, stamp_of, sweep

RESUME_JOURNAL = ".import-progress.jsonl"  # files finished by a running (or interrupted) import
_UNIT_END = object()


@dataclass(kw_only=True)
class ReadSettings:
    """How every importer reads images: the base of each format's config (`--verify-decode`, `--max-pixels`,
    a user's own mask folder: `--masks`, `--mask-convention`, applied by `with_user_masks`)."""

    verify_decode: bool = setting(False, "fully decode every image (slow); default: header + trailer check")
    max_pixels: int = setting(
        MAX_PIXELS,
        "refuse images whose header declares more than N pixels (width x height): a tiny file declaring "
        "60000x60000 would make later stages allocate gigabytes",
        parse=parse_pixels,
        metavar="N",
    )
    masks: Path | None = setting(
        None,
        "folder of your own per-frame masks (DIR/<scene id>/ when present, else DIR/), matched to frames by file "
        "name, else by the last number in the name; each of its frame's size",
        metavar="DIR",
    )
    mask_convention: str = setting(
        "exclude",
        "what nonzero mask pixels are: excluded (moving content; 0 = kept) or kept (0 = excluded, as nerfstudio)",
        choices=MASK_CONVENTIONS,
    )


def recorded_params(cfg: ReadSettings, format: str, **resolved) -> dict:
    """The manifest's params of an import: the format, every field of the format's config but
    `max_pixels` (paths as text, sets sorted), then the `resolved` values (near/far from a preset,
    the scans found) in place of the fields they resolve."""

    def plain(v):
        if isinstance(v, Path):
            return str(v)
        if isinstance(v, (set, frozenset)):
            return sorted(v)
        return list(v) if isinstance(v, tuple) else v

    unrecorded = {"max_pixels"} | ({"masks", "mask_convention"} if cfg.masks is None else set())
    params = {f.name: plain(getattr(cfg, f.name)) for f in fields(cfg) if f.name not in unrecorded}
    return {"format": format, **params, **resolved}


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
        return {
            "format": self.format,
            "imported_scenes": self.scenes,
            "imported_frames": self.frames,
            "skipped_scenes": len(self.skipped),
            "skipped": [{"scene_id": s.scene_id, "reason": s.reason} for s in self.skipped],
            **self.notes,
        }

    def count_dropped_frames(self, scene_meta: dict | None) -> None:
        """Add the frames an importer dropped from an imported scene (`meta["skipped_frames"]`: a
        list of {"frame", "reason"}, e.g. a missing image or a path leading outside the dataset)."""
        dropped = len((scene_meta or {}).get("skipped_frames") or [])
        if dropped:
            self.notes["skipped_frames"] = self.notes.get("skipped_frames", 0) + dropped

    def summary_line(self, out_dir: Path | str) -> str:
        line = f"imported {self.scenes} scenes ({self.frames} frames) from {self.format} into {out_dir}"
        if self.notes.get("skipped_frames"):
            line += f"; dropped {self.notes['skipped_frames']} frames (named in each scene's meta.skipped_frames)"
        if self.notes.get("resumed_files"):
            line += (
                f" ({self.notes['resumed_scenes']} scenes in {self.notes['resumed_files']} files kept "
                "from a previous run)"
            )
        if self.skipped:
            names = ", ".join(s.scene_id for s in self.skipped[:5]) + (", ..." if len(self.skipped) > 5 else "")
            line += f"; skipped {len(self.skipped)} scenes ({names}): see the manifest's report"
        return line


def probe_images(
    images: Sequence[BytesLike], names: Sequence[str], verify_decode: bool = False, max_pixels: int = MAX_PIXELS
) -> tuple[str, np.ndarray, np.ndarray]:
    """Format and sizes of a scene's encoded frames: `(format, width (N,), height (N,))`.

    Header parse plus trailer check per image (`dataset_check.check_image`: also refuses a header
    declaring more than `max_pixels`, so nothing decodes a header bomb); a full OpenCV decode after
    it when `verify_decode`. Raises SeeUError naming the frame when one fails, or when a scene mixes
    JPEG and PNG (a posed scene holds one format).
    """
    n = len(images)
    width = np.empty(n, dtype=np.int32)
    height = np.empty(n, dtype=np.int32)
    fmt = None
    for i, (data, name) in enumerate(zip(images, names)):
        info = check_image(data, None, None, name, max_pixels)
        if verify_decode:
            decode_check(data, name)
        if fmt is None:
            fmt = info.format
        elif info.format != fmt:
            raise SeeUError(f"scene mixes {fmt} and {info.format} images", name)
        width[i], height[i] = info.width, info.height
    if fmt is None:
        raise SeeUError("scene has no frames")
    return fmt, width, height


@dataclass(frozen=True)
class ImportUnit:
    """A piece of the input a re-run can skip when its output is already complete (a pixelSplat chunk,
    a RE10K camera file, a DTU scan, a whole COLMAP / nerfstudio scene).

    `key` names it (a chunk file name), `fingerprint` changes when its content may have (size and
    mtime of every file it reads, `resume.file_fingerprint` / `files_fingerprint`), `read()` yields its
    scenes and skips. A unit with key None is read on every run (bookkeeping such as scenes asked
    for but not found); when it yields scenes, the file holding them is not resumable.
    """

    key: str | None
    fingerprint: str
    read: Callable[[], Iterable[PosedScene | SkippedScene]]


@dataclass(frozen=True)
class ImportJob:
    """One import, as its format's `plan()` prepares it for `write_import`: `items` (scenes and skips,
    or an `ImportPlan` that can resume), `params` recorded in the manifest (`recorded_params`), `total`
    units for the progress bar (None: unknown), `inputs` named in the provenance."""

    items: Iterable[PosedScene | SkippedScene] | ImportPlan
    params: dict
    total: int | None
    inputs: list[str]


@dataclass
class ImportPlan:
    """Units of an importer that supports resuming (`write_import` skips units whose output is complete).

    `seen` receives the scene ids (imported or skipped) of the resumed units, for importers whose
    trailing bookkeeping unit reports what was asked for but not found; `fingerprint` covers inputs
    every unit depends on (index files, sidecars): when it changes nothing is resumed.
    """

    units: list[ImportUnit]
    seen: set[str] = field(default_factory=set)
    fingerprint: str = ""


class _ImportWriter(PosedDatasetWriter):
    """`PosedDatasetWriter` fed with scenes checked and converted on the reading thread.

    Files close when they reach the target size at a scene boundary (`at_units=False`) or, for
    resumable units, only at the end of a unit, so that every file covers whole units.
    """

    def finish_file(self, force: bool) -> FileEntry | None:
        """Close the open file when it reached the target size (or `force`); its entry, else None."""
        if self._writer is None or not (force or self._bytes >= self.target_file_bytes):
            return None
        self._finish_file()
        return self.files[-1]

    def restore(self, record: dict) -> None:
        """Take a verified file of a previous run (and its overlap file) as this run's next file."""
        self.files.append(FileEntry(**record["file"]))
        self.overlap_files.append(record["overlap"])
        self.scenes.extend(record["scenes"])
        self._seen.update(s["scene_id"] for s in record["scenes"])


def user_masks(scene: PosedScene, cfg: ReadSettings) -> PosedScene | SkippedScene:
    """`scene` with the masks of `cfg.masks` (`masks.masks_from_folder`: DIR/<scene id>/ when it is a
    folder, else DIR/); a SkippedScene with the one-line reason when none matches or a size differs, or
    when the importer undistorted the frames (their masks would need the same warp)."""
    assert cfg.masks is not None
    folder = Path(cfg.masks) / scene.scene_id
    folder = folder if folder.is_dir() else Path(cfg.masks)
    if scene.meta.get("undistorted"):
        return SkippedScene(
            scene.scene_id,
            "--masks with frames the importer undistorted (undistort the masks too, and import undistorted frames)",
        )
    try:
        sizes = list(zip(np.asarray(scene.width).tolist(), np.asarray(scene.height).tolist()))
        masks = masks_from_folder(
            folder,
            scene.source_name or [""] * len(scene),
            np.asarray(scene.source_frame).tolist(),
            sizes,
            cfg.mask_convention,
            cfg.max_pixels,
        )
    except SeeUError as exc:
        return SkippedScene(scene.scene_id, f"--masks: {exc}")
    scene.masks = masks
    scene.meta = {
        **scene.meta,
        "masks": {
            "source": str(folder),
            "convention": cfg.mask_convention,
            "frames": sum(m is not None for m in masks),
        },
    }
    return scene


def _masked_read(
    read: Callable[[], Iterable[PosedScene | SkippedScene]], cfg: ReadSettings
) -> Iterator[PosedScene | SkippedScene]:
    for item in read():
        yield user_masks(item, cfg) if isinstance(item, PosedScene) else item


def with_user_masks(job: ImportJob, cfg: ReadSettings) -> ImportJob:
    """`job` whose scenes get the masks of `cfg.masks` (`user_masks`); the mask files join the resume
    fingerprint. `job` as it is when `cfg.masks` is None."""
    if cfg.masks is None:
        return job
    folder = Path(cfg.masks)
    if not folder.is_dir():
        raise SeeUError("--masks: not a folder", folder)

    if isinstance(job.items, ImportPlan):
        plan = job.items
    else:
        items = job.items
        plan = ImportPlan([ImportUnit(None, "", lambda: items)])
    units = [ImportUnit(u.key, u.fingerprint, partial(_masked_read, u.read, cfg)) for u in plan.units]
    masks_seen = files_fingerprint(sorted(p for p in folder.rglob("*") if p.is_file()))
    return replace(job, items=ImportPlan(units, plan.seen, plan.fingerprint + masks_seen))


def _prepare(item: PosedScene | SkippedScene) -> PosedScene | SkippedScene:
    """On the reading side (thread, worker process or Ray task): check a scene (a SkippedScene when it
    fails) and measure its view overlap, which the writer stores with it."""
    if isinstance(item, PosedScene):
        try:
            item.check()
            item.overlap = scene_overlap(item)
        except SeeUError as exc:
            return SkippedScene(item.scene_id, str(exc))
    return item


def read_checked(read: Callable[[], Iterable[PosedScene | SkippedScene]]) -> list[PosedScene | SkippedScene]:
    """A unit's items, each checked (`_prepare`): what a Ray task returns for a unit (`ray_import`)."""
    return [_prepare(item) for item in read()]


def _read_records(out_dir: Path, key: str) -> list[dict]:
    """Files a previous run with the same stamp `key` completed, as journal records: the journal of
    an interrupted run, else the manifest's report."""
    records = list(takewhile(lambda r: r.get("stamp") == key, Journal(out_dir / RESUME_JOURNAL).read()))
    if records:
        return records
    try:
        doc = read_manifest(out_dir, expect_schema="seeu.posed_frames")
    except SeeUError:
        return []
    resume = (doc.get("report") or {}).get("resume") or {}
    if resume.get("key") != key:
        return []
    entries = {f["path"]: f for f in doc["files"]}
    scenes_in: dict[str, list[dict]] = {}
    for scene in doc.get("scenes", []):
        scenes_in.setdefault(scene["file"], []).append(scene)
    overlaps = {f["posed"]: f for f in (doc.get("overlap") or {}).get("files", [])}
    for rec in resume.get("files", []):
        if rec.get("file") not in entries or rec["file"] not in overlaps:
            break
        records.append(
            {
                "unit": rec["file"],
                "stamp": key,
                "file": entries[rec["file"]],
                "mtime_ns": rec.get("mtime_ns"),
                "overlap": overlaps[rec["file"]],
                "overlap_mtime_ns": rec.get("overlap_mtime_ns"),
                "units": rec["units"],
                "skipped": rec["skipped"],
                "scenes": scenes_in.get(rec["file"], []),
            }
        )
    return records


def _resumable_prefix(
    out_dir: Path, records: list[dict], units: list[ImportUnit], name_of, verify: bool = False
) -> tuple[list[dict], int]:
    """The records (in order) whose units are the next planned keyed units and whose file and overlap
    file are intact (`resume.file_intact`: their recorded size and mtime, or sha256 with `verify`), and
    how many keyed units they cover."""
    keyed = [[u.key, u.fingerprint] for u in units if u.key is not None]
    done: list[dict] = []
    pos = 0
    for i, rec in enumerate(records):
        entry = rec.get("file") or {}
        overlap = rec.get("overlap") or {}
        n = len(rec.get("units") or [])
        if n == 0 or rec["units"] != keyed[pos : pos + n] or entry.get("path") != name_of(i):
            break
        intact = [
            e and file_intact(out_dir / e["path"], e["bytes"], e["sha256"], rec.get(mtime), verify)
            for e, mtime in ((entry, "mtime_ns"), (overlap, "overlap_mtime_ns"))
        ]
        if not all(intact):
            break
        done.append(rec)
        pos += n
    return done, pos


def write_import(
    items: Iterable[PosedScene | SkippedScene] | ImportPlan,
    out_dir: str | Path,
    report: ImportReport,
    params: dict,
    provenance: dict,
    strict: bool = False,
    progress: bool = False,
    total: int | None = None,
    target_file_bytes: int = 256 << 20,
    fsync: bool = False,
    force: bool = False,
    verify: bool = False,
    engine: str = "local",
    ray_address: str | None = None,
    workers: int = 1,
) -> ImportReport:
    """Stream importer output into a posed-frames directory; the manifest (with the report) goes last.

    The importer runs in a background thread a few scenes ahead (`prefetch.prefetch`), where each
    scene is also checked (`PosedScene.check`: finite, orthonormal poses, valid near/far), so reading
    the input overlaps with writing and hashing the output. A scene that fails the check is skipped
    like the importer's own skips. `strict` turns the first skip into an error. `fsync`: every posed
    file and the manifest are fsynced before their rename. Raises SeeUError, leaving no manifest,
    when nothing usable remains.

    Resume: given an `ImportPlan` (units, e.g. pixelSplat chunks), files close only at unit ends, and
    each finished file is recorded (units covered, scenes, skips, bytes, sha256) in a journal
    (`RESUME_JOURNAL`, a `resume.Journal` stamped with the parameters and input fingerprint; removed
    when the manifest is written, the manifest's `report.resume` keeps the same for a later re-run)
    as soon as it is in place. A re-run with the same parameters and inputs keeps the leading files
    whose units are unchanged and that are still the files recorded (`resume.file_intact`: size and
    mtime, sha256 with `verify`), and reads only the units after them; `force` keeps none.

    `engine="ray"`: the units with a key are read on a Ray cluster at `ray_address` (None: a local
    instance), as `ray_import.read_units` says; everything else, the writing included, stays here.
    `workers` > 1 (local engine): they are read in that many worker processes
    (`read_ahead.read_in_processes`), the same bytes written.
    """
    from tqdm import tqdm

    out_dir = Path(out_dir)
    plan = items if isinstance(items, ImportPlan) else ImportPlan([ImportUnit(None, "", lambda: items)])
    units = plan.units
    resumable = any(u.key is not None for u in units)
    key = stamp_of({"params": params, "inputs": plan.fingerprint})
    out_dir.mkdir(parents=True, exist_ok=True)
    records = _read_records(out_dir, key) if resumable and not force else []
    name_of = lambda i: f"posed-{i:05d}.arrow"  # noqa: E731  (PosedDatasetWriter's file names)
    done, covered = _resumable_prefix(out_dir, records, units, name_of, verify)
    journal = Journal(out_dir / RESUME_JOURNAL, fsync)
    if resumable:
        journal.reset(done)  # before the manifest goes
    else:
        journal.remove()
    writer = _ImportWriter(
        out_dir, params=params, provenance=provenance, target_file_bytes=target_file_bytes, fsync=fsync
    )
    sweep(out_dir, POSED_FILES, keep={r["file"]["path"] for r in done})  # files not kept, partial writes
    sweep(out_dir, OVERLAP_FILES, keep={r["overlap"]["path"] for r in done})
    for rec in done:
        writer.restore(rec)
        report.scenes += len(rec["scenes"])
        report.frames += sum(s["num_frames"] for s in rec["scenes"])
        for s in rec["scenes"]:
            report.count_dropped_frames(s.get("meta"))
        report.skipped.extend(SkippedScene(sid, reason) for sid, reason in rec["skipped"])
        plan.seen.update(s["scene_id"] for s in rec["scenes"])
        plan.seen.update(sid for sid, _ in rec["skipped"])
    if done:
        report.notes["resumed_files"] = len(done)
        report.notes["resumed_scenes"] = report.scenes
    skip_units = set()
    pos = 0
    for i, u in enumerate(units):
        if u.key is not None:
            if pos < covered:
                skip_units.add(i)
            pos += 1

    todo = [i for i in range(len(units)) if i not in skip_units]
    keyed = [partial(read_checked, units[i].read) for i in todo if units[i].key is not None]
    in_processes = engine == "local" and workers > 1 and len(keyed) > 1

    def stream():
        remote: Iterator[list] = iter(())
        if engine == "ray":
            from seeu_data.importers.ray_import import read_units

            remote = read_units(keyed, ray_address)
        elif in_processes:
            from seeu_data.importers.read_ahead import read_in_processes

            remote = read_in_processes(keyed, workers, out_dir)
        for i in todo:
            if (engine == "ray" or in_processes) and units[i].key is not None:
                items = next(remote)
                plan.seen.update(item.scene_id for item in items)  # what the unit's own read adds there
            else:
                items = (_prepare(item) for item in units[i].read())
            for item in items:
                yield i, item
            yield i, _UNIT_END

    bar = tqdm(
        total=total,
        unit="scene",
        desc=f"import {report.format}",
        file=sys.stderr,
        disable=not progress,
        dynamic_ncols=True,
        initial=report.scenes + len(report.skipped),
    )
    cur_units: list[list[str]] = []
    cur_skipped: list[list[str]] = []
    recordable = True
    new_records = list(done)

    def record_file(entry: FileEntry | None) -> None:
        nonlocal cur_units, cur_skipped, recordable
        if entry is None:
            return
        if resumable and recordable and cur_units:
            rec = {
                "unit": entry.path,
                "stamp": key,
                "units": cur_units,
                "skipped": cur_skipped,
                "scenes": list(reversed(list(takewhile(lambda s: s["file"] == entry.path, reversed(writer.scenes))))),
                "file": asdict(entry),
                "mtime_ns": file_stat(out_dir / entry.path),
                "overlap": writer.overlap_files[-1],
                "overlap_mtime_ns": file_stat(out_dir / writer.overlap_files[-1]["path"]),
            }
            new_records.append(rec)
            journal.add(rec)
        else:
            recordable = False  # a file not recorded ends what a re-run can resume
        cur_units, cur_skipped = [], []

    try:
        # worker processes read ahead themselves (and are forked from this thread, not a reading thread)
        scenes = stream() if in_processes else prefetch(stream())
        for i, item in scenes:
            unit = units[i]
            if item is _UNIT_END:
                if unit.key is not None:
                    cur_units.append([unit.key, unit.fingerprint])
                    record_file(writer.finish_file(force=False))
                continue
            bar.update(1)
            if isinstance(item, PosedScene):
                try:
                    writer.add_checked(item, may_close=not resumable or unit.key is None)
                except SeeUError as exc:
                    item = SkippedScene(item.scene_id, str(exc))
                else:
                    report.scenes += 1
                    report.frames += len(item)
                    report.count_dropped_frames(item.meta)
                    if unit.key is None:
                        recordable = False  # files from here on are not resumable
                    continue
            if strict:
                raise SeeUError(f"scene {item.scene_id}: {item.reason} (--strict)")
            report.skipped.append(item)
            if unit.key is not None:
                cur_skipped.append([item.scene_id, item.reason])
            bar.set_postfix(skipped=len(report.skipped))
        if report.scenes == 0:
            reasons = "; ".join(f"{s.scene_id}: {s.reason}" for s in report.skipped[:3])
            raise SeeUError(
                "no usable scene to import" + (f" ({len(report.skipped)} skipped; {reasons})" if report.skipped else "")
            )
        record_file(writer.finish_file(force=True))
        writer.report = report.as_dict()
        if resumable:
            writer.report["resume"] = {
                "key": key,
                "files": [
                    {
                        "file": r["file"]["path"],
                        "mtime_ns": r.get("mtime_ns"),
                        "units": r["units"],
                        "skipped": r["skipped"],
                    }
                    for r in new_records
                ],
            }
    except BaseException as exc:
        scenes.close()  # the readers end now (a worker pool with the error, not when it is collected)
        writer.__exit__(type(exc), exc, None)
        raise
    finally:
        bar.close()
    writer.close()
    journal.remove()
    return report
