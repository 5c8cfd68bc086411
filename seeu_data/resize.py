"""Resize + centre-crop a whole posed scene (the peers' crop), intrinsics updated: what
`seeu export pixelsplat --resize` and `seeu ingest --size` do to make frames a given size."""

from __future__ import annotations

import numpy as np

from seeu_data.errors import SeeUError
from seeu_data.store.posed import PosedScene


def resize_scene(
    scene: PosedScene, out_hw: tuple[int, int], jpeg_quality: int = 95, interpolation: str = "area"
) -> PosedScene:
    """The scene with every frame resized to cover `out_hw` (H, W) and centre-cropped (the peers'
    crop; `seeu_data.image_ops`), intrinsics updated, frames re-encoded as JPEG; masks follow
    (`masks.resize_mask`)."""
    from dataclasses import replace

    from seeu_data.image_ops import decode_rgb, encode_jpeg, resize_cover_crop, resized_intrinsics
    from seeu_data.masks import decode_mask, encode_mask, resize_mask

    images, intr = [], []
    for i, data in enumerate(scene.images):
        img = decode_rgb(bytes(data))
        in_hw = img.shape[:2]
        if in_hw != (int(scene.height[i]), int(scene.width[i])):
            raise SeeUError(
                f"scene {scene.scene_id!r} frame {i}: image is {in_hw[1]}x{in_hw[0]}, the table says "
                f"{int(scene.width[i])}x{int(scene.height[i])}"
            )
        images.append(encode_jpeg(resize_cover_crop(img, out_hw, interpolation), jpeg_quality))
        intr.append(resized_intrinsics(scene.intrinsics_norm[i], in_hw, out_hw))
    masks = None
    if scene.masks is not None:
        masks = [
            None if m is None else encode_mask(resize_mask(decode_mask(m, f"scene {scene.scene_id} frame {i}"), out_hw))
            for i, m in enumerate(scene.masks)
        ]
    n = len(scene)
    meta = {
        **scene.meta,
        "resized": {
            "from_hw": [int(scene.height[0]), int(scene.width[0])],
            "to_hw": list(out_hw),
            "method": f"cover + centre crop ({interpolation}), JPEG {jpeg_quality}",
        },
    }
    return replace(
        scene,
        images=images,
        image_format="jpeg",
        width=np.full(n, out_hw[1]),
        height=np.full(n, out_hw[0]),
        intrinsics_norm=np.stack(intr),
        meta=meta,
        masks=masks,
    )
