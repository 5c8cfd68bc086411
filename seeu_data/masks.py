"""Per-frame masks of excluded pixels (moving or transient content): encode, decode, resize.

A mask is stored beside its frame (posed frames' and triples' `mask` column) as a PNG, 8-bit single
channel, of the frame's size: nonzero = excluded pixel, 0 = kept; null = no mask. In memory it is an
(H, W) bool array, True = excluded. `seeu ingest` writes the masks it finds with `encode_mask`;
importers convert a data set's own convention to this one.

Example:
    >>> import numpy as np
    >>> m = np.zeros((4, 6), bool); m[1:3, 2:5] = True
    >>> bool((decode_mask(encode_mask(m)) == m).all())
    True
"""

from __future__ import annotations

import cv2
import numpy as np

from seeu_data.errors import SeeUError


def encode_mask(mask: np.ndarray) -> bytes:
    """(H, W) bool (True = excluded; any nonzero counts as True) -> PNG bytes, 8-bit greyscale, 255 / 0."""
    m = np.asarray(mask)
    if m.ndim != 2 or 0 in m.shape:
        raise ValueError(f"a mask is (H, W), got shape {m.shape}")
    ok, buf = cv2.imencode(".png", np.where(m != 0, 255, 0).astype(np.uint8), [cv2.IMWRITE_PNG_COMPRESSION, 3])
    if not ok:
        raise ValueError("PNG encoding failed")
    return buf.tobytes()


def decode_mask(data, where: str | None = None) -> np.ndarray:
    """PNG bytes of an 8-bit single-channel mask -> (H, W) bool, True = excluded (nonzero).
    SeeUError (naming `where`) when the bytes are no such image."""
    arr = np.frombuffer(data, dtype=np.uint8)
    img = cv2.imdecode(arr, cv2.IMREAD_UNCHANGED) if arr.size else None
    if img is None or img.ndim != 2 or img.dtype != np.uint8:
        raise SeeUError("mask is not an 8-bit single-channel image", where)
    return img != 0
