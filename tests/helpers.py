"""Small test-data builders shared by the tests (real encoded images, valid camera paths)."""

from __future__ import annotations

import cv2
import numpy as np

from seeu_data.store.posed import PosedScene


def look_at_cam_to_world(eye: np.ndarray, target: np.ndarray, up=(0.0, -1.0, 0.0)) -> np.ndarray:
    """OpenCV camera-to-world (4, 4) at `eye` looking at `target` (+y down in the image)."""
    z = target - eye
    z = z / np.linalg.norm(z)
    down = -np.asarray(up, dtype=np.float64)
    x = np.cross(down, z)
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = x, y, z, eye
    return m


def make_posed_scene(
    scene_id: str = "scene0", n: int = 12, height: int = 48, width: int = 64, seed: int = 0, image_format: str = "jpeg"
) -> PosedScene:
    """A scene of `n` noise-textured encoded images along a sideways camera path."""
    rng = np.random.default_rng(seed)
    ext = ".jpg" if image_format == "jpeg" else ".png"
    images, poses = [], []
    for i in range(n):
        img = (rng.random((height, width, 3)) * 255).astype(np.uint8)
        cv2.putText(img, str(i), (2, height - 4), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1)
        ok, buf = cv2.imencode(ext, img)
        assert ok
        images.append(buf.tobytes())
        eye = np.array([0.1 * i, 0.0, -2.0])
        poses.append(look_at_cam_to_world(eye, np.array([0.1 * i, 0.0, 0.0])))
    return PosedScene(
        scene_id=scene_id,
        images=images,
        image_format=image_format,
        width=np.full(n, width),
        height=np.full(n, height),
        intrinsics_norm=np.tile([0.9, 1.2, 0.5, 0.5], (n, 1)),
        cam_to_world=np.stack(poses),
        near=0.5,
        far=10.0,
        source_frame=np.arange(n, dtype=np.int64) * 3,
        timestamp_us=np.arange(n, dtype=np.int64) * 100_000,
        source_name=[f"frame_{i * 3:05d}{ext}" for i in range(n)],
    )


def page_cache_bytes(path) -> int:
    """Bytes of the file `path` in the kernel's page cache: what was read from the disk since it was
    last evicted (`evict`), by any means (read(), a memory map, read-ahead). Linux `mincore` over a
    map of the file that touches nothing."""
    import ctypes
    import mmap
    import os

    size = os.path.getsize(path)
    if size == 0:
        return 0
    with open(path, "rb") as fh:
        mapped = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)
    view = np.frombuffer(mapped, np.uint8)
    vec = (ctypes.c_ubyte * ((size + mmap.PAGESIZE - 1) // mmap.PAGESIZE))()
    assert ctypes.CDLL(None).mincore(ctypes.c_void_p(view.ctypes.data), ctypes.c_size_t(size), vec) == 0
    del view
    mapped.close()
    return sum(v & 1 for v in vec) * mmap.PAGESIZE


def evict(path) -> bool:
    """Drop the file `path` from the page cache (fsync, then `POSIX_FADV_DONTNEED`); False where the
    file system keeps it (tmpfs)."""
    import os

    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
        os.posix_fadvise(fd, 0, 0, os.POSIX_FADV_DONTNEED)
    finally:
        os.close(fd)
    return page_cache_bytes(path) == 0
