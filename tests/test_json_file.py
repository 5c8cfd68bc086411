"""seeu_data/store/json_file.py: the bounded JSON reader (depth and size limits, one SeeUError line)."""

from __future__ import annotations

import json

import pytest

from seeu_data.errors import SeeUError
from seeu_data.store import json_file
from seeu_data.store.json_file import MAX_JSON_DEPTH, parse_json, read_json
from seeu_model.training.config import read_config_file


def _nested(depth: int) -> str:
    return "[" * depth + "]" * depth


def test_depth_at_the_limit_parses_one_more_is_refused():
    assert parse_json(_nested(MAX_JSON_DEPTH)) is not None
    with pytest.raises(SeeUError, match=f"nests deeper than {MAX_JSON_DEPTH} levels"):
        parse_json(_nested(MAX_JSON_DEPTH + 1))
    obj = '{"a": ' * (MAX_JSON_DEPTH + 1) + "1" + "}" * (MAX_JSON_DEPTH + 1)
    with pytest.raises(SeeUError, match="nests deeper"):
        parse_json(obj)


def test_recursion_depth_input_is_one_line_not_recursion_error():
    with pytest.raises(SeeUError, match="nests deeper") as err:
        parse_json("[" * 100_000, "manifest", "m.json")
    assert str(err.value).startswith("m.json: manifest")


def test_size_bound(tmp_path, monkeypatch):
    path = tmp_path / "big.json"
    path.write_text(json.dumps({"k": "x" * 200}))
    assert read_json(path)["k"] == "x" * 200
    monkeypatch.setattr(json_file, "MAX_JSON_BYTES", 100)
    with pytest.raises(SeeUError, match="over the 100 bytes"):
        read_json(path, "cameras file")
    with pytest.raises(SeeUError, match="over the 100 bytes"):
        parse_json(path.read_text())


def test_yaml_config_is_bounded_too(tmp_path):
    pytest.importorskip("yaml")
    ok = tmp_path / "ok.yaml"
    ok.write_text("data:\n  batch_size: 2\n")
    assert read_config_file(ok) == {"data": {"batch_size": 2}}
    deep = tmp_path / "deep.yaml"
    deep.write_text("a: " + _nested(MAX_JSON_DEPTH + 1) + "\n")
    with pytest.raises(SeeUError, match="nests deeper"):
        read_config_file(deep)
