"""The predict stage: a trained checkpoint's 3D Gaussians for your own posed scene, and novel views.

Input: a posed scene (the output of `seeu ingest` or `seeu import`: a posed-frames directory with
manifest.json; `scene` picks one when it holds several) and context frames: `context` (frame indices
0 .. N-1 of the scene, at least two) or, when None, `auto_context_pair`: by the scene's view overlap
(its stored table, `seeu_data.overlap`), the pair that covers the scene's views best (the mean over
its frames of the larger share either context sees) among the pairs that overlap at least the build
sampler's floor (`SamplingConfig().min_overlap`); when none does, the pair that overlaps most, with a
warning. The frames' numbering and names do not matter (the cameras' canonical order breaks ties).
With the auto pair, the extrapolated path is also kept where the contexts see something
(`extrapolation_limit`: at most `extrapolate`, as far as the path's end cameras still share the
floor with a context, by the cameras measure).

The context frames are decoded, resized to cover the model's input size and centre-cropped (the
intrinsics updated), with the scene's near/far: the same context `seeu render --cameras` builds
(`render.context_from_views`), the same checkpoint loading (`render.load_model`), encoder and
renderer. Writes OUT/gaussians.ply (3DGS layout) with OUT/cameras.json (the context cameras) and
OUT/gaussians.json, OUT/frames/{interp,extrap}_NNN.png (the camera path from the first to the last
context camera, t in [0, 1] and [-e, 1 + e]), OUT/context.png, and OUT/predict.json (written last).

Example:
    from pipelines.predict import PredictConfig, predict

    report = predict(PredictConfig(scene_dir="data/posed/clip", checkpoint="runs/re10k/checkpoints", out="out/p"))
    report["context_frames"], report["ply"], report["num_gaussians"]
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

from seeu_data.errors import SeeUError
from seeu_data.limits import MAX_CONTEXT_VIEWS, MAX_IMAGE_SIDE, MAX_PIXELS, MAX_RENDER_FRAMES, check_range
from seeu_data.settings import parse_dims, parse_indices, setting
from seeu_data.store.out_lock import locks_output

FRAMES = 5  # views per camera path
EXTRAPOLATE = 0.5  # the extrapolated path runs from t = -e to 1 + e


@dataclass(frozen=True, kw_only=True)
class PredictConfig:
    """One `seeu predict` run: `scene_dir` a posed-frames directory, `scene` its scene id (None: its
    only scene), `context` frame indices (None: `auto_context_pair`), `frames` views per path,
    `extrapolate` e, `image_size` (H, W) (None: the training size), `device` (None: cuda when
    available), `rasterizer` auto | torch | gsplat (None: the training config's); `auto_context` only
    says that `context` is None on the command line (--auto-context)."""

    scene_dir: str | Path = setting(
        help="posed-frames directory (manifest.json)", positional=True, metavar="POSED_SCENE"
    )
    checkpoint: str | Path = setting(help="a ckpt-*.pt file or a directory (its newest checkpoint)")
    out: str | Path
    scene: str | None = setting(None, "scene id (default: the directory's only scene)")
    context: tuple[int, ...] | None = setting(
        None, "context frame indices (0..N-1)", parse=parse_indices, metavar="I,J", exclusive="context"
    )
    auto_context: bool = setting(False, "pick the context pair (the default; rule above)", exclusive="context")
    frames: int = setting(FRAMES, "views per path")
    extrapolate: float = setting(EXTRAPOLATE, "extrapolated path runs from t=-e to 1+e")
    image_size: tuple[int, int] | None = setting(
        None, "default: the training image size", parse=parse_dims, metavar="HxW"
    )
    device: str | None = setting(None, "default: cuda when available")
    rasterizer: str | None = setting(None, "auto | torch | gsplat (default: the training config's)")
    max_pixels: int = MAX_PIXELS

    def check(self) -> None:
        check_range(self.frames, "--frames", 2, MAX_RENDER_FRAMES)
        for side in self.image_size or ():
            check_range(side, "--image-size", 1, MAX_IMAGE_SIDE)
        if not (math.isfinite(self.extrapolate) and self.extrapolate >= 0):
            raise SeeUError(f"--extrapolate must be a finite number >= 0, got {self.extrapolate}")
        if self.context is not None:
            check_range(len(self.context), "context frames in --context", 2, MAX_CONTEXT_VIEWS)
            if len(set(self.context)) != len(self.context):
                raise SeeUError(f"--context frames must differ, got {','.join(map(str, self.context))}")


def auto_context_pair(table, cam_to_world, intrinsics_norm) -> tuple[tuple[int, int], float, float]:
    """The context pair `--auto-context` picks (module docstring): ((i, j) with i < j, its overlap, its
    coverage of the scene's views). `table`: the scene's OverlapTable; cam_to_world (N, 4, 4),
    intrinsics_norm (N, 4) fix the canonical order that breaks ties."""
    import numpy as np

    from seeu_data.build.sampling import SamplingConfig
    from seeu_data.overlap import canonical_order

    n = table.num_frames
    if n < 2:
        raise SeeUError(f"the scene has {n} frame(s): at least two are needed as context views")
    order = canonical_order(cam_to_world, intrinsics_norm)
    m = table.matrix()[np.ix_(order, order)]
    score = np.minimum(m, m.T)
    a, b = np.triu_indices(n, 1)
    cover = np.maximum(m[:, a], m[:, b]).mean(0)  # (P,) per pair: mean over frames of the larger share seen
    ok = score[a, b] >= SamplingConfig().min_overlap
    best = int(np.argmax(np.where(ok, cover, -1.0))) if ok.any() else int(np.argmax(score[a, b]))
    i, j = sorted((int(order[a[best]]), int(order[b[best]])))
    return (i, j), float(score[a[best], b[best]]), float(cover[best])


def extrapolation_limit(c2w, intr, near: float, far: float, extrapolate: float, steps: int = 10) -> float:
    """The largest e in [0, `extrapolate`] (in `steps` steps) for which the extrapolated path's end
    cameras (t = -e and 1 + e, `camera_path`) still share at least `SamplingConfig().min_overlap` with
    a context camera (`overlap.camera_overlap_matrix`). c2w (2, 4, 4), intr (2, 3, 3) normalised."""
    import numpy as np

    from seeu_data.build.sampling import SamplingConfig
    from seeu_data.cameras import intrinsics_norm_vector
    from seeu_data.overlap import camera_overlap_matrix
    from seeu_model.camera_path import camera_path

    floor = SamplingConfig().min_overlap
    k = np.stack([intrinsics_norm_vector(x) for x in intr])
    for e in np.linspace(extrapolate, 0.0, steps + 1):
        poses, ks = camera_path(c2w[0], c2w[-1], intr[0], intr[-1], np.array([-e, 1.0 + e]))
        cams = np.concatenate([c2w[[0, -1]], poses])
        m = camera_overlap_matrix(
            cams, np.concatenate([k[[0, -1]], [intrinsics_norm_vector(x) for x in ks]]), near, far
        )
        if min(m[2, :2].max(), m[3, :2].max()) >= floor:
            return float(e)
    return 0.0


def load_posed_scene(scene_dir: str | Path, scene: str | None, max_pixels: int = MAX_PIXELS):
    """The PosedScene of a posed-frames directory (SeeUError, one line, for anything else: a folder of
    images, an unfinished ingest, another kind of dataset)."""
    from seeu_data.store.dataset_check import check_dataset
    from seeu_data.store.posed import SCHEMA, PosedDataset

    check_dataset(scene_dir, check_sha=False, max_pixels=max_pixels, expect_schema=SCHEMA)
    ds = PosedDataset(scene_dir)
    if scene is None:
        if len(ds.scene_ids) != 1:
            shown = ", ".join(ds.scene_ids[:5]) + (", ..." if len(ds.scene_ids) > 5 else "")
            raise SeeUError(f"the dataset holds {len(ds.scene_ids)} scenes ({shown}): pick one with --scene", scene_dir)
        scene = ds.scene_ids[0]
    if scene not in set(ds.scene_ids):
        raise SeeUError(f"no scene {scene!r} in this dataset", scene_dir)
    return ds.load_scene(scene)


@locks_output(lambda cfg: cfg.out)
def predict(cfg: PredictConfig) -> dict:
    """Python API of `seeu predict`; returns the report (also OUT/predict.json)."""
    import numpy as np
    import torch

    from pipelines.render import context_from_views, export_gaussians, load_model, render_paths, to_uint8, write_png
    from seeu_data.image_ops import decode_rgb
    from seeu_data.store.arrow_io import atomic_write_text
    from seeu_model.training.factory import encode_context
    from seeu_model.training.loop import batch_to

    cfg.check()
    scene = load_posed_scene(cfg.scene_dir, cfg.scene, cfg.max_pixels)
    n = len(scene)
    picked = "auto" if cfg.context is None else "given"
    auto: dict = {}
    context: tuple[int, ...]
    if cfg.context is None:
        from seeu_data.build.sampling import SamplingConfig
        from seeu_data.store.posed import PosedDataset

        table = PosedDataset(cfg.scene_dir).overlap(scene.scene_id)
        context, overlap, cover = auto_context_pair(table, scene.cam_to_world, scene.intrinsics_norm)
        floor = SamplingConfig().min_overlap
        auto = {"overlap": overlap, "coverage": cover, "floor": floor, "overlap_method": table.method}
        if overlap < floor:
            auto["warning"] = (
                f"the best context pair overlaps by {overlap:.2f}, under {floor:g}: its novel views will be poor "
                "(no two frames of this scene see enough of the same content)"
            )
    else:
        context = tuple(sorted(cfg.context))
    bad = [i for i in context if not 0 <= i < n]
    if bad:
        raise SeeUError(
            f"--context frame {bad[0]} is not in scene {scene.scene_id!r} (frames 0..{n - 1})", cfg.scene_dir
        )
    loaded = load_model(cfg.checkpoint, cfg.image_size, cfg.device, cfg.rasterizer)
    hw = loaded.image_hw
    images = []
    for i in context:
        where = f"{cfg.scene_dir} scene {scene.scene_id!r} frame {i}"
        images.append(decode_rgb(bytes(scene.images[i]), where, cfg.max_pixels))
    ctx = context_from_views(
        images, scene.cam_to_world[list(context)], scene.intrinsics_norm[list(context)], scene.near, scene.far, hw
    )
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "predict.json").unlink(missing_ok=True)
    ctx = batch_to({"context": ctx}, loaded.device)["context"]
    report: dict = {
        "checkpoint": loaded.ck["path"],
        "step": loaded.ck["step"],
        "scene_dir": str(cfg.scene_dir),
        "scene_id": scene.scene_id,
        "num_frames": n,
        "context_frames": list(context),
        "context_rule": picked,
        **({"auto_context": auto} if auto else {}),
        "image_hw": list(hw),
        "near": float(scene.near),
        "far": float(scene.far),
    }
    t0 = time.perf_counter()
    with torch.no_grad():
        g = encode_context(loaded.model, ctx)
    report["timing_s"] = {"encode": time.perf_counter() - t0}
    extrapolate = cfg.extrapolate
    if auto:
        c2w = ctx["cam_to_world"][0].double().cpu().numpy()
        intr = ctx["intrinsics"][0].double().cpu().numpy()
        extrapolate = extrapolation_limit(c2w, intr, scene.near, scene.far, cfg.extrapolate)
        auto["extrapolate"] = {"requested": cfg.extrapolate, "used": extrapolate}
    render_paths(loaded, ctx, g, out, cfg.frames, extrapolate, None, report)
    write_png(out / "context.png", np.concatenate([to_uint8(v) for v in ctx["image"][0]], axis=1))
    report.update(export_gaussians(out, g, {"context": ctx}, hw))
    report["num_gaussians"] = int(g.means.shape[1])
    atomic_write_text(out / "predict.json", json.dumps(report, indent=2) + "\n")
    return report
