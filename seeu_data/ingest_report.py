"""The ingest report: `report.json`, `trajectory.png` (matplotlib Agg) and one summary line.

report.json keys: scene, input, frames_decoded (frames in the source), frames_candidates (after --stride),
frames_selected, registered, registration_rate (registered / selected), frames_in_chunks,
mean_reprojection_error_px, sfm {num_keypoints, num_verified_pairs, timings_s, models: [...], discarded_models: [...],
mapping_attempts: [{seed, registered, models}]},
chunks [{scene_id, num_frames, source_frames [first, last], near, far, sfm_model}],
dropped_frames [{source_frame, reason}], timings_s {stage: seconds}, reused {stage: bool},
ground_truth (only when the input has a synthetic ground-truth JSON beside it), output.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .arrow_io import atomic_write_bytes, atomic_write_text


def mean_reprojection_error(models: list[dict]) -> float:
    """Image-count-weighted mean of the models' mean reprojection errors (pixels)."""
    if not models:
        return float("nan")
    w = np.array([len(m["images"]) for m in models], np.float64)
    e = np.array([m["mean_reprojection_error"] for m in models], np.float64)
    return float((w * e).sum() / w.sum())


def write_report(path: str | Path, report: dict) -> None:
    atomic_write_text(path, json.dumps(report, indent=1, default=float) + "\n")


def plot_trajectory(path: str | Path, chunks: list, title: str) -> None:
    """Top view (x-z) and side view (z-y) of every chunk's camera centres, with viewing directions.

    `chunks`: objects with `scene_id` and `cam_to_world (N, 4, 4)`; each chunk in its own frame.
    """
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4.5))
    for chunk in chunks:
        c = chunk.cam_to_world[:, :3, 3]
        fwd = chunk.cam_to_world[:, :3, 2]
        span = max(float(np.ptp(c, axis=0).max()), 1e-6)
        step = max(1, len(c) // 15)
        for ax, (i, j) in zip(axes, [(0, 2), (2, 1)]):
            line, = ax.plot(c[:, i], c[:, j], ".-", ms=3, lw=1, label=f"{chunk.scene_id} ({len(c)} frames)")
            ax.quiver(c[::step, i], c[::step, j], fwd[::step, i], fwd[::step, j], color=line.get_color(),
                      angles="xy", scale_units="xy", scale=1 / (0.12 * span), width=0.004)
            ax.plot(c[0, i], c[0, j], "o", color=line.get_color())
    axes[0].set(xlabel="x", ylabel="z", title="top view (x-z); arrows: viewing direction")
    axes[1].set(xlabel="z", ylabel="y", title="side view (z-y, +y down)")
    axes[1].invert_yaxis()
    for ax in axes:
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7, loc="best")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())


def summary_line(report: dict) -> str:
    """One line for the terminal."""
    rate = 100 * report["registration_rate"]
    attempts = len(report["sfm"].get("mapping_attempts", []))
    line = (f"{report['scene']}: {report['registered']}/{report['frames_selected']} frames registered ({rate:.1f}%"
            + (f" after {attempts} mapping runs" if attempts > 1 else "") + "), "
            f"{len(report['chunks'])} chunk(s) with {report['frames_in_chunks']} frames, "
            f"reprojection {report['mean_reprojection_error_px']:.2f} px, "
            f"{report['timings_s']['total']:.1f} s -> {report['output']}")
    gt = report.get("ground_truth")
    if gt and gt.get("chunks"):
        best = max(gt["chunks"], key=lambda c: c["num_frames"])
        line += (f" | vs ground truth: centre RMSE {best['centre_rmse_pct_path']:.3f}% of path, "
                 f"rel. rotation {best['rel_rot_err_mean_deg']:.3f} deg, focal {best['focal_err_pct']:.2f}%")
    return line
