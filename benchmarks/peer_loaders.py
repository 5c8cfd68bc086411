"""Our exports read by the peers' own code: pixelSplat's and MVSplat's RE10K datasets, DepthSplat's DL3DV
dataset, the 3DGS (INRIA) `.ply` loader and `cameras.json` writer, nerfstudio's dataparser. Not a test
(it needs the peers' sources, fetched by hand), so it is not run by CI; the tests re-implement these readers
(tests/test_peer_ready.py, test_export.py, test_ply.py, test_cameras_json.py) and this script checks
them against the real ones.

Our side, made in a temporary folder (or `--work DIR`, kept and reused) with our own CLI and writers:
`seeu synth` (24 frames, 640x360) -> `seeu ingest` -> `seeu export pixelsplat` (stages test and train)
and `seeu export nerfstudio`; random Gaussians (SH degree 3) + the scene's cameras through
`seeu_model.ply.save_ply_bundle` (`gaussians.ply`, `cameras.json`, `gaussians.json`, what `seeu render`
writes). "Ours" below is the posed dataset as our reader (`PosedDataset`) gives it, float64.

Checks, one line each with PASS/FAIL and the figures (exit 1 on any FAIL, 0 otherwise; a peer whose
folder is not given is skipped with a line):

* mvsplat, pixelsplat (one function, `check_re10k`: MVSplat's `src/dataset` is pixelSplat's with options
  added; `Re10kPeer` holds what differs): `src.dataset.get_dataset` (DatasetRE10k, torch.load of our chunk
  as it is written, torch's default `weights_only`) with the peer's `+experiment=re10k` dataset settings
  (config/dataset/re10k.yaml, view_sampler/bounded.yaml, experiment/re10k.yaml's dataset block; read
  from the checkout with OmegaConf, as Hydra reads them) at stage "test" with the evaluation view
  sampler (an index naming the scene: context first/last frame, every frame a target) and `image_shape`
  360x640 (the crop shim is then the identity): one example per scene, not skipped, 360x640 images, and
  the extrinsics / intrinsics equal ours (pixelSplat's `make_baseline_1`, off in MVSplat's experiment:
  translations divided by the distance between the two context cameras); then the same settings at
  stage "train" with the bounded sampler and the experiment's 256x256: it yields examples (3x256x256).
  Then a phone-size capture: a 1280x720 `seeu synth` clip through a default `seeu ingest` (its own line:
  PASS when it is posed; when that ingest fails, the line says why and our scene upscaled to 1280x720 by
  `resize_scene` stands in) and a default `seeu export pixelsplat` (360x640) is read at stage "test" as
  above: one example, 360x640 images, cameras equal to the 1280x720 ones after the peers' resize + centre
  crop (normalised intrinsics unchanged for 16:9, poses unchanged).
  The two checkouts both name their package `src`: each is imported alone and forgotten afterwards.
* depthsplat (DL3DV, `check_depthsplat`): our scene written as a DL3DV release scene (`1K/<hash>/`,
  transforms.json for 3840x2160, PNG frames in images_8/ 480x270 and images_4/ 960x540), the hash being
  the first scene of DepthSplat's own `assets/dl3dv_start_0_distance_10_ctx_2v_tgt_4v.json`; `seeu import
  dl3dv` at 480p and 960p; default `seeu export pixelsplat` (no warning expected). DepthSplat's
  `src.dataset.get_dataset` -> `DatasetDL3DV` with its `+experiment=dl3dv` dataset settings (the config
  built with dacite as its `load_typed_config` does) at stage "test" with its evaluation sampler on that
  unmodified index file: the scene found by its key, the index's context/target frames, 270x480 images
  (its `ori_image_shape`), cameras equal to our import's and to the source's; the 480p images equal the
  PNG files; then stage "train" with its boundedv2_360 sampler (4 context + 4 target views, augment).
* gaussian-splatting: `scene.gaussian_model.GaussianModel(sh_degree).load_ply` on our `gaussians.ply`
  gives back our means, opacities, scales, rotations and SH; `utils.camera_utils.camera_to_JSON` of the
  same cameras, as its `readColmapCameras` builds them (R = world-to-camera rotation transposed, T = its
  translation, FoV from the focal length in pixels), equals our `cameras.json` (keys, order, values).
* nerfstudio: `NerfstudioDataParserConfig(data=..., load_3D_points=True).setup().get_dataparser_outputs`
  for the train and val splits (default settings: orientation "up", centre "poses", auto scale): every
  frame parsed with our intrinsics and image size; `ply_file_path` read (open3d, as nerfstudio does) to
  our SfM points in its world; and the rays its `Cameras.generate_rays` casts through the pixels where
  our cameras project those points pass through them (distance in pixels).

Stubbed, and why (nothing that reads data): MVSplat's (and DepthSplat's) view-sampler package imports the evaluation
index generator, which imports `pytorch_lightning` (LightningModule, for its training-time index
generation) and `skvideo.io` (video writing) -- both replaced by empty modules; pixelSplat's imports
the same generator, which imports `lightning.pytorch` (LightningModule) -- replaced likewise. Not
stubbed: pixelSplat's evaluation sampler reads `num_context_views` from its global config
(`src.global_cfg`, set by its `main` from the Hydra config): set here the same way (an OmegaConf
config holding the dataset block). The 3DGS `scene.gaussian_model` imports the CUDA extension
`simple_knn._C` (`distCUDA2`, used only when a model is made from a point cloud) -- replaced by an
empty module; its optional `diff_gaussian_rasterization` import is in the peer's own try/except. Its
`load_ply` puts the tensors on device "cuda": without a GPU `torch.tensor(..., device="cuda")` is
redirected to the CPU for that call (values untouched).

How to run (Python 3.11; the peers' sources as checked out below, their code as it is):

    # sources: the GitHub repositories donydchen/mvsplat, dcharatan/pixelsplat, cvg/depthsplat,
    # graphdeco-inria/gaussian-splatting (or a fork holding its commits: check out the upstream commit) and
    # nerfstudio-project/nerfstudio, each checked out (git clone / git archive) into
    # /tmp/peers/{mvsplat,pixelsplat,depthsplat,gaussian-splatting,nerfstudio}; the commits used for RESULTS.md are
    # listed there
    # a virtualenv that sees ours, plus what the peers' imports need (open3d-cpu is the one large wheel)
    python -m venv /tmp/venv-peers
    S=$(.venv/bin/python -c "import site; print(site.getsitepackages()[0])")
    echo "import site; site.addsitedir('$S')" > /tmp/venv-peers/lib/python3.11/site-packages/seeu_venv.pth
    /tmp/venv-peers/bin/pip install jaxtyping einops dacite omegaconf              # pixelSplat, MVSplat
    /tmp/venv-peers/bin/pip install --no-deps viser==1.0.0 msgspec websockets tyro docstring_parser \\
        open3d-cpu plotly narwhals dash janus                                      # nerfstudio (+ open3d)
    apt-get install libusb-1.0-0                                                   # open3d's shared library
    PYTHONPATH=. /tmp/venv-peers/bin/python benchmarks/peer_loaders.py \\
        --mvsplat /tmp/peers/mvsplat --pixelsplat /tmp/peers/pixelsplat --depthsplat /tmp/peers/depthsplat \\
        --gaussian-splatting /tmp/peers/gaussian-splatting \\
        --nerfstudio /tmp/peers/nerfstudio [--work /tmp/peer-work]

(`--no-deps` because nerfstudio's and viser's pins, e.g. opencv-python 4.10 and rich < 15, conflict
with ours; only what the imports need is installed.) Results: benchmarks/RESULTS.md.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import io
import json
import sys
import tempfile
import types
import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from unittest import mock

import numpy as np
import torch
from PIL import Image

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from pipelines.cli import main as cli_main  # noqa: E402
from seeu_data import cameras as cam  # noqa: E402
from seeu_data.ingest.points import read_points_ply  # noqa: E402
from seeu_data.resize import resize_scene  # noqa: E402
from seeu_data.store.posed import PosedDataset, PosedDatasetWriter, PosedScene  # noqa: E402
from seeu_model.gaussians import Gaussians  # noqa: E402
from seeu_model.ply import save_ply_bundle  # noqa: E402

N_FRAMES, W, H = 24, 640, 360
HD_HW = (720, 1280)  # (H, W) of the phone-size capture exported with the default --resize
SH_DEGREE, N_GAUSSIANS = 3, 2000
RESULTS: list[bool] = []


def report(ok: bool, name: str, detail: str) -> None:
    RESULTS.append(ok)
    print(f"{'PASS' if ok else 'FAIL'} {name}: {detail}", flush=True)


def run_cli(args: list[str]) -> None:
    code = cli_main([*args, "--no-progress"])
    if code != 0:
        raise SystemExit(f"seeu {' '.join(args)} exited {code}")


def make_outputs(work: Path) -> None:
    """Our outputs with our own CLI (skipped where `work` already has them)."""
    posed = work / "posed" / "clip"
    if not (posed / "manifest.json").exists():
        run_cli(["synth", "--out", str(work), "--frames", str(N_FRAMES), "--size", f"{H}x{W}"])
        run_cli(["ingest", str(work / "clip.mp4"), "--out", str(work / "posed")])
    for stage in ("test", "train"):
        if not (work / "ps" / stage / "index.json").exists():
            run_cli(["export", "pixelsplat", str(posed), "--out", str(work / "ps"), "--stage", stage])
    # a phone-size capture: a 1280x720 clip through default ingest, else (when that ingest fails: noted in
    # hd_ingest.txt and reported) our scene upscaled to 1280x720; then a default export
    hd, failed = work / "posed_hd" / "clip", work / "hd_ingest.txt"
    if not (hd / "manifest.json").exists() and not failed.exists():
        run_cli(["synth", "--out", str(work / "hd"), "--frames", str(N_FRAMES), "--size", f"{HD_HW[0]}x{HD_HW[1]}"])
        err = io.StringIO()
        try:
            with contextlib.redirect_stderr(err):
                run_cli(["ingest", str(work / "hd" / "clip.mp4"), "--out", str(work / "posed_hd")])
        except SystemExit:
            failed.write_text(err.getvalue().strip().splitlines()[-1])
    if not (hd / "manifest.json").exists():
        hd = work / "posed_hd_upscaled"
        if not (hd / "manifest.json").exists():
            with PosedDatasetWriter(hd, params={}, provenance={}) as w:
                w.add(resize_scene(PosedDataset(posed).load_scene(PosedDataset(posed).scene_ids[0]), HD_HW))
    if not (work / "ps_hd" / "test" / "index.json").exists():
        run_cli(["export", "pixelsplat", str(hd), "--out", str(work / "ps_hd"), "--size-check", "refuse"])
    if not (work / "ns").exists():
        run_cli(["export", "nerfstudio", str(posed), "--out", str(work / "ns")])


def our_scene(work: Path) -> PosedScene:
    ds = PosedDataset(work / "posed" / "clip")
    (scene_id,) = ds.scene_ids
    return ds.load_scene(scene_id)


def random_gaussians(seed: int = 0) -> Gaussians:
    """SH degree 3 Gaussians spread over the scene's depth range, opacities and scales far from the clamps."""
    g = torch.Generator().manual_seed(seed)
    n, k = N_GAUSSIANS, (SH_DEGREE + 1) ** 2
    return Gaussians(
        means=(torch.rand(1, n, 3, generator=g, dtype=torch.float64) - 0.5) * torch.tensor([8.0, 4.0, 30.0]),
        scales=torch.exp(torch.empty(1, n, 3, dtype=torch.float64).uniform_(-6.0, 0.5, generator=g)),
        rotations=torch.randn(1, n, 4, generator=g, dtype=torch.float64),
        opacities=torch.empty(1, n, dtype=torch.float64).uniform_(0.01, 0.99, generator=g),
        sh=torch.randn(1, n, k, 3, generator=g, dtype=torch.float64) * 0.5,
    )


def stub_modules(names: list[str]) -> None:
    for name in names:
        sys.modules.setdefault(name, types.ModuleType(name))


def maxabs(a: Any, b: Any) -> float:
    return float(np.abs(np.asarray(a, np.float64) - np.asarray(b, np.float64)).max())


# ---------------------------------------------------------------- pixelSplat and MVSplat (RE10K)


@dataclass(frozen=True)
class Re10kPeer:
    """What differs between the two checkouts' RE10K reading (MVSplat's `src/dataset` is pixelSplat's with
    options added): the modules stubbed (unrelated to reading: see the module docstring) and whether its
    evaluation sampler reads `num_context_views` from the global config its `main` sets."""

    name: str
    stubs: dict[str, dict[str, Any]]
    global_cfg: bool


MVSPLAT = Re10kPeer(
    "mvsplat", {"pytorch_lightning": {"LightningModule": object}, "skvideo": {}, "skvideo.io": {}}, False
)
PIXELSPLAT = Re10kPeer("pixelsplat", {"lightning": {}, "lightning.pytorch": {"LightningModule": object}}, True)


@contextlib.contextmanager
def peer_src(src: Path) -> Iterator[None]:
    """The checkout's top-level `src` package (both repositories name it so): imported from `src` alone,
    forgotten afterwards so that the other checkout's `src` is not mixed in."""

    def forget() -> None:
        for name in [m for m in sys.modules if m == "src" or m.startswith("src.")]:
            del sys.modules[name]

    forget()
    sys.path.insert(0, str(src))
    try:
        yield
    finally:
        sys.path.remove(str(src))
        forget()


def check_re10k(peer: Re10kPeer, src: Path, work: Path, ours: PosedScene) -> None:
    with peer_src(src):
        read_re10k(peer, src, work, ours)


def read_re10k(peer: Re10kPeer, src: Path, work: Path, ours: PosedScene) -> None:
    from omegaconf import OmegaConf

    def conf(*parts: str) -> dict[str, Any]:  # a config file as Hydra reads it (YAML 1.2 numbers: 1e-3)
        return OmegaConf.to_container(OmegaConf.load(src.joinpath("config", *parts)))  # type: ignore[return-value]

    for module, attrs in peer.stubs.items():  # unrelated to reading: see the module docstring
        stub_modules([module])
        for attr, value in attrs.items():
            setattr(sys.modules[module], attr, value)
    from src.dataset import get_dataset
    from src.dataset.dataset_re10k import DatasetRE10kCfg
    from src.dataset.view_sampler.view_sampler_bounded import (
        ViewSamplerBoundedCfg,
    )
    from src.dataset.view_sampler.view_sampler_evaluation import (
        ViewSamplerEvaluationCfg,
    )

    dataset = conf("dataset", "re10k.yaml")
    dataset.pop("defaults")
    dataset.update(conf("experiment", "re10k.yaml")["dataset"])
    bounded = conf("dataset", "view_sampler", "bounded.yaml")
    dataset.update(roots=[work / "ps"], overfit_to_scene=None)
    n = len(ours)
    index = work / "re10k_eval_index.json"
    key = json.loads((work / "ps" / "test" / "index.json").read_text())
    index.write_text(json.dumps({k: {"context": [0, n - 1], "target": list(range(n))} for k in key}))

    def examples(stage: str, cfg: Any, sampler: dict[str, Any]) -> tuple[list[dict], str]:
        if peer.global_cfg:  # as its main does with the composed config (here the dataset block)
            from src.global_cfg import set_cfg

            set_cfg(
                OmegaConf.create(
                    {"dataset": {**dataset, "roots": [str(r) for r in dataset["roots"]], "view_sampler": sampler}}
                )
            )
        out = io.StringIO()
        with contextlib.redirect_stdout(out):
            got = list(get_dataset(cfg, stage, None))
        return got, out.getvalue().strip()

    # stage test: evaluation sampler, native size (crop shim = identity), every frame a target
    evaluation = {"name": "evaluation", "index_path": str(index), "num_context_views": 2}
    cfg = DatasetRE10kCfg(
        **{**dataset, "image_shape": [H, W]},
        view_sampler=ViewSamplerEvaluationCfg(**{**evaluation, "index_path": index}),
    )
    got, printed = examples("test", cfg, evaluation)
    shapes = [tuple(ex[v]["image"].shape) for ex in got for v in ("context", "target")]
    ok = len(got) == len(key) and shapes == [(2, 3, H, W), (n, 3, H, W)] * len(key)
    report(
        ok,
        f"{peer.name} test stage",
        f"{len(got)} example(s) of {len(key)} scene(s), images {shapes}"
        + (f"; printed: {printed!r}" if printed else ""),
    )
    if got:
        ex = got[0]["target"]
        ext = ex["extrinsics"].double().numpy()
        intr = ex["intrinsics"].double().numpy()
        centres = ours.cam_to_world[:, :3, 3]
        # make_baseline_1: its world scaled so that the two context cameras (frames 0 and n-1) are 1 apart
        baseline = float(np.linalg.norm(centres[0] - centres[n - 1])) if dataset["make_baseline_1"] else 1.0
        d_rot = maxabs(ext[:, :3, :3], ours.cam_to_world[:, :3, :3])
        d_pos = maxabs(ext[:, :3, 3], centres / baseline)
        d_k = maxabs(intr, cam.intrinsics_norm_matrix(ours.intrinsics_norm))
        report(
            max(d_rot, d_pos) < 1e-4 and d_k < 1e-6,
            f"{peer.name} cameras",
            f"{len(ext)} cameras vs ours: max |d| rotation {d_rot:.2e}, camera centre {d_pos:.2e} "
            f"(scene extent {np.ptp(centres, 0).max():.2f}"
            + (f"; ours / {baseline:.4f}, the context cameras' distance: make_baseline_1" if baseline != 1.0 else "")
            + f"), normalised K {d_k:.2e}; near/far {float(ex['near'][0]):g}/{float(ex['far'][0]):g} (ours {ours.near:g}/{ours.far:g})",
        )
        pixels = np.stack([np.asarray(Image.open(io.BytesIO(bytes(b))).convert("RGB")) for b in ours.images])
        d_px = maxabs(ex["image"].permute(0, 2, 3, 1).numpy() * 255.0, pixels)
        report(
            d_px <= 1.0 + 1e-3,
            f"{peer.name} images",
            f"vs our decode of the same JPEGs: max |d| {d_px:.3f} / 255",
        )

    # a 1280x720 clip through default ingest + export: 360x640 frames the test stage yields, same cameras
    failed = work / "hd_ingest.txt"
    hd_ds = PosedDataset(work / ("posed_hd_upscaled" if failed.exists() else "posed_hd/clip"))
    hd = hd_ds.load_scene(hd_ds.scene_ids[0])
    n_hd = len(hd)
    source = "our scene upscaled (resize_scene)" if failed.exists() else "the clip ingested"
    key_hd = json.loads((work / "ps_hd" / "test" / "index.json").read_text())
    index_hd = work / "re10k_eval_index_hd.json"
    index_hd.write_text(json.dumps({k: {"context": [0, n_hd - 1], "target": list(range(n_hd))} for k in key_hd}))
    hd_sampler = {**evaluation, "index_path": str(index_hd)}
    cfg = DatasetRE10kCfg(
        **{**dataset, "roots": [work / "ps_hd"], "image_shape": [H, W]},
        view_sampler=ViewSamplerEvaluationCfg(**{**hd_sampler, "index_path": index_hd}),
    )
    got, printed = examples("test", cfg, hd_sampler)
    shapes = [tuple(ex[v]["image"].shape) for ex in got for v in ("context", "target")]
    d_k = d_rot = np.inf
    if got:
        tgt = got[0]["target"]
        d_rot = maxabs(tgt["extrinsics"].double().numpy()[:, :3, :3], hd.cam_to_world[:, :3, :3])
        # after the peers' resize + centre crop of 1280x720 to 360x640 (scale 0.5, nothing cropped)
        k_crop = cam.intrinsics_norm_matrix(cam.crop_intrinsics_norm(hd.intrinsics_norm, (H, W), (0, 0), (H, W)))
        d_k = maxabs(tgt["intrinsics"].double().numpy(), k_crop)
    report(
        len(got) == 1 and shapes == [(2, 3, H, W), (n_hd, 3, H, W)] and d_k < 1e-6 and d_rot < 1e-4,
        f"{peer.name} 1280x720 capture, default export",
        f"{source}, {n_hd} frames {int(hd.width[0])}x{int(hd.height[0])}; {len(got)} example(s), "
        f"images {shapes}, max |d| rotation {d_rot:.2e}, normalised K after the crop "
        f"{d_k:.2e}" + (f"; printed: {printed!r}" if printed else ""),
    )

    # stage train with the peer's own +experiment=re10k dataset settings (bounded sampler, 256x256, augment)
    torch.manual_seed(0)
    cfg = DatasetRE10kCfg(**dataset, view_sampler=ViewSamplerBoundedCfg(**bounded))
    got = []
    for _ in range(4):
        more, printed = examples("train", cfg, bounded)
        got += more
    shapes = sorted({tuple(ex[v]["image"].shape) for ex in got for v in ("context", "target")})
    ok = len(got) == 4 and shapes == [(1, 3, 256, 256), (2, 3, 256, 256)]
    report(
        ok,
        f"{peer.name} train stage (experiment re10k: bounded sampler, 256x256, augment)",
        f"{len(got)} example(s) in 4 passes over 1 scene, images {shapes}"
        + (f"; printed: {printed!r}" if printed else ""),
    )


# ---------------------------------------------------------------- DepthSplat (DL3DV)

DL3DV_INDEX = "assets/dl3dv_start_0_distance_10_ctx_2v_tgt_4v.json"  # DepthSplat's own, 2 context views
DL3DV_FULL_WH = (3840, 2160)  # transforms.json's w, h in the DL3DV release (4K); images_8 = / 8, images_4 = / 4
BLENDER = np.diag([1.0, -1.0, -1.0, 1.0])  # OpenCV <-> OpenGL camera axes


def make_dl3dv_source(root: Path, ours: PosedScene, scene_hash: str) -> None:
    """Our scene as a DL3DV release scene `root/1K/<hash>/`: nerfstudio transforms.json for 3840x2160
    (Blender camera-to-world), `file_path` naming `images/frame_XXXXX.png`, the frames as PNG in
    `images_8/` (480x270) and `images_4/` (960x540), made with our peers' resize (`resize_scene`)."""
    folder = root / "1K" / scene_hash
    if (folder / "transforms.json").exists():
        return
    w, h = DL3DV_FULL_WH
    fx, fy, cx, cy = (float(v) for v in ours.intrinsics_norm[0])
    frames = [
        {"file_path": f"images/frame_{i + 1:05d}.png", "transform_matrix": (ours.cam_to_world[i] @ BLENDER).tolist()}
        for i in range(len(ours))
    ]
    doc: dict[str, Any] = {"w": w, "h": h, "fl_x": fx * w, "fl_y": fy * h, "cx": cx * w, "cy": cy * h}
    doc.update(k1=0.0, k2=0.0, p1=0.0, p2=0.0, camera_model="OPENCV", frames=frames)
    for sub, scale in (("images_8", 8), ("images_4", 4)):
        (folder / sub).mkdir(parents=True)
        small = resize_scene(ours, (h // scale, w // scale))
        for i, data in enumerate(small.images):
            Image.open(io.BytesIO(bytes(data))).convert("RGB").save(folder / sub / f"frame_{i + 1:05d}.png")
    (folder / "transforms.json").write_text(json.dumps(doc))


def make_dl3dv_outputs(work: Path, ours: PosedScene, scene_hash: str) -> dict[str, str]:
    """`seeu import dl3dv` (480p and 960p) of the DL3DV-layout source, then default `seeu export
    pixelsplat` (stages test and train; 960p: test); returns what each export printed on stderr."""
    make_dl3dv_source(work / "dl3dv_src", ours, scene_hash)
    printed = {}
    for res in ("480p", "960p"):
        posed = work / f"posed_dl3dv_{res}"
        if not (posed / "manifest.json").exists():
            run_cli(["import", "dl3dv", str(work / "dl3dv_src"), "--resolution", res, "--out", str(posed)])
        for stage in ("test", "train") if res == "480p" else ("test",):
            err = io.StringIO()
            with contextlib.redirect_stderr(err):
                run_cli(["export", "pixelsplat", str(posed), "--out", str(work / f"ps_dl3dv_{res}"), "--stage", stage])
            printed[f"{res} {stage}"] = err.getvalue().strip()
    return printed


def check_depthsplat(src: Path, work: Path, ours: PosedScene) -> None:
    with peer_src(src):
        read_dl3dv(src, work, ours)


def read_dl3dv(src: Path, work: Path, ours: PosedScene) -> None:
    from dacite import Config, from_dict
    from omegaconf import OmegaConf

    def conf(*parts: str) -> dict[str, Any]:
        return OmegaConf.to_container(OmegaConf.load(src.joinpath("config", *parts)))

    for module, attrs in MVSPLAT.stubs.items():  # the same generator imports as MVSplat's (docstring)
        stub_modules([module])
        for attr, value in attrs.items():
            setattr(sys.modules[module], attr, value)
    from src.dataset import get_dataset
    from src.dataset.dataset_dl3dv import DatasetDL3DVCfg

    index_path = src / DL3DV_INDEX
    index = json.loads(index_path.read_text())
    scene_hash = next(k for k, v in index.items() if v is not None)  # the index's first scene
    entry = index[scene_hash]
    printed_export = make_dl3dv_outputs(work, ours, scene_hash)
    report(
        not any(printed_export.values()),
        "depthsplat default export of DL3DV scenes",
        "no warning from seeu export pixelsplat ("
        + "; ".join(f"{k}: {v!r}" if v else f"{k}: none" for k, v in printed_export.items())
        + ")",
    )

    # +experiment=dl3dv: config/dataset/dl3dv.yaml with the experiment's dataset block
    dataset = conf("dataset", "dl3dv.yaml")
    dataset.pop("defaults")
    dataset.update(conf("experiment", "dl3dv.yaml")["dataset"])
    dataset.update(overfit_to_scene=None)
    hw = list(dataset["ori_image_shape"])

    def examples(root: Path, stage: str, sampler: dict[str, Any]) -> tuple[list[dict], str]:
        # as its src/config.py load_typed_config: dacite, Path type hook, keys the class lacks ignored
        block = {**dataset, "roots": [str(root)], "view_sampler": sampler}
        cfg = from_dict(DatasetDL3DVCfg, block, config=Config(type_hooks={Path: Path}))
        out = io.StringIO()
        with contextlib.redirect_stdout(out):
            got = list(get_dataset(cfg, stage, None))
        return got, out.getvalue().strip()

    evaluation = {"name": "evaluation", "index_path": str(index_path), "num_context_views": 2}
    posed = PosedDataset(work / "posed_dl3dv_480p").load_scene(f"dl3dv_{scene_hash}")
    for res in ("480p", "960p"):
        root = work / f"ps_dl3dv_{res}"
        keys = list(json.loads((root / "test" / "index.json").read_text()))
        got, printed = examples(root, "test", evaluation)
        shapes = [tuple(ex[v]["image"].shape) for ex in got for v in ("context", "target")]
        nc, nt = len(entry["context"]), len(entry["target"])
        ok = keys == [scene_hash] and len(got) == 1 and shapes == [(nc, 3, *hw), (nt, 3, *hw)]
        d_rot = d_pos = d_k = d_src = np.inf
        if got:
            ex = got[0]
            idx = np.concatenate([ex["context"]["index"].numpy(), ex["target"]["index"].numpy()])
            ext = torch.cat([ex["context"]["extrinsics"], ex["target"]["extrinsics"]]).double().numpy()
            intr = torch.cat([ex["context"]["intrinsics"], ex["target"]["intrinsics"]]).double().numpy()
            ok &= idx.tolist() == entry["context"] + entry["target"] and ex["scene"] == scene_hash
            d_rot = maxabs(ext[:, :3, :3], posed.cam_to_world[idx, :3, :3])
            d_pos = maxabs(ext[:, :3, 3], posed.cam_to_world[idx, :3, 3])
            d_src = maxabs(ext, ours.cam_to_world[idx])  # through the DL3DV layout and back
            d_k = maxabs(intr, cam.intrinsics_norm_matrix(posed.intrinsics_norm[idx]))
        ok &= max(d_rot, d_pos, d_src) < 1e-4 and d_k < 1e-6
        report(
            ok,
            f"depthsplat DL3DV test stage, {res} import, default export",
            f"key {keys[0][:12]}... ({len(keys)} key(s)) found by its own {Path(DL3DV_INDEX).name}: "
            f"{len(got)} example(s), images {shapes} (ori_image_shape {hw}), indices "
            f"{'as its index' if ok else 'WRONG'}; max |d| vs our import: rotation {d_rot:.2e}, centre "
            f"{d_pos:.2e}, normalised K {d_k:.2e}; vs the source cameras {d_src:.2e}; near/far "
            f"{float(got[0]['context']['near'][0]) if got else 0:g}/{float(got[0]['context']['far'][0]) if got else 0:g}"
            + (f"; printed: {printed!r}" if printed else ""),
        )
        if got and res == "480p":  # bytes kept as stored: its decode equals the PNG files'
            files = sorted((work / "dl3dv_src" / "1K" / scene_hash / "images_8").glob("*.png"))
            pixels = np.stack([np.asarray(Image.open(files[i]).convert("RGB")) for i in idx])
            imgs = torch.cat([got[0]["context"]["image"], got[0]["target"]["image"]])
            d_px = maxabs(imgs.permute(0, 2, 3, 1).numpy() * 255.0, pixels)
            report(d_px <= 1e-3, "depthsplat DL3DV images", f"vs the images_8 PNG files: max |d| {d_px:.3f} / 255")

    # stage train: its experiment's boundedv2_360 sampler (4 context + 4 target views), augment, 270x480
    torch.manual_seed(0)
    bounded = conf("dataset", "view_sampler", "boundedv2_360.yaml")
    got = []
    for _ in range(4):
        more, printed = examples(work / "ps_dl3dv_480p", "train", bounded)
        got += more
    shapes = sorted({tuple(ex[v]["image"].shape) for ex in got for v in ("context", "target")})
    report(
        len(got) == 4 and shapes == [(4, 3, *hw)],
        "depthsplat DL3DV train stage (experiment dl3dv: boundedv2 sampler, augment)",
        f"{len(got)} example(s) in 4 passes over 1 scene, images {shapes}"
        + (f"; printed: {printed!r}" if printed else ""),
    )


# ---------------------------------------------------------------- 3DGS (INRIA)


def check_gaussian_splatting(src: Path, work: Path, ours: PosedScene) -> None:
    gauss = random_gaussians()
    names = [f"frame_{int(f):05d}" for f in ours.source_frame]
    bundle = work / "bundle"
    save_ply_bundle(gauss, bundle, ours.cam_to_world, ours.intrinsics_norm, W, H, names)
    sidecar = json.loads((bundle / "gaussians.json").read_text())

    stub_modules(["simple_knn", "simple_knn._C"])  # CUDA extension: see the module docstring

    def no_cuda_knn(*args: Any) -> None:
        raise NotImplementedError("simple_knn is a CUDA extension, stubbed: not needed to read a .ply")

    sys.modules["simple_knn._C"].distCUDA2 = no_cuda_knn  # type: ignore[attr-defined]
    sys.path.insert(0, str(src))
    from scene.dataset_readers import CameraInfo
    from scene.gaussian_model import GaussianModel
    from utils.camera_utils import camera_to_JSON
    from utils.graphics_utils import focal2fov

    model = GaussianModel(sidecar["sh_degree"])
    tensor = torch.tensor

    def on_cpu(*args: Any, **kwargs: Any) -> torch.Tensor:
        if kwargs.get("device") == "cuda" and not torch.cuda.is_available():
            kwargs["device"] = "cpu"
        return tensor(*args, **kwargs)

    with mock.patch.object(torch, "tensor", on_cpu):
        model.load_ply(str(bundle / "gaussians.ply"))
    g = gauss.map(lambda t: t[0])
    with torch.no_grad():
        diffs = {
            "means": maxabs(model.get_xyz, g.means),
            "opacities": maxabs(model.get_opacity[:, 0], g.opacities),
            "scales": maxabs(model.get_scaling, g.scales),
            "rotations": maxabs(model.get_rotation, g.rotations / g.rotations.norm(dim=-1, keepdim=True)),
            "sh": maxabs(model.get_features, g.sh),
        }
    report(
        max(diffs.values()) < 1e-5 and model.get_xyz.shape[0] == N_GAUSSIANS,
        "3dgs load_ply",
        f"{model.get_xyz.shape[0]} Gaussians, SH degree {model.max_sh_degree}; max |d| vs ours: "
        + ", ".join(f"{k} {v:.1e}" for k, v in diffs.items()),
    )

    theirs = []
    for i in range(len(ours)):
        w2c = cam.world_to_cam_from_cam_to_world(ours.cam_to_world[i])
        k = cam.intrinsics_pixels(ours.intrinsics_norm[i], W, H)
        info = CameraInfo(
            uid=i,
            R=np.transpose(w2c[:3, :3]),
            T=np.array(w2c[:3, 3]),
            FovY=focal2fov(k[1, 1], H),
            FovX=focal2fov(k[0, 0], W),
            depth_params=None,
            image_path="",
            image_name=names[i],
            depth_path="",
            width=W,
            height=H,
            is_test=False,
        )
        theirs.append(camera_to_JSON(i, info))
    mine = json.loads((bundle / "cameras.json").read_text())
    keys_ok = [list(a) for a in mine] == [list(b) for b in theirs]
    same = all(a[x] == b[x] for a, b in zip(mine, theirs) for x in ("id", "img_name", "width", "height"))
    d = {x: max(maxabs(a[x], b[x]) for a, b in zip(mine, theirs)) for x in ("position", "rotation", "fx", "fy")}
    report(
        keys_ok and same and len(mine) == len(theirs) and max(d.values()) < 1e-6,
        "3dgs cameras.json",
        f"{len(mine)} cameras, keys {'in the same order' if keys_ok else 'DIFFER'} ({', '.join(theirs[0])}), "
        f"id/img_name/width/height {'equal' if same else 'DIFFER'}; max |d| "
        + ", ".join(f"{k} {v:.1e}" for k, v in d.items()),
    )


# ---------------------------------------------------------------- nerfstudio


def check_nerfstudio(src: Path, work: Path, ours: PosedScene) -> None:
    # nerfstudio's own deprecation warnings under our torch (torch.jit.script; a list used as a
    # multi-dimensional index in cameras.py, still read the old way): its results are checked below
    warnings.filterwarnings("ignore", message=".*torch.jit.script. is deprecated")
    warnings.filterwarnings("ignore", message="Using a non-tuple sequence for multidimensional indexing")
    sys.path.insert(0, str(src))
    from nerfstudio.data.dataparsers.nerfstudio_dataparser import (
        NerfstudioDataParserConfig,
    )

    folder = work / "ns" / ours.scene_id
    parser = NerfstudioDataParserConfig(data=folder, load_3D_points=True).setup()
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        splits = {split: parser.get_dataparser_outputs(split=split) for split in ("train", "val")}
    frame_of = {f"frame_{int(f):05d}": i for i, f in enumerate(ours.source_frame)}
    rows = {s: [frame_of[Path(p).stem] for p in o.image_filenames] for s, o in splits.items()}
    every = sorted(r for s in rows.values() for r in s) == list(range(len(ours)))
    d_k, sizes_ok = 0.0, True
    for s, o in splits.items():
        c = o.cameras
        k = cam.intrinsics_pixels(ours.intrinsics_norm[rows[s]], W, H)
        theirs = torch.stack([c.fx[:, 0], c.fy[:, 0], c.cx[:, 0], c.cy[:, 0]], -1).double().numpy()
        d_k = max(d_k, maxabs(theirs, k[:, [0, 1, 0, 1], [0, 1, 2, 2]]))
        sizes_ok &= bool((c.width == W).all() and (c.height == H).all())
        sizes_ok &= all(Image.open(p).size == (W, H) for p in o.image_filenames)
    report(
        every and sizes_ok and d_k < 1e-3,
        "nerfstudio dataparser",
        f"train {len(rows['train'])} + val {len(rows['val'])} frames ({'all' if every else 'NOT all'} of "
        f"{len(ours)}), camera type {splits['train'].cameras.camera_type[0].item()} (perspective = 1), "
        f"images {W}x{H} {'found' if sizes_ok else 'WRONG'}, fx fy cx cy max |d| {d_k:.1e} px",
    )

    o = splits["train"]
    pts_ns = o.metadata.get("points3D_xyz")
    pts, _ = read_points_ply(work / "posed" / "clip" / ours.meta["points3d"])
    if pts_ns is None:
        report(False, "nerfstudio ply_file_path", "no points3D_xyz in the dataparser outputs")
        return
    tf = o.dataparser_transform.double().numpy()
    mapped = (pts @ tf[:, :3].T + tf[:, 3]) * o.dataparser_scale
    d_pts = maxabs(pts_ns, mapped)
    report(
        len(pts_ns) == len(pts) and d_pts < 1e-4,
        "nerfstudio ply_file_path",
        f"{len(pts_ns)} points read (ours {len(pts)}); vs ours through its dataparser transform and scale "
        f"{o.dataparser_scale:.4f}: max |d| {d_pts:.1e}",
    )

    # rays its cameras cast through the pixels where our cameras project our points
    errs = []
    for s, o in splits.items():
        for j, row in enumerate(rows[s]):
            uv, depth = cam.project_points(pts, ours.cam_to_world[row], ours.intrinsics_norm[row], W, H)
            seen = (depth > 0) & (uv[:, 0] > 0) & (uv[:, 0] < W) & (uv[:, 1] > 0) & (uv[:, 1] < H)
            coords = torch.from_numpy(uv[seen][:, ::-1].copy()).float()  # (y, x)
            rays = o.cameras.generate_rays(camera_indices=torch.full((len(coords), 1), j), coords=coords)
            target = o.metadata["points3D_xyz"][torch.from_numpy(seen)].double()
            to_pt = target - rays.origins.double()
            dirs = rays.directions.double()
            along = (to_pt * dirs).sum(-1)
            off = torch.linalg.norm(torch.linalg.cross(to_pt, dirs, dim=-1), dim=-1) / along
            errs.append((off * float(o.cameras.fx[j, 0])).numpy())  # tangent of the angle x focal length = px
            errs[-1][along.numpy() <= 0] = np.inf
    e = np.concatenate(errs)
    report(
        len(e) > 1000 and float(e.max()) < 0.01,
        "nerfstudio projection",
        f"{len(e)} point-in-view pairs over {len(ours)} cameras: its ray through our pixel misses the point by "
        f"median {np.median(e):.1e} px, max {e.max():.1e} px",
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--mvsplat", type=Path, help="checkout of donydchen/mvsplat")
    ap.add_argument("--pixelsplat", type=Path, help="checkout of dcharatan/pixelsplat")
    ap.add_argument("--depthsplat", type=Path, help="checkout of cvg/depthsplat (DL3DV)")
    ap.add_argument("--gaussian-splatting", type=Path, help="checkout of graphdeco-inria/gaussian-splatting")
    ap.add_argument("--nerfstudio", type=Path, help="checkout of nerfstudio-project/nerfstudio")
    ap.add_argument("--work", type=Path, help="keep (and reuse) our outputs here instead of a temporary folder")
    args = ap.parse_args()
    with contextlib.ExitStack() as stack:
        work = args.work or Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="seeu-peers-")))
        work.mkdir(parents=True, exist_ok=True)
        make_outputs(work)
        ours = our_scene(work)
        print(f"ours: {work} scene {ours.scene_id}, {len(ours)} frames {W}x{H}", flush=True)
        failed = work / "hd_ingest.txt"
        report(
            not failed.exists(),
            "1280x720 clip, default seeu ingest",
            f"failed: {failed.read_text()!r}" if failed.exists() else "posed (work/posed_hd/clip)",
        )
        for name, path, check in (
            ("mvsplat", args.mvsplat, functools.partial(check_re10k, MVSPLAT)),
            ("pixelsplat", args.pixelsplat, functools.partial(check_re10k, PIXELSPLAT)),
            ("depthsplat", args.depthsplat, check_depthsplat),
            ("gaussian-splatting", args.gaussian_splatting, check_gaussian_splatting),
            ("nerfstudio", args.nerfstudio, check_nerfstudio),
        ):
            if path is None or not path.is_dir():
                print(
                    f"SKIP {name}: no checkout ({'not a folder: ' + str(path) if path else 'no --' + name + ' DIR'})",
                    flush=True,
                )
                continue
            check(path, work, ours)
    print(f"{sum(RESULTS)} passed, {len(RESULTS) - sum(RESULTS)} failed")
    return 0 if all(RESULTS) else 1


if __name__ == "__main__":
    sys.exit(main())
