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
    "seeu.overlap": "overlap",
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


@cache
def arrow_schema(name: str, major: int = 1) -> pa.Schema:
    """pyarrow schema of table `name`, with the schema name and version in its metadata; optional
    columns are the nullable fields (read once: every posed scene written asks for it)."""
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


# The JSON-schema keywords `json_check` knows (the manifest schema's); annotations are ignored.
_CHECKED = {"type", "const", "pattern", "minimum", "required", "properties", "items"}
_ANNOTATIONS = {"$schema", "$id", "title", "description"}


def _is_type(value: object, kind: str) -> bool:
    if kind in ("number", "integer"):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return False
        return kind == "number" or isinstance(value, int) or value.is_integer()
    return isinstance(value, {"object": dict, "array": list, "string": str, "boolean": bool}.get(kind, type(None)))


def json_check(schema: dict):
    """A predicate `ok(doc) -> bool` that is True only when `doc` satisfies `schema`, for schemas made of
    the keywords in `_CHECKED` (None for any other schema). A JSON-schema validator descends into every
    element of an array with a new validator (~0.5 ms a scene entry: 35 s for RE10K's 67,477 scenes, on
    every manifest read and write); this walks them in plain Python. Use it as a fast path: where it
    says False, let the full validator say why."""
    if not isinstance(schema, dict) or set(schema) - _CHECKED - _ANNOTATIONS:
        return None
    if not isinstance(schema.get("type", ""), str) or not isinstance(schema.get("items", {}), dict):
        return None
    parts = {k: json_check(v) for k, v in schema.get("properties", {}).items()}
    items = json_check(schema["items"]) if "items" in schema else True
    if None in parts.values() or items is None:
        return None
    kind, required = schema.get("type"), schema.get("required", ())
    pattern = re.compile(schema["pattern"]) if "pattern" in schema else None
    has_const, const = "const" in schema, schema.get("const")

    def ok(doc: object) -> bool:
        if kind is not None and not _is_type(doc, kind):
            return False
        if has_const and not (doc == const and type(doc) is type(const)):
            return False
        if pattern is not None and isinstance(doc, str) and not pattern.search(doc):
            return False
        if "minimum" in schema and _is_type(doc, "number") and doc < schema["minimum"]:
            return False
        if isinstance(doc, dict):
            if any(k not in doc for k in required):
                return False
            if not all(check(doc[k]) for k, check in parts.items() if k in doc):
                return False
        if isinstance(doc, list) and items is not True:
            return all(items(d) for d in doc)  # type: ignore[operator]
        return True

    return ok
