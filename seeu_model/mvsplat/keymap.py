"""MVSplat state-dict names -> `MVSplatEncoder` names, and the encoder shape a state dict implies.

MVSplat's Lightning checkpoints hold ``state_dict`` with the encoder under ``encoder.`` (and, from
training, the LPIPS loss network under ``losses.``). `map_key` translates one encoder key (without the
``encoder.`` prefix) or returns None when the name is not one of MVSplat's encoder parameters.
"""

from __future__ import annotations

import re

from .encoder import MVSplatShape

_UNET = [  # inside one of MVSplat's UNetModel instances
    (r"^input_blocks\.(\d+)\.(.+)$", r"enc.\1.\2"),
    (r"^middle_block\.0\.(.+)$", r"mid.0.\1"),
    (r"^middle_block\.2\.(.+)$", r"mid.1.\1"),
    (r"^output_blocks\.(\d+)\.(.+)$", r"dec.\1.\2"),
    (r"^out\.0\.(weight|bias)$", r"head_conv.\1"),
    (r"^out\.1\.(weight|bias)$", r"head_norm.\1"),
]
_UNET_BLOCK = [  # ResBlock / Downsample / Upsample / AttentionBlock parameters
    (r"\.in_layers\.0\.(weight|bias)$", r".conv1.\1"),
    (r"\.in_layers\.1\.(weight|bias)$", r".norm1.\1"),
    (r"\.out_layers\.0\.(weight|bias)$", r".conv2.\1"),
    (r"\.out_layers\.1\.(weight|bias)$", r".norm2.\1"),
    (r"\.skip_connection\.(weight|bias)$", r".skip.\1"),
    (r"\.op\.(weight|bias)$", r".conv.\1"),
    (r"\.conv\.(weight|bias)$", r".conv.\1"),
    (r"\.qkv\.(weight|bias)$", r".qkv.\1"),
    (r"\.proj_out\.(weight|bias)$", r".proj.\1"),
    (r"\.norm\.(weight|bias)$", r".norm.\1"),
]
_TOP = [
    (r"^backbone\.backbone\.conv1\.weight$", "backbone.cnn.stem.weight"),
    (r"^backbone\.backbone\.layer([123])\.([01])\.(conv[12])\.weight$", None),  # stage index shifts, below
    (r"^backbone\.backbone\.layer([123])\.([01])\.downsample\.0\.(weight|bias)$", None),
    (r"^backbone\.backbone\.conv2\.(weight|bias)$", r"backbone.cnn.proj.\1"),
    (r"^depth_predictor\.corr_refine_net\.0\.(weight|bias)$", r"cost_in.\1"),
    (r"^depth_predictor\.corr_refine_net\.1\.(weight|bias)$", r"cost_in_norm.\1"),
    (r"^depth_predictor\.corr_refine_net\.4\.(weight|bias)$", r"cost_out.\1"),
    (r"^depth_predictor\.regressor_residual\.(weight|bias)$", r"cost_skip.\1"),
    (r"^depth_predictor\.depth_head_lowres\.([02])\.(weight|bias)$", r"depth_head.\1.\2"),
    (r"^depth_predictor\.upsampler\.0\.(weight|bias)$", r"upsample_conv.\1"),
    (r"^depth_predictor\.proj_feature\.(weight|bias)$", r"feature_proj.\1"),
    (r"^depth_predictor\.refine_unet\.0\.(weight|bias)$", r"refine_in.\1"),
    (r"^depth_predictor\.refine_unet\.1\.(weight|bias)$", r"refine_in_norm.\1"),
    (r"^depth_predictor\.to_gaussians\.([02])\.(weight|bias)$", r"gaussian_head.\1.\2"),
    (r"^depth_predictor\.to_disparity\.([02])\.(weight|bias)$", r"disparity_head.\1.\2"),
]
_ATTN = {
    "q_proj": "q",
    "k_proj": "k",
    "v_proj": "v",
    "merge": "out",
    "norm1": "norm",
    "norm2": "ffn_norm",
    "mlp.0": "ffn.0",
    "mlp.2": "ffn.2",
}
_TRANSFORMER = re.compile(
    r"^backbone\.transformer\.layers\.(\d+)\.(self_attn|cross_attn_ffn)\."
    r"(q_proj|k_proj|v_proj|merge|norm1|norm2|mlp\.0|mlp\.2)\.(weight|bias)$"
)


def _map_unet(rest: str) -> str | None:
    for pattern, repl in _UNET:
        if re.match(pattern, rest):
            out = re.sub(pattern, repl, rest)
            if out.startswith(("head_conv", "head_norm")):
                return out
            for bp, brepl in _UNET_BLOCK:
                if re.search(bp, out):
                    return re.sub(bp, brepl, out)
            # the first input block is a bare conv: input_blocks.0.0.weight -> enc.0.0.weight
            if re.match(r"^enc\.0\.0\.(weight|bias)$", out):
                return out
            return None
    return None


def map_key(key: str) -> str | None:
    """An MVSplat encoder key (no ``encoder.`` prefix) -> the `MVSplatEncoder` key, or None."""
    m = re.match(r"^backbone\.backbone\.layer([123])\.([01])\.(conv[12])\.weight$", key)
    if m:
        return f"backbone.cnn.stages.{int(m[1]) - 1}.{m[2]}.{m[3]}.weight"
    m = re.match(r"^backbone\.backbone\.layer([123])\.([01])\.downsample\.0\.(weight|bias)$", key)
    if m:
        return f"backbone.cnn.stages.{int(m[1]) - 1}.{m[2]}.shortcut.{m[3]}"
    m = _TRANSFORMER.match(key)
    if m:
        part = "self_attn" if m[2] == "self_attn" else "cross_attn"
        return f"backbone.transformer.{part}.{m[1]}.{_ATTN[m[3]]}.{m[4]}"
    for prefix, ours in (
        ("depth_predictor.corr_refine_net.3.", "cost_unet."),
        ("depth_predictor.refine_unet.3.", "refine_unet."),
    ):
        if key.startswith(prefix):
            inner = _map_unet(key[len(prefix) :])
            return ours + inner if inner else None
    for pattern, repl in _TOP:
        if repl is not None and re.match(pattern, key):
            return re.sub(pattern, repl, key)
    return None


def _levels(keys: set[str], prefix: str) -> tuple[int, tuple[int, ...]]:
    """Number of UNet levels and the downsampling rates with attention, from its key names."""
    blocks = sorted({int(m[1]) for k in keys if (m := re.match(rf"^{re.escape(prefix)}input_blocks\.(\d+)\.", k))})
    # block 0 is the stem conv; then per level a ResBlock block, and a Downsample block between levels
    levels = sum(1 for i in blocks if f"{prefix}input_blocks.{i}.0.in_layers.0.weight" in keys)
    rates, rate, level = [], 1, 0
    for i in blocks[1:]:
        if f"{prefix}input_blocks.{i}.0.op.weight" in keys:
            rate *= 2
            continue
        if f"{prefix}input_blocks.{i}.1.qkv.weight" in keys:
            rates.append(rate)
        level += 1
    return levels, tuple(rates)


def shape_from_state(state: dict) -> MVSplatShape:
    """The encoder structure a (prefix-free) MVSplat encoder state dict was trained with.

    Channel multipliers other than 1 are not used by MVSplat's released models and not supported."""
    keys = set(state)
    sd = {k: tuple(v.shape) for k, v in state.items()}
    c = sd["backbone.backbone.conv2.weight"][0]
    cnn = (
        sd["backbone.backbone.conv1.weight"][0],
        sd["backbone.backbone.layer2.0.conv1.weight"][0],
        sd["backbone.backbone.layer3.0.conv1.weight"][0],
    )
    layers = len({m[1] for k in keys if (m := re.match(r"^backbone\.transformer\.layers\.(\d+)\.", k))})
    ffn_hidden = sd["backbone.transformer.layers.0.cross_attn_ffn.mlp.0.weight"][0]
    d = sd["depth_predictor.regressor_residual.weight"][0]
    cc = sd["depth_predictor.corr_refine_net.0.weight"][0]
    dc = sd["depth_predictor.proj_feature.weight"][0]
    raw = sd["depth_predictor.to_gaussians.2.weight"][0]
    sh_coeffs = (raw - 9) // 3
    sh_degree = round(sh_coeffs**0.5) - 1
    cost_levels, cost_attn = _levels(keys, "depth_predictor.corr_refine_net.3.")
    depth_levels, depth_attn = _levels(keys, "depth_predictor.refine_unet.3.")
    return MVSplatShape(
        cnn_channels=cnn,
        feature_dim=c,
        transformer_layers=layers,
        ffn_ratio=ffn_hidden // (2 * c),
        num_depth_candidates=d,
        cost_unet_channels=cc,
        cost_unet_mult=(1,) * cost_levels,
        cost_unet_attention=cost_attn,
        depth_unet_channels=dc,
        depth_unet_mult=(1,) * depth_levels,
        depth_unet_attention=depth_attn,
        sh_degree=sh_degree,
    )
