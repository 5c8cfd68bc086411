"""LPIPS (VGG) as the peers use it, loadable offline.

``lpips.LPIPS(net="vgg")`` normally asks torchvision to *download* the VGG-16 trunk
(``vgg16-397923af.pth``, ~528 MB) into ``$TORCH_HOME/hub/checkpoints``. This wrapper never
downloads: it builds the network with a random trunk and loads the trunk weights from

1. an explicit path (``--lpips-weights PATH``), or
2. torchvision's cache: ``torch.hub.get_dir()/checkpoints/vgg16-397923af.pth``,

and raises a `SeeUError` naming the missing file otherwise. The small linear heads ship with the
``lpips`` wheel. Trunk and heads are frozen; the module stays in eval mode (no dropout).
``random_trunk=True`` keeps the random trunk (tests only: the numbers are then not LPIPS).

Inputs are images in [0, 1] (``normalize=True`` maps them to [-1, 1] as LPIPS expects).
"""

from __future__ import annotations

import contextlib
import io
import os
import warnings
from pathlib import Path

import torch
from torch import nn

from seeu_data.errors import SeeUError
from seeu_model.safe_load import safe_torch_load

VGG16_FILENAME = "vgg16-397923af.pth"


def default_vgg_weights_path() -> Path:
    """Where torchvision caches the VGG-16 ImageNet weights (``$TORCH_HOME/hub/checkpoints/...``)."""
    return Path(torch.hub.get_dir()) / "checkpoints" / VGG16_FILENAME


def resolve_vgg_weights(path: str | os.PathLike | None) -> Path:
    """The VGG-16 weights file to use, or a SeeUError saying exactly what is missing and how to fix it."""
    if path is not None:
        p = Path(path).expanduser()
        if not p.is_file():
            raise SeeUError(
                "LPIPS VGG-16 weights file not found (expected torchvision's "
                f"{VGG16_FILENAME}; or switch LPIPS off with lpips_weight=0 / --no-lpips)",
                p,
            )
        return p
    p = default_vgg_weights_path()
    if not p.is_file():
        raise SeeUError(
            f"LPIPS needs torchvision's VGG-16 ImageNet weights ({VGG16_FILENAME}, ~528 MB), which cannot be "
            f"downloaded here: copy it to this path (or set TORCH_HOME), pass --lpips-weights PATH, "
            f"or switch LPIPS off (--no-lpips / lpips_weight=0)",
            p,
        )
    return p


def load_vgg16_features(path: Path) -> nn.Sequential:
    """The convolutional trunk (``features``) of torchvision's VGG-16 from a state-dict file.

    Accepts torchvision's full checkpoint (the classifier is ignored) or one holding only
    ``features.*`` keys.
    """
    from torchvision.models.vgg import cfgs, make_layers

    features = make_layers(cfgs["D"], batch_norm=False)
    state = safe_torch_load(path, "VGG-16 weights file")  # refuses a file that needs more than weights
    try:
        if not isinstance(state, dict):
            raise TypeError(f"a {type(state).__name__}, not a state dict")
        sub = {k[len("features.") :]: v for k, v in state.items() if k.startswith("features.")}
        features.load_state_dict(sub)
    except Exception as exc:  # noqa: BLE001 - any failure here means a bad weights file
        msg = str(exc).splitlines()[0] if str(exc) else ""
        raise SeeUError(f"not a torchvision VGG-16 state dict ({type(exc).__name__}: {msg[:200]})", path) from None
    return features


class LPIPS(nn.Module):
    """Frozen LPIPS(VGG). forward(pred, target): ``(..., 3, H, W)`` in [0, 1] -> per-image ``(...)``."""

    def __init__(self, weights: str | os.PathLike | None = None, random_trunk: bool = False):
        super().__init__()
        import lpips

        weights_path = None if random_trunk else resolve_vgg_weights(weights)
        features = load_vgg16_features(weights_path) if weights_path is not None else None  # fail fast
        with contextlib.redirect_stdout(io.StringIO()), warnings.catch_warnings():
            warnings.simplefilter("ignore")  # lpips prints set-up chatter; torchvision warns on pretrained=
            self.net = lpips.LPIPS(net="vgg", pretrained=True, pnet_rand=True, verbose=False)
        if features is not None:
            for slice_ in (
                self.net.net.slice1,
                self.net.net.slice2,
                self.net.net.slice3,
                self.net.net.slice4,
                self.net.net.slice5,
            ):
                for name, module in slice_.named_children():
                    module.load_state_dict(features[int(name)].state_dict())
        self.random_trunk = random_trunk
        self.weights_path = weights_path
        for p in self.parameters():
            p.requires_grad_(False)
        self.eval()

    def train(self, mode: bool = True) -> LPIPS:
        return super().train(False)  # always eval: the heads have dropout layers

    def forward(self, pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        lead = pred.shape[:-3]
        x = pred.reshape(-1, *pred.shape[-3:])
        y = target.reshape(-1, *target.shape[-3:])
        return self.net(x, y, normalize=True).reshape(lead)
