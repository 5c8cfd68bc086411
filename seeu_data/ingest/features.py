"""The SfM database and its features: the cameras and images written in frame order, SIFT extraction,
and matching with two-view verification (steps of the SfM child, `seeu_data.ingest.sfm_child`)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from seeu_data.ingest.sfm import FEATURES, Failed, Job, SfmConfig, emit


def create_database(db_path: Path, image_dir: Path, names: list[str], cfg: SfmConfig) -> None:
    """Write the cameras (one per frame size, in order of first use, each with its rig) and one frame +
    image per name, in frame order, before extraction.

    COLMAP's parallel extractor otherwise assigns image ids in completion order, which changes with the
    thread count and the machine's load; the ids fix the pair ids, the matching order and the mapper's
    tie-breaks. Each camera is the one the extractor would create (`default_focal_length_factor` x the
    longer side, principal point at the centre): a portrait and a landscape photo of one phone get the
    same focal length in pixels, as separate cameras. The extractor then adds the features of these images.
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
                focal = factor * max(size)
                camera = pycolmap.Camera.create_from_model_name(len(cameras) + 1, cfg.camera_model, focal, *size)
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
    between consecutive frames (px; None when keyframes are off)."""

    num_pairs: int
    graph: dict
    motion_px: float | None
    matcher: dict


def extract(job: Job) -> int:
    """The database (camera and images in frame order) and SIFT features; returns the keypoint count."""
    import pycolmap

    cfg, clock = job.cfg, job.clock
    emit("stage", "extract", len(job.names))
    t0 = clock.mark()
    create_database(job.db_path, Path(job.image_dir), job.names, cfg)
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = cfg.camera_model
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.sift.max_num_features = cfg.max_features
    extraction.num_threads = cfg.threads
    extraction.type = getattr(pycolmap.FeatureExtractorType, FEATURES[cfg.features][0])
    pycolmap.extract_features(
        job.db_path,
        job.image_dir,
        image_names=job.names,
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


def match(job: Job) -> Matches:
    """Sequential or exhaustive matching (`choose_matcher`) and two-view verification (RANSAC seeded per
    pair), then the facts read back."""
    import pycolmap

    from seeu_data.ingest.keyframes import consecutive_motion_px
    from seeu_data.ingest.match_graph import choose_matcher, match_graph_stats

    cfg, clock = job.cfg, job.clock
    matcher = choose_matcher(cfg.matcher, job.video, len(job.names), cfg.overlap)
    pairing = pycolmap.SequentialPairingOptions()
    pairing.overlap = matcher["overlap"] or cfg.overlap
    # frames 1, 2, 4, ..., 2**(overlap-1) apart (COLMAP's default; the keyframe stride relies on it), or
    # (the fallback for a large image folder) every one of the next `overlap` images
    pairing.quadratic_overlap = matcher["quadratic"]
    pairing.loop_detection = cfg.vocab_tree is not None
    if cfg.vocab_tree is not None:
        pairing.vocab_tree_path = str(cfg.vocab_tree)
    emit("stage", "match", len(job.names))
    t0 = clock.mark()
    matching = pycolmap.FeatureMatchingOptions()
    # Matching on the mapping threads (default 1): even with a seeded RANSAC per pair, two matching threads
    # can change the database under load; one thread cannot.
    matching.num_threads = cfg.map_threads
    if cfg.features != "sift":
        matching.type = getattr(pycolmap.FeatureMatcherType, FEATURES[cfg.features][1])
    verification = pycolmap.TwoViewGeometryOptions()
    # RANSAC seeded per pair: otherwise each worker thread's random state carries over from the pairs it
    # happened to verify before, and the verified inliers (even the pairs kept) change with the thread count.
    verification.ransac.random_seed = cfg.random_seed
    if matcher["used"] == "exhaustive":
        pycolmap.match_exhaustive(job.db_path, matching_options=matching, verification_options=verification)
    else:
        pycolmap.match_sequential(
            job.db_path, matching_options=matching, pairing_options=pairing, verification_options=verification
        )
    clock.add("match_s", t0)
    t0 = clock.mark()
    db = pycolmap.Database.open(job.db_path)
    num_pairs = int(db.num_verified_image_pairs())
    graph = match_graph_stats(db, job.names)
    # keyframes are for sequentially matched frames (the stride relies on the quadratic overlap)
    keyframes = cfg.keyframe_motion > 0 and matcher["quadratic"]
    motion = consecutive_motion_px(db, job.names) if keyframes else None
    db.close()
    clock.add("map_s", t0)
    return Matches(num_pairs, graph, motion, matcher)
