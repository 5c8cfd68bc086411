"""Moving content in a video's frames, found from dense optical flow (no learned weights).

SfM assumes a static scene: a person, a car or a box moving through the frames gives SIFT matches
that its two-view checks accept (motion along the epipolar lines passes them), and tracks that pull
the cameras. Here, for each frame i and its neighbours j (1 and up to `MAX_OFFSET` frames before and
after, as far as the image motion allows: `neighbour_offsets`):

1. flow (`Flows`): OpenCV's DIS optical flow between neighbouring frames, on grey frames shrunk to at
   most `WORK_SIDE` pixels, chained to reach the farther neighbours; a pixel's flow counts where the flow
   back agrees (`FB_MAX_PX`: not occluded, not out of frame) and the frames look alike (`PHOTO_MAX`).
2. the flow the static scene allows: cameras relative to frame i, x_j ~ M_j x + rho e_j, where x is
   the pixel in normalised image coordinates, rho its inverse depth and (M_j, e_j) = (R_ji, t_ji) the
   pose of frame j's camera in frame i's, from the SfM model (`model_pass`).
3. the residual (`static_residual`): the one rho that best explains every neighbour's flow at the
   pixel, and the largest distance in pixels between where that rho puts the pixel in a neighbour and
   where the flow does: epipolar distance and depth consistency in one number. A static pixel's
   neighbours agree on one depth; a moving one's do not, even when each move alone stays on its
   epipolar line.
4. masks (`detect`, `clean_masks`): the residual, median-filtered, carried along the flow to the next and
   previous frames (fading by `CARRY` per frame, so a mover stays found through the frames where its
   motion happens to look static), thresholded with hysteresis (`SEED_PX`, `GROW_PX`; seeds only where
   the frame has texture, `TEXTURE_MIN`), closed, specks below `MIN_AREA` of the frame dropped.

Motion within the plane of the camera's path and the point (a box at eye level crossing in front of
a camera walking straight, at constant speed) looks exactly like a static point at another depth;
the far neighbours, the camera's own turns and the carrying along the flow are what find it there.

The SfM child (`seeu_data.ingest.sfm_motion`, --dynamic) maps with every match, takes out frames whose
camera alone disagrees with the flow (`astray_frames`), then runs `model_pass` on the mapped frames
(`drop_observations` before the final bundle adjustment) and on every frame after registration;
`moving_content` says why unmasked moving content fails the solution check; `trial_frames` are placed again
on trial where a mover may have carried the cameras unseen; `rigid_gaps` compares the final cameras of each pair
of mapped frames with the best rigid motion of its flow; `report_section` is report.json's "motion".

    masks = model_pass(image_dir, names, rec)     # {name: (h, w) bool} where moving content was found
    dropped = drop_observations(rec, masks)       # its observations, removed from the model
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from functools import partial
from pathlib import Path

import cv2
import numpy as np

from seeu_data.errors import SeeUError

WORK_SIDE = 320  # flows on frames shrunk to this longer side (px)
GRID_STEP = 2  # the static test judges one pixel per GRID_STEP x GRID_STEP block (masks at that size)
MAX_OFFSET = 4  # the farther neighbours at most this many frames before and after ...
FAR_MOTION_PX = 20.0  # ... and at most about this far (median image motion, working px)
FB_MAX_PX = 1.0  # forward-backward disagreement above which a pixel's flow is not trusted
PHOTO_MAX = 8.0  # grey-level difference (blurred frames) above which a pixel's flow is not trusted
SEED_PX = 2.5  # residual (working px) that starts a moving region
GROW_PX = 1.25  # residual over which a moving region grows from its seeds
CARRY = 0.7  # evidence carried to the next / previous frame along the flow, per frame
MIN_AREA = 0.002  # smallest moving region kept, as a fraction of the frame
# A moving region must hold a seed (a pixel over SEED_PX) where the frame has texture in two directions: the
# smaller eigenvalue of its structure tensor (OpenCV's cornerMinEigenVal, 7 x 7 window, grey levels) at least
# this. Flow over sky, a smooth wall or along an edge is unconstrained (the aperture problem), its residual
# noise: the static street walk of benchmarks/footage.py had its sky masked in 85 of 90 frames (4.1 % of the
# pixels), 0.9 % with this; 3.0 took it to 0.4 % but lost the large mover's carried frames (benchmarks/dynamic.py)
TEXTURE_MIN = 2.0
# The final masks (`model_pass` over every registered frame) compare each frame with neighbours MODEL_REACH times
# as far as the other passes (`neighbour_offsets`: on the 90-frame walks of benchmarks/dynamic.py 6 frames instead of
# 3), a neighbour farther than MAX_OFFSET frames counting its residual per MAX_OFFSET frames (`static_residual`).
# Over 3 frames a box carried along 2.5 m ahead of a walking camera moves as a static point 3-5 m away would; over
# 6 it does not: its masks' IoU 0.44-0.45 -> 0.79-0.80 (320x180, 640x360), the static walks' false positives 0.04
# -> 0.11-0.15 % of the pixels, the orbit of benchmarks/footage.py (2 -> 4 frames) 0.08 -> 0.45 %. (Counting the
# residuals per reach-1 span instead, 0.04 % on the orbit, lost the slow box.) The passes that judge cameras (before
# the final adjustment, the trials) keep their reach: doubled there, the large mover's carried frames were no
# longer repaired.
MODEL_REACH = 2
MAX_ASTRAY_RUN = 3  # at most this many frames in a row are taken out as astray (`astray_runs`)
MIN_MOVING_FRAMES = 3  # --dynamic off: moving regions in this many mapped frames fail the solution check ...
# ... when they hold at least this share of the model's observations. The 90-frame static walk's specks held 2 of
# 122,598 (0.0016 %); the swinging box 493, the large mover 7,126, the slow box 24,278 of 106,006 (about 0.4 %,
# 6 % and 23 %; the first two of a total not recorded, taken as the static walk's).
MIN_MOVING_SHARE = 0.0002
# A mapped frame whose cameras leave more than this share of its pixels unexplained (found "moving") has wrong
# cameras or is mostly moving content: in MIN_MOVING_FRAMES such frames the solution check fails in either mode.
# Measured (benchmarks/dynamic.py, 90-frame walks): the swinging box and the static walk stay under 15 %, a
# mover crossing most of the frame reaches 79 %, with cameras 2.7 % of the path off that the two mapping runs
# agreed on. (A slow box carried along ahead of the camera reached 98 % through one frame placed astray, which
# `astray_frames` now takes out first.)
MOSTLY_MOVING = 0.5
# --dynamic mask: the mapped frames a mover carried (`carried_frames`) are those mostly unexplained, REPAIR_MARGIN
# more on each side, and any stretch left between them or at an end shorter than MIN_SOUND_RUN; the rest must hold
# MIN_SOUND_RUN frames in a row to place them against. Measured on the large crossing mover (90-frame walk, mostly
# unexplained in frames 4-23, its first 30 frames carried 2.8 % of the path off): re-registered against the rest
# with its first 24, 25 or 28 frames taken out, the cameras came to 0.038-0.062 % of the path.
REPAIR_MARGIN = 2
MIN_SOUND_RUN = 8
# A repair that leaves more than this share of the stretch it placed again (first to last carried frame) mostly
# unexplained by the final masks did not work: the solution check fails (and ingest tries again with the focal length
# held, `sfm_child`); a smaller share is left out (`unexplained_frames`). Measured at 320x180 (benchmarks/dynamic.py):
# the large crossing mover, 3 frames of 29 (a mover filling a third of the view; cameras 0.063 % of the path with
# them out, mapped once: 1.47x the walk without it, against 1.83x for the try with the focal length held); the
# person crossing ahead (`person_x`), 14 of 45 (left out: 74 % of the frames written; held: 100 %, 0.065 %).
REPAIR_LEFT_MAX = 0.25
# The rigid pass misses a mover in some frames: one walking straight ahead of the camera moves along the epipolar
# lines. Before the database mapped first (`sfm_motion.drop_matches`) loses the matches on moving content, in each
# frame where it found none a keypoint matched to a masked one in another frame is taken as the same moving point,
# out to this many matches away (`grown_moving`). Measured at 320x180 (benchmarks/dynamic.py): the person walking
# 3 m ahead (`follow`) kept 16,533 matches, carried SfM 2.6 % of the path off and ended in a warning; with this,
# 6,828, and 0.21 % with the check passed. Grown into the frames with masks as well (2,125 left), the swinging box
# lost 3 % of its static matches and two of the three mapping runs of its first try found no model.
MATCH_HOPS = 2
# Nothing carried: frames with moving content placed again against the rest on trial (`trial_frames`) are
# carried (mask: repaired; off: the solution check fails) when that moves the cameras more than this (% of the
# path: the accuracy ingest aims at). Measured: the large mover at 320x180 (cameras 7 % of the path off), frames
# 0-22 moved 5.3 %; the static walk's few false specks, 0.085 % (320x180) and 0.010 % (640x360). The other
# presets find moving content in most of the clip: no trial.
TRIAL_SHIFT_PCT = 0.5
# Wrong cameras that no frame shows as mostly moving: where the best rigid motion of a pair of mapped frames (an
# essential matrix fitted to their flow, `rigid_gaps`) explains more than RIGID_GAP more of the pair's trusted
# pixels (within RIGID_PX of their epipolar lines, working px) than the SfM cameras do, in MIN_MOVING_FRAMES pairs,
# the solution check fails. Measured (pairs as far apart as the static test's farthest neighbours): the mover
# crossing far ahead (`seeu synth --movers far`, 320x180) left the cameras 16 % of the path off with the two
# mapping runs agreeing and its masks under half of every frame: 16 of 44 pairs over 0.15 (up to 0.41); with
# right cameras the swinging box at 640x360 reached 0.099 mapped on every frame (0.015 on every second), the slow
# box 0.077, the static walk 0.001. (Over consecutive mapped frames instead, the box reached 0.12 in 3 pairs and
# the far mover only 0.19.)
# A pair is judged only where the flow is trusted (`Flows.step`) in at least RIGID_TRUSTED of the pixels followed:
# a 10-frame walk 0.8 m a frame apart kept 15-82 of 3,600 in some pairs, and a fit to those meant nothing.
RIGID_GAP = 0.15
RIGID_PX = 1.0
RIGID_TRUSTED = 0.25
# The passes of the SfM child over the same frames (astray, model, trial, rigid) share their frames and flows
# (`FlowMemo`), at most this many bytes of them (about 1.7 MB a frame at WORK_SIDE: a 90-frame clip's keyframes
# and frames all fit; a longer clip's later frames are computed again in each pass). The orbit of
# benchmarks/footage.py: 678 DIS flows -> 266, the motion stage 7.2 -> 5.2 s (poses and masks identical).
MEMO_BYTES = 384 * 2**20

Cameras = list[tuple[np.ndarray, np.ndarray]]  # per neighbour (M (3, 3), e (3,))


class FlowMemo:
    """The grey frames (`load_frames`) and neighbouring-frame flows (`Flows`) of one SfM child's motion passes,
    by frame name: a pass over frames another pass read reads them from here (at most MEMO_BYTES kept; the
    rest are computed again). The values are what each pass would compute itself."""

    def __init__(self, image_dir: str | Path) -> None:
        self.image_dir = image_dir
        self.kept: dict[tuple, np.ndarray] = {}
        self.bytes = 0

    def recall(self, key: tuple, make: Callable[[], np.ndarray]) -> np.ndarray:
        """The value kept under `key`, else `make()` (kept while under MEMO_BYTES)."""
        if key in self.kept:
            return self.kept[key]
        value = make()
        if self.bytes < MEMO_BYTES:
            self.kept[key] = value
            self.bytes += value.nbytes
        return value

    def frames(self, names: Sequence[str]) -> list[np.ndarray]:
        """`load_frames` of `names`."""
        return [self.recall(("frame", n), partial(self._load, n)) for n in names]

    def _load(self, name: str) -> np.ndarray:
        return load_frames(self.image_dir, [name])[0]


def _flows(source: str | Path | FlowMemo, names: Sequence[str], step: int = GRID_STEP) -> Flows:
    """`Flows` of the frames `names`, read from a folder (`load_frames`) or through a `FlowMemo`."""
    if isinstance(source, FlowMemo):
        return Flows(source.frames(names), step, source, names)
    return Flows(load_frames(source, names), step)


def load_frames(image_dir: str | Path, names: Sequence[str], side: int = WORK_SIDE) -> list[np.ndarray]:
    """The frames as grey `(h, w)` uint8, shrunk (area interpolation) so the longer side is at most `side`."""
    out = []
    for name in names:
        path = Path(image_dir) / name
        img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if img is None:
            raise SeeUError("cannot read frame for motion detection", path)
        scale = side / max(img.shape)
        if scale < 1:
            size = (max(1, round(img.shape[1] * scale)), max(1, round(img.shape[0] * scale)))
            img = cv2.resize(img, size, interpolation=cv2.INTER_AREA)
        out.append(img)
    return out


class Flows:
    """Where frame i's pixels land in the frames around it, from DIS optical flow between neighbouring
    frames only, chained: carried to i + 1 by the flow i -> i + 1, on to i + 2 by the flow i + 1 -> i + 2
    sampled where they landed, and so on (DIS fails on large displacements over weak texture, not on the
    small steps). A step is trusted where the flow back returns within FB_MAX_PX (not occluded, not out
    of frame) and the blurred frames agree within PHOTO_MAX grey levels; a chain where all its steps are.
    `forget(i)` drops what frames before i needed. With a `FlowMemo` and the frames' `names`, the flows and
    steps of frames another pass read come from it."""

    def __init__(
        self,
        frames: Sequence[np.ndarray],
        step: int = GRID_STEP,
        memo: FlowMemo | None = None,
        names: Sequence[str] = (),
    ) -> None:
        self.frames = frames
        self.memo, self.names = memo, names
        self.dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)  # type: ignore[attr-defined]
        self.flows: dict[tuple[int, int], np.ndarray] = {}
        self.steps: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
        self.smooth: dict[int, np.ndarray] = {}
        h, w = frames[0].shape
        self.full = pixel_grid(h, w).astype(np.float32)
        self.grid = pixel_grid(h, w, step).astype(np.float32)  # the pixels followed: one per step x step block

    def _recall(self, kind: str, frames: tuple[int, ...], make: Callable[[], np.ndarray]) -> np.ndarray:
        """`make()`, or the memo's value for these frames (by name)."""
        if self.memo is None:
            return make()
        return self.memo.recall((kind, *(self.names[i] for i in frames)), make)

    def _flow(self, i: int, j: int) -> np.ndarray:
        if (i, j) not in self.flows:
            self.flows[(i, j)] = self._recall(
                "flow", (i, j), lambda: self.dis.calc(self.frames[i], self.frames[j], None)
            )
        return self.flows[(i, j)]

    def _smoothed(self, i: int) -> np.ndarray:
        if i not in self.smooth:
            self.smooth[i] = self._recall(
                "smooth", (i,), lambda: cv2.GaussianBlur(self.frames[i].astype(np.float32), (0, 0), 1.0)
            )
        return self.smooth[i]

    def step(self, i: int, j: int) -> tuple[np.ndarray, np.ndarray]:
        """Flow from frame i to its neighbour j `(h, w, 2)` float32, and where it is trusted `(h, w)` float32 0/1."""
        if (i, j) not in self.steps:
            self.steps[(i, j)] = (self._flow(i, j), self._recall("trusted", (i, j), lambda: self._trusted(i, j)))
        return self.steps[(i, j)]

    def _trusted(self, i: int, j: int) -> np.ndarray:
        """Where the flow from frame i to j is trusted (`step`)."""
        flow = self._flow(i, j)
        land = self.full + flow
        mx, my = land[..., 0] - 0.5, land[..., 1] - 0.5
        back = cv2.remap(self._flow(j, i), mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
        seen = cv2.remap(
            self._smoothed(j), mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan
        )
        with np.errstate(invalid="ignore"):
            ok = (np.linalg.norm(flow + back, axis=-1) < FB_MAX_PX) & (np.abs(seen - self._smoothed(i)) < PHOTO_MAX)
        return ok.astype(np.float32)

    def observe(self, i: int, js: Sequence[int]) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per frame j of js: where frame i's followed pixels (`grid`, `(h', w', 2)`) land there `(h', w', 2)`
        float32, and where that is trusted `(h', w')` bool."""
        found: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        for d in (1, -1):
            ahead = [(j - i) * d for j in js if (j - i) * d > 0]
            land, ok, k = self.grid, np.ones(self.grid.shape[:2], bool), i
            for _ in range(max(ahead, default=0)):
                flow, trust = self.step(k, k + d)
                mx, my = land[..., 0] - 0.5, land[..., 1] - 0.5
                moved = cv2.remap(flow, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
                kept = cv2.remap(trust, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
                land = land + moved
                ok = ok & (kept > 0.99) & np.isfinite(moved).all(-1)
                k += d
                found[k] = (land, ok)
        return [found[j] for j in js]

    def forget(self, before: int) -> None:
        for cache in (self.flows, self.steps):
            for pair in [p for p in cache if min(p) < before]:
                del cache[pair]
        for i in [i for i in self.smooth if i < before]:
            del self.smooth[i]


def pixel_grid(h: int, w: int, step: int = 1) -> np.ndarray:
    """Centres `(h // step, w // step, 2)` (x, y) of the step x step blocks of an h x w image (step 1:
    the pixel centres (j + 0.5, i + 0.5))."""
    ys, xs = np.mgrid[0 : h // step, 0 : w // step].astype(np.float64)
    return np.stack([(xs + 0.5) * step, (ys + 0.5) * step], -1)


def _depth_terms(x: np.ndarray, land: np.ndarray, M: np.ndarray, e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares terms of rho in (M x + rho e) ~ land: numerator and denominator, `(h, w)` each."""
    h0 = x[..., 0:1] * M[:, 0] + x[..., 1:2] * M[:, 1] + M[:, 2]  # (h, w, 3) = M (x, y, 1)
    u = e[:2] - land * e[2]
    v = land * h0[..., 2:3] - h0[..., :2]
    return (u * v).sum(-1), (u * u).sum(-1)


def static_residual(
    x: np.ndarray,
    lands: Sequence[np.ndarray],
    oks: Sequence[np.ndarray],
    cameras: Cameras,
    scale: float = 1.0,
    spans: Sequence[int] = (),
) -> np.ndarray:
    """How far the flow of each pixel is from any static point's: `(...)` in pixels per MAX_OFFSET frames (0
    where no neighbour's flow is trusted).

    x: `(..., 2)` the pixels of frame i; lands / oks: per neighbour, where they land `(..., 2)` and
    whether that is trusted `(...)`, in the coordinates of x; cameras: per neighbour (M, e) with
    land ~ M x + rho e; scale: pixels per unit of those coordinates; spans: per neighbour, how many frames
    away it is (none given: at most MAX_OFFSET each). rho is fitted to all trusted neighbours at once, the
    residual is the largest reprojection distance among them, that of a neighbour farther than MAX_OFFSET
    frames in proportion (a mover's distance from the static flow, and the chained flow's drift, grow with
    it)."""
    num = np.zeros(x.shape[:-1])
    den = np.zeros(x.shape[:-1])
    for land, ok, (M, e) in zip(lands, oks, cameras):
        n, d = _depth_terms(x, land, M, e)
        num += np.where(ok, n, 0.0)
        den += np.where(ok, d, 0.0)
    rho = num / np.maximum(den, 1e-12)
    res = np.zeros(x.shape[:-1])
    per = [max(1.0, abs(k) / MAX_OFFSET) for k in spans] or [1.0] * len(lands)
    for land, ok, (M, e), p in zip(lands, oks, cameras, per):
        dist = np.linalg.norm(_project(x, M, e, rho) - land, axis=-1) / p
        res = np.where(ok & np.isfinite(dist), np.maximum(res, dist), res)
    return res * scale


def _project(x: np.ndarray, M: np.ndarray, e: np.ndarray, rho: np.ndarray) -> np.ndarray:
    """Where pixels `(..., 2)` of inverse depth `rho` `(...)` land with the camera (M, e): `(..., 2)`."""
    h = x[..., 0:1] * M[:, 0] + x[..., 1:2] * M[:, 1] + M[:, 2] + rho[..., None] * e
    with np.errstate(divide="ignore", invalid="ignore"):
        return h[..., :2] / h[..., 2:3]


# residual(i, js, grid, lands, oks, avoid) -> (h, w) pixels or None: see `detect`
Residual = Callable[[int, list[int], np.ndarray, list[np.ndarray], list[np.ndarray], np.ndarray], "np.ndarray | None"]


def neighbour_offsets(flows: Flows, n: int, reach: int = 1) -> tuple[int, ...]:
    """The neighbours' distances in frames: 1, and the farthest k <= `reach` x MAX_OFFSET whose median image
    motion (k times that of consecutive frames: the median flow of up to 5 pairs spread over the n frames) stays
    within `reach` x FAR_MOTION_PX, when k >= 2. A fast camera compared over 4 frames would leave the chained
    flow and the fits far behind."""
    pairs = sorted({int(k) for k in np.linspace(0, n - 2, min(5, n - 1))})
    if not pairs:
        return (1,)
    step = float(np.median([np.median(np.linalg.norm(flows.step(k, k + 1)[0], axis=-1)) for k in pairs]))
    far = int(reach * min(MAX_OFFSET, FAR_MOTION_PX // max(step, 1e-6)))
    return (1, far) if far >= 2 else (1,)


def neighbours(i: int, n: int, offsets: Sequence[int]) -> list[int]:
    """Frame i's neighbours among n frames: i -/+ each offset, those inside 0..n-1."""
    return [i + o for o in sorted({-o for o in offsets} | set(offsets)) if 0 <= i + o < n]


def detect(
    frames: Sequence[np.ndarray],
    residual: Residual,
    on_frame: Callable[[], None] | None = None,
    flows: Flows | None = None,
    reach: int = 1,
) -> list[np.ndarray]:
    """Masks of moving content `(h // GRID_STEP, w // GRID_STEP)` bool, one per frame of `frames` (grey `(h, w)`,
    in time order).

    `residual(i, js, grid, lands, oks, avoid)`: frame i's static residual `(h', w')` in pixels against its
    neighbours js (`neighbours` at `neighbour_offsets`), given the judged pixels `grid` `(h', w', 2)` (`Flows.grid`), per neighbour
    where they land and whether that is trusted (`Flows.observe`), and where the frames before found moving
    content (`(h', w')` bool: not to fit cameras on); None when frame i cannot be judged (no camera).
    `on_frame()` is called after each frame; `flows`: the frames' `Flows`, when the caller has them; `reach`: of
    `neighbour_offsets`."""
    n = len(frames)
    flows = flows or Flows(frames)
    grid = flows.grid.astype(np.float64)
    h, w = grid.shape[:2]
    evidence: list[np.ndarray] = []
    to_prev: list[np.ndarray | None] = []  # frame i's pixels in frame i - 1 (trusted ones), for the carrying
    to_next: list[np.ndarray | None] = []
    carried = np.zeros((h, w), np.float32)
    offsets = neighbour_offsets(flows, n, reach)
    for i in range(n):
        js = neighbours(i, n, offsets)
        obs = flows.observe(i, js)
        look = dict(zip(js, obs))
        to_prev.append(_carry_map(look.get(i - 1)))
        to_next.append(_carry_map(look.get(i + 1)))
        prior = CARRY * _warp(carried, to_prev[i])
        r = residual(i, js, grid, [o[0] for o in obs], [o[1] for o in obs], prior > GROW_PX) if js else None
        evidence.append(np.zeros((h, w), np.float32) if r is None else cv2.medianBlur(r.astype(np.float32), 5))
        carried = np.maximum(evidence[i], prior)
        flows.forget(i - max(offsets))
        if on_frame is not None:
            on_frame()
    return clean_masks(evidence, to_prev, to_next, [textured(f) for f in frames])


def _carry_map(obs: tuple[np.ndarray, np.ndarray] | None) -> np.ndarray | None:
    """remap coordinates `(h', w', 2)` float32 of the landing points on the judged grid, NaN where not trusted."""
    if obs is None:
        return None
    land, ok = obs
    out = land / GRID_STEP - 0.5
    out[~ok] = np.nan
    return out


def textured(frame: np.ndarray) -> np.ndarray:
    """Where the grey frame `(h, w)` has texture in two directions (`TEXTURE_MIN`), on the judged grid
    `(h // GRID_STEP, w // GRID_STEP)` bool."""
    h, w = frame.shape
    e = cv2.cornerMinEigenVal(frame.astype(np.float32), 7, ksize=3)
    return cv2.resize(e, (w // GRID_STEP, h // GRID_STEP), interpolation=cv2.INTER_AREA) >= TEXTURE_MIN


def clean_masks(
    evidence: list[np.ndarray],
    to_prev: list[np.ndarray | None],
    to_next: list[np.ndarray | None],
    texture: list[np.ndarray],
) -> list[np.ndarray]:
    """Per-frame residual maps -> masks: carried along the flow both ways in time (max with CARRY times
    the neighbour's), hysteresis (regions over GROW_PX holding a pixel over SEED_PX where the frame has
    `texture`, `textured`), closed, specks under MIN_AREA dropped."""
    n = len(evidence)
    fwd = list(evidence)
    for i in range(1, n):
        fwd[i] = np.maximum(evidence[i], CARRY * _warp(fwd[i - 1], to_prev[i]))
    both = list(fwd)
    back = evidence[-1]
    for i in range(n - 2, -1, -1):
        back = np.maximum(evidence[i], CARRY * _warp(back, to_next[i]))
        both[i] = np.maximum(fwd[i], back)
    h, w = evidence[0].shape
    min_px = MIN_AREA * h * w
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))
    masks = []
    for e, tex in zip(both, texture):
        count, labels, stats, _ = cv2.connectedComponentsWithStats((e > GROW_PX).astype(np.uint8), connectivity=8)
        seeded = np.zeros(count, bool)
        seeded[np.unique(labels[(e > SEED_PX) & tex])] = True
        seeded[0] = False
        m = cv2.morphologyEx(seeded[labels].astype(np.uint8), cv2.MORPH_CLOSE, kernel)
        count, labels, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
        keep = stats[:, cv2.CC_STAT_AREA] >= min_px
        keep[0] = False
        masks.append(keep[labels])
    return masks


def _warp(values: np.ndarray, coords: np.ndarray | None) -> np.ndarray:
    """`values` `(h, w)` sampled at `coords` (`_carry_map`); 0 where there is none."""
    if coords is None:
        return np.zeros_like(values)
    out = cv2.remap(values, coords[..., 0], coords[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    return np.nan_to_num(out, nan=0.0)


# ---------------------------------------------------------------------------------------------
# In the SfM child (seeu_data.ingest.sfm_motion): against the SfM cameras
# ---------------------------------------------------------------------------------------------


class _ModelCameras:
    """The flow the SfM cameras of the pycolmap Reconstruction `rec` allow between the frames `names`
    (in time order, all registered), for frames shrunk to `(h, w)` working pixels. Coordinates are the
    cameras' normalised image coordinates (their distortion undone: `Camera.cam_from_img`)."""

    def __init__(self, rec, names: Sequence[str], h: int, w: int) -> None:
        from seeu_data.cameras import homogeneous_from_3x4

        self.rec, self.h, self.w = rec, h, w
        by_name = {rec.image(i).name: rec.image(i) for i in rec.reg_image_ids()}
        self.images = [by_name[n] for n in names]
        self.poses = [
            homogeneous_from_3x4(np.asarray(img.cam_from_world().matrix(), np.float64)) for img in self.images
        ]
        self.grids: dict[int, np.ndarray] = {}  # camera id -> the judged pixels in its normalised coordinates

    def _normalised(self, camera, pts: np.ndarray) -> np.ndarray:
        full = pts.reshape(-1, 2) * (camera.width / self.w, camera.height / self.h)  # working px -> the camera's px
        return np.asarray(camera.cam_from_img(full.astype(np.float64)), np.float64).reshape(pts.shape)

    def residual(self, i: int, js: Sequence[int], grid: np.ndarray, lands, oks) -> np.ndarray:
        """`static_residual` of frame i's pixels `grid` against its neighbours `js` (see `Residual`)."""
        from seeu_data.cameras import invert_rigid

        cams: Cameras = []
        for j in js:
            rel = self.poses[j] @ invert_rigid(self.poses[i])  # frame i's camera -> frame j's
            cams.append((rel[:3, :3], rel[:3, 3]))
        camera_id = self.images[i].camera_id
        cam_i = self.rec.cameras[camera_id]
        if camera_id not in self.grids:
            self.grids[camera_id] = self._normalised(cam_i, grid)
        seen = [self._normalised(self.rec.cameras[self.images[j].camera_id], la) for j, la in zip(js, lands)]
        scale = cam_i.mean_focal_length() * self.w / cam_i.width
        return static_residual(self.grids[camera_id], seen, oks, cams, scale, [j - i for j in js])


def model_pass(
    source: str | Path | FlowMemo,
    names: Sequence[str],
    rec,
    on_frame: Callable[[], None] | None = None,
    reach: int = 1,
) -> dict[str, np.ndarray]:
    """Moving content of the frames `names` (in time order, all registered in the pycolmap
    Reconstruction `rec`; in the folder or `FlowMemo` `source`) against the flow its cameras allow, to
    neighbours as far as `reach` lets (`neighbour_offsets`; the final masks: MODEL_REACH):
    {name: (h, w) bool at the working size} for frames where some was found."""
    flows = _flows(source, names)
    cameras = _ModelCameras(rec, names, *flows.frames[0].shape)

    def residual(i, js, grid, lands, oks, avoid):
        return cameras.residual(i, js, grid, lands, oks)

    found = detect(flows.frames, residual, on_frame, flows, reach)
    return {n: m for n, m in zip(names, found) if m.any()}


def rigid_pass(
    source: str | Path | FlowMemo, names: Sequence[str], on_frame: Callable[[], None] | None = None
) -> dict[str, np.ndarray]:
    """Moving content of the frames `names` (in time order, in the folder or `FlowMemo` `source`) against the
    best rigid motion of each frame's flow to its neighbours, without cameras: per neighbour, a fundamental
    matrix fitted by RANSAC (seeded) to the trusted flow (RIGID_PX, working px; not fitted where fewer than
    RIGID_TRUSTED of the pixels are trusted), each pixel's residual its largest Sampson distance to them, through
    `detect`'s clean-up: {name: (h, w) bool} for frames where some was found.

    Where a mover carried the SfM cameras, the flow test against them (`model_pass`) finds the static scene
    instead; the best rigid motion of a pair's flow is the static scene's wherever that fills most of the trusted
    pixels. It sees no motion along the epipolar lines (`model_pass`'s depth consistency does)."""
    from seeu_data.camera_check import sampson_error

    flows = _flows(source, names)
    cv2.setRNGSeed(0)

    def residual(i, js, grid, lands, oks, avoid):
        res = np.zeros(grid.shape[:2])
        for land, ok in zip(lands, oks):
            if ok.mean() < RIGID_TRUSTED:
                continue
            fit = cv2.findFundamentalMat(grid[ok], land[ok].astype(np.float64), cv2.FM_RANSAC, RIGID_PX, 0.999)[0]
            if fit is None or fit.shape != (3, 3):
                continue
            dist = sampson_error(fit, grid.reshape(-1, 2), land.reshape(-1, 2).astype(np.float64)).reshape(ok.shape)
            res = np.where(ok & np.isfinite(dist), np.maximum(res, dist), res)
        return res

    found = detect(flows.frames, residual, on_frame, flows)
    return {n: m for n, m in zip(names, found) if m.any()}


def rigid_gaps(
    source: str | Path | FlowMemo, names: Sequence[str], rec, masks: dict[str, np.ndarray]
) -> list[tuple[int, int, float]]:
    """Per pair (i, j) of the frames `names` (in time order, all registered in the pycolmap Reconstruction `rec`),
    j the farthest neighbour after i (`neighbour_offsets`: up to MAX_OFFSET frames, about FAR_MOTION_PX of image
    motion: a wider baseline than consecutive frames, for a better defined rigid motion): the share of the
    pair's trusted flow (`Flows.observe`, one pixel per 2 x GRID_STEP block) that the best rigid motion explains
    (an essential matrix fitted by RANSAC, seeded) less the share that the SfM cameras explain, a pixel explained
    within RIGID_PX of its epipolar line (Sampson distance, working px). 0 where most of what the best rigid
    motion explains is frame i's moving content (`masks`, as `model_pass`'s: the motion found is a mover's,
    filling much of the view); NaN where the flow is trusted in fewer than RIGID_TRUSTED of the pixels (not
    judged). Returns [(i, j, gap)]."""
    from seeu_data.camera_check import sampson_error, skew
    from seeu_data.cameras import invert_rigid

    flows = _flows(source, names, step=2 * GRID_STEP)
    h, w = flows.frames[0].shape
    at = flows.grid.astype(int) // GRID_STEP  # the pixels judged, on the masks' grid
    cameras = _ModelCameras(rec, names, h, w)
    k = max(neighbour_offsets(flows, len(names)))
    cv2.setRNGSeed(0)
    gaps = []
    for i, name in enumerate(names[:-k]):
        land, ok = flows.observe(i, [i + k])[0]
        flows.forget(i + 1)
        if ok.mean() < RIGID_TRUSTED:
            gaps.append((i, i + k, float("nan")))
            continue
        x1, x2 = flows.grid[ok].astype(np.float64), land[ok].astype(np.float64)
        moving = masks[name][at[..., 1], at[..., 0]][ok] if name in masks else None
        cam1, cam2 = (rec.cameras[cameras.images[f].camera_id] for f in (i, i + k))
        n1, n2 = cameras._normalised(cam1, x1), cameras._normalised(cam2, x2)
        tol = RIGID_PX / (cam1.mean_focal_length() * w / cam1.width)  # in normalised units
        rel = cameras.poses[i + k] @ invert_rigid(cameras.poses[i])
        sfm = skew(rel[:3, 3]) @ rel[:3, :3]  # the cameras' essential matrix
        best = cv2.findEssentialMat(n1, n2, np.eye(3), cv2.RANSAC, 0.999, tol)[0]
        found = np.zeros((0, 3)) if best is None else np.asarray(best)  # up to 3 solutions, stacked
        fitted = [sampson_error(found[r : r + 3], n1, n2) < tol for r in range(0, len(found), 3)]
        inliers = max(fitted, key=np.mean, default=np.zeros(len(x1), bool))
        mover = moving is not None and inliers.any() and moving[inliers].mean() > 0.5
        explained = float((sampson_error(sfm, n1, n2) < tol).mean())
        gaps.append((i, i + k, 0.0 if mover else float(inliers.mean()) - explained))
    return gaps


def cameras_unlike_rigid(over: Sequence[tuple[str, str, float]], pairs: int) -> str | None:
    """Why the SfM cameras cannot be trusted when, in at least MIN_MOVING_FRAMES of the `pairs` pairs of mapped
    frames judged, a rigid motion explains more than RIGID_GAP more of the flow than they do (`over`: those
    pairs' frames and gaps, `rigid_gaps`, in time order); None otherwise."""
    if len(over) < MIN_MOVING_FRAMES:
        return None
    return (
        f"the cameras explain the optical flow worse than a rigid motion does in {len(over)} of {pairs} pairs of "
        f"mapped frames ({over[0][0]} to {over[-1][1]}, by up to {100 * max(g for *_, g in over):.0f}% of the "
        "pixels): a moving object carried SfM, or the poses are wrong there"
    )


def astray_frames(source: str | Path | FlowMemo, names: Sequence[str], rec) -> list[str]:
    """The frames among `names` (in time order, all registered in `rec`) whose SfM cameras alone are wrong
    (`astray_runs` of which neighbouring frames disagree: the pair's residual, `static_residual`, over
    GROW_PX in most pixels judged). A frame that SfM placed astray (registered through a mover held still
    in the frame, say) would otherwise leave its neighbours' flow unexplained and stand for a mover over all
    of them."""
    if len(names) < 3:
        return []
    flows = _flows(source, names)
    cameras = _ModelCameras(rec, names, *flows.frames[0].shape)
    grid = flows.grid.astype(np.float64)
    bad = []
    for k in range(len(names) - 1):
        land, ok = flows.observe(k, [k + 1])[0]
        r = cameras.residual(k, [k + 1], grid, [land], [ok])
        bad.append(bool(ok.sum() >= 0.05 * ok.size and np.median(r[ok]) > GROW_PX))
        flows.forget(k)
    return [names[k] for k in astray_runs(bad)]


def astray_runs(bad: Sequence[bool], run: int = MAX_ASTRAY_RUN) -> list[int]:
    """Which frames are astray, from `bad[k]`: frames k and k + 1 disagree. The disagreeing pairs cut the
    frames into stretches that agree within; a stretch is sound when it holds more than `run` frames, or
    two or more at an end of the clip. Between two sound stretches (or one and an end of the clip), at most
    `run` frames in all are astray. More disagreement in a row (a mover filling most of the view) keeps its
    frames, as does a clip with no sound stretch."""
    n = len(bad) + 1
    starts = [0] + [k + 1 for k, b in enumerate(bad) if b]
    stretches = list(zip(starts, [*starts[1:], n]))
    sound = [e - s > run or (e - s >= 2 and (s == 0 or e == n)) for s, e in stretches]
    if not any(sound):
        return []
    out: list[int] = []
    i = 0
    while i < len(stretches):
        j = i
        while j < len(stretches) and not sound[j]:
            j += 1
        if j > i and stretches[j - 1][1] - stretches[i][0] <= run:
            out.extend(range(stretches[i][0], stretches[j - 1][1]))
        i = j + 1
    return out


def moving_keypoints(xy: np.ndarray, mask: np.ndarray, width: int, height: int) -> np.ndarray:
    """Which keypoints `(N, 2)` (pixels of a `width` x `height` frame, COLMAP's: the top-left corner at 0)
    fall in `mask` `(h, w)` bool (working size): `(N,)` bool."""
    h, w = mask.shape
    cols = np.clip((np.asarray(xy)[:, 0] * w / width).astype(np.int64), 0, w - 1)
    rows = np.clip((np.asarray(xy)[:, 1] * h / height).astype(np.int64), 0, h - 1)
    return mask[rows, cols]


def grown_moving(moving: dict[int, np.ndarray], pairs: Sequence[tuple[int, int, np.ndarray]]) -> dict[int, np.ndarray]:
    """`moving` {image id: (N,) bool over its keypoints} grown along verified matches `pairs` [(image a, image b,
    (M, 2) keypoint indices)] into the images with no moving keypoint, MATCH_HOPS times: there a keypoint matched
    to a moving one becomes moving (new arrays; an image with some keeps its own)."""
    empty = {k for k, v in moving.items() if not v.any()}
    for _ in range(MATCH_HOPS):
        grown = {k: v.copy() for k, v in moving.items()}
        for a, b, matches in pairs:
            if a in empty:
                grown[a][matches[moving[b][matches[:, 1]], 0]] = True
            if b in empty:
                grown[b][matches[moving[a][matches[:, 0]], 1]] = True
        moving = grown
    return moving


def drop_observations(rec, masks: dict[str, np.ndarray]) -> int:
    """Remove from the Reconstruction `rec` (in place) every observation whose keypoint lies in its frame's
    moving mask (a point left with fewer than two observations goes); returns how many."""
    dropped = 0
    for iid in rec.reg_image_ids():
        img = rec.image(iid)
        if img.name not in masks:
            continue
        cam = rec.cameras[img.camera_id]
        idxs = np.asarray(img.get_observation_point2D_idxs(), np.int64)
        if not len(idxs):
            continue
        xy = np.array([img.point2D(int(k)).xy for k in idxs], np.float64)
        for k in idxs[moving_keypoints(xy, masks[img.name], cam.width, cam.height)]:
            if rec.image(iid).point2D(int(k)).has_point3D():  # not gone with a point deleted before
                rec.delete_observation(iid, int(k))
                dropped += 1
    return dropped


def full_size(mask: np.ndarray, width: int, height: int) -> np.ndarray:
    """A working-size mask `(h, w)` bool at the frame's size `(height, width)` bool (bilinear, halfway)."""
    up = cv2.resize(mask.astype(np.uint8) * 255, (width, height), interpolation=cv2.INTER_LINEAR)
    return up >= 128


def moving_content(facts: dict) -> str | None:
    """With --dynamic off: why the moving content found in the mapped frames makes the poses
    untrustworthy (from result.json's "motion" `facts`), or None when too little was found: regions in
    fewer than MIN_MOVING_FRAMES frames, or holding less than MIN_MOVING_SHARE of the model's
    observations (what the static synthetic clips stay under)."""
    seen = facts.get("keyframes") or {}
    found = seen.get("frames_with_motion", 0)
    left = facts.get("leave_out")
    if found < MIN_MOVING_FRAMES or (left and left["observations"] < MIN_MOVING_SHARE * left.get("total", 0)):
        return None
    out = f"moving content in {found} of {seen.get('judged')} mapped frames is not masked (--dynamic off)"
    if left:
        out += (
            f"; leaving its {left['observations']} observations out moves the cameras "
            f"{left['centre_change_pct']:.2g}% of the path"
        )
    return out + "; re-run with --dynamic mask"


def masked_content_carried(facts: dict, line_pct: float) -> str | None:
    """With --dynamic mask: why the cameras cannot be trusted when the moving content found in the mapped frames
    carried them (from result.json's "motion" `facts`): adjusted with and without its observations (`leave_out`),
    the cameras lie more than `line_pct` of the path apart (the solution check's line between two mapping runs,
    `max_disagreement_pct`): the adjustment that leaves it out starts from cameras it pulled, and nothing confirms
    where that ends; None otherwise. Measured (`benchmarks/dynamic.py`, 320x180): the person walking ahead of the
    camera 2.1-3.1 % (cameras 1.6-2.6 % of the path off after it); with the cameras right after it, the slow box
    0.87 %, the others at most 0.2 %."""
    left = facts.get("leave_out")
    if not left or left["centre_change_pct"] <= line_pct:
        return None
    return (
        f"leaving out the {left['observations']} observations of the moving content found moves the cameras "
        f"{left['centre_change_pct']:.2g}% of the path: it carried SfM, and the cameras masked are not confirmed"
    )


def _mostly_moving(masks: dict[str, np.ndarray], judged: Sequence[str]) -> list[int]:
    """Indices into `judged` of the frames whose `masks` cover more than MOSTLY_MOVING of the frame."""
    return [i for i, name in enumerate(judged) if name in masks and masks[name].mean() > MOSTLY_MOVING]


def cameras_disagree(masks: dict[str, np.ndarray], judged: Sequence[str]) -> str | None:
    """Why the SfM cameras cannot be trusted when, in at least MIN_MOVING_FRAMES of the frames `judged`
    (in time order), more than MOSTLY_MOVING of the pixels disagree with the flow they allow (`masks`
    from `model_pass`); None otherwise."""
    most = _mostly_moving(masks, judged)
    if len(most) < MIN_MOVING_FRAMES:
        return None
    return (
        f"the cameras disagree with the optical flow over most of {len(most)} of {len(judged)} mapped frames "
        f"({judged[most[0]]} to {judged[most[-1]]}): a large or slow moving object carried SfM, or the poses are "
        "wrong there"
    )


def unexplained_frames(masks: dict[str, np.ndarray], judged: Sequence[str], repaired: Sequence[str] = ()) -> list[str]:
    """The frames of `judged` (registered, in time order) that the final masks find mostly unexplained (`masks`
    over MOSTLY_MOVING), to be left out of the output: all of them when there are at least MIN_MOVING_FRAMES and at
    most half of `judged`, and at most REPAIR_LEFT_MAX of the stretch of `judged` from the first to the last of the
    frames a mover carried (`repaired`: `carried_frames`, placed again); else none (`cameras_disagree` fails the
    check where there are MIN_MOVING_FRAMES).

    The final masks, reaching farther, can find the cameras of a stretch wrong where the keyframes looked right:
    `far` at 320x180 (`benchmarks/dynamic.py`) had frames 60-71 60-90 % masked, their cameras 0.5-2.8 % of the path
    off, the rest within 0.2 %. Or a mover that carried frames still fills much of a few after their repair."""
    most = _mostly_moving(masks, judged)
    if not MIN_MOVING_FRAMES <= len(most) <= len(judged) // 2:
        return []
    carried = set(repaired)
    span = [i for i, name in enumerate(judged) if name in carried]
    if span:
        left = [i for i in most if span[0] <= i <= span[-1]]
        if len(left) > REPAIR_LEFT_MAX * (span[-1] - span[0] + 1):
            return []
    return [judged[i] for i in most]


def carried_frames(masks: dict[str, np.ndarray], judged: Sequence[str]) -> list[str]:
    """The frames of `judged` (mapped, in time order) whose cameras a mover carried, to be placed again against
    the rest once its observations there are gone: the frames mostly unexplained
    (`masks` over MOSTLY_MOVING), widened (`_widened`, REPAIR_MARGIN). Empty when fewer than MIN_MOVING_FRAMES
    are mostly unexplained (`cameras_disagree` says nothing), or when no stretch of MIN_SOUND_RUN frames is
    left (nothing sound to place them against).

    A mover filling much of the view pulls SfM's cameras along with it: its own flow then fits them, the
    static scene's does not, and the frames look mostly moving where the mover was. Frames without it
    (or where it is small) keep cameras that the flow confirms."""
    most = _mostly_moving(masks, judged)
    if len(most) < MIN_MOVING_FRAMES:
        return []
    return _widened(most, judged, REPAIR_MARGIN)


def trial_frames(masks: dict[str, np.ndarray], judged: Sequence[str], margin: int) -> list[str]:
    """Nothing carried (`carried_frames`): the frames of `judged` (mapped, in time order) to place again against
    the rest on trial, because a mover may have carried them where the flow test cannot see it: the frames with
    moving content (`masks`), widened (`_widened`, `margin` frames). Empty when fewer than MIN_MOVING_FRAMES have
    any, or the frames to place again would be more than half of `judged` (moving content through most of the
    clip: nothing to place them against).

    A mover moving along the epipolar lines of a forward walk stays in the flow test's blind spot, and the
    scale drift it gives SfM's cameras is absorbed by each pixel's free depth: only a few of its pixels are
    found (2-13 % of 8 of 46 frames of the large mover at 320x180, whose cameras were 7 % of the path off)."""
    found = [i for i, name in enumerate(judged) if name in masks]
    if len(found) < MIN_MOVING_FRAMES:
        return []
    out = _widened(found, judged, margin)
    return out if 2 * len(out) <= len(judged) else []


def _widened(flagged: Sequence[int], judged: Sequence[str], margin: int) -> list[str]:
    """The frames of `judged` at the indices `flagged`, `margin` more on each side of each, and every stretch left
    between them or at an end of the clip shorter than MIN_SOUND_RUN; empty when no stretch of MIN_SOUND_RUN
    frames is left."""
    doubtful = np.zeros(len(judged), bool)
    for i in flagged:
        doubtful[max(0, i - margin) : i + margin + 1] = True
    edges = np.flatnonzero(np.diff(np.r_[True, doubtful, True].astype(np.int8)))  # where sound stretches start/end
    for start, end in zip(edges[::2], edges[1::2]):
        if end - start < MIN_SOUND_RUN:
            doubtful[start:end] = True
    if doubtful.all():
        return []
    return [judged[int(i)] for i in np.flatnonzero(doubtful)]


def report_section(facts: dict | None, frames: Sequence[dict]) -> dict | None:
    """report.json's "motion": the SfM stage's facts (`facts`, None for a stage without them), with
    "masked_pct" as [source frame, % of the frame masked] for each of the selected `frames` (records with
    "name", "source_frame") that has a mask, "frames_masked" and "mean_masked_pct" over all of them."""
    if not facts:
        return None
    pct = facts.get("masked_pct", {})
    per = [[f["source_frame"], round(float(pct[f["name"]]), 3)] for f in frames if f["name"] in pct]
    out = {k: v for k, v in facts.items() if k != "masked_pct"}
    out["masked_pct"] = per
    out["frames_masked"] = len(per)
    out["mean_masked_pct"] = sum(p for _, p in per) / max(len(frames), 1)
    return out
