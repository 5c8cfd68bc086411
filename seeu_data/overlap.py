"""View overlap: how much of one view's content another view sees. One measure for every stage.

`overlap[a, b]` is the fraction of view a's content that view b also sees (directed: a wide view
seen by a narrow one has a small overlap[a, b] and may have a large overlap[b, a]). A pair's score
is the smaller of the two, `min(overlap[a, b], overlap[b, a])`, as pixelSplat's evaluation-index
generator symmetrises its own. "Content" is sampled in one of two ways, whichever the data has:

* ``tracks`` (`overlap_from_observations`): the scene's structure-from-motion observations (an
  ingest's or a COLMAP model's 3D points and the frames that observe each). overlap[a, b] = the
  share of the 3D points frame a observes that frame b observes too. Occlusion and image content
  are in it (the SfM matcher saw them); the cameras are not used, so a camera convention mistake
  does not change it.
* ``cameras`` (`overlap_from_cameras`): the cameras and the scene's depth range only (pixelSplat
  chunks, nerfstudio, DL3DV, DTU). A `GRID` x `GRID` grid of view a's pixel centres is lifted to
  `DEPTHS` depths spread evenly in log-depth strictly inside [near, far]; overlap[a, b] = the share
  of those points in front of camera b and inside its image. No occlusion: for cameras that face
  each other across an object it over-estimates (both see the object's middle depth).

Stored sparse (`OverlapTable`): pairs a < b with max(overlap[a, b], overlap[b, a]) >= `FLOOR`, at
most `MAX_PARTNERS` partners kept per frame (evenly spread over its partners in overlap order, the
best always kept), so a long video's table stays a few hundred kilobytes. An absent pair is below
the floor (0). Written per posed file by `seeu_data.store.overlap_table`.

Order: nothing here depends on how frames are numbered or named. `canonical_order` sorts frames by
their cameras, so stages that must pick the same views however a photo set is shuffled or renamed
work in that order; `frame_order_is_path` tells from the poses whether the numbering is a camera
path (a video) or arbitrary (a photo set).

    table = overlap_from_cameras(cam_to_world (N, 4, 4), intrinsics_norm (N, 4), near, far)
    m = table.matrix()           # (N, N) float32, m[a, b] = fraction of a seen by b, diagonal 1
    s = table.pair_scores()      # (N, N) min(m, m.T)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seeu_data.cameras import project_points_to_cameras, unproject_pixels

FLOOR = 0.05  # pairs below this overlap (both directions) are not stored: NoPoSplat's lowest bin edge
MAX_PARTNERS = 64  # most partners kept per frame
GRID = 6  # cameras measure: GRID x GRID pixel centres of each view ...
DEPTHS = 2  # ... at this many depths inside [near, far]
METHODS = ("tracks", "cameras")
PATH_STEP_FACTOR = 3.0  # a step i -> i + 1 is a path step when at most this times a nearest-neighbour distance
PATH_STEP_SHARE = 0.8  # ... and the frame order is a path when this share of the steps are
# NoPoSplat's overlap bins (src/misc/utils.py get_overlap_tag), inclusive upper edges; outside them: no bin
BINS = {"small": (0.05, 0.3), "medium": (0.3, 0.55), "large": (0.55, 0.8)}
_CAMERA_BLOCK = 32  # cameras projected onto at once (bounds memory: block x N x GRID^2 x DEPTHS points)


@dataclass(frozen=True)
class OverlapTable:
    """One scene's overlap, sparse. P = stored pairs.

    frame_a, frame_b: (P,) int32 frame indices with a < b; overlap_ab: (P,) float32 the fraction of
    frame a's content frame b sees; overlap_ba: (P,) the reverse; method: 'tracks' or 'cameras'.
    """

    num_frames: int
    frame_a: np.ndarray
    frame_b: np.ndarray
    overlap_ab: np.ndarray
    overlap_ba: np.ndarray
    method: str

    def __len__(self) -> int:
        return len(self.frame_a)

    def matrix(self) -> np.ndarray:
        """(N, N) float32: [a, b] = fraction of frame a's content frame b sees; 1 on the diagonal, 0 for
        pairs not stored (below the floor)."""
        n = self.num_frames
        m = np.zeros((n, n), np.float32)
        m[self.frame_a, self.frame_b] = self.overlap_ab
        m[self.frame_b, self.frame_a] = self.overlap_ba
        np.fill_diagonal(m, 1.0)
        return m

    def pair_scores(self) -> np.ndarray:
        """(N, N) float32 symmetric pair score min(m[a, b], m[b, a])."""
        m = self.matrix()
        return np.minimum(m, m.T)


def context_overlap(m: np.ndarray, views) -> float:
    """The overlap of a set of context views: the smallest pair score min(m[a, b], m[b, a]) among them."""
    v = list(views)
    return float(min(min(m[a, b], m[b, a]) for i, a in enumerate(v) for b in v[i + 1 :]))


def overlap_bin(value: float) -> str | None:
    """The `BINS` name of a context overlap (small, medium, large), None outside them (as NoPoSplat's
    evaluation ignores such pairs)."""
    for name, (lo, hi) in BINS.items():
        if (lo <= value if name == "small" else lo < value) and value <= hi:
            return name
    return None


def from_matrix(m: np.ndarray, method: str, floor: float = FLOOR, max_partners: int = MAX_PARTNERS) -> OverlapTable:
    """The sparse table of a dense (N, N) directed overlap matrix (see the module docstring)."""
    m = np.asarray(m, np.float32)
    n = len(m)
    score = np.minimum(m, m.T)
    upper = np.maximum(m, m.T)
    keep = np.zeros((n, n), bool)
    for a in range(n):
        partners = np.nonzero(upper[a] >= floor)[0]
        partners = partners[partners != a]
        if len(partners) > max_partners:  # evenly spread over the partners in overlap order, best first
            ranked = partners[np.argsort(-score[a, partners], kind="stable")]
            partners = ranked[np.unique(np.round(np.linspace(0, len(ranked) - 1, max_partners)).astype(int))]
        keep[a, partners] = True
    keep |= keep.T
    a_idx, b_idx = np.nonzero(np.triu(keep, 1))
    return OverlapTable(
        n,
        a_idx.astype(np.int32),
        b_idx.astype(np.int32),
        m[a_idx, b_idx].astype(np.float32),
        m[b_idx, a_idx].astype(np.float32),
        method,
    )


def overlap_from_observations(
    num_frames: int,
    frame_of_obs: np.ndarray,
    point_of_obs: np.ndarray,
    floor: float = FLOOR,
    max_partners: int = MAX_PARTNERS,
    block: int = 1 << 16,
) -> OverlapTable:
    """Overlap from SfM tracks. frame_of_obs, point_of_obs: (M,) the frame index (0..N-1) and 3D point
    id of every observation. overlap[a, b] = |points of a observed by b| / |points of a| (0 when a
    observes none). Counted with a frames x points incidence matrix, `block` points at a time."""
    frames = np.asarray(frame_of_obs, np.int64)
    _, point = np.unique(np.asarray(point_of_obs, np.int64), return_inverse=True)
    counts = np.zeros((num_frames, num_frames), np.float64)
    num_points = int(point.max()) + 1 if len(point) else 0
    order = np.argsort(point, kind="stable")
    frames, point = frames[order], point[order]
    for start in range(0, num_points, block):
        lo, hi = np.searchsorted(point, [start, start + block])
        inc = np.zeros((num_frames, min(block, num_points - start)), np.float32)
        inc[frames[lo:hi], point[lo:hi] - start] = 1.0  # a point observed twice by a frame counts once
        counts += inc @ inc.T
    own = np.diag(counts).copy()
    with np.errstate(divide="ignore", invalid="ignore"):
        m = np.where(own[:, None] > 0, counts / own[:, None], 0.0)
    return from_matrix(m, "tracks", floor, max_partners)


def depth_samples(near: float, far: float, count: int = DEPTHS) -> np.ndarray:
    """(count,) depths spread evenly in log-depth strictly inside [near, far]."""
    return np.geomspace(near, far, count + 2)[1:-1]


def overlap_from_cameras(
    cam_to_world: np.ndarray,
    intrinsics_norm: np.ndarray,
    near: float,
    far: float,
    floor: float = FLOOR,
    max_partners: int = MAX_PARTNERS,
    grid: int = GRID,
    depths: int = DEPTHS,
) -> OverlapTable:
    """Overlap from the cameras and the depth range (see the module docstring).

    Shapes: cam_to_world (N, 4, 4), intrinsics_norm (N, 4). Computed on normalised images (1 x 1), so
    it does not depend on the resolution."""
    return from_matrix(
        camera_overlap_matrix(cam_to_world, intrinsics_norm, near, far, grid, depths), "cameras", floor, max_partners
    )


def camera_overlap_matrix(
    cam_to_world: np.ndarray,
    intrinsics_norm: np.ndarray,
    near: float,
    far: float,
    grid: int = GRID,
    depths: int = DEPTHS,
) -> np.ndarray:
    """The dense (N, N) matrix of `overlap_from_cameras`. Each sample point of view a counts for view b
    when it lies in front of camera b and inside its image, weighted by the chance that b sees the
    same side of a surface there: 1 - theta / pi for the angle theta between the directions from the
    point to the two cameras (a surface of unknown orientation facing a faces b too with that
    probability), so cameras that face each other across an object do not count it as shared."""
    from threadpoolctl import threadpool_limits

    # One BLAS thread: its products have 3 columns, where more threads only wait. Measured on a DL3DV
    # scene (300 views): 0.8 s of CPU against 2.0 s with 2 threads; a 16-core node's 8 import workers
    # with 16 threads each ran 2x slower than 8 single threads.
    with threadpool_limits(1, user_api="blas"):
        return _camera_overlap_matrix(cam_to_world, intrinsics_norm, near, far, grid, depths)


def _camera_overlap_matrix(
    cam_to_world: np.ndarray, intrinsics_norm: np.ndarray, near: float, far: float, grid: int, depths: int
) -> np.ndarray:
    c2w = np.asarray(cam_to_world, np.float64).reshape(-1, 4, 4)
    intr = np.asarray(intrinsics_norm, np.float64).reshape(-1, 4)
    n = len(c2w)
    ticks = (np.arange(grid) + 0.5) / grid
    uv = np.stack(np.meshgrid(ticks, ticks, indexing="xy"), -1).reshape(-1, 2)
    z = depth_samples(near, far, depths)
    uv_all = np.tile(uv, (len(z), 1))  # (S, 2), S = grid^2 * depths
    z_all = np.repeat(z, len(uv))
    pts = unproject_pixels(
        np.broadcast_to(uv_all, (n, *uv_all.shape)), np.broadcast_to(z_all, (n, len(z_all))), c2w, intr, 1, 1
    ).reshape(-1, 3)  # (N * S, 3): the samples of view 0, then view 1, ...
    rays = np.repeat(c2w[:, :3, 3], len(z_all), axis=0) - pts
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)  # (N * S, 3): unit, from each point to its own camera
    along = np.einsum("pk,pk->p", pts, rays)
    sq = np.einsum("pk,pk->p", pts, pts)
    centres = c2w[:, :3, 3]
    m = np.empty((n, n), np.float64)
    for b0 in range(0, n, _CAMERA_BLOCK):
        b1 = min(n, b0 + _CAMERA_BLOCK)
        c = centres[b0:b1]
        uv_b, z_b = project_points_to_cameras(pts, c2w[b0:b1], intr[b0:b1])  # (B, N*S, 2), (B, N*S)
        seen = (z_b > 0) & (uv_b >= 0).all(-1) & (uv_b <= 1).all(-1)
        # |p - c|^2 and (c - p) . ray by matrix products: (B, N*S) each
        dist = np.sqrt(np.maximum(sq[None] - 2.0 * (c @ pts.T) + (c * c).sum(-1)[:, None], 1e-24))
        cos = ((c @ rays.T) - along[None]) / dist
        facing = 1.0 - np.arccos(np.clip(cos, -1.0, 1.0)) / np.pi
        m[:, b0:b1] = np.where(seen, facing, 0.0).reshape(b1 - b0, n, -1).mean(-1).T
    np.fill_diagonal(m, 1.0)
    return m


# ---------------------------------------------------------------------------------------------
# Frame order
# ---------------------------------------------------------------------------------------------


def pose_distances(cam_to_world: np.ndarray) -> np.ndarray:
    """(N, N) distance between poses: camera-centre distance over the scene's extent (the largest
    one) plus the angle between the rotations over pi. 0 on the diagonal."""
    c2w = np.asarray(cam_to_world, np.float64).reshape(-1, 4, 4)
    centres = c2w[:, :3, 3]
    dc = np.linalg.norm(centres[:, None] - centres[None], axis=-1)
    extent = float(dc.max()) if dc.size else 0.0
    rot = c2w[:, :3, :3]
    trace = np.einsum("aij,bij->ab", rot, rot)  # trace(R_a^T R_b)
    angle = np.arccos(np.clip((trace - 1.0) / 2.0, -1.0, 1.0))
    return (dc / extent if extent > 0 else dc) + angle / np.pi


def frame_order_is_path(cam_to_world: np.ndarray) -> bool:
    """True when the frame numbering follows a camera path (a video, or photos taken along a walk):
    at least `PATH_STEP_SHARE` of the steps i -> i + 1 are at most `PATH_STEP_FACTOR` times the larger
    of the two frames' nearest-neighbour pose distances (`pose_distances`). False for a shuffled
    photo set, whose consecutive frames are as far apart as any two."""
    d = pose_distances(cam_to_world)
    n = len(d)
    if n < 3:
        return True
    nn = np.where(np.eye(n, dtype=bool), np.inf, d).min(1)
    steps = np.diagonal(d, 1)
    ok = steps <= PATH_STEP_FACTOR * np.maximum(nn[:-1], nn[1:])
    return bool(ok.mean() >= PATH_STEP_SHARE)


def canonical_order(cam_to_world: np.ndarray, intrinsics_norm: np.ndarray) -> np.ndarray:
    """(N,) a permutation that sorts frames by their cameras (centre, rotation, intrinsics), so the same
    photos give the same order however they are numbered or named."""
    c2w = np.asarray(cam_to_world, np.float64).reshape(-1, 4, 4)
    keys = np.concatenate([c2w[:, :3, 3], c2w[:, :3, :3].reshape(-1, 9), np.asarray(intrinsics_norm).reshape(-1, 4)], 1)
    return np.lexsort(keys.T[::-1])
