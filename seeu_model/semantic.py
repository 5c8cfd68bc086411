"""Frozen semantic encoders (paper §3.2.1): a DINOv3 ViT through timm, and for the condition ablation
CLIP's image tower (timm) and BLIP-2's image side, ViT-g + Q-Former (Hugging Face ``transformers``, the
optional ``blip2`` extra). Weights come from the hub name, or from a local file (timm) / directory
(BLIP-2) for offline use; a clear `SeeUError` says what is missing otherwise. Random initialisation
happens only when asked (``pretrained=False``), which the tests and the CPU demo use.

The encoders are frozen: parameters have ``requires_grad=False``, the module stays in eval mode
even under ``model.train()``, its forward runs under ``torch.no_grad()``, and `SeeU.trainable_state_dict`
leaves its weights out of checkpoints.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from seeu_data.errors import SeeUError
from seeu_data.store.json_file import read_json
from seeu_model.safe_load import safe_torch_load


def create_timm_model(
    name: str, weights: str | None, pretrained: bool, what: str, flag: str, **kwargs: Any
) -> nn.Module:
    """Build a timm model with pretrained weights from ``weights`` (a local file), the hub, or (only when
    ``pretrained`` is False and no file is given) random initialisation. Raises SeeUError when weights
    cannot be loaded. ``flag`` names the config field / CLI option that supplies the file."""
    try:
        import timm
    except ImportError as exc:  # pragma: no cover - timm is a core dependency here
        raise SeeUError(f"the {what} needs the 'timm' package (pip install timm): {exc}") from exc
    if name not in timm.list_models(pretrained=False) and name.split(".")[0] not in timm.list_models():
        raise SeeUError(f"unknown timm model {name!r} for the {what}")
    if weights is not None:
        path = Path(weights)
        if not path.is_file():
            raise SeeUError(f"{what} weights file not found (given by {flag})", path)
        if path.suffix != ".safetensors":
            safe_torch_load(path, f"{what} weights file")  # refused here if it needs more than weights
        try:
            return timm.create_model(name, pretrained=True, pretrained_cfg_overlay=dict(file=str(path)), **kwargs)
        except Exception as exc:
            first = str(exc).splitlines()[0] if str(exc) else ""
            raise SeeUError(
                f"cannot load {what} weights for {name!r} from this file: {type(exc).__name__}: {first}", path
            ) from exc
    if not pretrained:
        return timm.create_model(name, pretrained=False, **kwargs)
    try:
        return timm.create_model(name, pretrained=True, **kwargs)
    except Exception as exc:
        first = str(exc).splitlines()[0] if str(exc) else ""
        raise SeeUError(
            f"cannot load pretrained {what} weights {name!r} from the Hugging Face hub "
            f"({type(exc).__name__}: {first[:160]}). Download the checkpoint once (e.g. model.safetensors of "
            f"https://huggingface.co/timm/{name}; DINOv3 weights are gated under the DINOv3 license) and pass "
            f"{flag}=PATH; random initialisation (semantic_pretrained=False) is for tests only"
        ) from exc


class FrozenModule(nn.Module):
    """Base class: all parameters frozen, always in eval mode."""

    def freeze(self) -> None:
        for p in self.parameters():
            p.requires_grad_(False)
        super().train(False)

    def train(self, mode: bool = True) -> FrozenModule:  # noqa: ARG002 - stays in eval mode
        return super().train(False)


class FrozenViTEncoder(FrozenModule):
    """A frozen timm ViT (DINOv3 by default): images (B, V, 3, H, W) in [0, 1] ->
    cls (B, V, D) and patch features (B, V, D, H'/p, W'/p), where H', W' are H, W rounded to
    multiples of the patch size p (bilinear resize when needed). ImageNet-normalised input."""

    model: Any  # a timm model: its class depends on the name (ViT, EVA, ...), its attributes are duck-typed
    mean: torch.Tensor  # (1, 3, 1, 1) buffers: the input normalisation
    std: torch.Tensor

    def __init__(
        self, name: str, weights: str | None = None, pretrained: bool = True, model_kwargs: dict[str, Any] | None = None
    ):
        super().__init__()
        self.name = name
        self.model = create_timm_model(
            name, weights, pretrained, "semantic encoder", "semantic_weights", **(model_kwargs or {})
        )
        cfg = getattr(self.model, "pretrained_cfg", {}) or {}
        mean = cfg.get("mean", (0.485, 0.456, 0.406))
        std = cfg.get("std", (0.229, 0.224, 0.225))
        self.register_buffer("mean", torch.tensor(mean).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(std).view(1, 3, 1, 1), persistent=False)
        patch = getattr(self.model, "patch_embed", None)
        self.patch_size = int(patch.patch_size[0]) if patch is not None else 16
        self.embed_dim = int(self.model.embed_dim)
        self.num_prefix_tokens = int(getattr(self.model, "num_prefix_tokens", 1))
        self.freeze()

    @torch.no_grad()
    def forward(self, images: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        b, v, _, h, w = images.shape
        p = self.patch_size
        gh, gw = max(1, round(h / p)), max(1, round(w / p))
        x = images.reshape(b * v, 3, h, w).float()
        if (gh * p, gw * p) != (h, w):
            x = F.interpolate(x, size=(gh * p, gw * p), mode="bilinear", align_corners=False, antialias=True)
        x = (x - self.mean) / self.std
        tokens = self.model.forward_features(x)  # (BV, prefix + gh*gw, D)
        cls = tokens[:, 0]
        patches = tokens[:, self.num_prefix_tokens :].transpose(1, 2).reshape(b * v, -1, gh, gw)
        return cls.reshape(b, v, -1), patches.reshape(b, v, -1, gh, gw)


class FrozenCLIPImageEncoder(FrozenModule):
    """CLIP's frozen image tower through timm (the paper's "CLIP embedding" ablation):
    images (B, V, 3, H, W) in [0, 1] -> projected image embeddings (B, V, D_clip), input resized to the
    model's native resolution (224 for ViT-B/16) and CLIP-normalised."""

    model: Any  # a timm model: its class depends on the name (ViT, EVA, ...), its attributes are duck-typed
    mean: torch.Tensor  # (1, 3, 1, 1) buffers: the input normalisation
    std: torch.Tensor

    def __init__(
        self, name: str, weights: str | None = None, pretrained: bool = True, model_kwargs: dict[str, Any] | None = None
    ):
        super().__init__()
        self.model = create_timm_model(
            name, weights, pretrained, "CLIP image encoder", "clip_weights", **(model_kwargs or {})
        )
        cfg = getattr(self.model, "pretrained_cfg", {}) or {}
        self.input_size = tuple(cfg.get("input_size", (3, 224, 224))[1:])
        self.register_buffer(
            "mean", torch.tensor(cfg.get("mean", (0.4815, 0.4578, 0.4082))).view(1, 3, 1, 1), persistent=False
        )
        self.register_buffer(
            "std", torch.tensor(cfg.get("std", (0.2686, 0.2613, 0.2758))).view(1, 3, 1, 1), persistent=False
        )
        self.embed_dim = int(getattr(self.model, "num_classes", 0) or self.model.num_features)
        self.freeze()

    @torch.no_grad()
    def forward(self, images: torch.Tensor) -> torch.Tensor:
        b, v, _, h, w = images.shape
        x = images.reshape(b * v, 3, h, w).float()
        x = F.interpolate(x, size=self.input_size, mode="bilinear", align_corners=False, antialias=True)
        return self.model((x - self.mean) / self.std).reshape(b, v, -1)


# ---- BLIP-2 (optional extra: pip install -e '.[blip2]') --------------------------------------------------
BLIP2_DEFAULT_MODEL = "Salesforce/blip2-opt-2.7b"
BLIP2_PREFIXES = ("vision_model.", "query_tokens", "qformer.")  # the image side of every BLIP-2 checkpoint
OPENAI_CLIP_MEAN = (0.48145466, 0.4578275, 0.40821073)  # BLIP-2's image processor normalisation
OPENAI_CLIP_STD = (0.26862954, 0.26130258, 0.27577711)


def import_blip2() -> Any:
    """The ``transformers`` module, or a one-line SeeUError naming the pip extra to install."""
    try:
        import transformers
        from transformers import Blip2Config, Blip2QFormerModel, Blip2VisionModel  # noqa: F401
    except ImportError as exc:
        raise SeeUError(
            f"condition 'blip2' needs the optional 'transformers' package ({type(exc).__name__}: "
            f"{str(exc).splitlines()[0] if str(exc) else ''}): install the 'blip2' extra, "
            "pip install -e '.[blip2]' in the SeeU checkout (or pip install transformers)"
        ) from None
    return transformers


def _first_line(exc: BaseException) -> str:
    text = (str(exc).strip().splitlines() or [""])[0]
    return f"{type(exc).__name__}: {text[:160] + '...' if len(text) > 160 else text}"


def _blip2_resolver(model: str, weights: str | None) -> tuple[Callable[[str], Path | None], str, bool]:
    """A function filename -> local path (None when the file does not exist), the source's name, and
    whether it is the hub. Local: the ``weights`` directory (or ``model`` when it names a directory)."""
    local = Path(weights) if weights is not None else Path(model) if Path(model).is_dir() else None
    if local is not None:
        if not local.is_dir():
            raise SeeUError(
                "BLIP-2 weights directory not found (given by blip2_weights; it should hold "
                "config.json and *.safetensors)",
                local,
            )
        return (lambda name: (local / name) if (local / name).is_file() else None), str(local), False
    try:
        from huggingface_hub import hf_hub_download
        from huggingface_hub.errors import EntryNotFoundError, LocalEntryNotFoundError
    except ImportError as exc:  # pragma: no cover - a dependency of transformers
        raise SeeUError(f"downloading BLIP-2 weights needs 'huggingface_hub' ({_first_line(exc)})") from None

    def fetch(name: str) -> Path | None:
        try:
            try:
                return Path(hf_hub_download(model, name))
            except LocalEntryNotFoundError:  # offline and not cached: an error, not a missing file
                raise
            except EntryNotFoundError:  # the repo has no such file
                return None
        except Exception as exc:
            raise SeeUError(
                f"cannot load BLIP-2 weights {model!r} from the Hugging Face hub ({_first_line(exc)}). Download its "
                "config.json and safetensors once (or export the image part with "
                "seeu_model.semantic.export_blip2_image_part) and pass blip2_weights=DIR; random initialisation "
                "(semantic_pretrained=False) is for tests only"
            ) from None

    return fetch, model, True


def _image_side_files(resolve: Callable[[str], Path | None], where: str, hub: bool, single: str) -> list[Path]:
    """The weight files (``single``, e.g. model.safetensors, or the shards of ``single``.index.json that
    hold image-side tensors; locally every ``*.<ext>`` when there is no index); [] when there are none."""
    index = resolve(single + ".index.json")
    if index is not None:
        try:
            weight_map = read_json(index, "weight index").get("weight_map", {})
        except (OSError, ValueError, AttributeError) as exc:
            raise SeeUError(f"unreadable weight index ({_first_line(exc)})", index) from None
        names = sorted({f for k, f in weight_map.items() if k.startswith(BLIP2_PREFIXES)})
    elif hub:
        names = [single]
    else:
        names = sorted(p.name for p in Path(where).glob("*" + Path(single).suffix))
    files = [resolve(name) for name in names]
    return [f for f in files if f is not None] if names and all(f is not None for f in files) else []


def load_blip2_image_state(
    model: str = BLIP2_DEFAULT_MODEL, weights: str | None = None
) -> tuple[Any, dict[str, torch.Tensor]]:
    """The Blip2Config and the image-side tensors (vision encoder, query tokens, Q-Former) of a BLIP-2
    checkpoint: a local directory (``weights``, or ``model`` naming one) or a hub repo (``model``). Only
    the shards that hold image-side tensors are read (downloaded), never the language model's."""
    transformers = import_blip2()
    resolve, where, hub = _blip2_resolver(model, weights)
    cfg_path = resolve("config.json")
    if cfg_path is None:
        raise SeeUError("no config.json in the BLIP-2 weights" + ("" if hub else " directory"), where)
    try:
        cfg_dict = read_json(cfg_path, "BLIP-2 config.json")
        if not isinstance(cfg_dict, dict):
            raise ValueError("not a JSON object")
    except (OSError, ValueError) as exc:
        raise SeeUError(f"unreadable BLIP-2 config.json ({_first_line(exc)})", cfg_path) from None
    if cfg_dict.get("model_type") != "blip-2":
        raise SeeUError(
            f"not a BLIP-2 checkpoint (config.json model_type {cfg_dict.get('model_type')!r}, expected 'blip-2')", where
        )
    config = transformers.Blip2Config.from_dict(cfg_dict)
    files = _image_side_files(resolve, where, hub, "model.safetensors") or _image_side_files(
        resolve, where, hub, "pytorch_model.bin"
    )
    if not files:
        raise SeeUError(
            "no weights of BLIP-2's image side found (expected model.safetensors, or "
            "model.safetensors.index.json with its shards; pytorch_model.bin also works)",
            where,
        )
    state: dict[str, torch.Tensor] = {}
    for f in files:
        try:
            if f.suffix == ".safetensors":
                from safetensors import safe_open

                with safe_open(str(f), framework="pt") as fh:
                    for key in fh.keys():
                        if key.startswith(BLIP2_PREFIXES):
                            state[key] = fh.get_tensor(key)
            else:
                shard = safe_torch_load(f, "BLIP-2 weights file", mmap=True)
                state.update({k: v for k, v in shard.items() if k.startswith(BLIP2_PREFIXES)})
        except SeeUError:
            raise
        except Exception as exc:
            raise SeeUError(f"cannot read BLIP-2 weights ({_first_line(exc)})", f) from None
    return config, state


def export_blip2_image_part(model: str, out_dir: str | Path, dtype: torch.dtype | None = torch.float16) -> Path:
    """Write only BLIP-2's image side (ViT-g + query tokens + Q-Former, ~1.1 B parameters, ~2.2 GB in
    float16) of ``model`` (hub repo or local directory) to ``out_dir`` as config.json + model.safetensors,
    for offline use as ``blip2_weights``. Returns ``out_dir``."""
    from safetensors.torch import save_file

    config, state = load_blip2_image_state(model)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    state = {
        k: (v.to(dtype) if dtype is not None and v.is_floating_point() else v).contiguous() for k, v in state.items()
    }
    save_file(state, str(out / "model.safetensors"), metadata={"format": "pt", "source": str(model)})
    config.to_json_file(str(out / "config.json"))
    return out


_BLIP2_RANDOM_ON_META = False


@contextmanager
def blip2_random_init_on_meta() -> Iterator[None]:
    """Inside: a randomly initialised BLIP-2 encoder is built on the meta device (shapes and parameter
    counts only, no memory, no 30 s init of ~1.1 B parameters); `seeu model-info` counts with it."""
    global _BLIP2_RANDOM_ON_META
    before, _BLIP2_RANDOM_ON_META = _BLIP2_RANDOM_ON_META, True
    try:
        yield
    finally:
        _BLIP2_RANDOM_ON_META = before


class FrozenBLIP2ImageEncoder(FrozenModule):
    """BLIP-2's frozen image side through Hugging Face ``transformers`` (the paper's "BLIP-2 embedding"
    ablation): images (B, V, 3, H, W) in [0, 1] -> Q-Former query-token features (B, V * Q, D_q), i.e. the
    Q learned queries of every view after cross-attending to the vision encoder's tokens (BLIP-2's
    image representation, which its language model reads to caption the image). Input resized to the
    model's resolution (224 for ViT-g) and CLIP-normalised as BLIP-2's image processor does.
    Salesforce/blip2-opt-2.7b: ViT-g/14 (D_v 1408) + Q-Former (D_q 768), Q = 32.

    Weights: ``weights`` (a local directory with config.json and *.safetensors, e.g. from
    `export_blip2_image_part` or a hub snapshot), else the hub repo ``model``; only the image-side
    tensors are loaded. ``pretrained=False`` without ``weights``: random initialisation of
    ``Blip2Config(**model_kwargs)`` (tests only; default config = blip2-opt-2.7b's image side)."""

    mean: torch.Tensor  # (1, 3, 1, 1) buffers: the input normalisation
    std: torch.Tensor

    def __init__(
        self,
        model: str = BLIP2_DEFAULT_MODEL,
        weights: str | None = None,
        pretrained: bool = True,
        model_kwargs: dict[str, Any] | None = None,
    ):
        super().__init__()
        transformers = import_blip2()
        if weights is None and not pretrained:
            try:
                config = transformers.Blip2Config(**(model_kwargs or {}))
            except Exception as exc:  # TypeError / ValueError / huggingface_hub's strict-dataclass errors
                raise SeeUError(f"invalid blip2_model_kwargs ({_first_line(exc)})") from None
            if _BLIP2_RANDOM_ON_META:
                with torch.device("meta"):
                    self._build(transformers, config)
            else:
                self._build(transformers, config)
        else:
            if model_kwargs:
                raise SeeUError(
                    "blip2_model_kwargs only apply to random initialisation (semantic_pretrained=False "
                    "without blip2_weights); the architecture comes from the checkpoint's config.json"
                )
            config, state = load_blip2_image_state(model, weights)
            with torch.device("meta"):  # no random init of ~1 B parameters that are overwritten at once
                self._build(transformers, config)
            expected = {k: v for k, v in self.state_dict().items()}
            missing = [k for k in expected if k not in state]
            bad = [k for k in expected if k in state and tuple(state[k].shape) != tuple(expected[k].shape)]
            if missing or bad:
                raise SeeUError(
                    f"BLIP-2 checkpoint does not match its config.json: {len(missing)} image-side tensors "
                    f"missing (e.g. {missing[:2]}), {len(bad)} of another shape (e.g. {bad[:2]})",
                    weights or model,
                )
            self.load_state_dict({k: state[k].float() for k in expected}, strict=True, assign=True)
        self.config = config
        size = config.vision_config.image_size
        self.input_size = (size, size) if isinstance(size, int) else tuple(size)
        self.register_buffer("mean", torch.tensor(OPENAI_CLIP_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(OPENAI_CLIP_STD).view(1, 3, 1, 1), persistent=False)
        self.num_query_tokens = int(config.num_query_tokens)
        self.embed_dim = int(config.qformer_config.hidden_size)
        self.freeze()

    def _build(self, transformers: Any, config: Any) -> None:
        # Same attribute names as transformers' Blip2Model, so checkpoint keys load unchanged.
        self.vision_model = transformers.Blip2VisionModel._from_config(config.vision_config)
        self.query_tokens = nn.Parameter(torch.zeros(1, config.num_query_tokens, config.qformer_config.hidden_size))
        self.qformer = transformers.Blip2QFormerModel._from_config(config.qformer_config)
        if not self.query_tokens.is_meta:
            nn.init.normal_(self.query_tokens, std=config.initializer_range)

    @torch.no_grad()
    def forward(self, images: torch.Tensor) -> torch.Tensor:
        b, v, _, h, w = images.shape
        x = images.reshape(b * v, 3, h, w).float()
        if (h, w) != self.input_size:
            x = F.interpolate(x, size=self.input_size, mode="bicubic", align_corners=False, antialias=True)
        x = (x - self.mean) / self.std
        image_tokens = self.vision_model(pixel_values=x).last_hidden_state  # (BV, 1 + N, D_v)
        queries = self.query_tokens.expand(b * v, -1, -1)  # (BV, Q, D_q)
        out = self.qformer(query_embeds=queries, encoder_hidden_states=image_tokens).last_hidden_state  # (BV, Q, D_q)
        return out.reshape(b, v * out.shape[1], out.shape[2])
