"""The ingest report: `report.json`, `trajectory.png` (matplotlib Agg) and one summary line.

report.json keys: scene, input, frames_decoded (frames in the source), frames_candidates (after --stride),
frames_selected, registered, registration_rate (registered / selected), frames_in_chunks,
mean_reprojection_error_px, sfm {num_keypoints, num_verified_pairs, timings_s, cpu_timings_s (the SfM child's
stages: extract_s, match_s, map_s, undistort_s, export_s), models: [...], discarded_models: [...],
mapping_attempts: [{seed, registered, models, seconds, disagreement_pct, init ("forward motion": the run's
models came from its forward-motion retry, `mapping.forward_below`)}], keyframes {stride, count, motion_px,
target_px, registered_after}, resumed {images, pairs, map_runs: what the SfM run kept of an interrupted
one of the same job: frames with features, matched pairs, finished mapping runs},
solution_check {ran, passed, state (passed | failed | not run), disagreement_pct, kept_seed, focal_spread_pct (a
video mapped into several models: how far apart their focal lengths are, `solution_check.one_camera`), focal_hold
(a video: how firmly the footage holds the focal length, `solution_check.focal_held`), corner_pincushion_pct (a
video: the fitted distortion's push at the image corners, `solution_check.no_pincushion`),
planar_or_panoramic_pairs, verified_pairs (among the mapped frames), init ("forward motion": the model kept
came from a forward-motion retry), reason (why a failed check failed), weak_geometry [str] (`weak_geometry`: low parallax, a dominant plane,
too few matches; the likely causes a failed check names)}}, input_identity {path, fingerprint},
chunks [{scene_id, num_frames, source_frames [first, last], near, far, sfm_model, baseline_over_depth (widest
baseline over median point depth, on the SfM model as mapped: the same under every --scale), degeneracy (null, or
why the chunk's depth is unreliable: the camera mostly rotated in place)}],
motion (null for an SfM stage without it): {mode (--dynamic), judged (a video), keyframes, frames
(each pass's frames_with_motion and observations dropped; frames.astray and frames.unexplained: taken out for
good), astray (mapped frames whose camera alone disagreed with the flow, taken out; with mask registered again),
trials [{frames (first, last), count, placed, shift_pct (null: most ended outside the model), unexplained}]
(frames with moving content placed again on trial), carried (mapped frames a mover carried: with mask taken out and registered again),
rigid_gap {max, pairs_judged, pairs_over, taken_out} (the final cameras against each pair's best rigid motion),
leave_out (observations, centre_change_pct: the cameras adjusted without them), static_first {frames_masked,
matches_dropped, kept, reason, focal (its models' focal lengths over the image's longer side), focal_held, held
{frames_masked, matches_dropped, kept, reason} (not kept: the try with that focal length held, `sfm_motion.held_job`)}
(with mask, mapped first without the matches on moving content; not kept: mapped
again with every match), masked_pct [[source frame, % of the frame]] of the frames with a mask, frames_masked,
mean_masked_pct} (seeu_data.ingest.motion),
warnings [str] (a failed solution check, moving content not masked, a camera rotating in place, low parallax;
also in the summary line),
dropped_frames [{source_frame, reason}], timings_s {stage: seconds}, reused {stage: bool},
output. (A synthetic clip's ground truth is compared by `seeu_data.synthetic.ingest_accuracy`, not here.)
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from seeu_data.ingest.video import skipped_line
from seeu_data.store.arrow_io import atomic_write_bytes, atomic_write_text


def mean_reprojection_error(models: list[dict]) -> float:
    """Image-count-weighted mean of the models' mean reprojection errors (pixels)."""
    if not models:
        return float("nan")
    w = np.array([len(m["images"]) for m in models], np.float64)
    e = np.array([m["mean_reprojection_error"] for m in models], np.float64)
    return float((w * e).sum() / w.sum())


def write_report(path: str | Path, report: dict, fsync: bool = False) -> None:
    atomic_write_text(path, json.dumps(report, indent=1, default=float) + "\n", fsync)


def plot_trajectory(
    path: str | Path, chunks: list, title: str, fsync: bool = False, masked: list | None = None
) -> None:
    """Top view (x-z) and side view (z-y) of every chunk's camera centres, with viewing directions; with
    `masked` ([source frame, % of the frame] of the frames with a mask of moving content: report.json's
    motion.masked_pct) a third panel, the share masked per frame.

    `chunks`: objects with `scene_id` and `cam_to_world (N, 4, 4)`; each chunk in its own frame.
    """
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3 if masked else 2, figsize=(15 if masked else 10, 4.5))
    for chunk in chunks:
        c = chunk.cam_to_world[:, :3, 3]
        fwd = chunk.cam_to_world[:, :3, 2]
        span = max(float(np.ptp(c, axis=0).max()), 1e-6)
        step = max(1, len(c) // 15)
        for ax, (i, j) in zip(axes, [(0, 2), (2, 1)]):
            (line,) = ax.plot(c[:, i], c[:, j], ".-", ms=3, lw=1, label=f"{chunk.scene_id} ({len(c)} frames)")
            ax.quiver(
                c[::step, i],
                c[::step, j],
                fwd[::step, i],
                fwd[::step, j],
                color=line.get_color(),
                angles="xy",
                scale_units="xy",
                scale=1 / (0.12 * span),
                width=0.004,
            )
            ax.plot(c[0, i], c[0, j], "o", color=line.get_color())
    axes[0].set(xlabel="x", ylabel="z", title="top view (x-z); arrows: viewing direction")
    axes[1].set(xlabel="z", ylabel="y", title="side view (z-y, +y down)")
    axes[1].invert_yaxis()
    for ax in axes[:2]:
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7, loc="best")
    if masked:
        frames, pct = zip(*masked)
        axes[2].bar(frames, pct, width=1.0, color="tab:red")
        axes[2].set(xlabel="source frame", ylabel="% of the frame", title="moving content masked")
        axes[2].grid(alpha=0.3)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue(), fsync)


def motion_sheet(path: str | Path, frames: list, fsync: bool = False, count: int = 8) -> None:
    """A contact sheet of up to `count` frames with a mask of moving content, evenly spaced, in two rows,
    their masked pixels tinted (`masks.tint_masked`) and their source frame written on them.

    `frames`: (source frame, encoded image, its mask PNG) of every frame with a mask, in order."""
    import cv2

    from seeu_data.image_ops import decode_rgb
    from seeu_data.masks import tint_masked

    picks = [frames[round(k)] for k in np.linspace(0, len(frames) - 1, min(count, len(frames)))]
    tiles = []
    for source_frame, image, mask in picks:
        rgb = tint_masked(decode_rgb(image, f"frame {source_frame}"), mask)
        scale = 320 / max(rgb.shape[:2])
        tile = cv2.resize(rgb, (round(rgb.shape[1] * scale), round(rgb.shape[0] * scale)), interpolation=cv2.INTER_AREA)
        cv2.putText(tile, str(source_frame), (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (255, 255, 255), 1, cv2.LINE_AA)
        tiles.append(tile)
    h, w = tiles[0].shape[:2]
    tiles = [cv2.resize(t, (w, h)) for t in tiles]  # frames of other sizes (photos) fit the first's tile
    cols = -(-len(tiles) // 2) if len(tiles) > 1 else 1
    tiles += [np.zeros_like(tiles[0])] * (2 * cols - len(tiles) if len(tiles) > 1 else 0)
    rows = [np.hstack(tiles[r * cols : (r + 1) * cols]) for r in range(len(tiles) // cols)]
    ok, buf = cv2.imencode(".png", cv2.cvtColor(np.vstack(rows), cv2.COLOR_RGB2BGR))
    if ok:
        atomic_write_bytes(path, buf.tobytes(), fsync)


# Low parallax: the widest baseline b of a chunk over the median scene depth d. Two views b apart see a
# point at depth d under an angle of about b/d radians, and depth from triangulation is uncertain by about
# d * (pixel error / focal) / (b/d), i.e. relative error ~ (1/f) / (b/d). COLMAP drops points seen under
# less than 1.5 deg (b/d ~ 0.026); at b/d = 0.1 (5.7 deg, four times that) even the widest pair only
# reaches ~1.4 % depth error per pixel of noise at a 700 px focal, and the chunk's neighbouring frames far
# less, so its geometry (and the scale, near/far derived from it) is weakly constrained. A pan in place
# or a few centimetres of sway in front of a scene metres away is below it.
LOW_PARALLAX = 0.1
# Degenerate motion: at least this fraction of the verified pairs is explained by a homography (one
# plane, or a rotation without translation) *and* the chunk's parallax is low: the camera mostly turned
# in place, so the SfM depths (and the poses' translations) rest on a few near points. A walk along a
# wall has planar pairs too, but its baseline is large.
MOSTLY_PLANAR = 0.8
ROTATES_IN_PLACE = "camera mostly rotates in place: depth is unreliable"
# Too few matches: a median verified pair of fewer inliers than this (a relative pose from 50 points is
# already uncertain by degrees when they are noisy), or frames matched to fewer than this many others
FEW_INLIERS = 50
FEW_MATCHED_FRAMES = 2.0


def baseline_over_depth(world_to_cam: np.ndarray, depths: np.ndarray) -> float:
    """Largest distance between two camera centres of a chunk over the median depth of the SfM points in
    their cameras, both as mapped (one unit), so the ratio does not depend on any later scale (--scale).

    `world_to_cam`: the chunk's cameras `(N, 3, 4)` or `(N, 4, 4)` in the SfM model's frame; `depths`: `(M,)`
    depths of the model's point observations (`points_depth_<k>.npy`). 0 for one camera; nan without depths."""
    w2c = np.asarray(world_to_cam, np.float64)
    c = -np.einsum("nji,nj->ni", w2c[:, :3, :3], w2c[:, :3, 3])  # centre = -R^T t
    d = np.asarray(depths, np.float64)
    d = d[np.isfinite(d) & (d > 0)]
    if not len(d):
        return float("nan")
    widest = float(np.sqrt(((c[:, None] - c[None]) ** 2).sum(-1)).max()) if len(c) > 1 else 0.0
    return widest / float(np.median(d))


def degeneracy(solution_check: dict, parallax: float) -> str | None:
    """`ROTATES_IN_PLACE` when at least `MOSTLY_PLANAR` of the verified pairs are planar/panoramic
    (`solution_check`: the SfM result's, with `planar_or_panoramic_pairs`, `verified_pairs`) and the
    chunk's baseline/depth `parallax` is below `LOW_PARALLAX`; else None."""
    verified = solution_check.get("verified_pairs") or 0
    planar = solution_check.get("planar_or_panoramic_pairs") or 0
    if verified and planar >= MOSTLY_PLANAR * verified and parallax < LOW_PARALLAX:
        return ROTATES_IN_PLACE
    return None


def weak_geometry(report: dict) -> list[str]:
    """Why the scene's geometry is weakly constrained, as far as the SfM facts in `report` tell (what a
    failed solution check is most likely owed to): low parallax (the smallest `baseline_over_depth` of the
    chunks below `LOW_PARALLAX`), a dominant plane or a camera turning in place (at least `MOSTLY_PLANAR`
    of the verified pairs planar or panoramic: a homography explains them), too few matches (the median
    verified pair below `FEW_INLIERS` inliers, or frames matched to fewer than `FEW_MATCHED_FRAMES`
    others on average). [] when none of these shows."""
    causes = []
    parallax = [c["baseline_over_depth"] for c in report["chunks"] if np.isfinite(c.get("baseline_over_depth", np.nan))]
    if parallax and min(parallax) < LOW_PARALLAX:
        causes.append(f"low parallax (baseline/depth {min(parallax):.3f} < {LOW_PARALLAX})")
    check = report["sfm"].get("solution_check", {})
    verified, planar = check.get("verified_pairs") or 0, check.get("planar_or_panoramic_pairs") or 0
    if verified and planar >= MOSTLY_PLANAR * verified:
        causes.append(
            f"a dominant plane or a camera turning in place ({planar}/{verified} verified pairs planar or panoramic)"
        )
    graph = (report["sfm"].get("mapper") or {}).get("match_graph") or {}
    inliers, degree = graph.get("median_inliers"), graph.get("mean_degree")
    if (inliers is not None and inliers < FEW_INLIERS) or (degree is not None and degree < FEW_MATCHED_FRAMES):
        causes.append(
            f"too few matches (median {inliers or 0:.0f} inliers per verified pair, each frame matched to "
            f"{degree or 0:.1f} others)"
        )
    return causes


def scene_warnings(report: dict) -> list[str]:
    """What the user must know before trusting the scene: a failed solution check, with the likely causes
    (`weak_geometry`); else chunks whose camera mostly rotated in place, other low-parallax chunks."""
    out = []
    check = report["sfm"].get("solution_check", {})
    if check.get("state") == "failed":
        d = check.get("disagreement_pct")
        reason = check.get("reason") or (  # an SfM stage result from before `reason` was recorded
            "no two mapping runs agree"
            + (f" (closest {d:.2g}% of the path apart)" if d is not None and np.isfinite(d) else "")
        )
        causes = None if check.get("moving_content") else check.get("weak_geometry")  # moving content: the reason
        why = (
            f"; likely owed to {', '.join(causes)}"
            if causes
            else ("; no sign of low parallax, a dominant plane or too few matches" if causes is not None else "")
        )
        out.append(f"SfM solution check failed: {reason}{why}; the poses may be wrong")
        return out  # the causes name what the chunk warnings below would
    elif check.get("moving_content"):  # --dynamic off, the check not run (seeu_data.ingest.motion)
        out.append(f"{check['moving_content']}; the poses may be wrong")
    chunks = report["chunks"]
    flagged = [c for c in chunks if c.get("degeneracy")]
    if flagged:
        pairs = f"{check.get('planar_or_panoramic_pairs')}/{check.get('verified_pairs')}"
        out.append(
            f"{ROTATES_IN_PLACE} in "
            + ", ".join(c["scene_id"] for c in flagged)
            + f" (baseline/depth {min(c['baseline_over_depth'] for c in flagged):.3f}, "
            f"{pairs} verified pairs planar or panoramic)"
        )
    low = [c for c in chunks if c.get("baseline_over_depth", np.inf) < LOW_PARALLAX and not c.get("degeneracy")]
    if low:
        out.append(
            f"low parallax: baseline/depth {min(c['baseline_over_depth'] for c in low):.3f} < {LOW_PARALLAX} in "
            + ", ".join(c["scene_id"] for c in low)
            + " (geometry weakly constrained)"
        )
    return out


def summary_line(report: dict) -> str:
    """One line for the terminal."""
    rate = 100 * report["registration_rate"]
    attempts = len(report["sfm"].get("mapping_attempts", []))
    check = report["sfm"].get("solution_check", {})
    expected = 2 if check.get("ran") else 1  # the solution check maps twice
    forward = check.get("init") == "forward motion"  # the model kept came from a forward-motion retry
    first = (report.get("motion") or {}).get("static_first") or {}  # sfm_motion.static_job, held_job
    static, held = first.get("kept"), (first.get("held") or {}).get("kept")
    skipped = skipped_line([(f["name"], f["reason"]) for f in report.get("skipped_files", [])])
    line = (
        f"{report['scene']}: {report['registered']}/{report['frames_selected']} frames registered ({rate:.1f}%"
        + (f" after {attempts} mapping runs" if attempts > expected else "")
        + (", forward motion allowed for the initial pair" if forward else "")
        + (", mapped without a moving object's matches" if static else "")
        + (f", mapped again with the focal length held at {first['focal_held']:.3f}" if held else "")
        + (", mapped again with every match" if static is False and not held else "")
        + "), "
        + (f"{skipped}, " if skipped else "")
        + f"{len(report['chunks'])} chunk(s) with {report['frames_in_chunks']} frames, "
        f"reprojection {report['mean_reprojection_error_px']:.2f} px, "
        + (
            f"solution check passed ({check['disagreement_pct']:.2g}% apart), "
            if check.get("state") == "passed"
            else ""
        )
        + _resumed(report)
        + f"{report['timings_s']['total']:.1f} s -> {report['output']}"
    )
    for w in report.get("warnings", []):
        line += f" | WARNING: {w}"
    return line


def _resumed(report: dict) -> str:
    """`SfM resumed (kept ...), ` when this run's SfM continued an interrupted one, else ''."""
    kept = report["sfm"].get("resumed") or {}
    if report.get("reused", {}).get("sfm") or not any(kept.values()):
        return ""
    what = {"images": "images' features", "pairs": "matched pairs", "map_runs": "mapping runs"}
    return "SfM resumed (kept " + ", ".join(f"{kept[k]} {w}" for k, w in what.items() if kept.get(k)) + "), "
