"""benchmarks/peers.py (the loader against LitData): what its figures rest on, on tiny data.

The LitData half needs the optional extra `peers` (litdata) and is skipped without it.
"""

from __future__ import annotations

import pytest
import torch

from benchmarks import peers
from benchmarks.loader import make_triples, write_seeu_shards

SAMPLES = 12


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    root = tmp_path_factory.mktemp("peers")
    triples = make_triples(SAMPLES)
    write_seeu_shards(root / "seeu", triples, shard_rows=5)
    return root, triples


def test_resume_counting_finds_repeats_and_losses(data, tmp_path):
    """Our loader resumes exactly once with other workers; a state moved back / forward by 4 samples
    must be counted as 4 duplicates / 4 losses (the known answer for the counting)."""
    root, _ = data
    where = {"seeu": str(root / "seeu")}

    def moved(delta):
        return lambda state: {**state, "samples_seen": state["samples_seen"] + delta}

    args = ("seeu", where, 2, tmp_path / "cache", SAMPLES, 3)  # 6 of 12 samples before the stop
    assert peers.resume_counts(*args, 1, 0) == {
        "before": 6,
        "after": 6,
        "duplicates": 0,
        "losses": 0,
        "same_order": True,
    }
    assert peers.resume_counts(*args, 0, 0, edit_state=moved(-4)) == {
        "before": 6,
        "after": 10,
        "duplicates": 4,
        "losses": 0,
        "same_order": False,
    }
    assert peers.resume_counts(*args, 0, 0, edit_state=moved(+4)) == {
        "before": 6,
        "after": 2,
        "duplicates": 0,
        "losses": 4,
        "same_order": False,
    }


def test_litdata_items_hold_the_same_jpegs_and_decode_to_the_same_images(data, tmp_path):
    """The LitData copy stores each row's JPEG bytes unchanged, and both loaders hand out identical
    uint8 images for every sample: the benchmark compares loaders, not decoders."""
    pytest.importorskip("litdata")
    from litdata import StreamingDataset

    root, triples = data
    peers.build_litdata(root / "litdata", triples)
    ds = StreamingDataset(str(root / "litdata"), cache_dir=str(tmp_path / "lit-cache"))
    assert len(ds) == SAMPLES
    for item in ds:
        assert [bytes(item[f"img{v}"]) for v in range(peers.VIEWS)] == triples[item["index"]]
    where = {"seeu": str(root / "seeu"), "litdata": str(root / "litdata")}
    images = {}
    for name in ("seeu", "litdata"):
        seen = {}
        for b in peers.make(name, where, 0, 4, tmp_path / f"cache-{name}"):
            for i, im in zip(peers.ids_of(name, b), peers.images_of(name, b)):
                seen[i] = im
        images[name] = seen
    assert sorted(images["seeu"]) == sorted(images["litdata"]) == list(range(SAMPLES))
    assert all(torch.equal(images["seeu"][i], images["litdata"][i]) for i in range(SAMPLES))
