"""Shared fixtures of the training / evaluation tests: tiny triple shards of the synthetic corridor.

`synthetic_triples(root, ...)` renders the built-in synthetic scene (exact cameras, no SfM) at a
small size, writes posed frames and builds interp (or extrap) triple shards with `pipelines.build`.
"""

from __future__ import annotations

from pathlib import Path

from pipelines.build import BuildConfig, build
from seeu_data.build.sampling import SamplingConfig
from seeu_data.build.triples import ImageOptions
from seeu_data.store.manifest import provenance
from seeu_data.store.posed import PosedDatasetWriter
from seeu_data.synthetic import synthetic_posed_scene


def synthetic_posed(root: Path, n_frames: int = 16, hw: tuple[int, int] = (32, 32), seeds=(0,)) -> Path:
    out = Path(root) / "posed"
    if (out / "manifest.json").exists():
        return out
    with PosedDatasetWriter(out, {"test": True}, provenance("tests")) as w:
        for s in seeds:
            w.add(synthetic_posed_scene(n_frames, hw[0], hw[1], seed=s, scene_id=f"syn{s}"))
    return out


def synthetic_triples(
    root: Path,
    n_frames: int = 16,
    hw: tuple[int, int] = (32, 32),
    seeds=(0,),
    mode: str = "interp",
    samples_per_scene: int = 8,
    gap=(3, 6),
    extrap_frames: int = 3,
    name: str | None = None,
    seed: int = 0,
) -> Path:
    posed = synthetic_posed(root, n_frames, hw, seeds)
    out = Path(root) / (name or f"triples_{mode}")
    if (out / "manifest.json").exists():
        return out
    sampling = SamplingConfig(
        mode=mode,
        num_context=2,
        num_target=3,
        gap_min=gap[0],
        gap_max=gap[1],
        extrap_frames=extrap_frames,
        samples_per_scene=samples_per_scene,
    )
    build(
        BuildConfig(
            inputs=(str(posed),),
            out=str(out),
            mode=mode,
            sampling=sampling,
            seed=seed,
            image=ImageOptions(resize=None),
            workers=1,
        )
    )
    return out


# ------------------------------------------------------------------------------------------------
# A minimal pixel-aligned Gaussian model (stand-in with the SeeU interface: encode + forward)
# ------------------------------------------------------------------------------------------------

import torch  # noqa: E402
from torch import nn  # noqa: E402

from seeu_data.cameras import unproject_pixels  # noqa: E402
from seeu_model.gaussians import Gaussians  # noqa: E402


class PixelSplat2(nn.Module):
    """Per pixel of every context view: depth in [near, far], opacity, scale, colour (SH degree 0)."""

    def __init__(self, hidden: int = 8):
        super().__init__()
        self.net = nn.Sequential(nn.Conv2d(3, hidden, 3, padding=1), nn.ReLU(), nn.Conv2d(hidden, 6, 3, padding=1))

    def encode(self, context: dict) -> Gaussians:
        img = context["image"]
        b, v, _, h, w = img.shape
        out = self.net(img.flatten(0, 1)).view(b, v, 6, h * w)
        near, far = context["near"][..., None], context["far"][..., None]
        depth = near + torch.sigmoid(out[:, :, 0]) * (far - near)  # (B, V, HW)
        ys, xs = torch.meshgrid(torch.arange(h, dtype=img.dtype), torch.arange(w, dtype=img.dtype), indexing="ij")
        uv = torch.stack([xs + 0.5, ys + 0.5], -1).reshape(1, 1, h * w, 2).expand(b, v, h * w, 2)
        means = unproject_pixels(uv, depth, context["cam_to_world"], context["intrinsics"], w, h)
        fx = context["intrinsics"][..., 0, 0][..., None] * w
        scale = (depth / fx * (0.5 + torch.sigmoid(out[:, :, 1])))[..., None].expand(b, v, h * w, 3)
        colour = torch.sigmoid(out[:, :, 2:5] + img.view(b, v, 3, h * w)).permute(0, 1, 3, 2)
        sh = ((colour - 0.5) / 0.28209479177387814)[..., None, :]
        rot = torch.zeros(b, v, h * w, 4, dtype=img.dtype)
        rot[..., 0] = 1
        return Gaussians(
            means.flatten(1, 2),
            scale.flatten(1, 2),
            rot.flatten(1, 2),
            torch.sigmoid(out[:, :, 5] + 2).flatten(1, 2),
            sh.flatten(1, 2),
        )

    def forward(self, batch: dict):
        from seeu_model.rasterizer import rasterize

        g = self.encode(batch["context"])
        t = batch["target"]
        h, w = t["image"].shape[-2:]
        return rasterize(g, t["cam_to_world"], t["intrinsics"], w, h, backend="torch")


def ddp_worker(rank: int, world_size: int, port: int, kwargs: dict) -> None:
    """torch.multiprocessing.spawn target: one rank of a gloo DDP run of `pipelines.train.train`."""
    import os

    os.environ.update(
        MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port), RANK=str(rank), WORLD_SIZE=str(world_size), LOCAL_RANK=str(rank)
    )
    torch.set_num_threads(1)
    from pipelines.train import TrainRunConfig, train

    train(TrainRunConfig(**kwargs))


def tiny_model_factory(section: dict):
    """A minimal pixel-aligned stand-in model (fast loop tests with another model than SeeU)."""
    torch.manual_seed(0)
    return PixelSplat2(), {}


def initial_state(model_section: dict, seed: int = 0) -> dict:
    """The state dict `seeu train` starts from for this model section and config seed."""
    from pipelines.train import seed_everything
    from seeu_model.training.factory import build_model

    seed_everything(seed)
    return build_model(model_section)[0].state_dict()
