"""Per-frame masks of excluded pixels: storage (posed frames schema 1.1), import, build, loader, loss, eval."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pyarrow as pa
import pytest

from pipelines.validate import validate_dataset
from seeu_data.errors import SeeUError
from seeu_data.masks import decode_mask, encode_mask
from seeu_data.store.arrow_io import read_table, sha256_file, write_table
from seeu_data.store.posed import PosedDataset, PosedDatasetWriter
from tests.helpers import make_posed_scene


def box_mask(height: int, width: int, i: int) -> np.ndarray:
    """(H, W) bool: a box that moves right by 3 px per frame `i`."""
    m = np.zeros((height, width), bool)
    m[10:30, 5 + 3 * i : 25 + 3 * i] = True
    return m


def masked_scene(scene_id: str = "m", n: int = 6, every: int = 2):
    """make_posed_scene with a moving-box mask on every `every`-th frame (None on the others)."""
    scene = make_posed_scene(scene_id, n=n)
    scene.masks = [encode_mask(box_mask(48, 64, i)) if i % every == 0 else None for i in range(n)]
    return scene


# ---- storage ---------------------------------------------------------------------------------


def test_mask_png_round_trip_and_format():
    m = box_mask(48, 64, 2)
    data = encode_mask(m)
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert img.dtype == np.uint8 and img.shape == (48, 64) and set(np.unique(img)) == {0, 255}
    assert np.array_equal(decode_mask(data), m)
    with pytest.raises(SeeUError, match="8-bit single-channel"):
        decode_mask(cv2.imencode(".png", np.zeros((4, 4, 3), np.uint8))[1].tobytes())


def test_posed_masks_round_trip_and_validate(tmp_path):
    scenes = [masked_scene("m"), make_posed_scene("plain", n=4)]
    with PosedDatasetWriter(tmp_path / "ds", params={}, provenance={}) as w:
        for s in scenes:
            w.add(s)
    ds = PosedDataset(tmp_path / "ds", verify=True)
    assert ds.manifest["schema_version"] == "1.1"
    got = ds.load_scene("m")
    assert got.masks == scenes[0].masks and got.masks[1] is None
    assert np.array_equal(decode_mask(got.masks[4]), box_mask(48, 64, 4))
    assert ds.load_scene("plain").masks is None
    assert validate_dataset(tmp_path / "ds")["rows"] == 10


def test_posed_version_1_0_without_mask_column_still_reads(tmp_path):
    """A dataset written before masks (schema 1.0: no `mask` column) validates and loads as mask-less."""
    with PosedDatasetWriter(tmp_path / "ds", params={}, provenance={}) as w:
        w.add(make_posed_scene("old", n=5))
    doc = json.loads((tmp_path / "ds" / "manifest.json").read_text())
    entry = doc["files"][0]
    path = tmp_path / "ds" / entry["path"]
    table = read_table(path).drop_columns(["mask"])
    table = table.replace_schema_metadata({**table.schema.metadata, b"seeu.schema_version": b"1.0"})
    write_table(path, table)
    entry["bytes"], entry["sha256"] = path.stat().st_size, sha256_file(path)
    doc["schema_version"] = "1.0"
    (tmp_path / "ds" / "manifest.json").write_text(json.dumps(doc))
    assert validate_dataset(tmp_path / "ds")["schema_version"] == "1.0"
    scene = PosedDataset(tmp_path / "ds", verify=True).load_scene("old")
    assert scene.masks is None and len(scene) == 5


@pytest.mark.parametrize(
    "mask, text",
    [
        (encode_mask(np.ones((40, 64), bool)), "mask is 64x40, its frame 64x48"),
        (cv2.imencode(".png", np.zeros((48, 64, 3), np.uint8))[1].tobytes(), "8-bit greyscale expected"),
        (cv2.imencode(".jpg", np.zeros((48, 64), np.uint8))[1].tobytes(), "not a PNG"),
        (b"nope", "failed to decode"),
    ],
)
def test_posed_scene_check_refuses_bad_masks(mask, text):
    scene = masked_scene()
    scene.masks = list(scene.masks)
    scene.masks[2] = mask
    with pytest.raises(SeeUError, match=text) as exc:
        scene.check()
    assert "frame 2" in str(exc.value)
    scene.masks = scene.masks[:3]
    with pytest.raises(SeeUError, match="masks has 3 entries for 6 frames"):
        scene.check()


def test_validate_refuses_a_mask_of_another_size_in_the_file(tmp_path):
    with PosedDatasetWriter(tmp_path / "ds", params={}, provenance={}) as w:
        w.add(masked_scene())
    doc = json.loads((tmp_path / "ds" / "manifest.json").read_text())
    entry = doc["files"][0]
    path = tmp_path / "ds" / entry["path"]
    table = read_table(path)
    masks = table.column("mask").to_pylist()
    masks[3] = encode_mask(np.ones((8, 8), bool))
    i = table.schema.get_field_index("mask")
    write_table(path, table.set_column(i, table.schema.field(i), pa.array(masks, pa.binary())))
    entry["bytes"], entry["sha256"] = path.stat().st_size, sha256_file(path)
    (tmp_path / "ds" / "manifest.json").write_text(json.dumps(doc))
    with pytest.raises(SeeUError, match="scene 'm' frame 3: mask is 8x8, its frame 64x48"):
        validate_dataset(tmp_path / "ds")
