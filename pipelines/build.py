"""`seeu build`: posed chunks -> sample plan -> shard specs -> shards (local pool or Ray) -> manifest.

Stages:

1. Scan the posed-frames directories with the one dataset validator (`dataset_check.check_dataset`:
   manifest, files present with the listed size, rows and schema metadata, finite rigid cameras,
   frames numbered 0..n-1 per scene, scene rows inside their files, image headers equal to the
   recorded sizes and under `max_pixels`; sha256 too with `verify`), before anything is
   written. Scene ids must be unique across inputs.
2. Plan on the driver (indices only, cheap): interp/extrap samples per scene (`seeu_data.build.sampling`,
   scenes in sorted order, drawn lazily so that the first shards are written while the rest is
   planned; context pairs by frame gap or by view overlap, `--pairs`), or the entries of an
   evaluation index (file order; entries naming a missing scene or frame are reported and not
   written; each row's context overlap is recorded in the report for `seeu eval`'s bins).
3. Cut the plan into shards of about `shard_bytes`, estimated from the source images' byte sizes
   (scaled by the pixel ratio when resizing); each `triples.ShardSpec` is handed on as soon as it is
   complete.
4. Materialise every spec with `triples.write_shard`: `shard-XXXXX.arrow`, written atomically
   (the local process pool and Ray run the same function: byte-identical shards; a `ShardResult`
   each), its sha256 computed as it is written. Resume
   (`seeu_data.store.resume`): a shard already on disk is kept when a previous run recorded it (its
   manifest, or the journal `.build-progress.jsonl` of an interrupted run: one unit per shard,
   stamped with its plan hash) and it still has the recorded size and sha256, the spec's plan hash
   in its metadata and the planned row count (`resumable_shard`). Shards no run recorded, shards
   the plan no longer has and partial writes are swept (`resume.sweep`).
5. Write `manifest.json` last (files with rows/bytes/sha256, full build parameters, report), then
   drop the journal. Files are renamed into place atomically; fsynced before the rename only with
   `BuildConfig.fsync` (`--fsync`).
"""

from __future__ import annotations

import hashlib
import sys
from collections.abc import Iterable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from seeu_data.build.eval_index import FORMATS as EVAL_INDEX_FORMATS
from seeu_data.build.sampling import (
    Sample,
    SamplingConfig,
    make_sample,
    min_scene_length,
    pair_rule,
    sample_overlap_scene,
    sample_scene,
)
from seeu_data.build.shard_task import ShardResult, materialise
from seeu_data.build.triples import PLAN_KEY, SCHEMA, ImageOptions, SceneRows, ShardSpec
from seeu_data.errors import SeeUError
from seeu_data.interrupts import raise_if_terminated
from seeu_data.limits import (
    MAX_IMAGE_SIDE,
    MAX_PIXELS,
    MAX_PIXELS_CEILING,
    MAX_ROWS_PER_BATCH,
    MAX_SEED,
    MAX_WORKERS,
    check_range,
)
from seeu_data.overlap import OverlapTable, context_overlap
from seeu_data.process_pool import default_workers
from seeu_data.settings import parse_bytes, setting
from seeu_data.store.arrow_io import ReleasableIpcFile
from seeu_data.store.dataset_check import check_dataset
from seeu_data.store.json_file import read_json
from seeu_data.store.manifest import MANIFEST_NAME, FileEntry, provenance, read_manifest, write_manifest
from seeu_data.store.out_lock import locks_output
from seeu_data.store.posed import PosedDataset
from seeu_data.store.resume import Journal, file_intact, file_stat, files_fingerprint, stamp_of, sweep
from seeu_data.store.schema import schema_version

SHARD_PATTERN = "shard-{:05d}.arrow"
SHARD_FILES = "shard-*.arrow"
PROGRESS_NAME = ".build-progress.jsonl"  # shards completed by a running (or interrupted) build
_VIEW_OVERHEAD_BYTES = 200  # per-view camera/metadata bytes in a row (for the shard-size estimate)
MAX_SHARD_BYTES = 1 << 30  # list<binary> has int32 offsets: a shard's image bytes must stay < 2 GiB
MAX_REPORTED_PROBLEMS = 1000  # per-entry eval-index problems kept in the manifest (all are counted)


@dataclass(frozen=True, kw_only=True)
class BuildConfig:
    """Everything `seeu build` needs. mode: 'interp' | 'extrap' | 'eval'."""

    inputs: tuple[str, ...] = setting(help="posed-frames directories (hold manifest.json)", positional=True, many=True)
    out: str | Path
    mode: str = setting("interp", "interp, extrap or eval (the module docstring)", choices=("interp", "extrap", "eval"))
    sampling: SamplingConfig = field(default_factory=SamplingConfig)  # its mode: `mode` (unused with eval)
    index_path: str | None = setting(None, "eval: evaluation index JSON file", flag="--index", metavar="INDEX")
    index_format: str = setting(
        "auto", "eval: format of --index (default: detected)", choices=("auto", *EVAL_INDEX_FORMATS)
    )
    seed: int = setting(0, "random seed")
    image: ImageOptions = field(default_factory=ImageOptions)
    shard_bytes: int = setting(
        128_000_000, "target shard size, e.g. 128MB or 64MiB", flag="--shard-size", parse=parse_bytes, metavar="SIZE"
    )
    rows_per_batch: int = setting(64, "rows per Arrow record batch")
    engine: str = setting("local", "local process pool or Ray Data; identical shards", choices=("local", "ray"))
    workers: int | None = setting(
        None,
        f"worker processes (at most {MAX_WORKERS}) of the local engine (default: the CPU count, at most 8; 1 when "
        "copying images on up to 4 cores, where one process hashes on threads while it writes)",
        metavar="N",
    )
    ray_address: str | None = setting(None, "Ray cluster address (default: start a local instance)")
    progress: bool = False  # a progress bar on stderr
    verify: bool = setting(
        False,
        "hash (sha256) the posed inputs before anything else and the shards a re-run keeps; default: a "
        "file whose size and mtime are those recorded is taken as its recorded sha256",
        aliases=("--verify-inputs",),
    )
    fsync: bool = False  # fsync every shard and the manifest before its rename (`--fsync`)
    force: bool = False  # rebuild every shard instead of keeping those a previous run completed (`--force`)
    near: float | None = setting(
        None,
        "near plane for every view instead of the posed data's (e.g. 1 with --far 100: the peers' "
        "RealEstate10K values); default: the data's",
    )
    far: float | None = setting(None, "far plane for every view (with --near)")
    max_pixels: int = MAX_PIXELS  # largest input image (width x height), `--max-pixels`

    @property
    def near_far(self) -> tuple[float, float] | None:
        """The near/far planes overriding the posed data's (None: the data's)."""
        return None if self.near is None or self.far is None else (self.near, self.far)

    def check(self) -> None:
        """One-line SeeUError for a bad value (named by its `seeu build` flag), before anything is read."""
        if self.mode not in ("interp", "extrap", "eval"):
            raise SeeUError(f"unknown mode {self.mode!r} (interp, extrap or eval)")
        if not self.inputs:
            raise SeeUError("no posed-frames directory given")
        if self.mode == "eval" and not self.index_path:
            raise SeeUError("--mode eval needs --index FILE")
        if self.mode != "eval" and self.index_path:
            raise SeeUError("--index is only used with --mode eval")
        if self.mode != "eval" and self.sampling.mode != self.mode:
            raise SeeUError(f"sampling config mode {self.sampling.mode!r} differs from build mode {self.mode!r}")
        if not 0 < self.shard_bytes <= MAX_SHARD_BYTES:
            raise SeeUError(
                f"shard size must be in 1 byte .. {MAX_SHARD_BYTES >> 20} MiB (the image column has 32-bit offsets)"
            )
        if not 1 <= self.image.jpeg_quality <= 100:
            raise SeeUError("--jpeg-quality must be in 1..100")
        check_range(self.rows_per_batch, "--rows-per-batch", 1, MAX_ROWS_PER_BATCH)
        if self.engine not in ("local", "ray"):
            raise SeeUError(f"unknown engine {self.engine!r} (local or ray)")
        if self.workers is not None:  # None: `default_workers`
            check_range(self.workers, "--workers", 1, MAX_WORKERS)
        for side in self.image.resize or ():
            check_range(side, "--resize", 1, MAX_IMAGE_SIDE)
        check_range(self.seed, "--seed", 0, MAX_SEED)
        check_range(self.max_pixels, "--max-pixels", 1, MAX_PIXELS_CEILING)
        if (self.near is None) != (self.far is None):
            raise SeeUError("--near and --far go together")
        if self.near_far is not None and not (0 < self.near_far[0] < self.near_far[1] < float("inf")):
            raise SeeUError(f"--near/--far must satisfy 0 < near < far, got {self.near_far[0]} / {self.near_far[1]}")

    def params(self) -> dict:
        """The build parameters recorded in the manifest (engine and workers are not: they do not change bytes)."""
        out = {
            "inputs": [str(Path(p).resolve()) for p in self.inputs],
            "mode": self.mode,
            "seed": self.seed,
            "image": self.image.as_dict(),
            "shard_bytes": self.shard_bytes,
            "rows_per_batch": self.rows_per_batch,
        }
        if self.near_far is not None:
            out["near_far"] = list(self.near_far)
        if self.mode == "eval":
            out.update(
                index=str(Path(self.index_path).resolve()) if self.index_path else None, index_format=self.index_format
            )
        else:
            out["sampling"] = asdict(self.sampling)
        return out


def scan_inputs(
    inputs: tuple[str, ...] | list[str], verify: bool = False, max_pixels: int = MAX_PIXELS
) -> dict[str, SceneRows]:
    """Scene id -> where its rows are, over all posed directories (duplicates refused), each checked
    by `dataset_check.check_dataset` (sha256 only with `verify`)."""
    scenes: dict[str, SceneRows] = {}
    for root in inputs:
        root_p = Path(root)
        manifest = check_dataset(root_p, check_sha=verify, max_pixels=max_pixels, expect_schema="seeu.posed_frames")[
            "manifest"
        ]
        sha = {entry["path"]: entry["sha256"] for entry in manifest["files"]}
        for s in manifest.get("scenes", []):
            if s["scene_id"] in scenes:
                raise SeeUError(
                    f"scene id {s['scene_id']!r} appears in two inputs "
                    f"({Path(scenes[s['scene_id']].path).parent} and {root_p})",
                    root_p,
                )
            scenes[s["scene_id"]] = SceneRows(
                str((root_p / s["file"]).resolve()),
                int(s["row_start"]),
                int(s["num_frames"]),
                sha[s["file"]],
            )
    return scenes


# ---------------------------------------------------------------------------------------------
# Planning
# ---------------------------------------------------------------------------------------------


@dataclass
class Plan:
    samples: Iterable[Sample]  # in order; for the sampled modes drawn as consumed (iterate once)
    total: int  # how many `samples` yields
    report: dict


class InputScenes:
    """The posed datasets of the inputs, by scene id: cameras and overlap tables read when asked."""

    def __init__(self, inputs: tuple[str, ...] | list[str]):
        self._ds: dict[str, PosedDataset] = {}
        for root in inputs:
            ds = PosedDataset(root)
            self._ds.update({sid: ds for sid in ds.scene_ids})

    def cameras(self, scene_id: str) -> tuple[np.ndarray, np.ndarray, float, float]:
        return self._ds[scene_id].load_cameras(scene_id)

    def overlap(self, scene_id: str) -> OverlapTable:
        return self._ds[scene_id].overlap(scene_id)

    def stored_overlap(self, scene_id: str) -> OverlapTable | None:
        return self._ds[scene_id].stored_overlap(scene_id)


def plan_sampled(cfg: BuildConfig, scenes: dict[str, SceneRows]) -> Plan:
    """interp / extrap: `samples_per_scene` samples of every usable scene, scenes sorted by id.

    Each scene's context pairs come by frame gap or by view overlap (`sampling.pair_rule`: with
    ``--pairs auto`` the poses are read to tell a camera path from a photo set); with ``gap`` alone
    nothing but the frame counts is read. The samples are drawn lazily, scene by scene, so the first
    shards are written while the rest of the plan is drawn; which scenes are usable is settled first
    (a scene gives all its samples or none)."""
    s = cfg.sampling
    need = min_scene_length(s)
    views = InputScenes(cfg.inputs) if s.pairs != "gap" else None
    rule: dict[str, str] = {}
    draws_of: dict[str, list[Sample]] = {}  # overlap-rule scenes, drawn while settling usability
    for sid in sorted(scenes):
        n = scenes[sid].num_frames
        c2w = views.cameras(sid)[0] if views is not None and s.pairs == "auto" and n >= need else None
        rule[sid] = pair_rule(s, n, c2w)
        if rule[sid] == "overlap":
            assert views is not None
            c2w, intr, _, _ = views.cameras(sid)
            draws_of[sid] = sample_overlap_scene(s, views.overlap(sid), c2w, intr, sid, cfg.seed)
    used = [
        sid for sid in sorted(scenes) if (draws_of[sid] if rule[sid] == "overlap" else scenes[sid].num_frames >= need)
    ]
    short = sorted(sid for sid in set(scenes) - set(used) if rule[sid] == "gap")
    no_pair = sorted(sid for sid in set(scenes) - set(used) if rule[sid] == "overlap")
    report = {
        "scenes": len(scenes),
        "scenes_used": len(used),
        "scenes_skipped_too_short": len(short),
        "skipped_scene_examples": short[:20],
        "min_scene_frames": need,
        "samples": len(used) * s.samples_per_scene,
    }
    if s.pairs != "gap":
        report["pairs"] = {
            "gap": sum(1 for sid in used if rule[sid] == "gap"),
            "overlap": sum(1 for sid in used if rule[sid] == "overlap"),
            "overlap_scenes_without_a_pair": len(no_pair),
            "overlap_scenes_without_a_pair_examples": no_pair[:20],
            "overlap_range": [s.min_overlap, s.max_overlap],
        }

    def scene_samples(sid: str) -> list[Sample]:
        return draws_of[sid] if rule[sid] == "overlap" else sample_scene(s, scenes[sid].num_frames, sid, cfg.seed)

    draws = (sample for sid in used for sample in scene_samples(sid))
    return Plan(draws, len(used) * s.samples_per_scene, report)


def plan_eval(cfg: BuildConfig, scenes: dict[str, SceneRows]) -> Plan:
    """eval: exactly the entries of the index, in file order; problems reported per entry."""
    from seeu_data.build.eval_index import read_index

    if not cfg.index_path:
        raise SeeUError("--mode eval needs --index FILE")
    index = read_index(cfg.index_path, cfg.index_format)
    views = InputScenes(cfg.inputs)
    samples, problems = [], []
    overlaps: dict[str, float | str] = {}
    for e in index.entries:
        src = scenes.get(e.scene_id)
        if src is None:
            problems.append({"key": e.key, "scene_id": e.scene_id, "problem": "scene not in the posed data"})
            continue
        bad = [v for v in e.context + e.target if not 0 <= v < src.num_frames]
        if bad:
            problems.append(
                {"key": e.key, "scene_id": e.scene_id, "problem": f"frame(s) {bad} outside 0..{src.num_frames - 1}"}
            )
            continue
        samples.append(make_sample(e.scene_id, "eval", e.k, e.context, e.target))
        table = views.stored_overlap(e.scene_id) if e.overlap is None and len(e.context) > 1 else None
        if e.overlap is not None:
            overlaps[samples[-1].sample_id] = e.overlap
        elif table is not None:  # data without a stored table: not measured here (thousands of scenes)
            overlaps[samples[-1].sample_id] = round(context_overlap(table.matrix(), e.context), 4)
    kinds: dict[str, int] = {}
    for prob in problems:
        kind = "scene not in the posed data" if prob["problem"].startswith("scene") else "frames out of range"
        kinds[kind] = kinds.get(kind, 0) + 1
    report = {
        "index": index.path,
        "index_format": index.format,
        "index_keys": index.num_keys,
        "index_null_skipped": index.num_null,
        "index_entries": len(index.entries),
        "written": len(samples),
        "not_written": len(problems),
        "problems_by_kind": kinds,
        "problems": problems[:MAX_REPORTED_PROBLEMS],
        "problems_truncated": len(problems) > MAX_REPORTED_PROBLEMS,
        # each row's context overlap: the index entry's "overlap" (NoPoSplat's value or bin name), else
        # from the posed data's stored overlap table (`overlap.context_overlap`); `seeu eval` bins by it
        "context_overlap": overlaps,
    }
    if not samples:
        raise SeeUError(
            f"none of the {len(index.entries)} index entries match the posed data "
            f"(first problem: {problems[0]['key']}: {problems[0]['problem']})"
            if problems
            else "the index lists no entries",
            cfg.index_path,
        )
    return Plan(samples, len(samples), report)


class _ViewBytes:
    """Estimated stored bytes per frame of a scene: the image size, pixel-scaled when resizing, plus
    the row's other columns. The first time a scene of a posed file is asked for, the sizes of all the
    file's scenes are read from its image offsets (no image byte) and the file is released."""

    def __init__(self, scenes: dict[str, SceneRows], resize: tuple[int, int] | None):
        self.scenes, self.resize = scenes, resize
        self._sizes: dict[str, np.ndarray] = {}
        self._in_file: dict[str, list[str]] = {}
        for sid, src in scenes.items():
            self._in_file.setdefault(src.path, []).append(sid)

    def __call__(self, sample: Sample) -> float:
        if sample.scene_id not in self._sizes:
            self._read_file(self.scenes[sample.scene_id].path)
        return float(self._sizes[sample.scene_id][list(sample.views)].sum())

    def _read_file(self, path: str) -> None:
        # image sizes from the offsets, width, height: copied out batch by batch, the pages given back as it goes
        columns = [
            [
                np.array(x, np.float64)
                for x in (pc.binary_length(b.column("image")), b.column("width"), b.column("height"))
            ]
            for b in ReleasableIpcFile(path, random_access=True).batches()
        ]
        nbytes, width, height = (np.concatenate([c[k] for c in columns]) for k in range(3))
        if self.resize is not None:
            nbytes = nbytes * (self.resize[0] * self.resize[1]) / np.maximum(width * height, 1)
        for sid in self._in_file[path]:
            src = self.scenes[sid]
            self._sizes[sid] = nbytes[src.row_start : src.row_start + src.num_frames] + _VIEW_OVERHEAD_BYTES


def shard_specs(cfg: BuildConfig, plan: Plan, scenes: dict[str, SceneRows]) -> Iterator[ShardSpec]:
    """Cut the plan (in order) into shards of about `shard_bytes` each; the specs are yielded as soon
    as each shard is complete."""
    view_bytes = _ViewBytes(scenes, cfg.image.resize)

    def spec(index: int, group: list[Sample]) -> ShardSpec:
        return ShardSpec(
            index=index,
            file=SHARD_PATTERN.format(index),
            samples=tuple(group),
            sources={sid: scenes[sid] for sid in sorted({s.scene_id for s in group})},
            image=cfg.image,
            rows_per_batch=cfg.rows_per_batch,
            near_far=cfg.near_far,
        )

    group: list[Sample] = []
    acc = 0.0
    index = 0
    for s in plan.samples:
        est = view_bytes(s)
        if group and acc + est > cfg.shard_bytes:
            yield spec(index, group)
            index, group, acc = index + 1, [], 0.0
        group.append(s)
        acc += est
    yield spec(index, group)


# ---------------------------------------------------------------------------------------------
# Resume (materialising a spec, the same task in every engine, is `shard_task.materialise`)
# ---------------------------------------------------------------------------------------------


def existing_shard_matches(path: Path, spec: ShardSpec) -> bool:
    """True when `path` is a complete shard written from this very spec (plan hash and row count)."""
    if not path.exists():
        return False
    try:
        reader = pa.ipc.open_file(pa.memory_map(str(path), "r"))
        meta = reader.schema.metadata or {}
        rows = sum(reader.get_batch(i).num_rows for i in range(reader.num_record_batches))
    except (pa.ArrowInvalid, OSError):
        return False
    return meta.get(PLAN_KEY) == spec.plan_sha256.encode() and rows == len(spec.samples)


def resumable_shard(out: Path, spec: ShardSpec, known: dict[str, dict], verify: bool = False) -> FileEntry | None:
    """The manifest entry of a shard a previous run completed for this very spec, or None.

    Not trusted blindly: the shard must be recorded (`known`: journal records by file name, from the
    previous manifest's `report.resume` and the journal of an interrupted run) with the spec's plan
    hash as its stamp and the planned rows, and still be the file recorded: its size and mtime (or,
    with `verify` or without a recorded mtime, its sha256, plan hash in its metadata and row count).
    """
    rec = known.get(spec.file)
    if rec is None or rec.get("stamp", spec.plan_sha256) != spec.plan_sha256:
        return None
    entry = FileEntry(**rec["file"])
    path = out / spec.file
    if entry.rows != len(spec.samples):
        return None
    mtime = None if verify or "stamp" not in rec else rec.get("mtime_ns")
    if mtime is None and not existing_shard_matches(path, spec):
        return None
    return entry if file_intact(path, entry.bytes, entry.sha256, mtime) else None


def shard_record(result: ShardResult, out: Path) -> dict:
    """The journal record of a shard in place: unit = its file, stamp = its plan hash, its mtime."""
    assert result.entry is not None
    return {
        "unit": result.entry.path,
        "stamp": result.plan_sha256,
        "file": asdict(result.entry),
        "mtime_ns": file_stat(out / result.entry.path),
    }


def run_local(
    specs: Iterable[ShardSpec], out_dir: str, workers: int, bar, journal: Journal | None = None, fsync: bool = False
) -> list[ShardResult]:
    """Materialise the specs (taken from `specs` as they are needed) in this process (workers <= 1)
    or in a process pool; each shard is recorded in the journal once it is in place."""
    results: list[ShardResult] = []

    def collect(result: ShardResult) -> None:
        results.append(result)
        if journal is not None and result.entry is not None:
            journal.add(shard_record(result, Path(out_dir)))
        bar.update(result.entry.rows if result.entry is not None else 0)
        raise_if_terminated()

    if workers <= 1:
        for spec in specs:
            collect(materialise(spec, out_dir, fsync))
    else:
        from concurrent.futures import as_completed

        from seeu_data.process_pool import ForkedPool

        with ForkedPool(workers, "build", out_dir, kept="finished shards are kept") as pool:
            futures = [pool.submit(materialise, s, out_dir, fsync) for s in specs]  # specs drawn lazily
            for fut in as_completed(futures):
                collect(fut.result())
    return results


# ---------------------------------------------------------------------------------------------
# Driver
# ---------------------------------------------------------------------------------------------


def _progress_bar(total: int, enabled: bool):
    from tqdm import tqdm

    return tqdm(total=total, unit="triple", desc="seeu build", file=sys.stderr, disable=not enabled)


def known_shards(out: Path) -> dict[str, dict]:
    """Shards a previous run recorded as complete, as journal records by file name: its manifest's
    (with the plan hash and mtime its `report.resume` kept; without them the shard's metadata is
    checked), then its journal."""
    known: dict[str, dict] = {}
    if (out / MANIFEST_NAME).exists():
        try:
            doc = read_manifest(out, expect_schema=SCHEMA)
        except SeeUError:
            doc = {"files": []}
        kept = ((doc.get("report") or {}).get("resume") or {}).get("shards") or {}
        for f in doc["files"]:
            rec = {"unit": f["path"], "file": f}
            if f["path"] in kept:
                rec["stamp"], rec["mtime_ns"] = kept[f["path"]]
            known[f["path"]] = rec
    known.update({rec["unit"]: rec for rec in Journal(out / PROGRESS_NAME).read()})
    return known


def build_stamp(cfg: BuildConfig) -> str:
    """What a complete build is made from: its parameters, and of each input the digest of what its
    manifest records of the data (files and overlap tables with their sha256, scenes; not its provenance
    or report) and the
    size and mtime of each file (`resume.files_fingerprint`)."""
    inputs = []
    for root in cfg.inputs:
        try:
            doc = read_json(Path(root) / MANIFEST_NAME, "manifest")
            overlap = (doc.get("overlap") or {}).get("files", [])
            listed = {"files": doc["files"], "scenes": doc.get("scenes", []), "overlap": overlap}
            files = [Path(root) / f["path"] for f in doc["files"] + overlap]
        except (SeeUError, AttributeError, TypeError, KeyError):
            listed, files = {}, []  # no usable manifest: scan_inputs says why
        inputs.append([stamp_of(listed), files_fingerprint(files)])
    return stamp_of({"params": cfg.params(), "inputs": inputs})


def unchanged_build(out: Path, stamp: str) -> dict | None:
    """The manifest of the complete build in `out` when it was made with `stamp` and each of its shards
    still has the size and mtime recorded (nothing is read but the manifest); else None."""
    try:
        doc = read_manifest(out, expect_schema=SCHEMA)
    except SeeUError:
        return None
    resume = (doc.get("report") or {}).get("resume") or {}
    shards = resume.get("shards") or {}
    if resume.get("stamp") != stamp:
        return None
    for f in doc["files"]:
        if f["path"] not in shards or not file_intact(out / f["path"], f["bytes"], f["sha256"], shards[f["path"]][1]):
            return None
    return doc


@locks_output(lambda cfg, *_, **__: cfg.out)
def build(cfg: BuildConfig, argv_command: str = "seeu build") -> dict:
    """Run a whole build; return the manifest document.

    Example:
        from pipelines.build import BuildConfig, build
        from seeu_data.build.sampling import SamplingConfig
        from seeu_data.build.triples import ImageOptions

        cfg = BuildConfig(inputs=("data/posed/clip",), out="data/shards/extrap", mode="extrap",
                          sampling=SamplingConfig(mode="extrap", extrap_frames=45), image=ImageOptions(resize=(256, 256)))
        manifest = build(cfg)     # manifest["total_rows"] triples in manifest["files"]
    """
    cfg.check()
    workers = cfg.workers if cfg.workers is not None else default_workers(cfg.image.resize is not None)
    out = Path(cfg.out)
    for p in cfg.inputs:
        if Path(p).resolve() == out.resolve():
            raise SeeUError("the output directory is also an input", out)
    stamp = build_stamp(cfg)
    done = None if cfg.verify or cfg.force else unchanged_build(out, stamp)
    if done is not None:  # nothing to do: the report says every shard was kept
        report = dict(done["report"], shards_resumed=len(done["files"]), stale_files_removed=[])
        return dict(done, report=report)
    scenes = scan_inputs(cfg.inputs, cfg.verify, cfg.max_pixels)
    if not scenes:
        raise SeeUError("the inputs hold no scenes", cfg.inputs[0])
    plan = plan_eval(cfg, scenes) if cfg.mode == "eval" else plan_sampled(cfg, scenes)
    if not plan.total:
        raise SeeUError(no_samples_reason(cfg, plan.report), cfg.inputs[0])
    out.mkdir(parents=True, exist_ok=True)
    known = {} if cfg.force else known_shards(out)
    journal = Journal(out / PROGRESS_NAME, cfg.fsync)
    # Before the manifest goes: what a previous run completed stays known if this one is interrupted
    # (every record is verified again before a shard is kept: `resumable_shard`).
    journal.reset(known.values())
    (out / MANIFEST_NAME).unlink(missing_ok=True)  # incomplete from here on
    removed = sweep(out, SHARD_FILES, keep=known)  # shards no run recorded, partial writes
    results: list[ShardResult] = []
    plan_hashes: list[str] = []

    def todo(bar) -> Iterator[ShardSpec]:
        """The shard specs, planned as they are taken; the shards a previous run completed are kept."""
        for spec in shard_specs(cfg, plan, scenes):
            plan_hashes.append(spec.plan_sha256)
            entry = resumable_shard(out, spec, known, cfg.verify)
            if entry is None:
                (out / spec.file).unlink(missing_ok=True)  # not resumable: never served from a stale file
                yield spec
            else:
                results.append(ShardResult(spec.index, spec.plan_sha256, entry, resumed=True))
                bar.update(entry.rows)

    with _progress_bar(plan.total, cfg.progress) as bar:
        if cfg.engine == "ray":
            from seeu_data.build.ray_build import run_ray

            specs = list(todo(bar))
            if specs:
                results += run_ray(
                    specs, str(out), cfg.ray_address, bar, lambda r: journal.add(shard_record(r, out)), fsync=cfg.fsync
                )
        else:
            results += run_local(todo(bar), str(out), workers, bar, journal, fsync=cfg.fsync)
    removed += sweep(out, SHARD_FILES, keep={SHARD_PATTERN.format(i) for i in range(len(plan_hashes))})
    results.sort(key=lambda r: r.index)
    errors = [r.error for r in results if r.error is not None]
    if errors:
        raise SeeUError(errors[0] + (f" (and {len(errors) - 1} more shard errors)" if len(errors) > 1 else ""))
    files = [r.entry for r in results if r.entry is not None]
    report = dict(plan.report)
    report.update(
        shards=len(files),
        shards_resumed=sum(1 for r in results if r.resumed),
        stale_files_removed=sorted(removed),
        plan_sha256=hashlib.sha256("".join(plan_hashes).encode()).hexdigest(),
        resume={
            "stamp": stamp,
            "shards": {r.entry.path: [r.plan_sha256, file_stat(out / r.entry.path)] for r in results if r.entry},
        },
    )
    prov = provenance(argv_command, list(cfg.inputs), engine=cfg.engine, workers=workers)
    doc = write_manifest(out, SCHEMA, schema_version(SCHEMA), files, cfg.params(), prov, report=report, fsync=cfg.fsync)
    journal.remove()
    return doc


def no_samples_reason(cfg: BuildConfig, report: dict) -> str:
    """Why a sampled build drew nothing, in one line, with what to change."""
    pairs = report.get("pairs")
    s = cfg.sampling
    if pairs is None:
        return (
            f"no scene is long enough: all {report['scenes']} scenes have fewer than {report['min_scene_frames']} "
            "frames for --pairs gap (lower --gap-min, or choose pairs by view overlap: --pairs overlap)"
        )
    parts = []
    if report["scenes_skipped_too_short"]:
        parts.append(f"{report['scenes_skipped_too_short']} scenes too short for the gaps")
    if pairs["overlap_scenes_without_a_pair"]:
        parts.append(
            f"{pairs['overlap_scenes_without_a_pair']} scenes without a context pair of overlap "
            f"{s.min_overlap:g}..{s.max_overlap:g} that has the targets --mode {s.mode} needs "
            f"(e.g. {pairs['overlap_scenes_without_a_pair_examples'][0]!r}; widen --min-overlap / --max-overlap)"
        )
    return "no scene yields a sample: " + "; ".join(parts)
