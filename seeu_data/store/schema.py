"""Table schemas: read from the versioned JSON files in `schemas/` (the single source of truth).

`seeu_data/schemas` is a symbolic link to the repository's `schemas/`, so the same files are package
data in the wheel and are read through `importlib.resources` from a checkout, an editable install
or an installed wheel alike.

A schema file lists columns with a small type language:
`string | binary | int32 | int64 | float32 | float64 | list<T> | fixed_size_list<T>[n]`.

Versions are "major.minor". A file's name holds the major (`posed_frames.v1.json`); readers refuse
another major (`check_version`) and read every minor of theirs. Adding a column marked
`"optional": true` is a minor bump: such a column is nullable (null = no value) and files of an
earlier minor lack it, which readers treat as all null (`dataset_check.check_columns` lets it be
missing). Anything else (removing, renaming or retyping a column, a required new column) is a new major.
"""

from __future__ import annotations

import json
import re
from functools import cache
from importlib.resources import files
from pathlib import Path

import pyarrow as pa

from seeu_data.errors import SeeUError

SCHEMAS_DIR = files("seeu_data") / "schemas"

# Schema name -> file stem prefix in schemas/.
_SCHEMA_FILES = {
    "seeu.posed_frames": "posed_frames",
    "seeu.triples": "triples",
}
MANIFEST_VERSION = "1.0"

_PRIMITIVES = {
    "string": pa.string(),
    "binary": pa.binary(),
    "int32": pa.int32(),
    "int64": pa.int64(),
    "float32": pa.float32(),
    "float64": pa.float64(),
}


def parse_type(spec: str) -> pa.DataType:
    """Parse the schema files' type language into a pyarrow type."""
    spec = spec.strip()
    if spec in _PRIMITIVES:
        return _PRIMITIVES[spec]
    m = re.fullmatch(r"fixed_size_list<(.+)>\[(\d+)\]", spec)
    if m:
        return pa.list_(parse_type(m.group(1)), int(m.group(2)))
    m = re.fullmatch(r"list<(.+)>", spec)
    if m:
        return pa.list_(parse_type(m.group(1)))
    raise ValueError(f"unknown column type {spec!r}")


@cache
def load_schema_doc(name: str, major: int = 1) -> dict:
    """The JSON schema document of table `name` at major version `major`."""
    stem = _SCHEMA_FILES.get(name)
    if stem is None:
        raise SeeUError(f"unknown table schema {name!r} (known: {', '.join(sorted(_SCHEMA_FILES))})")
    path = SCHEMAS_DIR / f"{stem}.v{major}.json"
    if not path.is_file():
        raise SeeUError(f"schema {name} major version {major} is not supported by this seeu version", str(path))
    return json.loads(path.read_text())


def arrow_schema(name: str, major: int = 1) -> pa.Schema:
    """pyarrow schema of table `name`, with the schema name and version in its metadata; optional
    columns are the nullable fields."""
    doc = load_schema_doc(name, major)
    fields = [pa.field(c["name"], parse_type(c["type"]), nullable=bool(c.get("optional"))) for c in doc["columns"]]
    return pa.schema(fields, metadata={"seeu.schema": doc["name"], "seeu.schema_version": doc["version"]})


def schema_version(name: str) -> str:
    return load_schema_doc(name)["version"]


def check_version(name: str, version: str, where: str | Path) -> None:
    """Refuse an unknown schema or an unknown major version with a clear error."""
    if name not in _SCHEMA_FILES:
        raise SeeUError(f"unknown table schema {name!r}", where)
    try:
        major = int(str(version).split(".")[0])
    except ValueError:
        raise SeeUError(f"malformed schema version {version!r}", where) from None
    supported = int(schema_version(name).split(".")[0])
    if major != supported:
        raise SeeUError(
            f"{name} schema version {version} is not supported (this seeu reads major version {supported})", where
        )


def manifest_json_schema() -> dict:
    return json.loads((SCHEMAS_DIR / "manifest.v1.json").read_text())
