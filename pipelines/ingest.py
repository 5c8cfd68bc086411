"""The ingest stage: a video, an image folder or a folder of videos -> posed chunks (COLMAP SfM).

`ingest(IngestConfig(...))` runs every input (several at once with `workers`); `ingest_scene` runs
one. Per scene, stages are kept under OUT/.work/<scene>/ with a stamp of their inputs and parameters,
so a re-run resumes (`force` redoes them): decode -> select frames -> SfM in a child process ->
posed chunks -> OUT/<scene>/ posed-frames dataset with report.json and trajectory.png, manifest.json
written last. `seeu ingest --help` describes every parameter; the flags are made from the `setting` fields of
`IngestConfig` and its nested configs (`--max-features` -> `sfm.max_features`, `--no-sfm-check` ->
`sfm.sfm_check=False`).

Example:
    from pathlib import Path
    from pipelines.ingest import IngestConfig, ingest
    from seeu_data.ingest.frame_select import SelectConfig

    cfg = IngestConfig(out=Path("data/posed"), inputs=("clip.mp4",), select=SelectConfig(target_frames=120))
    (result,) = ingest(cfg)
    print(result.report["summary"])          # also OUT/clip/report.json
"""

from __future__ import annotations

import os
import re
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

from pipelines.ingest_ray import SceneResult
from seeu_data.errors import SeeUError
from seeu_data.ingest.chunks import ChunkConfig
from seeu_data.ingest.frame_select import SelectConfig
from seeu_data.ingest.sfm import SfmConfig
from seeu_data.limits import MAX_IMAGE_SIDE, MAX_PIXELS, MAX_PIXELS_CEILING, MAX_WORKERS, check_range
from seeu_data.masks import MASK_CONVENTIONS
from seeu_data.settings import parse_dims, setting
from seeu_data.store.json_file import read_json
from seeu_data.store.out_lock import locks_output

# Bump when a stage's output layout changes, so old work directories are redone rather than misread.
DECODE_STAGE_FORMAT = 4  # 4: container timestamps (variable frame rate), frames counted as decoded
SFM_STAGE_FORMAT = 8


@dataclass(frozen=True)
class IngestRunConfig:
    """Where and how an ingest runs, not what it computes (not recorded in the manifests' params).

    engine: local (`workers` scenes at once in worker processes) or ray (one scene per Ray task on the
    cluster at `ray_address`, None: a local instance; `pipelines/ingest_ray.py`). heartbeat_s: a status
    line on stderr this often while no progress bars are shown (None: $SEEU_HEARTBEAT_S, else 10 s; 0:
    off); progress: tqdm bars; force: redo every stage; fsync: fsync every file before its rename.
    """

    engine: str = setting(
        "local",
        "local processes or Ray: one scene per task, as many at once as the cluster's CPUs allow; the same posed files",
        choices=("local", "ray"),
    )
    ray_address: str | None = setting(
        None, "--engine ray: a running cluster (host:port, or auto); default: start a local instance"
    )
    workers: int = setting(1, f"local engine: scenes processed in parallel (at most {MAX_WORKERS})", metavar="N")
    heartbeat_s: float | None = setting(
        None,
        "while no progress bars show (no terminal, or --no-progress), print a status line every SECONDS "
        "(default 10, or $SEEU_HEARTBEAT_S; 0 = off)",
        flag="--heartbeat",
        metavar="SECONDS",
    )
    force: bool = False
    progress: bool = False
    fsync: bool = False
    max_pixels: int = MAX_PIXELS  # largest frame or image (width x height) decoded, `--max-pixels`


@dataclass(frozen=True)
class IngestConfig:
    """Everything `seeu ingest` needs, in the stages' own configs: `select` (frame selection), `sfm`
    (structure from motion), `chunks` (posed chunks and their scale), `run` (how the run goes). Each
    field declared with `setting` is a flag of `seeu ingest` (pipelines/cli/config_flags.py); `params()`
    (recorded in each manifest) leaves out the inputs, names and `run`.

    inputs: video files, image folders or folders of videos; out: OUT (one dataset per scene:
    OUT/<scene>/); name: the scene name of a single input; max_size / size: the decoded frames' longer
    side, and the written frames' (H, W) (cover-resize + centre crop after SfM); strict: an entry of an
    image folder that cannot be read as an image is an error (else it is skipped and counted).
    """

    out: Path
    inputs: tuple[str | Path, ...] = setting(
        (), "video file, folder of images, or folder of videos", positional=True, many=True, metavar="INPUT"
    )
    name: str | None = setting(
        None,
        "scene name for a single input (default: the file's or folder's name; inputs sharing a name get their "
        "parent folder's name in front: a/images, b/images -> a-images, b-images)",
    )
    max_size: int | None = setting(None, "downscale so the longer side is at most N pixels (default: as decoded)")
    size: tuple[int, int] | None = setting(
        None,
        "make the posed frames exactly HxW: resize to cover + centre crop after SfM (intrinsics updated), e.g. "
        "360x640 for the peers' RE10K loaders; default: the (undistorted) frame size",
        metavar="HxW",
        parse=parse_dims,
    )
    strict: bool = setting(
        False,
        "refuse an image folder holding an entry with an image name that cannot be read as an image (a FIFO, "
        "a directory, no read permission, other bytes); default: skip it and name it in the summary",
    )
    masks: str | None = setting(
        None,
        "folder of your own per-frame masks of moving content (DIR/<scene>/ when present, else DIR/), matched to "
        "the frames by file name, else by frame number; of the decoded frames' size",
        metavar="DIR",
    )
    mask_convention: str = setting(
        "exclude",
        "what nonzero --masks pixels are: excluded (moving content; 0 = kept) or kept (0 = excluded)",
        choices=MASK_CONVENTIONS,
    )
    jpeg_quality: int = 95
    select: SelectConfig = field(default_factory=SelectConfig)
    sfm: SfmConfig = field(default_factory=SfmConfig)
    chunks: ChunkConfig = field(default_factory=ChunkConfig)
    run: IngestRunConfig = field(default_factory=IngestRunConfig)

    def check(self) -> None:
        """One-line SeeUError for a bad value, before any scene starts (e.g. ALIKED without ONNX)."""
        run = self.run
        if not self.inputs:
            raise SeeUError("no input given")
        check_range(run.workers, "--workers", 1, MAX_WORKERS)
        check_range(run.max_pixels, "--max-pixels", 1, MAX_PIXELS_CEILING)
        if self.max_size is not None:
            check_range(self.max_size, "--max-size", 1, MAX_IMAGE_SIDE)
        for side in self.size or ():
            check_range(side, "--size", 1, MAX_IMAGE_SIDE)
        if run.engine not in ("local", "ray"):
            raise SeeUError(f"--engine must be local or ray, got {run.engine!r}")
        if run.engine == "ray" and run.workers != 1:
            raise SeeUError("--workers is for the local engine; on Ray each scene is a task that takes --threads CPUs")
        if run.engine == "local" and run.ray_address is not None:
            raise SeeUError("--ray-address needs --engine ray")
        if run.engine == "ray":
            from pipelines.ingest_ray import task_cpus

            task_cpus(1 if self.sfm.threads == -1 else self.sfm.threads, self.sfm.map_threads)  # before Ray starts
        if self.name is not None and not re.fullmatch(r"[A-Za-z0-9_-][A-Za-z0-9_.-]*", self.name):
            raise SeeUError(f"--name must be letters, digits, '_', '-', '.' (not first), got {self.name!r}")
        if not 1 <= self.jpeg_quality <= 100:
            raise SeeUError(f"JPEG quality must be in 1..100, got {self.jpeg_quality}")
        if self.sfm.threads == 0 or self.sfm.threads < -1:
            raise SeeUError(f"--threads must be >= 1 or -1 (all cores / workers), got {self.sfm.threads}")
        if run.heartbeat_s is not None and not run.heartbeat_s >= 0:
            raise SeeUError(f"--heartbeat must be >= 0 seconds, got {run.heartbeat_s}")
        self.select.check()
        self.chunks.check()
        self.sfm.check()

    def params(self) -> dict:
        """The processing parameters (recorded in each manifest's params)."""
        skip = ("inputs", "out", "name", "strict", "run") + (("masks", "mask_convention") if self.masks is None else ())
        return {k: v for k, v in asdict(self).items() if k not in skip}

    def stage_sfm(self) -> SfmConfig:
        """The SfM stage's config: the vocabulary tree's path resolved, models kept from the chunk length."""
        vocab = None if self.sfm.vocab_tree is None else str(Path(self.sfm.vocab_tree).resolve())
        return replace(self.sfm, vocab_tree=vocab, min_model_size=max(3, min(self.chunks.min_chunk_frames, 10)))


def _encode_jpeg(rgb, quality: int) -> bytes:
    import cv2

    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:  # pragma: no cover
        raise SeeUError("JPEG encoding failed")
    return buf.tobytes()


def _decode_stage(source, cfg: IngestConfig, prog):
    """Stage function: decode every stride-th frame (an image turned upright by its EXIF orientation),
    resize, write JPEGs + per-frame metadata (with its width and height: photos may differ in size and
    orientation; SfM gives each size its own camera)."""

    from seeu_data.ingest.video import iter_frames, probe_video, resize_max_side, sharpness
    from seeu_data.store.arrow_io import atomic_write_bytes

    def fn(d: Path) -> dict:
        frames_dir = d / "frames"
        frames_dir.mkdir()
        in_source = (
            probe_video(source.path, cfg.run.max_pixels).frame_count
            if source.kind == "video"
            else len(source.image_files)
        )
        total = -(-in_source // cfg.select.stride)
        frames: list[dict] = []
        counted: list[int] = []  # the frames the source holds, as its stream gave them
        prog.stage("decode", total, "frames")
        for fr in iter_frames(source, cfg.select.stride, cfg.run.max_pixels, counted):
            prog.advance()
            rgb = resize_max_side(fr.rgb, cfg.max_size)
            name = f"{fr.source_frame:06d}.jpg"
            # OS errors name the file
            atomic_write_bytes(frames_dir / name, _encode_jpeg(rgb, cfg.jpeg_quality), cfg.run.fsync)
            frames.append(
                {
                    "name": name,
                    "source_frame": fr.source_frame,
                    "timestamp_us": fr.timestamp_us,
                    "source_name": fr.source_name,
                    "sharpness": sharpness(rgb),
                    "width": int(rgb.shape[1]),
                    "height": int(rgb.shape[0]),
                }
            )
        if not frames:
            raise SeeUError("no frames decoded", source.path)
        return {"frames": frames, "frames_in_source": counted[0]}

    return fn


def input_identity(source) -> dict:
    """What makes an input the same input: its resolved path and its content fingerprint."""
    return {"path": str(source.path.resolve()), "fingerprint": source.fingerprint()}


def check_scene_owner(out_dir: Path, identity: dict, force: bool) -> None:
    """Refuse to overwrite OUT/<scene> when it holds another input's scene (unless `force`).

    The same input: the same resolved path, or the same content fingerprint (a moved folder); the
    identity is read from the scene's report.json (`input_identity`, or `input` for older reports).
    A dataset without an ingest report counts as another input's.
    """
    if force or not out_dir.exists():
        return
    report_path = out_dir / "report.json"
    recorded = None
    if report_path.exists():
        try:
            doc = read_json(report_path, "ingest report")
            recorded = doc.get("input_identity") or {"path": str(Path(doc["input"]).resolve())}
        except (SeeUError, OSError, ValueError, KeyError, TypeError, AttributeError):
            recorded = None
    elif not (out_dir / "manifest.json").exists():
        return  # nothing finished there (an interrupted run): nothing to lose
    if recorded and (
        recorded.get("path") == identity["path"] or recorded.get("fingerprint") == identity["fingerprint"]
    ):
        return
    what = f"scene of another input ({recorded['path']})" if recorded else "dataset not written by seeu ingest"
    raise SeeUError(f"already holds a {what}; choose another --name or --out, or --force to replace it", out_dir)


def heartbeat_seconds(cfg: IngestConfig) -> float:
    """Seconds between status lines: none while progress bars show; else `heartbeat_s`, $SEEU_HEARTBEAT_S or 10."""
    if cfg.run.progress:
        return 0.0
    return cfg.run.heartbeat_s if cfg.run.heartbeat_s is not None else float(os.environ.get("SEEU_HEARTBEAT_S", "10"))


def ingest_scene(source, cfg: IngestConfig) -> dict:
    """Run every stage for one scene (`source`: a `seeu_data.ingest.video.SceneSource`) into cfg.out/<name>/;
    returns its report (also written to OUT/<scene>/report.json, with `summary`: the one-line result).

    Raises SeeUError for bad input, and when OUT/<scene> holds another input's scene and not `cfg.run.force`.
    """
    from seeu_data.progress import StageProgress

    out_dir = Path(cfg.out) / source.name
    identity = input_identity(source)
    check_scene_owner(out_dir, identity, cfg.run.force)
    label = f"seeu ingest: {source.name}"
    with StageProgress(label, bar=cfg.run.progress, heartbeat_s=heartbeat_seconds(cfg)) as prog:
        return _ingest_scene(source, Path(cfg.out), cfg, cfg.run.force, prog, identity)


@dataclass
class Decoded:
    """The decode stage's result: every decoded frame's record (`name`, `source_frame`, `timestamp_us`,
    `source_name`, `sharpness`), the input's frame count, the stage's stamp key and its frames folder."""

    frames: list[dict]
    frames_in_source: int
    key: dict
    frames_dir: Path


@dataclass
class Selected:
    """The frames kept for SfM (records of `Decoded.frames`) and the ones dropped, with reasons."""

    frames: list[dict]
    dropped: list[dict]


@dataclass
class Chunked:
    """Posed chunks (`seeu_data.ingest.chunks.Chunk`), every dropped frame (selection and chunking, by
    source frame), the registered frame count and the solution check's state."""

    chunks: list
    dropped: list[dict]
    registered: int
    check_state: str


def _ingest_scene(source, out_root: Path, cfg: IngestConfig, force: bool, prog, identity: dict) -> dict:
    """One scene's stages in turn: decode, select, SfM, chunks, report, write (`ingest_scene`)."""
    from seeu_data.ingest.report import summary_line
    from seeu_data.store.manifest import MANIFEST_NAME
    from seeu_data.store.resume import StageCache

    t_start = time.perf_counter()
    out_dir = out_root / source.name
    (out_dir / MANIFEST_NAME).unlink(missing_ok=True)  # being redone: must not look complete meanwhile
    cache = StageCache(out_root / ".work" / source.name, force=force, fsync=cfg.run.fsync)
    decoded = _decode(source, cfg, cache, identity, prog)
    selected = _select(source, cfg, cache, decoded)
    sfm_result = _sfm(source, cfg, cache, decoded, selected, prog)
    prog.stage("write")
    chunked = _chunk(source, cfg, cache, selected, sfm_result)
    report = _scene_report(source, cfg, identity, decoded, selected, sfm_result, chunked, out_dir)
    _write(source, cfg, cache, selected, chunked, report, out_dir, identity, t_start)
    report["summary"] = summary_line(report)
    return report


def _decode(source, cfg: IngestConfig, cache, identity: dict, prog) -> Decoded:
    """Decode every stride-th frame (resumable stage "decode")."""
    key = {
        "input": identity["path"],
        "fingerprint": identity["fingerprint"],
        "kind": source.kind,
        "stride": cfg.select.stride,
        "max_size": cfg.max_size,
        "jpeg_quality": cfg.jpeg_quality,
        "format": DECODE_STAGE_FORMAT,
    }
    d = cache.stage_dir("decode")
    decoded, _ = cache.run("decode", key, lambda: _decode_stage(source, cfg, prog)(d), d)
    return Decoded(decoded["frames"], decoded["frames_in_source"], key, d / "frames")


def _select(source, cfg: IngestConfig, cache, decoded: Decoded) -> Selected:
    """Drop blurred frames and thin to --target-frames; SeeUError when too few remain for SfM and a chunk."""
    from seeu_data.ingest.frame_select import select_frames

    t0 = time.perf_counter()
    frames_all = decoded.frames
    keep, dropped = select_frames(
        [f["sharpness"] for f in frames_all], [f["source_frame"] for f in frames_all], cfg.select
    )
    frames = [frames_all[i] for i in keep]
    cache.timings["select"] = time.perf_counter() - t0
    need = max(3, cfg.chunks.min_chunk_frames)
    if len(frames) < need:
        raise SeeUError(
            f"only {len(frames)} usable frame(s) after selection; SfM and --min-chunk-frames need at least {need}",
            source.path,
        )
    return Selected(frames, dropped)


def _sfm(source, cfg: IngestConfig, cache, decoded: Decoded, selected: Selected, prog) -> dict:
    """COLMAP SfM in a child process (resumable stage "sfm", resuming inside itself too); its result.json."""
    from seeu_data.ingest.sfm import run_sfm
    from seeu_data.store.resume import stamp_of

    sfm_cfg = cfg.stage_sfm()
    names = [f["name"] for f in selected.frames]
    mask_dir = None if cfg.masks is None else sfm_masks(cfg, source.name, decoded.frames_dir, selected.frames, cache)
    # the thread count does not change the results (image ids and RANSAC seeds are fixed by the frames)
    params = {k: v for k, v in asdict(sfm_cfg).items() if k != "threads"}
    key = {"decode": stamp_of(decoded.key), "names": names, "sfm": params, "format": SFM_STAGE_FORMAT}
    if mask_dir is not None:
        key["masks"] = mask_dir.name  # their digest
    d = cache.stage_dir("sfm")
    video = source.kind == "video"
    # the stage resumes inside itself: run_sfm keeps what an interrupted run of the same job finished in d
    result, _ = cache.run(
        "sfm",
        key,
        lambda: run_sfm(
            decoded.frames_dir,
            names,
            d,
            sfm_cfg,
            source.path,
            prog,
            video=video,
            resume=not cfg.run.force,
            mask_dir=mask_dir,
        ),
        outputs=lambda _: [d / "result.json"],
    )
    return result


def sfm_masks(cfg: IngestConfig, scene: str, frames_dir: Path, frames: list[dict], cache) -> Path:
    """`--masks` for SfM: each frame's mask (`masks.masks_from_folder`, at the decoded frame's size) as COLMAP
    reads them (`ImageReaderOptions.mask_path`: <name>.png, 0 where no feature is extracted, 255 elsewhere),
    written to the work folder's sfm_masks/<digest of the masks>/ (a changed mask, a new folder: the SfM stage
    is redone; each file written whole). Frames without a mask file keep all their features."""
    import hashlib

    import cv2
    import numpy as np

    from seeu_data.masks import decode_mask, masks_from_folder
    from seeu_data.store.arrow_io import atomic_write_bytes
    from seeu_data.store.image_header import file_image_size

    sizes = [file_image_size(frames_dir / f["name"]) for f in frames]
    masks = masks_from_folder(
        _mask_folder(cfg, scene),
        [f["source_name"] for f in frames],
        [int(f["source_frame"]) for f in frames],
        sizes,
        cfg.mask_convention,
        fit=lambda k, mask: _downscaled(mask, *sizes[k]),
    )
    digest = hashlib.sha256()
    for f, png in zip(frames, masks):
        digest.update(f["name"].encode() + b"\0" + (png or b""))
    out = cache.stage_dir("sfm_masks") / digest.hexdigest()[:16]
    out.mkdir(parents=True, exist_ok=True)
    for f, png in zip(frames, masks):
        if png is not None:
            colmap = cv2.imencode(".png", np.where(decode_mask(png), 0, 255).astype(np.uint8))[1].tobytes()
            atomic_write_bytes(out / (f["name"] + ".png"), colmap)
    return out


def _mask_folder(cfg: IngestConfig, scene: str) -> Path:
    """The folder of `--masks` for `scene`: DIR/<scene>/ when present, else DIR/."""
    folder = Path(cfg.masks or "") / scene
    folder = folder if folder.is_dir() else Path(cfg.masks or "")
    if not folder.is_dir():
        raise SeeUError("--masks: not a folder", folder)
    return folder


def _downscaled(mask, w: int, h: int):
    """A user's mask `(H, W)` bool brought to its frame's `w` x `h` when the frames were downscaled
    (`--max-size`: the same aspect); as it was otherwise."""
    from seeu_data.masks import resize_mask

    if mask.shape != (h, w) and abs(mask.shape[1] * h - w * mask.shape[0]) <= max(mask.shape):
        return resize_mask(mask, (h, w))
    return mask


def registered_frames(sfm_result: dict) -> int:
    """How many frames the SfM child's result.json `sfm_result` registered, over all its models."""
    return len({im["name"] for m in sfm_result["models"] for im in m["images"]})


def no_chunks_message(sfm_result: dict, num_frames: int, min_chunk_frames: int) -> str:
    """The one-line error when no chunk can be written from `sfm_result` (the SfM child's result.json) of
    `num_frames` frames: how many were registered, and what SfM found that explains it (frames a moving object
    carried, taken out; a failed solution check's reason)."""
    registered = registered_frames(sfm_result)
    run = "contiguous run" if (sfm_result.get("matcher") or {}).get("quadratic", True) else "model"
    why = []
    carried = (sfm_result.get("motion") or {}).get("carried") or []
    if carried:
        why.append(
            f"a moving object carried {len(carried)} mapped frames, taken out: the static scene in them did not "
            "place them again"
        )
    check = sfm_result.get("solution_check") or {}
    if check.get("passed") is False and check.get("reason"):
        why.append(f"solution check failed: {check['reason']}")
    because = f" ({'; '.join(why)})" if why else ""
    return f"SfM registered {registered}/{num_frames} frames but no {run} reaches --min-chunk-frames {min_chunk_frames}{because}"


def _chunk(source, cfg: IngestConfig, cache, selected: Selected, sfm_result: dict) -> Chunked:
    """Contiguous registered runs as scaled chunks; SeeUError when none reaches --min-chunk-frames."""
    import numpy as np

    from seeu_data.ingest.chunks import plan_chunks
    from seeu_data.ingest.report import baseline_over_depth, degeneracy
    from seeu_data.ingest.scale import distance_frame_names

    t0 = time.perf_counter()
    frames = selected.frames
    chunks, dropped_chunk = plan_chunks(
        source.name,
        [f["name"] for f in frames],
        sfm_result,
        cache.stage_dir("sfm"),
        cfg.chunks,
        distance_frame_names(frames, cfg.chunks.scale.distance_frames, source.path),
    )
    if not chunks:
        raise SeeUError(no_chunks_message(sfm_result, len(frames), cfg.chunks.min_chunk_frames), source.path)
    registered = registered_frames(sfm_result)
    cache.timings["chunks"] = time.perf_counter() - t0
    dropped = selected.dropped + [
        {"source_frame": frames[d["position"]]["source_frame"], "reason": d["reason"]} for d in dropped_chunk
    ]
    dropped.sort(key=lambda d: d["source_frame"])
    check = sfm_result.get("solution_check", {})
    check_state = "not run" if not check.get("ran") else ("passed" if check.get("passed") else "failed")
    models = {m["index"]: m for m in sfm_result["models"]}
    for c in chunks:
        # parallax on the model as mapped (its cameras and point depths): the same under every --scale
        w2c = {im["name"]: im["world_to_cam"] for im in models[c.model_index]["images"]}
        depths = np.load(cache.stage_dir("sfm") / f"points_depth_{c.model_index}.npy")
        parallax = baseline_over_depth(np.array([w2c[frames[p]["name"]] for p in c.frame_positions]), depths)
        c.meta["baseline_over_depth"] = parallax
        c.meta["degeneracy"] = degeneracy(check, parallax)
        c.meta["sfm_solution_check"] = check_state
    return Chunked(chunks, dropped, registered, check_state)


def _scene_report(
    source,
    cfg: IngestConfig,
    identity: dict,
    decoded: Decoded,
    selected: Selected,
    sfm_result: dict,
    chunked: Chunked,
    out_dir: Path,
) -> dict:
    """report.json's content (seeu_data/ingest/report.py documents its fields), without the timings."""
    from seeu_data.ingest.motion import report_section
    from seeu_data.ingest.report import mean_reprojection_error, scene_warnings, weak_geometry

    frames, chunks = selected.frames, chunked.chunks
    report = {
        "scene": source.name,
        "input": str(source.path),
        "input_kind": source.kind,
        "input_identity": identity,
        "frames_decoded": decoded.frames_in_source,
        "skipped_files": [{"name": name, "reason": reason} for name, reason in source.skipped],
        "frames_candidates": len(decoded.frames),
        "frames_selected": len(frames),
        "registered": chunked.registered,
        "registration_rate": chunked.registered / len(frames),
        "frames_in_chunks": sum(len(c.frame_positions) for c in chunks),
        "mean_reprojection_error_px": mean_reprojection_error(sfm_result["models"]),
        "sfm": {
            "num_keypoints": sfm_result.get("num_keypoints"),
            "num_verified_pairs": sfm_result.get("num_verified_pairs"),
            "timings_s": sfm_result.get("timings", {}),
            "cpu_timings_s": sfm_result.get("cpu_timings", {}),
            "models": [
                {
                    "index": m["index"],
                    "registered": len(m["images"]),
                    "points3D": m["num_points3D"],
                    "mean_reprojection_error_px": m["mean_reprojection_error"],
                    "camera": m["camera"],
                    "undistorted": m["undistorted"],
                    "distortion_max_px": m.get("distortion_max_px"),
                }
                for m in sfm_result["models"]
            ],
            "discarded_models": sfm_result.get("discarded_models", []),
            "mapping_attempts": sfm_result.get("mapping_attempts", []),
            "mapper": sfm_result.get("mapper"),
            "matcher": sfm_result.get("matcher"),
            "solution_check": {**sfm_result.get("solution_check", {}), "state": chunked.check_state},
            "keyframes": sfm_result.get("keyframes"),
            "final_ba": sfm_result.get("final_ba"),
            "resumed": sfm_result.get("resumed", {}),
        },
        "motion": report_section(sfm_result.get("motion"), frames),
        "chunks": [
            {
                "scene_id": c.scene_id,
                "num_frames": len(c.frame_positions),
                "source_frames": [
                    frames[c.frame_positions[0]]["source_frame"],
                    frames[c.frame_positions[-1]]["source_frame"],
                ],
                "near": c.near,
                "far": c.far,
                "sfm_model": c.model_index,
                "baseline_over_depth": c.meta["baseline_over_depth"],
                "degeneracy": c.meta["degeneracy"],
            }
            for c in chunks
        ],
        "dropped_frames": chunked.dropped,
        "output": str(out_dir),
    }
    report["sfm"]["solution_check"]["weak_geometry"] = weak_geometry(report)
    report["warnings"] = scene_warnings(report)
    return report


def _write(
    source,
    cfg: IngestConfig,
    cache,
    selected: Selected,
    chunked: Chunked,
    report: dict,
    out_dir: Path,
    identity: dict,
    t_start: float,
) -> None:
    """The posed-frames dataset OUT/<scene> (its SfM points per chunk; --size applied), report.json (its
    timings added) and trajectory.png, the manifest last."""
    import numpy as np

    from seeu_data.ingest.points import POINTS_DIR, chunk_observations, write_chunk_points
    from seeu_data.ingest.report import motion_sheet, plot_trajectory, write_report
    from seeu_data.resize import resize_scene
    from seeu_data.store.manifest import provenance
    from seeu_data.store.overlap_table import OVERLAP_FILES
    from seeu_data.store.posed import POSED_FILES, PosedDatasetWriter, TrackedScene
    from seeu_data.store.resume import sweep

    t0 = time.perf_counter()
    params = {**cfg.params(), "inputs": [str(source.path)], "sfm": asdict(cfg.stage_sfm())}
    prov = provenance("seeu ingest", [str(source.path)], input_fingerprint=identity["fingerprint"])
    sweep(out_dir, POSED_FILES, keep=())  # an earlier run's files: this run writes its own
    sweep(out_dir, OVERLAP_FILES, keep=())
    sweep(out_dir / POINTS_DIR, "*.ply", keep=())
    (out_dir / "motion.png").unlink(missing_ok=True)  # an earlier run's contact sheet of masked frames
    masked: list = []  # (source frame, image, mask) of every frame with a mask, for motion.png
    with PosedDatasetWriter(out_dir, params=params, provenance=prov, fsync=cfg.run.fsync) as writer:
        for c in chunked.chunks:
            imgs = []
            for path in c.image_paths:
                if not path.exists():
                    raise SeeUError("SfM image missing from the work directory (re-run with --force)", path)
                imgs.append(path.read_bytes())
            fr = [selected.frames[p] for p in c.frame_positions]
            points = write_chunk_points(
                cache.stage_dir("sfm"), c.model_index, c.meta["sfm_to_chunk"], out_dir, c.scene_id, cfg.run.fsync
            )
            scene = TrackedScene(
                scene_id=c.scene_id,
                images=imgs,
                image_format="jpeg",
                width=c.width,
                height=c.height,
                intrinsics_norm=c.intrinsics_norm,
                cam_to_world=c.cam_to_world,
                near=c.near,
                far=c.far,
                source_frame=np.array([f["source_frame"] for f in fr], np.int64),
                timestamp_us=np.array([f["timestamp_us"] for f in fr], np.int64),
                source_name=[f["source_name"] for f in fr],
                meta={**c.meta, "source": str(source.path), **points},
                observations=chunk_observations(
                    cache.stage_dir("sfm"), c.model_index, [selected.frames[p]["name"] for p in c.frame_positions]
                ),
            )
            scene.masks = moving_masks(cache.stage_dir("sfm"), c, fr)  # --dynamic mask (seeu_data.ingest.motion)
            if cfg.masks is not None:
                scene.masks = union_masks(scene.masks, chunk_masks(cfg, source.name, c, fr))
            for f, image, mask in zip(fr, imgs, scene.masks or ()):
                if mask is not None:
                    masked.append((f["source_frame"], image, mask))
            writer.add(scene if cfg.size is None else resize_scene(scene, cfg.size, cfg.jpeg_quality))
        cache.timings["write"] = time.perf_counter() - t0
        keys = ("frames_selected", "registered", "registration_rate", "frames_in_chunks", "mean_reprojection_error_px")
        writer.report = {k: report[k] for k in keys}
        writer.report["dropped_frames"] = len(chunked.dropped)
        writer.report["skipped_files"] = len(source.skipped)
        writer.report["warnings"] = report["warnings"]
        report["timings_s"] = {**cache.timings, "total": time.perf_counter() - t_start}
        report["reused"] = dict(cache.reused)
        write_report(out_dir / "report.json", report, cfg.run.fsync)
        title = f"{source.name}: {chunked.registered}/{len(selected.frames)} registered, {len(chunked.chunks)} chunk(s)"
        motion = report.get("motion") or {}
        plot_trajectory(out_dir / "trajectory.png", chunked.chunks, title, cfg.run.fsync, motion.get("masked_pct"))
        if masked:
            motion_sheet(out_dir / "motion.png", masked, cfg.run.fsync)


def moving_masks(sfm_dir: Path, chunk, frames: list[dict]) -> list[bytes | None] | None:
    """The chunk's frames' masks of moving content found in SfM (`--dynamic mask`: the SfM stage's
    masks/<model>/<frame>.png, already undistorted as the frames are), None for a frame without; None when
    no frame has one."""
    folder = sfm_dir / "masks" / str(chunk.model_index)
    masks = [(folder / f["name"]).read_bytes() if (folder / f["name"]).is_file() else None for f in frames]
    return masks if any(m is not None for m in masks) else None


def union_masks(a: list[bytes | None] | None, b: list[bytes | None]) -> list[bytes | None]:
    """Per frame, the pixels excluded by either list of masks (PNG bytes or None; `a` None: no masks)."""
    from seeu_data.masks import decode_mask, encode_mask

    if a is None:
        return b
    return [x if y is None else y if x is None else encode_mask(decode_mask(x) | decode_mask(y)) for x, y in zip(a, b)]


def chunk_masks(cfg: IngestConfig, scene: str, chunk, frames: list[dict]) -> list[bytes | None]:
    """The chunk's frames' masks from `--masks` (`masks.masks_from_folder`), brought to the posed
    frames as their images were: downscaled like the decoded frames (`--max-size`) and undistorted
    with the chunk's camera when SfM undistorted the frames."""
    import numpy as np
    import pycolmap

    from seeu_data.masks import masks_from_folder, undistort_mask

    cam = chunk.meta["camera_as_mapped"]
    camera = pycolmap.Camera(model=cam["model"], width=cam["width"], height=cam["height"], params=cam["params"])
    sizes = list(zip(np.asarray(chunk.width).tolist(), np.asarray(chunk.height).tolist()))

    def fit(k: int, mask):
        w, h = sizes[k]
        mask = _downscaled(mask, w, h)
        if chunk.meta["undistorted"] and (w, h) == (camera.width, camera.height):
            mask = undistort_mask(mask, camera)
        return mask

    names = [f["source_name"] for f in frames]
    numbers = [int(f["source_frame"]) for f in frames]
    return masks_from_folder(_mask_folder(cfg, scene), names, numbers, sizes, cfg.mask_convention, fit=fit)


def _scene_worker(payload: tuple) -> SceneResult:
    """Process-pool entry: one scene -> its SceneResult (a SeeUError becomes the result's error)."""
    source, cfg = payload
    try:
        return SceneResult(source.name, report=ingest_scene(source, cfg))
    except SeeUError as exc:
        return SceneResult(source.name, error=str(exc))


@locks_output(lambda cfg, *_, **__: cfg.out)
def ingest(cfg: IngestConfig, on_result: Callable[[SceneResult], None] | None = None) -> list[SceneResult]:
    """Ingest every scene of `cfg.inputs` into `cfg.out`; one SceneResult per scene, in input order.

    A single input's error raises SeeUError (on the local engine). With several inputs, or on Ray, each
    scene's error is kept in its result (`error`) and the others go on; `cfg.run.workers` scenes run at once
    in worker processes, or every scene is a Ray task. `on_result(result)` is called as each scene
    finishes (to print it).
    """
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    from tqdm import tqdm

    from seeu_data.ingest.video import discover_sources
    from seeu_data.interrupts import end_pool, quiet_worker

    cfg.check()
    sources = discover_sources(list(cfg.inputs), cfg.strict)
    if cfg.name is not None:
        if len(sources) != 1:
            raise SeeUError(f"--name names one scene, but the inputs hold {len(sources)}")
        sources = [replace(sources[0], name=cfg.name)]
    workers = min(cfg.run.workers, len(sources))
    if cfg.sfm.threads == -1:  # the cores shared by the scenes running at once (on Ray: each task's own)
        threads = 1 if cfg.run.engine == "ray" else max(1, (os.cpu_count() or 1) // workers)
        cfg = replace(cfg, sfm=replace(cfg.sfm, threads=threads))
    if cfg.run.engine == "ray":
        from pipelines.ingest_ray import ingest_on_ray

        return ingest_on_ray(
            sources,
            cfg,
            scene_fn=ingest_scene,
            address=cfg.run.ray_address,
            on_result=on_result,
            progress=cfg.run.progress,
        )
    Path(cfg.out).mkdir(parents=True, exist_ok=True)
    report = on_result or (lambda result: None)
    results: list[SceneResult] = []
    if len(sources) == 1:
        results.append(SceneResult(sources[0].name, report=ingest_scene(sources[0], cfg)))
        report(results[-1])
    elif workers == 1:
        for s in sources:
            results.append(_scene_worker((s, cfg)))
            report(results[-1])
    else:
        # no bars from the workers (they would interleave): the scenes' bar here, or their heartbeats
        quiet = replace(cfg, run=replace(cfg.run, progress=False, heartbeat_s=heartbeat_seconds(cfg)))
        ctx = multiprocessing.get_context("spawn")
        # workers end their SfM child on SIGTERM (`end_pool` sends it) before they go
        with ProcessPoolExecutor(workers, mp_context=ctx, initializer=quiet_worker) as pool:
            try:
                futures = pool.map(_scene_worker, [(s, quiet) for s in sources])
                for result in tqdm(futures, total=len(sources), desc="scenes", disable=not cfg.run.progress):
                    results.append(result)
                    report(result)
            except BaseException:  # Ctrl-C, SIGTERM, an error: no worker outlives the ingest
                end_pool(pool)
                raise
    return results
