"""Gaussians <-> the standard 3DGS `.ply` (the layout the INRIA code writes and common viewers open).

One `vertex` element, binary little-endian float32 properties in this order:
`x y z nx ny nz f_dc_0 f_dc_1 f_dc_2 f_rest_0 .. f_rest_{3(K-1)-1} opacity scale_0 scale_1 scale_2
rot_0 rot_1 rot_2 rot_3`, where
* normals are zeros,
* `f_dc_c` = SH coefficient 0 of channel c; `f_rest` is channel-major: `f_rest_{c (K-1) + k - 1}` is
  coefficient k >= 1 of channel c,
* opacity is the logit of our [0, 1] opacity (clamped to [1e-6, 1 - 1e-6] so it stays finite),
* scales are the natural log of our linear scales (clamped to >= 1e-12),
* rotation is the unit quaternion (w, x, y, z).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import torch
from plyfile import PlyData, PlyElement, PlyParseError

from seeu_data.errors import SeeUError
from seeu_model.gaussians import Gaussians
from seeu_model.rasterizer.sh import sh_degree_from_bases

OPACITY_EPS = 1e-6


def ply_property_names(sh_degree: int) -> list[str]:
    """The 3DGS vertex property names, in file order, for SH of `sh_degree`."""
    n_rest = 3 * ((sh_degree + 1) ** 2 - 1)
    return (
        ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
        + [f"f_rest_{i}" for i in range(n_rest)]
        + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    )


def save_ply(gaussians: Gaussians, path: str | Path, batch_index: int = 0) -> Path:
    """Write scene `batch_index` of `gaussians` (B, N, ...) to `path` in the 3DGS layout (atomic)."""
    g = gaussians.map(lambda t: t[batch_index].detach().to("cpu", torch.float64))
    n, k = g.sh.shape[0], g.sh.shape[1]
    degree = sh_degree_from_bases(k)
    opac = g.opacities.clamp(OPACITY_EPS, 1.0 - OPACITY_EPS)
    quat = g.rotations / g.rotations.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    columns = (
        torch.cat(
            [
                g.means,
                torch.zeros(n, 3, dtype=torch.float64),
                g.sh[:, 0, :],
                g.sh[:, 1:, :].transpose(1, 2).reshape(n, 3 * (k - 1)),  # channel-major rest
                torch.log(opac / (1.0 - opac))[:, None],
                torch.log(g.scales.clamp_min(1e-12)),
                quat,
            ],
            1,
        )
        .numpy()
        .astype(np.float32)
    )
    names = ply_property_names(degree)
    vertex = np.empty(n, dtype=[(name, "<f4") for name in names])
    for i, name in enumerate(names):
        vertex[name] = columns[:, i]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    PlyData([PlyElement.describe(vertex, "vertex")], byte_order="<").write(str(tmp))
    os.replace(tmp, path)
    return path


def cameras_json(
    cam_to_world: np.ndarray, intrinsics_norm: np.ndarray, width: int, height: int, names: list[str]
) -> list[dict]:
    """Cameras in the layout the 3DGS viewers read (`cameras.json` of the INRIA code): per camera
    `id, img_name, width, height, position` (camera centre), `rotation` (3x3 camera-to-world rotation,
    rows; OpenCV axes as in COLMAP), `fx, fy` (pixels). The layout has no principal point: viewers
    assume the image centre. cam_to_world: (N, 4, 4); intrinsics_norm: (N, 4) or (N, 3, 3)."""
    c2w = np.asarray(cam_to_world, np.float64).reshape(-1, 4, 4)
    k = np.asarray(intrinsics_norm, np.float64)
    k = k.reshape(-1, 3, 3)[:, [0, 1, 0, 1], [0, 1, 2, 2]] if k.shape[-2:] == (3, 3) else k.reshape(-1, 4)
    return [
        {
            "id": i,
            "img_name": names[i],
            "width": int(width),
            "height": int(height),
            "position": c2w[i, :3, 3].tolist(),
            "rotation": c2w[i, :3, :3].tolist(),
            "fy": float(k[i, 1] * height),
            "fx": float(k[i, 0] * width),
        }
        for i in range(len(c2w))
    ]


def save_ply_bundle(
    gaussians: Gaussians,
    out_dir: str | Path,
    cam_to_world: np.ndarray,
    intrinsics_norm: np.ndarray,
    width: int,
    height: int,
    names: list[str],
    batch_index: int = 0,
) -> dict:
    """`out_dir/gaussians.ply` (3DGS layout) + `cameras.json` (`cameras_json`) + `gaussians.json`, a
    sidecar saying the SH degree, the Gaussian count and the conventions. Returns the sidecar."""
    from seeu_data.store.arrow_io import atomic_write_text

    out_dir = Path(out_dir)
    ply = save_ply(gaussians, out_dir / "gaussians.ply", batch_index)
    cams = cameras_json(cam_to_world, intrinsics_norm, width, height, names)
    atomic_write_text(out_dir / "cameras.json", json.dumps(cams, indent=1))
    sidecar = {
        "ply": ply.name,
        "cameras": "cameras.json",
        "sh_degree": sh_degree_from_bases(gaussians.sh.shape[2]),
        "num_gaussians": int(gaussians.means.shape[1]),
        "layout": "3DGS (INRIA) binary little-endian",
        "axes": "OpenCV (x right, y down, z forward), the world of the context cameras",
    }
    atomic_write_text(out_dir / "gaussians.json", json.dumps(sidecar, indent=1))
    return sidecar


_PLY_TYPES = {
    **dict.fromkeys(("char", "int8"), "i1"),
    **dict.fromkeys(("uchar", "uint8"), "u1"),
    **dict.fromkeys(("short", "int16"), "i2"),
    **dict.fromkeys(("ushort", "uint16"), "u2"),
    **dict.fromkeys(("int", "int32"), "i4"),
    **dict.fromkeys(("uint", "uint32"), "u4"),
    **dict.fromkeys(("float", "float32"), "f4"),
    **dict.fromkeys(("double", "float64"), "f8"),
}
CHUNK_ROWS = 1 << 16  # vertices read at a time when a .ply is streamed


def binary_vertex_layout(path: str | Path) -> tuple[np.dtype, int, int] | None:
    """(row dtype, vertex count, file offset of the first vertex) of a binary `.ply` whose first element
    is `vertex` with scalar properties (every 3DGS .ply), read from the header alone; None for any
    other layout (ASCII, list properties), which `plyfile` reads whole."""
    with open(path, "rb") as f:
        head = f.read(1 << 16)
    end = head.find(b"end_header\n")
    if not head.startswith(b"ply\n") or end < 0:
        return None
    order, count, fields = None, None, []
    for line in head[:end].decode("ascii", "replace").splitlines()[1:]:
        words = line.split()
        if words[:1] == ["format"] and len(words) > 1:
            order = {"binary_little_endian": "<", "binary_big_endian": ">"}.get(words[1])
        elif words[:1] == ["element"]:
            if count is not None:
                break  # elements after the vertices are not read
            if len(words) != 3 or words[1] != "vertex" or not words[2].isdigit():
                return None
            count = int(words[2])
        elif words[:1] == ["property"] and count is not None:
            if len(words) != 3 or words[1] not in _PLY_TYPES:
                return None  # a list property
            fields.append((words[2], _PLY_TYPES[words[1]]))
    if order is None or count is None or not fields:
        return None
    return np.dtype([(name, order + kind) for name, kind in fields]), count, end + len(b"end_header\n")


def _stream_rows(path: Path, row: np.dtype, n: int, offset: int, most: int | None) -> np.ndarray:
    """The vertex rows of a binary .ply, `CHUNK_ROWS` at a time: all of them, or (when there are more
    than `most`) the `most` with the largest opacity, in file order. Memory: the kept rows, one chunk
    and 4 bytes per vertex (the opacities), never the whole file."""
    with open(path, "rb") as f:

        def chunks():
            f.seek(offset)
            for start in range(0, n, CHUNK_ROWS):
                block = np.fromfile(f, row, count=min(CHUNK_ROWS, n - start))
                if len(block) < min(CHUNK_ROWS, n - start):
                    raise SeeUError(f"truncated: {start + len(block)} of the {n} vertices its header declares", path)
                yield start, block

        if most is None or n <= most:
            return np.concatenate([b for _, b in chunks()]) if n else np.zeros(0, row)
        opacity = np.concatenate([b["opacity"].astype(np.float32) for _, b in chunks()])
        keep = np.sort(np.argpartition(-opacity, most)[:most])
        del opacity
        out = np.empty(most, row)
        done = 0
        for start, block in chunks():
            lo, hi = np.searchsorted(keep, [start, start + len(block)])
            out[done : done + hi - lo] = block[keep[lo:hi] - start]
            done += hi - lo
        return out


def load_ply(path: str | Path, dtype: torch.dtype = torch.float32, most: int | None = None) -> Gaussians:
    """Read a 3DGS `.ply` into Gaussians with B = 1 (sigmoid opacity, exp scales, unit wxyz quaternions).

    `most`: at most this many Gaussians, the most opaque (`seeu view`'s bound): a binary file is then
    streamed (`_stream_rows`), so a 0.74 GB file of 3 M Gaussians never sits in memory whole."""
    path = Path(path)
    try:
        layout = binary_vertex_layout(path)
        if layout is None:
            ply = PlyData.read(str(path))
            rows = ply["vertex"].data
            names = [p.name for p in ply["vertex"].properties]
        else:
            names = list(layout[0].names or ())
    except (OSError, KeyError, ValueError, IndexError, PlyParseError) as exc:
        raise SeeUError(f"not a readable .ply with a vertex element ({exc})", path) from exc
    n_rest = sum(1 for name in names if name.startswith("f_rest_"))
    if n_rest % 3:
        raise SeeUError(f"{n_rest} f_rest properties is not a multiple of 3", path)
    try:
        degree = sh_degree_from_bases(n_rest // 3 + 1)
    except ValueError as exc:
        raise SeeUError(str(exc), path) from exc
    missing = [name for name in ply_property_names(degree) if name not in names and name[0] != "n"]
    if missing:
        raise SeeUError(f"missing 3DGS properties: {', '.join(missing[:5])}", path)
    if layout is not None:
        rows = _stream_rows(path, *layout, most)
    elif most is not None and len(rows) > most:
        rows = rows[np.sort(np.argpartition(-np.asarray(rows["opacity"]), most)[:most])]
    col = lambda name: np.asarray(rows[name], dtype=np.float64)  # noqa: E731
    stack = lambda keys: torch.from_numpy(np.stack([col(key) for key in keys], -1))  # noqa: E731
    n = len(rows)
    k = (degree + 1) ** 2
    means = stack(["x", "y", "z"])
    dc = stack(["f_dc_0", "f_dc_1", "f_dc_2"])
    rest = stack([f"f_rest_{i}" for i in range(3 * (k - 1))]) if k > 1 else torch.zeros(n, 0, dtype=torch.float64)
    sh = torch.cat([dc[:, None, :], rest.reshape(n, 3, k - 1).transpose(1, 2)], 1)
    quat = stack(["rot_0", "rot_1", "rot_2", "rot_3"])
    quat = quat / quat.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    g = Gaussians(
        means=means,
        scales=torch.exp(stack(["scale_0", "scale_1", "scale_2"])),
        rotations=quat,
        opacities=torch.sigmoid(torch.from_numpy(col("opacity"))),
        sh=sh,
    )
    if not all(torch.isfinite(t).all() for t in (g.means, g.scales, g.rotations, g.opacities, g.sh)):
        raise SeeUError("non-finite values in the Gaussians", path)
    return g.map(lambda t: t[None].to(dtype))
