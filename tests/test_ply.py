"""3DGS .ply export: exact standard layout, round trip, and files written the INRIA way."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from plyfile import PlyData, PlyElement

from seeu_data.errors import SeeUError
from seeu_model.gaussians import Gaussians
from seeu_model.ply import load_ply, ply_property_names, save_ply


def _scene(n: int, degree: int, b: int = 2, seed: int = 0) -> Gaussians:
    gen = torch.Generator().manual_seed(seed)
    q = torch.randn(b, n, 4, generator=gen)
    return Gaussians(
        means=torch.randn(b, n, 3, generator=gen),
        scales=torch.rand(b, n, 3, generator=gen) * 0.3 + 1e-3,
        rotations=q / q.norm(dim=-1, keepdim=True),
        opacities=torch.rand(b, n, generator=gen) * 0.98 + 0.01,
        sh=torch.randn(b, n, (degree + 1) ** 2, 3, generator=gen),
    )


def test_header_is_the_standard_3dgs_layout(tmp_path):
    path = save_ply(_scene(5, 3), tmp_path / "g.ply")
    raw = path.read_bytes()
    header = raw[: raw.index(b"end_header\n") + len(b"end_header\n")].decode("ascii")
    lines = header.splitlines()
    assert lines[:3] == ["ply", "format binary_little_endian 1.0", "element vertex 5"]
    props = [line.split() for line in lines if line.startswith("property")]
    assert all(p[1] == "float" for p in props)
    names = [p[2] for p in props]
    expected = (
        ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
        + [f"f_rest_{i}" for i in range(45)]
        + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    )
    assert names == expected == ply_property_names(3)
    assert len(raw) - len(header) == 5 * 62 * 4  # 62 float32 per Gaussian, nothing else


@pytest.mark.parametrize("degree", [0, 1, 3, 4])
def test_round_trip_and_stored_encodings(tmp_path, degree):
    g = _scene(17, degree)
    path = save_ply(g, tmp_path / "sub" / "g.ply", batch_index=1)
    back = load_ply(path)
    assert back.means.shape == (1, 17, 3) and back.sh.shape == (1, 17, (degree + 1) ** 2, 3)
    for name in ("means", "scales", "rotations", "opacities", "sh"):
        assert torch.allclose(getattr(back, name)[0], getattr(g, name)[1], rtol=1e-5, atol=1e-6), name
    v = PlyData.read(str(path))["vertex"]
    # stored encodings: logit opacity, log scale, wxyz, zero normals, channel-major SH rest
    o = g.opacities[1].double()
    assert np.allclose(v["opacity"], torch.log(o / (1 - o)).numpy(), atol=1e-5)
    assert np.allclose(v["scale_2"], torch.log(g.scales[1, :, 2]).numpy(), atol=1e-6)
    assert np.allclose(v["rot_0"], g.rotations[1, :, 0].numpy(), atol=1e-7)
    assert np.all(v["nx"] == 0)
    if degree >= 1:
        k = (degree + 1) ** 2
        assert np.allclose(v["f_rest_0"], g.sh[1, :, 1, 0].numpy())  # coefficient 1, red
        assert np.allclose(v[f"f_rest_{k - 1}"], g.sh[1, :, 1, 1].numpy())  # coefficient 1, green
        assert np.allclose(v[f"f_rest_{2 * (k - 1) + 2}"], g.sh[1, :, 3, 2].numpy())  # coefficient 3, blue


def test_reads_a_file_written_like_the_inria_code(tmp_path):
    """The INRIA writer: attributes concatenated as [xyz, normals, f_dc, f_rest (N, 3*(K-1)), opacity,
    scale, rotation] from features_rest transposed to (N, 3, K-1); opacity logit, log scales."""
    n, k = 4, 4
    rng = np.random.default_rng(1)
    xyz = rng.normal(size=(n, 3))
    feat = rng.normal(size=(n, k, 3))  # (N, K, 3) like the model's sh
    f_dc = feat[:, :1, :].transpose(0, 2, 1).reshape(n, -1)
    f_rest = feat[:, 1:, :].transpose(0, 2, 1).reshape(n, -1)
    opac = rng.uniform(0.1, 0.9, size=(n, 1))
    scale = rng.uniform(0.01, 0.2, size=(n, 3))
    rot = rng.normal(size=(n, 4)) * 3  # unnormalised, as INRIA stores it
    attrs = np.concatenate([xyz, np.zeros((n, 3)), f_dc, f_rest, np.log(opac / (1 - opac)), np.log(scale), rot], 1)
    names = ply_property_names(1)
    el = np.empty(n, dtype=[(a, "f4") for a in names])
    el[:] = list(map(tuple, attrs))
    PlyData([PlyElement.describe(el, "vertex")]).write(str(tmp_path / "inria.ply"))
    g = load_ply(tmp_path / "inria.ply", dtype=torch.float64)
    assert np.allclose(g.sh[0].numpy(), feat, atol=1e-6)
    assert np.allclose(g.opacities[0].numpy(), opac[:, 0], atol=1e-6)
    assert np.allclose(g.scales[0].numpy(), scale, rtol=1e-6)
    assert np.allclose(g.rotations[0].numpy(), rot / np.linalg.norm(rot, axis=1, keepdims=True), atol=1e-6)


def test_extreme_values_stay_finite_and_bad_files_raise(tmp_path):
    g = _scene(3, 0, b=1)
    g.opacities[0, 0], g.opacities[0, 1] = 1.0, 0.0
    back = load_ply(save_ply(g, tmp_path / "e.ply"))
    assert torch.allclose(back.opacities[0, :2], torch.tensor([1.0, 0.0]), atol=1e-5)
    (tmp_path / "bad.ply").write_bytes(b"not a ply")
    with pytest.raises(SeeUError, match="bad.ply"):
        load_ply(tmp_path / "bad.ply")
    el = np.zeros(2, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
    PlyData([PlyElement.describe(el, "vertex")]).write(str(tmp_path / "points.ply"))
    with pytest.raises(SeeUError, match="missing 3DGS properties: f_dc_0"):
        load_ply(tmp_path / "points.ply")
