"""The JSON Schemas (draft 2020-12) of the JSON files the ``tissue`` command line writes.

One schema per output, ``tissue/schemas/<name>.schema.json`` (docs/outputs.md describes each):
solve, verify, suite, converge, jacobian, mpc, table1 (``table1.json``), table1_scenarios
(``table1_scenarios.json`` of ``table1 --scenarios``), manipulability
(``manipulability_<case>.json``), dynamics, implant and demo (``summary.json``). The parts they
share (material, probes, discretization, a solve result, ...) are ``common.schema.json``,
referred to by its ``$id`` (``urn:tissue-reference:output:common``); ``validate`` resolves it,
and an output's ``$id`` (``urn:tissue-reference:output:verify``) in another's schema.

    import json
    from tissue_reference.tissue.output_schema import validate

    validate("solve", json.loads(open("result.json").read()))   # OutputSchemaError if not
"""
from __future__ import annotations

import functools
import json
import re
from pathlib import Path

__all__ = ["COMMON", "SCHEMA_DIR", "OutputSchemaError", "json_path", "names", "schema",
           "validate", "validate_file"]

SCHEMA_DIR = Path(__file__).with_name("schemas")
COMMON = "common"
"""The schema of the shared definitions (not an output of its own)."""


class OutputSchemaError(ValueError):
    """An output that does not match its schema. ``command``: the schema's name; ``path``: where
    the (most relevant) violation is, as a JSON path (``$`` the whole document, ``$.a['b'][0]``
    below it); ``reason``: what is wrong there; ``count``: violations in all."""

    def __init__(self, command: str, path: str, reason: str, count: int):
        self.command, self.path, self.reason, self.count = command, path, reason, count
        more = f" ({count} violations in all)" if count > 1 else ""
        super().__init__(f"{command} output does not match "
                         f"tissue/schemas/{command}.schema.json at {path}: {reason}{more}")


def names() -> list[str]:
    """The outputs that have a schema (the file names' stems, without the shared one)."""
    return sorted(p.name.removesuffix(".schema.json") for p in SCHEMA_DIR.glob("*.schema.json")
                  if p.name != f"{COMMON}.schema.json")


@functools.cache
def _load(name: str) -> dict:
    path = SCHEMA_DIR / f"{name}.schema.json"
    if not path.is_file():
        raise ValueError(f"no output schema {name!r}; schemas: {', '.join(names())}")
    return json.loads(path.read_text(encoding="utf-8"))


def schema(command: str) -> dict:
    """The JSON Schema of ``command``'s output (a fresh copy: the caller may change it)."""
    return json.loads(json.dumps(_load(command)))


@functools.cache
def _validator(command: str):
    from jsonschema import Draft202012Validator
    from referencing import Registry, Resource

    # every schema by its $id: the shared parts, and an output that holds another's (the demo
    # summary holds a verify output)
    registry = Registry().with_resources(
        (_load(n)["$id"], Resource.from_contents(_load(n))) for n in [COMMON, *names()])
    s = _load(command)
    Draft202012Validator.check_schema(s)
    return Draft202012Validator(s, registry=registry)


def validate(command: str, data) -> None:
    """Check ``data`` (an output as loaded from its JSON file) against ``command``'s schema;
    OutputSchemaError naming the path of the most relevant violation when it does not match."""
    from jsonschema.exceptions import best_match

    found = list(_validator(command).iter_errors(data))
    if not found:
        return
    err = best_match(found)
    raise OutputSchemaError(command, json_path(err.absolute_path), err.message, len(found))


def json_path(keys) -> str:
    """``$`` followed by ``.key`` for a plain name, ``['a key']`` for any other, ``[i]`` for
    a list index: the place of an entry in a JSON document."""
    out = "$"
    for k in keys:
        if isinstance(k, int):
            out += f"[{k}]"
        elif re.fullmatch(r"[A-Za-z][A-Za-z0-9_]*", k):
            out += f".{k}"
        else:
            out += "['" + k.replace("\\", "\\\\").replace("'", "\\'") + "']"
    return out


def validate_file(command: str, path) -> dict:
    """Read the JSON file ``path``, validate it as ``command``'s output and return its data."""
    data = json.loads(Path(path).read_text(encoding="utf-8"))
    validate(command, data)
    return data
