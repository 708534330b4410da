"""JSON Schemas (draft 2020-12) of the machine-readable outputs, shipped as package data.

* ``run.schema.json``: ``cip-validate run``'s ``DIR/results.json`` (and
  ``baseline``'s file), version ``"cipval_results": 1``;
* ``engines.schema.json``: ``cip-validate engines --json``, ``"cipval_engines": 1``;
* ``selftest.schema.json``: ``cip-validate selftest --json``, ``"cipval_selftest": 1``;
* ``sweep-study.schema.json`` and ``sweep-point.schema.json``: a sweep's
  ``DIR/study.json`` and ``DIR/points/*.json`` (their ``fingerprint`` names
  the study and package versions).

A field may be added without a version change; removing or changing the
meaning of one raises the version.  :func:`validate` checks a document
against a schema with the keywords these schemas use (``type``, ``const``,
``enum``, ``required``, ``properties``, ``additionalProperties``, ``items``,
``minimum``, ``$ref`` to ``#/$defs/...``); the ``jsonschema`` package, where
installed, validates them too.
"""

from __future__ import annotations

import json
from functools import cache
from importlib.resources import files
from typing import Any

__all__ = ["SCHEMAS", "SchemaError", "load_schema", "validate"]

SCHEMAS = ("run", "engines", "selftest", "sweep-study", "sweep-point")


class SchemaError(ValueError):
    """A document does not follow its schema; the message names the path."""


@cache
def load_schema(name: str) -> dict:
    """The schema called ``name`` (one of :data:`SCHEMAS`)."""
    if name not in SCHEMAS:
        raise KeyError(f"no schema {name!r}; known: {', '.join(SCHEMAS)}")
    return json.loads(files(__package__).joinpath(f"{name}.schema.json").read_text())


_TYPES = {
    "object": dict, "array": list, "string": str, "boolean": bool, "null": type(None),
    "integer": int, "number": (int, float),
}  # fmt: skip


def _is(value: Any, t: str) -> bool:
    if t in ("integer", "number") and isinstance(value, bool):
        return False
    return isinstance(value, _TYPES[t])


def validate(doc: Any, schema: dict | str, _root: dict | None = None, _path: str = "$") -> None:
    """Raise :class:`SchemaError` naming the first place ``doc`` breaks ``schema``."""
    if isinstance(schema, str):
        schema = load_schema(schema)
    root = _root or schema
    if "$ref" in schema:
        ref = schema["$ref"].removeprefix("#/$defs/")
        validate(doc, root["$defs"][ref], root, _path)
    t = schema.get("type")
    if t is not None and not any(_is(doc, x) for x in ([t] if isinstance(t, str) else t)):
        raise SchemaError(f"{_path}: expected {t}, got {type(doc).__name__}")
    if "const" in schema and doc != schema["const"]:
        raise SchemaError(f"{_path}: expected {schema['const']!r}, got {doc!r}")
    if "enum" in schema and doc not in schema["enum"]:
        raise SchemaError(f"{_path}: {doc!r} not one of {schema['enum']}")
    if "minimum" in schema and _is(doc, "number") and doc < schema["minimum"]:
        raise SchemaError(f"{_path}: {doc} < minimum {schema['minimum']}")
    if isinstance(doc, dict):
        for k in schema.get("required", []):
            if k not in doc:
                raise SchemaError(f"{_path}: missing required {k!r}")
        props = schema.get("properties", {})
        extra = schema.get("additionalProperties", True)
        for k, v in doc.items():
            if k in props:
                validate(v, props[k], root, f"{_path}.{k}")
            elif extra is False:
                raise SchemaError(f"{_path}: unexpected property {k!r}")
            elif isinstance(extra, dict):
                validate(v, extra, root, f"{_path}.{k}")
    if isinstance(doc, list) and "items" in schema:
        for i, v in enumerate(doc):
            validate(v, schema["items"], root, f"{_path}[{i}]")
