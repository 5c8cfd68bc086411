"""The SfM database and its features: the cameras and images written in frame order, SIFT extraction,
and matching of the pairs that can overlap (`seeu_data.ingest.pairs`) with two-view verification (steps
of the SfM child, `seeu_data.ingest.sfm_child`).

Both commit to the database as they go (COLMAP's extractor one image at a time, matched pairs batch by batch),
and both leave alone what the database already holds: a run interrupted in either continues from what
it finished, with the same result (each image's features and each pair's verification are the same
whoever computes them, whenever: RANSAC is seeded per pair).
"""

from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

from seeu_data.ingest.keyframes import Keyframes
from seeu_data.ingest.sfm import FEATURES, Failed, Job, SfmConfig, emit
from seeu_data.interrupts import end_with_parent

# A round of fewer pairs than this, before any is larger, is matched in this process: starting the matching
# processes (Python and pycolmap, a copy of the database each) costs about a second of CPU; once they run,
# every round uses them
PARALLEL_MIN_PAIRS = 64
# --vocab-tree: each keyframe is matched with this many keyframes most like it (COLMAP's loop detection
# default: 50 images every 10th frame)
LOOP_IMAGES = 20


def create_database(db_path: Path, image_dir: Path, names: list[str], cfg: SfmConfig) -> None:
    """Write the cameras (one per frame size, in order of first use, each with its rig) and one frame +
    image per name, in frame order, before extraction.

    COLMAP's parallel extractor otherwise assigns image ids in completion order, which changes with the
    thread count and the machine's load; the ids fix the pair ids, the matching order and the mapper's
    tie-breaks. Each camera is the one the extractor would create (`default_focal_length_factor` x the
    longer side, principal point at the centre; --focal instead, as a known prior): a portrait and a
    landscape photo of one phone get the same focal length in pixels, as separate cameras. `extract` then
    adds the features of these images.
    """
    import pycolmap

    from seeu_data.store.image_header import image_info

    factor = pycolmap.ImageReaderOptions().default_focal_length_factor
    db = pycolmap.Database.open(db_path)
    try:
        cameras: dict[tuple[int, int], tuple[int, int]] = {}  # (width, height) -> (camera id, rig id)
        for name in names:
            path = image_dir / name
            info = image_info(path.read_bytes(), str(path))
            size = (info.width, info.height)
            if size not in cameras:
                camera = pycolmap.Camera.create_from_model_name(len(cameras) + 1, cfg.camera_model, 1.0, *size)
                set_focal(camera, cfg.focal or factor, known=cfg.focal is not None)
                camera.camera_id = db.write_camera(camera)
                rig = pycolmap.Rig()
                rig.add_ref_sensor(camera.sensor_id)
                cameras[size] = (camera.camera_id, db.write_rig(rig))
            camera_id, rig_id = cameras[size]
            image = db.read_image(db.write_image(pycolmap.Image(name=name, camera_id=camera_id)))
            frame = pycolmap.Frame()
            frame.rig_id = rig_id
            frame.add_data_id(image.data_id)
            db.write_frame(frame)
    finally:
        db.close()


@dataclass(frozen=True)
class Matches:
    """The match step's facts: verified pairs, the match graph's statistics, the median image motion
    between consecutive frames (px; None when not matched in order or keyframes are off), the matcher
    chosen with its pair counts, and the keyframes (every frame when not matched in order)."""

    num_pairs: int
    graph: dict
    motion_px: float | None
    matcher: dict
    keyframes: Keyframes


def set_focal(camera, focal: float, known: bool) -> None:
    """Start the database `camera` (pycolmap.Camera, in place) at the focal length `focal` over the image's longer
    side, as a prior that mapping holds (`known`, as --focal) or fits."""
    import numpy as np

    params = np.array(camera.params)
    params[list(camera.focal_length_idxs())] = focal * max(camera.width, camera.height)
    camera.params = params.tolist()
    camera.has_prior_focal_length = known


def open_database(job: Job) -> bool:
    """The database of `job`: kept when an earlier run of this stage created it (its journal says so;
    SQLite rolls back what an interruption left half-written), else created afresh (`create_database`).
    Returns whether it was kept."""
    if job.finished("database"):
        return True
    for stale in (job.db_path, *(job.db_path.with_name(job.db_path.name + s) for s in ("-wal", "-shm", "-journal"))):
        stale.unlink(missing_ok=True)  # a leftover -shm of an earlier database makes SQLite fail to open a new one
    create_database(job.db_path, Path(job.image_dir), job.names, job.cfg)
    job.journal.add({"unit": "database"})
    return False


def _images_with_features(db_path: Path) -> set[str]:
    """The names of the images whose keypoints and descriptors the database holds."""
    import pycolmap

    db = pycolmap.Database.open(db_path)
    try:
        return {
            im.name
            for im in db.read_all_images()
            if db.exists_keypoints(im.image_id) and db.exists_descriptors(im.image_id)
        }
    finally:
        db.close()


def extract(job: Job) -> int:
    """SIFT features (or `features`') of every frame without them yet, with COLMAP's extractor on
    `threads` threads, on the frames downscaled to `feature_size` (keypoints in full-frame pixels), at
    most `max_features` each, none where a user's mask excludes (`Job.mask_dir`); COLMAP commits each
    image's as it finishes, so an interrupted extraction keeps what it finished. Returns the keypoint count;
    `job.resumed["images"]`: the frames whose features an earlier run had extracted. COLMAP reports "Processed
    file [k/N]" (the parent follows it)."""
    import pycolmap

    cfg, clock = job.cfg, job.clock
    t0 = clock.mark()
    done = _images_with_features(job.db_path)
    todo = [n for n in job.names if n not in done]
    job.resumed["images"] = len(job.names) - len(todo)
    emit("stage", "extract", len(job.names), "images")
    emit("done", len(job.names) - len(todo))  # COLMAP's "Processed file [k/N]" lines count from here
    if todo:
        reader = pycolmap.ImageReaderOptions()
        reader.camera_model = cfg.camera_model
        if job.mask_dir is not None:  # no features where the user's masks exclude (`run_sfm`)
            reader.mask_path = job.mask_dir
        extraction = pycolmap.FeatureExtractionOptions()
        extraction.max_image_size = cfg.feature_size
        extraction.sift.max_num_features = cfg.max_features
        extraction.num_threads = cfg.threads
        extraction.type = getattr(pycolmap.FeatureExtractorType, FEATURES[cfg.features][0])
        pycolmap.extract_features(
            job.db_path,
            job.image_dir,
            image_names=todo,
            camera_mode=pycolmap.CameraMode.AUTO,  # the images' cameras are in the database already
            reader_options=reader,
            extraction_options=extraction,
        )
    clock.add("extract_s", t0)
    db = pycolmap.Database.open(job.db_path)
    num_kp = int(db.num_keypoints())
    db.close()
    if num_kp < 50:
        raise Failed(f"SfM found only {num_kp} image features in {len(job.names)} frames (blank or textureless video?)")
    return num_kp


def copy_database(src: Path, dst: Path) -> None:
    """A consistent copy of the SQLite database `src` (SQLite's backup: pages still in a -wal file included)."""
    import sqlite3

    with sqlite3.connect(src) as a, sqlite3.connect(dst) as b:
        a.backup(b)
    a.close()
    b.close()


def _options(features: str, seed: int) -> tuple:
    """COLMAP's (matching, verification) options: one thread (a matching thread's result could depend on
    the others under load; processes give the parallelism, `_PairMatching`), RANSAC seeded per pair (each
    pair's verification then does not depend on the pairs verified before it)."""
    import pycolmap

    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = 1
    if features != "sift":
        matching.type = getattr(pycolmap.FeatureMatcherType, FEATURES[features][1])
    verification = pycolmap.TwoViewGeometryOptions()
    verification.ransac.random_seed = seed
    return matching, verification


def _match_pairs(db_path: str, names: list[tuple[str, str]], features: str, seed: int) -> None:
    """Match and verify the image pairs `names` into the database `db_path` (COLMAP commits them)."""
    import pycolmap

    matching, verification = _options(features, seed)
    list_path = Path(db_path).with_suffix(".pairs.txt")
    list_path.write_text("".join(f"{a} {b}\n" for a, b in names))
    pairing = pycolmap.ImportedPairingOptions()
    pairing.match_list_path = str(list_path)
    pycolmap.match_image_pairs(
        db_path, matching_options=matching, pairing_options=pairing, verification_options=verification
    )
    list_path.unlink()


def verify_again(job: Job) -> None:
    """Every matched pair of `job`'s database verified again (its two-view geometries replaced) against the cameras
    the database now holds: with a known focal length, an essential matrix."""
    import pycolmap

    db = pycolmap.Database.open(job.db_path)
    try:
        ids = {image.image_id: image.name for image in db.read_all_images()}
        pairs = [pycolmap.pair_id_to_image_pair(pair_id) for pair_id in db.read_all_matches()[0]]
        db.clear_two_view_geometries()
    finally:
        db.close()
    list_path = Path(job.db_path).with_suffix(".pairs.txt")
    list_path.write_text("".join(f"{ids[a]} {ids[b]}\n" for a, b in pairs))
    pycolmap.verify_matches(job.db_path, list_path, _options(job.cfg.features, job.cfg.random_seed)[1])
    list_path.unlink()


class _PairMatching:
    """Matches image pairs (frame numbers into `job.names`) with COLMAP, in batches, each committed to the
    database as it finishes; pairs the database already holds (an earlier, interrupted run's) are kept.
    With `threads` > 1 (from the first round of at least `PARALLEL_MIN_PAIRS` pairs on, every round) each batch
    is split into as many runs of consecutive pairs (which share most of their images: COLMAP reads each image's
    features once per call) for as many worker processes, each matching on one thread into a copy of the
    database, and the copies' pairs are written to the database in one transaction: each pair's result is the
    same whichever process computes it, so the database is too (its tables are keyed by pair). Reports the pairs
    done against the planned total (`emit`)."""

    def __init__(self, job: Job) -> None:
        self.job = job
        self.index = {n: i for i, n in enumerate(job.names)}
        self.inlier_counts: dict[tuple[int, int], int] = {}
        self._read()
        self.kept = len(self.inlier_counts)
        self.done = 0  # pairs of the plan done (matched here or kept)
        self.workers = job.cfg.cores()
        self.pool: ProcessPoolExecutor | None = None
        self.copies = [job.out / "match_dbs" / f"{k}.db" for k in range(self.workers)]

    def _read(self) -> None:
        """The verified inliers of every pair the database holds (a failed pair: 0)."""
        import pycolmap

        db = pycolmap.Database.open(self.job.db_path)
        try:
            self.ids = {im.name: im.image_id for im in db.read_all_images()}
            pair_ids, geometries = db.read_two_view_geometries()
        finally:
            db.close()
        by_id = {i: self.index.get(n) for n, i in self.ids.items()}
        for pid, g in zip(pair_ids, geometries):
            a, b = (by_id.get(int(i)) for i in pycolmap.pair_id_to_image_pair(pid))
            if a is not None and b is not None:
                self.inlier_counts[(min(a, b), max(a, b))] = len(g.inlier_matches)

    def inliers(self, a: int, b: int) -> int:
        return self.inlier_counts.get((min(a, b), max(a, b)), 0)

    def run(self, pairs: list[tuple[int, int]]) -> None:
        """Match `pairs` not matched yet, in order of their first frame (consecutive pairs share images), in
        batches of equal size (at most ten, at least 32 pairs per worker: each batch starts COLMAP's matcher,
        which reads the features of its images again)."""
        todo = sorted({(min(p), max(p)) for p in pairs} - self.inlier_counts.keys())
        self.done += len(pairs) - len(todo)
        emit("done", self.done)
        parts = max(1, min(10, len(todo) // (32 * self.workers)))
        batch = max(1, -(-len(todo) // parts))
        names = self.job.names
        for k in range(0, len(todo), batch):
            part = [(names[a], names[b]) for a, b in todo[k : k + batch]]
            if self.workers == 1 or (self.pool is None and len(todo) < PARALLEL_MIN_PAIRS):
                _match_pairs(str(self.job.db_path), part, self.job.cfg.features, self.job.cfg.random_seed)
            else:
                self._in_parallel(part)
            self.done += len(part)
            emit("done", self.done)
        self._read()

    def _in_parallel(self, part: list[tuple[str, str]]) -> None:
        """`part` split among the workers (each into its copy of the database), then copied into the database."""
        import multiprocessing

        import pycolmap

        if self.pool is None:
            self.copies[0].parent.mkdir(exist_ok=True)
            for copy in self.copies:
                copy.unlink(missing_ok=True)
                copy_database(self.job.db_path, copy)
            ctx = multiprocessing.get_context("spawn")
            self.pool = ProcessPoolExecutor(self.workers, mp_context=ctx, initializer=end_with_parent)
        k = -(-len(part) // self.workers)
        parts = [part[w * k : (w + 1) * k] for w in range(self.workers)]
        cfg = self.job.cfg
        list(
            self.pool.map(
                _match_pairs, map(str, self.copies), parts, [cfg.features] * len(parts), [cfg.random_seed] * len(parts)
            )
        )
        db = pycolmap.Database.open(self.job.db_path)
        try:
            transaction = pycolmap.DatabaseTransaction(db)
            for copy, names in zip(self.copies, parts):
                src = pycolmap.Database.open(copy)
                for a, b in names:
                    i, j = self.ids[a], self.ids[b]
                    db.write_matches(i, j, src.read_matches(i, j))
                    db.write_two_view_geometry(i, j, src.read_two_view_geometry(i, j))
                src.close()
            del transaction  # commits
        finally:
            db.close()

    def close(self) -> None:
        """Stop the workers and remove the database copies."""
        import shutil

        if self.pool is not None:
            self.pool.shutdown(cancel_futures=True)
        shutil.rmtree(self.copies[0].parent, ignore_errors=True)


def match(job: Job) -> Matches:
    """Match the pairs that can overlap (`seeu_data.ingest.pairs`; which ones: `choose_matcher`) with
    two-view verification (RANSAC seeded per pair), choosing the keyframes of a video on the way; then the
    facts read back. `job.resumed["pairs"]`: the pairs an earlier run had matched."""
    import pycolmap

    from seeu_data.ingest.keyframes import choose_keyframes, consecutive_motion_px
    from seeu_data.ingest.match_graph import choose_matcher, match_graph_stats
    from seeu_data.ingest.pairs import (
        SHORTLIST_FEATURES,
        exhaustive_pairs,
        keyframe_distances,
        keyframe_pairs,
        keyframe_rounds,
        neighbour_pairs,
        other_frame_pairs,
        shortlist_pairs,
        window_pairs,
    )

    cfg, clock, n = job.cfg, job.clock, len(job.names)
    matcher = choose_matcher(cfg.matcher, job.video, n, cfg.overlap)
    t0 = clock.mark()
    pm = _PairMatching(job)
    job.resumed["pairs"] = pm.kept
    motion = None
    try:
        if matcher["used"] == "exhaustive" or not matcher["quadratic"]:
            plan = exhaustive_pairs(n) if matcher["used"] == "exhaustive" else window_pairs(n, matcher["overlap"])
            if matcher["shortlist"]:
                plan = shortlist_pairs(_prominent_descriptors(job, SHORTLIST_FEATURES))
                matcher["pairs_shortlisted"] = f"{len(plan)} of {n * (n - 1) // 2}"
            emit("stage", "match", len(plan), "pairs")
            pm.run(plan)
            kf = choose_keyframes(job.names, None, cfg.keyframe_motion, cfg.min_keyframes, cfg.overlap)
        else:
            # the most pairs the rounds can come to: every frame a keyframe, no distance left out
            distances = keyframe_distances(n, cfg.overlap)
            emit("stage", "match", sum(n - d for d in distances), "pairs")
            pm.run(neighbour_pairs(n))
            if cfg.keyframe_motion > 0:
                db = pycolmap.Database.open(job.db_path)
                motion = consecutive_motion_px(db, job.names)
                db.close()
            kf = choose_keyframes(job.names, motion, cfg.keyframe_motion, cfg.min_keyframes, cfg.overlap)
            keys = [pm.index[k] for k in kf.names]
            rest = other_frame_pairs(n, keys)
            distances = [d for d in keyframe_distances(len(keys), cfg.overlap) if d > 1 or kf.stride > 1]
            for j, ds in enumerate(rounds := keyframe_rounds(distances)):
                emit("total", pm.done + sum(len(keys) - e for r in rounds[j:] for e in r) + len(rest))
                pm.run([p for d in ds for p in keyframe_pairs(keys, d, pm.inliers)])
            emit("total", pm.done + len(rest))
            pm.run(rest)
    finally:
        pm.close()
    if cfg.vocab_tree is not None and kf.names:
        _loop_pairs(job, kf.names)
        pm._read()
    matcher["pairs_matched"] = len(pm.inlier_counts)
    clock.add("match_s", t0)
    t0 = clock.mark()
    db = pycolmap.Database.open(job.db_path)
    num_pairs = int(db.num_verified_image_pairs())
    graph = match_graph_stats(db, job.names)
    db.close()
    clock.add("map_s", t0)
    return Matches(num_pairs, graph, motion, matcher, kf)


def _prominent_descriptors(job: Job, count: int):
    """`(n, count, 128)` uint8: each frame's `count` largest-scale SIFT descriptors (zeros where fewer)."""
    import numpy as np
    import pycolmap

    out = np.zeros((len(job.names), count, 128), np.uint8)
    db = pycolmap.Database.open(job.db_path)
    try:
        ids = {im.name: im.image_id for im in db.read_all_images()}
        for i, name in enumerate(job.names):
            kp = np.asarray(db.read_keypoints(ids[name]), np.float64)
            desc = np.asarray(db.read_descriptors(ids[name]).data, np.uint8)
            if not len(kp):
                continue
            scale = np.sqrt(np.abs(kp[:, 2] * kp[:, 5] - kp[:, 3] * kp[:, 4]))  # COLMAP's affine shape
            top = np.argsort(-scale, kind="stable")[:count]
            out[i, : len(top)] = desc[top]
    finally:
        db.close()
    return out


def _loop_pairs(job: Job, keyframes: list[str]) -> None:
    """Loop detection with the vocabulary-tree file `--vocab-tree`: each keyframe with the
    `LOOP_IMAGES` keyframes most like it (COLMAP's vocabulary-tree retrieval), matched and verified."""
    import pycolmap

    queries = job.out / "loop_queries.txt"
    queries.write_text("".join(f"{k}\n" for k in keyframes))
    pairing = pycolmap.VocabTreePairingOptions()
    pairing.vocab_tree_path = str(job.cfg.vocab_tree)
    pairing.num_images = LOOP_IMAGES
    pairing.match_list_path = str(queries)
    matching, verification = _options(job.cfg.features, job.cfg.random_seed)
    emit("stage", "match-loops", None)
    pycolmap.match_vocabtree(
        job.db_path, matching_options=matching, pairing_options=pairing, verification_options=verification
    )
    queries.unlink(missing_ok=True)
