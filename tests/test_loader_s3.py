"""Streaming loader over object storage: a moto S3 server on 127.0.0.1, started and stopped here."""

from __future__ import annotations

import warnings

import boto3
import pytest
import torch
from moto.server import ThreadedMotoServer

from seeu_data.errors import SeeUError
from seeu_data.loader import make_loader
from tests.loader_fixtures import all_sample_ids, write_triples

ROWS = [6, 4, 5]


@pytest.fixture(scope="module")
def s3(tmp_path_factory):
    mp = pytest.MonkeyPatch()
    for key, value in {
        "AWS_ACCESS_KEY_ID": "testing",
        "AWS_SECRET_ACCESS_KEY": "testing",
        "AWS_DEFAULT_REGION": "us-east-1",
        "AWS_EC2_METADATA_DISABLED": "true",
    }.items():
        mp.setenv(key, value)
    server = ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    server.start()
    host, port = server.get_host_and_port()
    client = boto3.client("s3", endpoint_url=f"http://{host}:{port}", region_name="us-east-1")
    client.create_bucket(Bucket="data")
    local = write_triples(tmp_path_factory.mktemp("s3src") / "ds", ROWS, hw=(10, 14))
    for f in sorted(local.iterdir()):
        client.upload_file(str(f), "data", f"ds/{f.name}")
    try:
        yield {
            "client": client,
            "local": local,
            "url": f"s3://data/ds?endpoint_override={host}:{port}&scheme=http&region=us-east-1",
            "opts": f"endpoint_override={host}:{port}&scheme=http&region=us-east-1",
        }
    finally:
        server.stop()
        mp.undo()


@pytest.mark.parametrize("workers", [0, 2])
def test_s3_stream_equals_local_and_is_cached_by_content(s3, tmp_path, workers):
    cache = tmp_path / "cache"
    remote = list(make_loader(s3["url"], 2, seed=4, image_hw=(8, 8), cache_dir=str(cache), num_workers=workers))
    local = list(make_loader(s3["local"], 2, seed=4, image_hw=(8, 8), cache_dir=str(tmp_path / "c2")))
    assert [b["sample_id"] for b in remote] == [b["sample_id"] for b in local]
    assert all(torch.equal(a["target"]["image"], b["target"]["image"]) for a, b in zip(remote, local))
    assert sorted(s for b in remote for s, p in zip(b["sample_id"], b["is_padding"]) if not p) == sorted(
        all_sample_ids(ROWS)
    )
    import json

    shas = {f["sha256"] for f in json.loads((s3["local"] / "manifest.json").read_text())["files"]}
    assert {p.stem for p in (cache / "objects").glob("*.arrow")} == shas


def test_s3_cache_is_bounded(s3, tmp_path):
    sizes = [f.stat().st_size for f in s3["local"].glob("*.arrow")]
    cache = tmp_path / "cache"
    ld = make_loader(
        s3["url"],
        3,
        seed=1,
        image_hw=(8, 8),
        cache_dir=str(cache),
        cache_limit_bytes=int(max(sizes) * 1.5),
        max_open_shards=1,
    )
    got = [s for b in ld for s in b["sample_id"]]
    assert sorted(got) == sorted(all_sample_ids(ROWS))
    cached = list((cache / "objects").glob("*.arrow"))
    assert sum(p.stat().st_size for p in cached) <= max(sizes) * 1.5 and len(cached) == 1
    with warnings.catch_warnings(record=True) as caught:  # smaller than one shard: works, warns
        warnings.simplefilter("always")
        tiny = make_loader(s3["url"], 5, image_hw=(8, 8), cache_dir=str(tmp_path / "tiny"), cache_limit_bytes=10)
        assert len([s for b in tiny for s in b["sample_id"]]) == 15
    assert any("smaller than one shard" in str(w.message) for w in caught)


def test_s3_corrupt_object_and_missing_manifest(s3, tmp_path):
    client = s3["client"]
    client.create_bucket(Bucket="bad")
    for f in sorted(s3["local"].iterdir()):
        data = bytearray(f.read_bytes())
        if f.name == "shard-00002.arrow":
            data[len(data) // 3] ^= 0x55
        client.put_object(Bucket="bad", Key=f"ds/{f.name}", Body=bytes(data))
    url = f"s3://bad/ds?{s3['opts']}"
    with pytest.raises(SeeUError, match=r"s3://bad/ds/shard-00002\.arrow: sha256"):
        list(make_loader(url, 2, image_hw=(8, 8), cache_dir=str(tmp_path / "c")))
    with pytest.raises(SeeUError, match=r"s3://data/nothing.*no manifest"):
        make_loader(f"s3://data/nothing?{s3['opts']}", 2, cache_dir=str(tmp_path / "c"))
