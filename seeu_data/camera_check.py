"""Check that stored cameras agree with the images: SIFT matches against the cameras' epipolar geometry.

For a few frame pairs per scene, chosen by the scene's view-overlap table (`seeu_data.overlap`): the
pairs whose overlap is just above PAIR_OVERLAP (wide enough for a camera error to show, close enough
for matches), apart by at least MIN_BASELINE_FRACTION of the scene's extent, ranked in the cameras'
canonical order so the frames' numbering and names do not matter (`pick_pairs`; a pair with fewer
than MIN_PAIR_INLIERS inliers is passed over for the next), SIFT features are
matched (OpenCV; Lowe's ratio test, mutual best matches,
then the inliers of a RANSAC fundamental matrix fitted to the matches themselves, so outliers do not
reach the check) and the Sampson error (pixels) of each inlier is computed under the fundamental
matrix the stored cameras give, `F = K2^-T [t]x R K1^-1` with (R, t) the pose of camera 1 in camera 2. A
median under `max_error` means the cameras are consistent with the images, unless a convention fix
fits at least BETTER_FACTOR times better (a principal point off by 5 % of the width moves epipolar
lines of forward motion by well under a pixel: 0.55 px median on the synthetic clip). The common
convention mistakes are tried (`HYPOTHESES`: poses inverted, OpenGL axes, pixel intrinsics in
the normalised field and the reverse, a centred principal point, transposed rotations) and the one
with the lowest median under `max_error` is named as the likely cause.

Inputs (`detect_kind`): a posed-frames directory (manifest.json), nerfstudio `transforms.json` (or
its folder), a COLMAP model folder (cameras/images .bin or .txt; images in `--images`, else the
`images/` folder beside `sparse/`), pixelSplat chunks (a folder of *.torch or holding train/ / test/).
Foreign formats are read by their importer's `iter_scenes` (the same `PosedScene`s `seeu import`
writes), so the check sees what an import would store.

Also noted per scene: what the pixelSplat / MVSplat RE10K loader would skip (views not 360x640, a
field of view above 100 degrees), and near/far suggested from the points (`suggest_near_far`: the
SfM points an ingest kept, else the matches triangulated with consistent cameras) by the rule
`seeu ingest` uses, with the RE10K rescale, and whether the stored near/far clip the points.

Example:
    from pathlib import Path
    from seeu_data.camera_check import CameraCheckConfig, check_cameras

    report = check_cameras(CameraCheckConfig(path=Path("data/posed/clip")))
    print(report["verdict"], report["median_error_px"])
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from seeu_data.cameras import intrinsics_pixels, invert_rigid, opencv_from_opengl
from seeu_data.errors import SeeUError
from seeu_data.exporters.pixelsplat import peer_skip_reason
from seeu_data.image_ops import decode_rgb
from seeu_data.limits import MAX_PIXELS
from seeu_data.overlap import OverlapTable, canonical_order
from seeu_data.settings import setting
from seeu_data.store.arrow_io import atomic_write_bytes, atomic_write_text
from seeu_data.store.posed import PosedDataset, PosedScene, scene_overlap

MAX_ERROR_PX = 2.0  # median Sampson error (pixels) under which cameras are consistent, `--max-error`
PAIRS_PER_SCENE = 3  # frame pairs matched per scene, `--pairs`
MAX_SCENES = 20  # scenes checked at most, `--max-scenes`
MIN_MATCHES = 15  # fewer SIFT matches in a scene: not checked
RATIO = 0.75  # Lowe's ratio test
PAIR_OVERLAP = 0.4  # pairs overlapping just above this are matched: wide enough to show a camera error, enough matches
MIN_PAIR_INLIERS = 8  # a pair with fewer inlier matches is passed over for the next candidate ...
CANDIDATES = 3  # ... among at most this many times --pairs candidates
RANSAC_PX = 1.5  # inlier threshold (pixels) of the fundamental matrix fitted to the matches
RANSAC_CONFIDENCE = 0.999
MIN_BASELINE_FRACTION = 0.1  # a pair's camera centres at least this fraction of the scene's extent apart
SIFT_FEATURES = 2000
BETTER_FACTOR = 3.0  # a convention fix whose median error is this many times lower flags the scene ...
MIN_FLAG_PX = 0.3  # ... when the stored cameras' median is above this (below it, noise)
CLIP_PCT = 1.0  # stored near/far clip the points when more than this % of their depths fall outside
MAX_DEPTH_CAMERAS = 50  # cameras (evenly spread) the kept SfM points' depths are measured in
MAX_DEPTH_POINTS = 20_000  # kept SfM points (evenly spread) measured

STORED_NEAR_FAR = ("posed", "pixelsplat")  # kinds whose near/far are data (pixelSplat: the RE10K 1 / 100)

Hypothesis = Callable[[np.ndarray, np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


def _transpose_rotation(c2w: np.ndarray) -> np.ndarray:
    out = c2w.copy()
    out[:, :3, :3] = np.swapaxes(c2w[:, :3, :3], -1, -2)
    return out


def _scaled(intr: np.ndarray, wh: np.ndarray, power: int) -> np.ndarray:
    scale = np.stack([wh[:, 0], wh[:, 1], wh[:, 0], wh[:, 1]], -1).astype(np.float64)
    return intr * scale**power


def _centred(intr: np.ndarray) -> np.ndarray:
    out = intr.copy()
    out[:, 2:] = 0.5
    return out


# name -> (the cause in words, what to do, the fix: (cam_to_world (N,4,4), intrinsics_norm (N,4), wh (N,2)) -> fixed)
HYPOTHESES: dict[str, tuple[str, str, Hypothesis]] = {
    "w2c": (
        "poses look like world-to-camera (c2w/w2c swapped)",
        "invert the poses (cameras.cam_to_world_from_world_to_cam) when importing",
        lambda c, k, wh: (invert_rigid(c), k),
    ),
    "opengl": (
        "camera axes look like OpenGL's (+y up, +z back), not OpenCV's",
        "convert with cameras.opencv_from_opengl (flip camera y and z)",
        lambda c, k, wh: (opencv_from_opengl(c), k),
    ),
    "pixel_intrinsics": (
        "intrinsics look like pixels stored in the normalised field",
        "divide fx, cx by the width and fy, cy by the height",
        lambda c, k, wh: (c, _scaled(k, wh, -1)),
    ),
    "normalised_as_pixels": (
        "intrinsics look normalised where pixels were expected (divided by the size twice)",
        "multiply fx, cx by the width and fy, cy by the height",
        lambda c, k, wh: (c, _scaled(k, wh, 1)),
    ),
    "principal_point": (
        "the principal point looks wrong (the image centre fits)",
        "store cx/W, cy/H of the image centre (0.5, 0.5) or the calibrated values, corner-at-origin",
        lambda c, k, wh: (c, _centred(k)),
    ),
    "transposed_rotation": (
        "rotations look transposed",
        "transpose the 3x3 rotation of each pose",
        lambda c, k, wh: (_transpose_rotation(c), k),
    ),
}


@dataclass(frozen=True)
class CameraCheckConfig:
    """One `seeu check-cameras` run. `path`: dataset (kind detected); `images`: a COLMAP model's image
    folder (None: `images/` beside `sparse/`); `out`: folder for check.json and the epipolar figure."""

    path: Path = setting(
        help="dataset: posed frames, transforms.json, COLMAP model or pixelSplat chunks", positional=True
    )
    pairs: int = setting(PAIRS_PER_SCENE, "frame pairs matched per scene")
    max_error: float = setting(
        MAX_ERROR_PX, "largest median Sampson error (pixels) of consistent cameras", metavar="PX"
    )
    max_scenes: int = setting(MAX_SCENES, "scenes checked at most")
    images: Path | None = setting(None, "a COLMAP model's image folder (default: images/ beside sparse/)")
    out: Path | None = setting(None, "write check.json and epipolar.png (a pair with its epipolar lines) here")
    max_pixels: int = MAX_PIXELS


# ---------------------------------------------------------------------------------------------
# Reading
# ---------------------------------------------------------------------------------------------


def detect_kind(path: Path) -> str:
    """'posed', 'nerfstudio', 'colmap' or 'pixelsplat'; SeeUError for anything else."""
    path = Path(path)
    if path.is_file() and path.suffix == ".json" and path.name != "manifest.json":
        return "nerfstudio"
    if not path.is_dir():
        raise SeeUError("not a dataset folder or transforms.json", path)
    if (path / "manifest.json").is_file():
        return "posed"
    if (path / "transforms.json").is_file():
        return "nerfstudio"
    if any((path / f"cameras{ext}").is_file() for ext in (".bin", ".txt")):
        return "colmap"
    if any(path.glob("*.torch")) or any(any((path / s).glob("*.torch")) for s in ("train", "test")):
        return "pixelsplat"
    raise SeeUError(
        "unknown dataset kind: expected a posed-frames folder (manifest.json), nerfstudio transforms.json, "
        "a COLMAP model folder (cameras.bin/.txt) or pixelSplat chunks (*.torch)",
        path,
    )


def _colmap_images(cfg: CameraCheckConfig) -> Path:
    if cfg.images is not None:
        return Path(cfg.images)
    model = Path(cfg.path).resolve()
    for parent in model.parents:
        if parent.name == "sparse":
            return parent.parent / "images"
    return model.parent / "images"


def iter_scenes(cfg: CameraCheckConfig, kind: str) -> Iterator[PosedScene | tuple[str, str]]:
    """The scenes of `cfg.path` as `PosedScene`s (foreign formats through their importer), or
    (scene_id, reason) for scenes the importer skips."""
    from seeu_data.importers.common import SkippedScene

    path = Path(cfg.path)
    if kind == "posed":
        ds = PosedDataset(path)
        yield from ds.iter_scenes(ds.scene_ids[: cfg.max_scenes])
        return
    items: Iterator
    if kind == "nerfstudio":
        from seeu_data.importers.nerfstudio import NerfstudioImportConfig
        from seeu_data.importers.nerfstudio import iter_scenes as ns_scenes

        transforms = path if path.is_file() else path / "transforms.json"
        items = ns_scenes(NerfstudioImportConfig(transforms=transforms, near=0.1, far=100.0, max_pixels=cfg.max_pixels))
    elif kind == "colmap":
        from seeu_data.importers.colmap import ColmapImportConfig
        from seeu_data.importers.colmap import iter_scenes as colmap_scenes

        items = colmap_scenes(
            ColmapImportConfig(
                model_dir=path, images_dir=_colmap_images(cfg), near=0.1, far=100.0, max_pixels=cfg.max_pixels
            )
        )
    else:
        from seeu_data.importers.pixelsplat import PixelSplatImportConfig
        from seeu_data.importers.pixelsplat import iter_scenes as ps_scenes

        stage = "test" if (path / "test").is_dir() and not (path / "train").is_dir() else "train"
        items = ps_scenes(PixelSplatImportConfig(root=path, stage=stage, max_pixels=cfg.max_pixels))
    count = 0
    for item in items:
        if count >= cfg.max_scenes:
            return
        count += 1
        yield (item.scene_id, item.reason) if isinstance(item, SkippedScene) else item


# ---------------------------------------------------------------------------------------------
# Geometry
# ---------------------------------------------------------------------------------------------


def skew(t: np.ndarray) -> np.ndarray:
    """(3,) -> the (3, 3) cross-product matrix [t]x."""
    return np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])


def fundamental(c2w1: np.ndarray, c2w2: np.ndarray, K1: np.ndarray, K2: np.ndarray) -> np.ndarray:
    """F (3, 3) with x2^T F x1 = 0 for pixels x1 of camera 1 and x2 of camera 2 (OpenCV c2w, pixel K)."""
    rel = invert_rigid(c2w2) @ c2w1  # camera 1 -> camera 2
    E = skew(rel[:3, 3]) @ rel[:3, :3]
    F = np.linalg.inv(K2).T @ E @ np.linalg.inv(K1)
    norm = np.linalg.norm(F)
    return F / norm if norm > 0 else F


def sampson_error(F: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """Sampson distance (pixels) of matches x1, x2 `(M, 2)` under F: `(M,)`."""
    h1 = np.concatenate([x1, np.ones((len(x1), 1))], 1)
    h2 = np.concatenate([x2, np.ones((len(x2), 1))], 1)
    Fx1 = h1 @ F.T
    Ftx2 = h2 @ F
    num = np.einsum("ij,ij->i", h2, Fx1) ** 2
    den = Fx1[:, 0] ** 2 + Fx1[:, 1] ** 2 + Ftx2[:, 0] ** 2 + Ftx2[:, 1] ** 2
    return np.sqrt(num / np.maximum(den, 1e-300))


def _decode(scene: PosedScene, k: int) -> np.ndarray:
    """Frame k as (H, W, 3) uint8 BGR (`image_ops.decode_rgb`, at most its recorded size); SeeUError
    when it does not decode."""
    recorded = int(scene.width[k]) * int(scene.height[k])
    rgb = decode_rgb(memoryview(scene.images[k]), f"scene {scene.scene_id}: frame {k}", recorded)  # type: ignore[arg-type]
    return np.ascontiguousarray(rgb[..., ::-1])


def _gray(bgr: np.ndarray) -> np.ndarray:
    return np.asarray(cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY))


def match_sift(img1: np.ndarray, img2: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """SIFT matches between two grayscale images that pass the ratio test both ways (mutual best
    matches) and are inliers of a RANSAC fundamental matrix fitted to them (`RANSAC_PX`): pixel
    coordinates (M, 2) each, corner-at-origin (OpenCV keypoints are pixel-centre based: +0.5), and
    the number of ratio-test matches before the filters."""
    sift = cv2.SIFT_create(nfeatures=SIFT_FEATURES)  # type: ignore[attr-defined]
    k1, d1 = sift.detectAndCompute(img1, None)
    k2, d2 = sift.detectAndCompute(img2, None)
    empty = np.zeros((0, 2))
    if d1 is None or d2 is None or len(k1) < 2 or len(k2) < 2:
        return empty, empty, 0
    bf = cv2.BFMatcher(cv2.NORM_L2)

    def ratio(da, db) -> dict[int, int]:
        return {
            m[0].queryIdx: m[0].trainIdx
            for m in bf.knnMatch(da, db, k=2)
            if len(m) == 2 and m[0].distance < RATIO * m[1].distance
        }

    forward, backward = ratio(d1, d2), ratio(d2, d1)
    mutual = [(q, t) for q, t in forward.items() if backward.get(t) == q]
    x1 = np.array([k1[q].pt for q, _ in mutual], dtype=np.float64).reshape(-1, 2) + 0.5
    x2 = np.array([k2[t].pt for _, t in mutual], dtype=np.float64).reshape(-1, 2) + 0.5
    if len(x1) < 8:
        return empty, empty, len(forward)
    _, inlier = cv2.findFundamentalMat(x1, x2, cv2.FM_RANSAC, RANSAC_PX, RANSAC_CONFIDENCE)
    keep = np.zeros(len(x1), bool) if inlier is None else inlier.ravel().astype(bool)
    return x1[keep], x2[keep], len(forward)


def pick_pairs(
    scores: np.ndarray, cam_to_world: np.ndarray, intrinsics_norm: np.ndarray, limit: int
) -> list[tuple[int, int]]:
    """Up to `limit` candidate frame pairs (i, j), best first: the pairs whose overlap score (`scores`
    (N, N), symmetric) is at least PAIR_OVERLAP, least first (the widest that still match well), then
    the others, most first; only pairs whose camera centres are at least MIN_BASELINE_FRACTION of the
    scene's extent (its largest centre distance) apart. Ranked in the cameras' canonical order
    (`overlap.canonical_order`; ties go to the canonically earlier pair, i before j canonically), so
    renaming or shuffling the frames picks the same photos. None when the cameras do not move."""
    c2w = np.asarray(cam_to_world, np.float64)
    order = canonical_order(c2w, intrinsics_norm)
    centres = c2w[order, :3, 3]
    n = len(centres)
    dist = np.linalg.norm(centres[:, None] - centres[None], axis=-1)
    extent = float(dist.max()) if n else 0.0
    if n < 2 or extent <= 0:
        return []
    s = np.asarray(scores, np.float64)[np.ix_(order, order)]
    a, b = np.nonzero(np.triu(dist >= MIN_BASELINE_FRACTION * extent, 1) & (s > 0))
    ranked = sorted(zip(a.tolist(), b.tolist()), key=lambda p: (s[p] < PAIR_OVERLAP, abs(s[p] - PAIR_OVERLAP), p))
    return [(int(order[i]), int(order[j])) for i, j in ranked[:limit]]


# ---------------------------------------------------------------------------------------------
# Near / far from the points
# ---------------------------------------------------------------------------------------------


def triangulated_depths(matched: list, c2w: np.ndarray, intr: np.ndarray, wh: np.ndarray, max_error: float):
    """Depths (M,) of the matches triangulated with the stored cameras, in both cameras of each pair;
    only matches in front of both cameras with a Sampson error under `max_error` (inliers)."""
    out = []
    for (i, j), x1, x2 in matched:
        K1 = intrinsics_pixels(intr[i], int(wh[i, 0]), int(wh[i, 1]))
        K2 = intrinsics_pixels(intr[j], int(wh[j, 0]), int(wh[j, 1]))
        w2c1, w2c2 = invert_rigid(c2w[i])[:3], invert_rigid(c2w[j])[:3]
        keep = sampson_error(fundamental(c2w[i], c2w[j], K1, K2), x1, x2) < max_error
        if not keep.any():
            continue
        X = cv2.triangulatePoints(K1 @ w2c1, K2 @ w2c2, x1[keep].T, x2[keep].T)  # same pixel convention as K
        with np.errstate(divide="ignore", invalid="ignore"):
            X = (X[:3] / X[3]).T
        z1, z2 = X @ w2c1[2, :3] + w2c1[2, 3], X @ w2c2[2, :3] + w2c2[2, 3]
        front = np.isfinite(z1) & np.isfinite(z2) & (z1 > 0) & (z2 > 0)
        out += [z1[front], z2[front]]
    return np.concatenate(out) if out else np.zeros(0)


def sfm_point_depths(scene: PosedScene, root: Path) -> np.ndarray | None:
    """Depths of the SfM points an ingest kept (`points3d` in the scene's meta, a .ply under `root`)
    in the cameras that see them (in front, inside the image); None when the scene keeps none.
    At most MAX_DEPTH_POINTS points in MAX_DEPTH_CAMERAS cameras, evenly spread."""
    from seeu_data.ingest.points import read_points_ply

    rel = scene.meta.get("points3d") if isinstance(scene.meta, dict) else None
    if not isinstance(rel, str) or not (root / rel).is_file():
        return None
    xyz = read_points_ply(root / rel)[0]
    xyz = xyz[np.unique(np.linspace(0, len(xyz) - 1, min(len(xyz), MAX_DEPTH_POINTS)).astype(int))] if len(xyz) else xyz
    out = []
    for k in np.unique(np.linspace(0, len(scene) - 1, min(len(scene), MAX_DEPTH_CAMERAS)).astype(int)):
        w, h = int(scene.width[k]), int(scene.height[k])
        K = intrinsics_pixels(np.asarray(scene.intrinsics_norm[k], np.float64), w, h)
        w2c = invert_rigid(np.asarray(scene.cam_to_world[k], np.float64))
        cam = xyz @ w2c[:3, :3].T + w2c[:3, 3]
        z = cam[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = K[0, 0] * cam[:, 0] / z + K[0, 2]
            v = K[1, 1] * cam[:, 1] / z + K[1, 2]
        out.append(z[(z > 0) & (u >= 0) & (u < w) & (v >= 0) & (v < h)])
    depths = np.concatenate(out) if out else np.zeros(0)
    return depths if len(depths) else None


def suggest_near_far(depths: np.ndarray, source: str, near: float | None, far: float | None) -> dict:
    """Near/far for point depths (M,) by the toolkit's rule (`ingest.scale.near_far_from_depths`:
    0.4 x p0.1, 1.5 x p99.9, what `seeu ingest --scale median-depth / metric` records), the RE10K
    rescale (`ingest.scale.chunk_scale` with re10k: multiply the poses' translations by `re10k_scale`
    to use the peers' fixed near/far 1 / 100), and how much of the points the stored `near`/`far` clip
    (None: the format stores none, as nerfstudio and COLMAP)."""
    from seeu_data.ingest.chunks import NEAR_FAR_METHOD
    from seeu_data.ingest.scale import ScaleConfig, chunk_scale, near_far_from_depths

    suggested = near_far_from_depths(depths)
    re10k = chunk_scale(ScaleConfig("re10k"), depths, suggested)
    nearer = float(100.0 * np.mean(depths < near)) if near is not None else None
    farther = float(100.0 * np.mean(depths > far)) if far is not None else None
    clips = (
        [f"near {near:g} is beyond {nearer:.1f} % of the points"] if nearer is not None and nearer > CLIP_PCT else []
    )
    if farther is not None and farther > CLIP_PCT:
        clips.append(f"far {far:g} is nearer than {farther:.1f} % of the points")
    return {
        "source": source,
        "points": len(depths),
        "depth_percentiles": dict(zip(("p0.1", "p50", "p99.9"), np.percentile(depths, [0.1, 50, 99.9]).tolist())),
        "near": suggested[0],
        "far": suggested[1],
        "method": NEAR_FAR_METHOD,
        "re10k_scale": re10k.factor,
        "re10k_points_farther_than_far_pct": re10k.meta["points_farther_than_far_pct"],
        "stored": [near, far] if near is not None and far is not None else None,
        "points_nearer_than_stored_near_pct": nearer,
        "points_farther_than_stored_far_pct": farther,
        "stored_clips": "; ".join(clips) or None,
    }


# ---------------------------------------------------------------------------------------------
# The check
# ---------------------------------------------------------------------------------------------


def _errors(scene_pairs: list, c2w: np.ndarray, intr: np.ndarray, wh: np.ndarray) -> np.ndarray:
    errs = []
    for (i, j), x1, x2 in scene_pairs:
        K1 = intrinsics_pixels(intr[i], int(wh[i, 0]), int(wh[i, 1]))
        K2 = intrinsics_pixels(intr[j], int(wh[j, 0]), int(wh[j, 1]))
        if not (np.isfinite(K1).all() and np.isfinite(K2).all()) or 0 in (K1[0, 0], K1[1, 1], K2[0, 0], K2[1, 1]):
            errs.append(np.full(len(x1), np.inf))
            continue
        errs.append(sampson_error(fundamental(c2w[i], c2w[j], K1, K2), x1, x2))
    return np.concatenate(errs) if errs else np.zeros(0)


def peer_loader_skips(scene: PosedScene) -> list[str]:
    """Why the pixelSplat / MVSplat RE10K loader would skip this scene (empty: it would not); the
    exporter's rule (`exporters.pixelsplat.peer_skip_reason`)."""
    reason = peer_skip_reason(scene.width, scene.height, scene.intrinsics_norm)
    return [reason] if reason else []


def check_scene(
    scene: PosedScene,
    cfg: CameraCheckConfig,
    root: Path | None = None,
    stored_near_far: bool = True,
    overlap: OverlapTable | None = None,
) -> tuple[dict, tuple | None]:
    """One scene's report (and its first pair with matches, for the figure: (i, j, x1, x2)). `root`: the
    posed dataset holding the scene (its kept SfM points give the near/far suggestion; else the
    matches triangulated with the stored cameras do, when they are consistent); `stored_near_far`:
    the scene's near/far come from the data (not a reader's placeholder), so their clipping is checked;
    `overlap`: the scene's stored overlap table (None: measured, `posed.scene_overlap`)."""
    c2w = np.asarray(scene.cam_to_world, dtype=np.float64)
    intr = np.asarray(scene.intrinsics_norm, dtype=np.float64)
    wh = np.stack([np.asarray(scene.width), np.asarray(scene.height)], -1)
    rep: dict = {"scene_id": scene.scene_id, "frames": len(scene), "peer_loader_skips": peer_loader_skips(scene)}
    table = overlap if overlap is not None else scene_overlap(scene)
    scores = table.pair_scores()
    rep["overlap_method"] = table.method
    matched: list[tuple[tuple[int, int], np.ndarray, np.ndarray]] = []
    details: list[dict] = []
    for i, j in pick_pairs(scores, c2w, intr, CANDIDATES * cfg.pairs):
        if len(matched) == cfg.pairs:
            break
        x1, x2, raw = match_sift(_gray(_decode(scene, i)), _gray(_decode(scene, j)))
        names = [scene.source_name[k] for k in (i, j)] if scene.source_name else []
        details.append(
            {"frames": [i, j], "names": names, "overlap": float(scores[i, j]), "matches": raw, "inliers": len(x1)}
        )
        details[-1]["used"] = len(x1) >= MIN_PAIR_INLIERS
        if details[-1]["used"]:
            matched.append(((i, j), x1, x2))
    rep["pairs"] = [list(p) for p, _, _ in matched]
    rep["pair_details"] = details
    rep["matches"] = int(sum(len(x1) for _, x1, _ in matched))
    if rep["matches"] < MIN_MATCHES:
        rep["verdict"] = "unchecked"
        rep["reason"] = (
            f"{rep['matches']} SIFT matches (need {MIN_MATCHES}): too little texture or overlap, or static cameras"
        )
        return rep, None
    err = _errors(matched, c2w, intr, wh)
    used = (d for d in details if d["used"])
    for d, e in zip(used, np.split(err, np.cumsum([len(x1) for _, x1, _ in matched])[:-1])):
        d["median_error_px"] = float(np.median(e))
    rep["median_error_px"] = float(np.median(err))
    rep["p90_error_px"] = float(np.percentile(err, 90))
    tried = {}
    for name, (_, _, fix) in HYPOTHESES.items():
        c2, k2 = fix(c2w, intr, wh)
        tried[name] = float(np.median(_errors(matched, c2, k2, wh)))
    rep["hypotheses_median_px"] = tried
    best = min(tried, key=lambda k: tried[k])
    stored = rep["median_error_px"]
    fits_better = tried[best] <= stored / BETTER_FACTOR and stored > MIN_FLAG_PX
    rep["verdict"] = "inconsistent" if stored > cfg.max_error or fits_better else "consistent"
    if rep["verdict"] == "inconsistent":
        if tried[best] <= cfg.max_error and (fits_better or stored > cfg.max_error):
            what, todo, _ = HYPOTHESES[best]
            rep["cause"] = best
            rep["cause_text"] = (
                f"{what}: median Sampson error {tried[best]:.2f} px after the fix, {stored:.2f} px as stored"
            )
            rep["suggestion"] = todo
        else:
            rep["cause"] = None
            rep["cause_text"] = (
                f"none of the common convention mistakes fits (best: {best} at {tried[best]:.1f} px); "
                "check the poses' scale/order, the image-camera pairing, or lens distortion"
            )
            rep["suggestion"] = "plot the epipolar lines (--out) and compare frames by eye"
    depths = sfm_point_depths(scene, root) if root is not None else None
    source = "sfm_points"
    if depths is None and rep["verdict"] == "consistent":
        depths, source = triangulated_depths(matched, c2w, intr, wh, cfg.max_error), "triangulated_matches"
    if depths is not None and len(depths) >= MIN_MATCHES:
        stored = (float(scene.near), float(scene.far)) if stored_near_far else (None, None)
        rep["near_far"] = suggest_near_far(depths, source, *stored)
    (i, j), x1, x2 = matched[0]
    K1 = intrinsics_pixels(intr[i], int(wh[i, 0]), int(wh[i, 1]))
    K2 = intrinsics_pixels(intr[j], int(wh[j, 0]), int(wh[j, 1]))
    return rep, (scene, i, j, x1, x2, fundamental(c2w[i], c2w[j], K1, K2))


def epipolar_figure(
    scene: PosedScene, i: int, j: int, x1: np.ndarray, x2: np.ndarray, F: np.ndarray, n: int = 20
) -> bytes:
    """PNG: frames i and j side by side; `n` matches as dots, each with its epipolar line (from the
    stored cameras) in the other image. A consistent pair has its dots on the lines."""
    a, b = _decode(scene, i), _decode(scene, j)
    h = max(a.shape[0], b.shape[0])
    canvas = np.zeros((h, a.shape[1] + b.shape[1], 3), np.uint8)
    canvas[: a.shape[0], : a.shape[1]] = a
    canvas[: b.shape[0], a.shape[1] :] = b
    rng = np.random.default_rng(0)
    pick = rng.choice(len(x1), size=min(n, len(x1)), replace=False)
    for k, m in enumerate(pick):
        hsv = np.array([[[k * 180 // max(1, len(pick)), 255, 255]]], dtype=np.uint8)
        colour = tuple(int(c) for c in np.asarray(cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR))[0, 0])
        for pt, line, img, off in (
            (x2[m], F @ np.append(x1[m], 1.0), b, a.shape[1]),  # line in image j from the point in i
            (x1[m], F.T @ np.append(x2[m], 1.0), a, 0),  # line in image i from the point in j
        ):
            w = img.shape[1]
            la, lb, lc = line
            if abs(lb) > 1e-12:
                p0, p1 = (0.0, -lc / lb), (float(w), -(lc + la * w) / lb)
            else:
                p0, p1 = (-lc / la, 0.0), (-lc / la, float(img.shape[0]))
            cv2.line(canvas, (int(p0[0] + off), int(p0[1])), (int(p1[0] + off), int(p1[1])), colour, 1, cv2.LINE_AA)
            cv2.circle(canvas, (int(pt[0] - 0.5 + off), int(pt[1] - 0.5)), 3, colour, -1, cv2.LINE_AA)
    ok, buf = cv2.imencode(".png", canvas)
    if not ok:  # pragma: no cover - OpenCV always encodes uint8 BGR
        raise SeeUError("PNG encoding failed")
    return buf.tobytes()


def check_cameras(cfg: CameraCheckConfig) -> dict:
    """Check every scene (up to `max_scenes`); the report written to `out/check.json` when `out` is set.

    Returns {"path", "kind", "max_error_px", "scenes": [per scene: frames, pairs (those with inliers),
    pair_details ([{frames, names, overlap, matches (ratio test), inliers, used (enough inliers),
    median_error_px}] of every pair tried), overlap_method, matches (inliers of the pairs used),
    median_error_px, p90_error_px, verdict (consistent / inconsistent / unchecked), cause, cause_text,
    suggestion, hypotheses_median_px, peer_loader_skips, near_far (`suggest_near_far`; absent when
    there are no points: no kept SfM points and inconsistent cameras)], "skipped": [{scene_id, reason}],
    "median_error_px" (over checked scenes' medians), "verdict", "cause", "figure"}.
    SeeUError when the path is not a dataset or no scene could be checked.
    """
    if cfg.pairs < 1:
        raise SeeUError(f"--pairs must be at least 1, got {cfg.pairs}")
    if cfg.max_scenes < 1:
        raise SeeUError(f"--max-scenes must be at least 1, got {cfg.max_scenes}")
    if not cfg.max_error > 0:
        raise SeeUError(f"--max-error must be positive, got {cfg.max_error}")
    kind = detect_kind(cfg.path)
    scenes, skipped, figure_pair = [], [], None
    for item in iter_scenes(cfg, kind):
        if isinstance(item, tuple):
            skipped.append({"scene_id": item[0], "reason": item[1]})
            continue
        item.check()  # finite rigid poses, positive focal lengths (a bad dataset, not a convention mistake)
        root = Path(cfg.path) if kind == "posed" else None
        stored = PosedDataset(root).overlap(item.scene_id) if root is not None else None
        rep, pair = check_scene(item, cfg, root, stored_near_far=kind in STORED_NEAR_FAR, overlap=stored)
        scenes.append(rep)
        if pair is not None and (
            figure_pair is None or (rep["verdict"] != "consistent" and figure_pair[0] == "consistent")
        ):
            figure_pair = (rep["verdict"], pair)
    checked = [s for s in scenes if s["verdict"] != "unchecked"]
    if not checked:
        why = scenes[0]["reason"] if scenes else (skipped[0]["reason"] if skipped else "no scenes")
        raise SeeUError(f"no scene could be checked ({why})", cfg.path)
    bad = [s for s in checked if s["verdict"] == "inconsistent"]
    causes = sorted({s["cause"] for s in bad if s.get("cause")})
    report = {
        "path": str(cfg.path),
        "kind": kind,
        "max_error_px": cfg.max_error,
        "median_error_px": float(np.median([s["median_error_px"] for s in checked])),
        "verdict": "inconsistent" if bad else "consistent",
        "cause": f"{bad[0]['cause_text']} (scene {bad[0]['scene_id']})" if bad else None,
        "causes": causes,
        "suggestion": bad[0]["suggestion"] if bad else None,
        "scenes": scenes,
        "skipped": skipped,
        "near_far_clipped": [s["scene_id"] for s in scenes if s.get("near_far", {}).get("stored_clips")],
        "figure": None,
    }
    if cfg.out is not None:
        out = Path(cfg.out)
        out.mkdir(parents=True, exist_ok=True)
        if figure_pair is not None:
            atomic_write_bytes(out / "epipolar.png", epipolar_figure(*figure_pair[1]))
            report["figure"] = str(out / "epipolar.png")
        atomic_write_text(out / "check.json", json.dumps(report, indent=1))
    return report
