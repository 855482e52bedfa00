"""The case-file schema (``case.schema.json``, JSON Schema draft 2020-12): the one description of
the TOML format, and its faults in words, one line each, naming the file and the key:

    case.toml: [material].E: expected a finite number in [1e-09, 1e+12], found true (a boolean)
    case.toml: [[boundary]][2].type: expected one of 'fixed', ..., found 'glued'

Arrays of tables are counted from 1 in file order. What the schema cannot say (numbers finite,
names unique) is checked here too; what needs the mesh is checked in ``case_file``.
"""
from __future__ import annotations

import difflib
import functools
import json
import math
import re
import sys
from pathlib import Path

__all__ = ["SCHEMA_PATH", "case_schema", "expected", "schema_errors", "show", "where"]

SCHEMA_PATH = Path(__file__).with_name("case.schema.json")


@functools.cache
def case_schema() -> dict:
    """The JSON Schema (draft 2020-12) of a case file, parsed."""
    return json.loads(SCHEMA_PATH.read_text(encoding="utf-8"))


@functools.cache
def _validator():
    from jsonschema import Draft202012Validator

    return Draft202012Validator(case_schema())


# --------------------------------------------------------------------------- schema walking
def resolve_ref(s):
    """A schema with its ``$ref`` (local, ``#/$defs/...``) merged under its own keys."""
    if isinstance(s, dict) and "$ref" in s:
        node = case_schema()
        for part in s["$ref"].removeprefix("#/").split("/"):
            node = node[part]
        return {**resolve_ref(node), **{k: v for k, v in s.items() if k != "$ref"}}
    return s


def is_table(s) -> bool:
    return isinstance(s, dict) and resolve_ref(s).get("type") == "object"


def _child(s, key, instance):
    """Schema of ``instance[key]`` under ``s``: the items of an array, or a property, taking the
    branch (if/then) that applies to ``instance``; None for a key the table does not know."""
    s = resolve_ref(s)
    if isinstance(key, int):
        return s.get("items")
    out = s.get("properties", {}).get(key)
    if out is None and isinstance(s.get("additionalProperties"), dict):
        return s["additionalProperties"]     # a table of free names (name -> value)
    if out is None:
        return None
    for branch in s.get("allOf", ()):
        if "if" in branch and isinstance(instance, dict) and _branch_validator(
                json.dumps(branch["if"])).is_valid(instance):
            out = branch["then"].get("properties", {}).get(key, out)
    return out


@functools.cache
def _branch_validator(if_schema: str):
    return _validator().evolve(schema=json.loads(if_schema))


def _walk(loc, data):
    """(schema, instance) at ``loc``; schema None where the schema has none, False where the
    table's branch forbids the key."""
    s, x = case_schema(), data
    for key in loc:
        if s is None or s is False:
            return None, None
        s = _child(s, key, x)
        try:
            x = x[key]
        except (KeyError, IndexError, TypeError):
            x = None
    return s, x


def _leaf(path, data) -> tuple:
    """The path cut at the key of a table (or at the first place that is not a table)."""
    s, x = case_schema(), data
    for i, key in enumerate(path):
        if not isinstance(s, dict) or not (is_table(s) or (
                isinstance(key, int) and is_table(resolve_ref(s).get("items")))):
            return tuple(path[:i])
        s = _child(s, key, x)
        try:
            x = x[key]
        except (KeyError, IndexError, TypeError):
            x = None
    return tuple(path)


def _key(k) -> str:
    """A key as written in TOML: bare when it can be, else quoted (control characters escaped)."""
    return k if re.fullmatch(r"[A-Za-z0-9_-]+", str(k)) else repr(k)


def where(loc) -> str:
    """``[mesh].size``, ``[[boundary]][2].type`` (arrays of tables counted from 1), ``name``."""
    out, s = "", case_schema()
    for i, key in enumerate(loc):
        r = resolve_ref(s) if s else {}
        if isinstance(key, int):
            out += f"[{key + 1}]"
            s = r.get("items")
        elif i == 0 and r.get("properties", {}).get(key) is not None:
            sub = resolve_ref(r["properties"][key])
            kind = sub.get("type")
            out += f"[[{key}]]" if kind == "array" and is_table(resolve_ref(sub).get("items")) \
                else f"[{key}]" if kind == "object" else _key(key)
            s = sub
        else:
            out += f".{_key(key)}" if out else _key(key)
            s = r.get("properties", {}).get(key)
    return out


# --------------------------------------------------------------------------- words
def _range(s) -> str:
    lo = s.get("exclusiveMinimum", s.get("minimum"))
    hi = s.get("exclusiveMaximum", s.get("maximum"))
    if lo is not None and hi is not None:
        if s.get("type") == "integer":
            return f" in {lo}..{hi}"
        return f" in {'(' if 'exclusiveMinimum' in s else '['}{lo:g}, {hi:g}" \
               f"{')' if 'exclusiveMaximum' in s else ']'}"
    if lo is not None:
        return f" {'>' if 'exclusiveMinimum' in s else '>='} {lo:g}"
    if hi is not None:
        return f" {'<' if 'exclusiveMaximum' in s else '<='} {hi:g}"
    return ""


def _count(s) -> str:
    lo, hi = s.get("minItems"), s.get("maxItems")
    if lo is not None and hi is not None:
        return f"{lo}" if lo == hi else f"{lo} or {hi}" if hi == lo + 1 else f"{lo} to {hi}"
    return f"at least {lo}" if lo else "any number of"


def expected(s) -> str:
    """What a schema asks for, in words: 'a finite number > 0', "one of 'box', ..."."""
    if s is None or s is False:
        return "nothing here"
    s = resolve_ref(s)
    if "enum" in s:
        return (repr(s["enum"][0]) if len(s["enum"]) == 1 else
                "one of " + ", ".join(repr(v) for v in s["enum"]))
    kind = s.get("type")
    if kind == "object" and not s.get("properties") and isinstance(s.get("additionalProperties"),
                                                                     dict):
        return f"a table of at least {s.get('minProperties', 0)} name = " \
               f"{expected(s['additionalProperties'])}"
    if kind == "object":
        return f"a table with keys {', '.join(s.get('properties', {}))}"
    if kind == "array":
        items = resolve_ref(s.get("items", {}))
        if is_table(items):
            return "an array of tables"
        if items.get("type") == "array":
            return f"a square matrix: {_count(s)} rows of {_count(items)} finite numbers"
        words = "finite numbers" if items.get("type") == "number" else \
            f"distinct integers{_range(items)}" if s.get("uniqueItems") else f"{items.get('type')}s"
        nonzero = "a non-zero list" if "contains" in s else "a list"
        return f"{nonzero} of {_count(s)} {words}"
    if kind == "number":
        return f"a finite number{_range(s)}"
    if kind == "integer":
        return f"an integer{_range(s)}"
    if kind == "string":
        return "a non-empty string" if s.get("minLength") else "a string"
    if kind == "boolean":
        return "true or false"
    if isinstance(kind, list):
        return " or ".join({"array": "a list", "object": "a table"}.get(k, f"a {k}") for k in kind)
    return "a value"


_KINDS = {bool: "a boolean", str: "a string", int: "an integer", float: "a number",
          list: "a list", dict: "a table"}


def show(v, limit: int = 60) -> str:
    """A value as its TOML spelling (strings quoted Python-style), cut to about ``limit`` chars."""
    if isinstance(v, bool):
        text = "true" if v else "false"
    elif isinstance(v, float):
        text = "nan" if math.isnan(v) else repr(v)
    elif isinstance(v, list):
        text = "[" + ", ".join(show(x, limit) for x in v) + "]"
    elif isinstance(v, dict):
        text = "{" + ", ".join(f"{_key(k)} = {show(x, limit)}" for k, x in v.items()) + "}"
    else:
        text = repr(v) if isinstance(v, str) else str(v)
    return text if len(text) <= limit else text[:limit - 3] + "..."


def _found(v, s) -> str:
    """``show(v)``, with its kind when the kind is what is wrong."""
    kind = _KINDS.get(type(v), f"a {type(v).__name__}")
    want = resolve_ref(s).get("type") if isinstance(s, dict) else None
    wrong_kind = want is not None and not {
        "number": isinstance(v, (int, float)) and not isinstance(v, bool),
        "integer": isinstance(v, int) and not isinstance(v, bool),
        "string": isinstance(v, str), "array": isinstance(v, list),
        "object": isinstance(v, dict)}.get(want if isinstance(want, str) else "", True)
    return f"{show(v)} ({kind})" if wrong_kind else show(v)


def _suggest(key, allowed) -> str:
    low = {k.lower(): k for k in allowed}
    close = difflib.get_close_matches(str(key).lower(), list(low), n=1)
    return f" (did you mean {low[close[0]]!r}?)" if close else ""


# --------------------------------------------------------------------------- schema errors
def _lines_of(err, data, skip_mesh: bool) -> list[tuple]:
    """(loc, text) lines of one jsonschema error."""
    path = tuple(err.absolute_path)
    v = err.validator
    if v in ("additionalProperties", "required", "oneOf", "dependentRequired") and \
            not isinstance(err.instance, dict):
        return []  # these apply to tables only; the type error reports the value
    if v == "additionalProperties":
        allowed = list(resolve_ref(err.schema).get("properties", {}))
        table = where(path) or "the top level"
        return [(path + (k,), (f"expected a key of {table} ({', '.join(allowed)}), found unknown "
                               f"key {k!r}{_suggest(k, allowed)}"))
                for k in err.instance if k not in allowed]
    if v == "required":
        out = []
        for k in err.validator_value:
            if k not in err.instance and not (skip_mesh and path == () and k == "mesh"):
                s, _ = _walk(path + (k,), data)
                out.append((path + (k,), f"expected {expected(s)}, found nothing"))
        return out
    if v == "oneOf" and all(set(b) == {"required"} for b in err.validator_value):
        keys = [b["required"][0] for b in err.validator_value]
        have = [k for k in keys if k in err.instance]
        if have:
            return [(path, f"expected {' or '.join(keys)}, not both, found "
                           + " and ".join(f"{k} = {show(err.instance[k])}" for k in have))]
        return [(path, f"expected {' or '.join(keys)}, found neither")]
    if v == "dependentRequired":
        return [(path + (k,), (f"expected {k} only together with {', '.join(deps)}, found "
                               f"{k} = {show(err.instance[k])} without it"))
                for k, deps in err.validator_value.items()
                if k in err.instance and any(d not in err.instance for d in deps)]
    if v is None:  # a key that the branch of this table forbids (False schema)
        if not is_table(_walk(path, data)[0]):
            path = path[:-1]
        parent = _walk(path, data)[1]
        bad = [k for k in parent if _walk(path + (k,), data)[0] is False]
        used = [k for k in resolve_ref(_walk(path, data)[0]).get("properties", {})
                if _walk(path + (k,), data)[0] is not False]
        return [(path + (k,), (f"expected no {k} with {_forbidding(path, data, parent, k)} "
                               f"(its keys: {', '.join(used)}), found {k} = {show(parent[k])}"))
                for k in bad]
    loc = _leaf(path, data)
    s, x = _walk(loc, data)
    if s is False:  # reported by the error of the False schema itself
        return []
    cond = _condition(loc[:-1], data, _walk(loc[:-1], data)[1], loc[-1], s) if loc else None
    where_from = f" with {cond}" if cond else ""
    return [(loc, f"expected {expected(s)}{where_from}, found {_found(x, s)}")]


def _forbidding(path, data, parent, key) -> str:
    """The condition (``type = 'fixed'``, ``tip = 'sphere'``) of the branch of the table at
    ``path`` that forbids ``key`` in ``parent``."""
    return _condition(path, data, parent, key, False) or \
        f"type = {show(parent.get('type', 'fixed'))}"


def _condition(path, data, parent, key, schema) -> str | None:
    """The condition (``tip = 'sphere'``) of the branch of the table at ``path`` that gives
    ``key`` in ``parent`` the schema ``schema`` (False: forbids it); None when no branch does."""
    if schema is None:
        return None
    for branch in resolve_ref(_walk(path, data)[0]).get("allOf", ()):
        if branch["then"].get("properties", {}).get(key) == schema and _branch_validator(
                json.dumps(branch["if"])).is_valid(parent):
            return ", ".join(f"{k} = {show(v['const'])}"
                             for k, v in branch["if"].get("properties", {}).items() if "const" in v)
    return None


def _nonfinite(x, path=()):
    """Paths of the numbers that are not finite floats (nan, inf, integers past the float range)."""
    if isinstance(x, float) and not math.isfinite(x) or \
            isinstance(x, int) and not isinstance(x, bool) and abs(x) > sys.float_info.max:
        yield path
    elif isinstance(x, dict):
        for k, y in x.items():
            yield from _nonfinite(y, path + (k,))
    elif isinstance(x, list):
        for k, y in enumerate(x):
            yield from _nonfinite(y, path + (k,))


def _order(loc):
    return tuple((0, k, "") if isinstance(k, int) else (1, 0, str(k)) for k in loc)


def schema_errors(data: dict, source: str = "case", *, need_mesh: bool = True) -> list[str]:
    """One line per fault of ``data`` (a parsed case file) against the schema, each
    ``SOURCE: [table].key: expected ..., found ...``; empty when the data is valid."""
    found: dict[tuple, str] = {}
    for err in _validator().iter_errors(data):
        for loc, text in _lines_of(err, data, not need_mesh):
            found.setdefault(loc, text)
    for path in _nonfinite(data):
        loc = _leaf(path, data)
        s, x = _walk(loc, data)
        if s is not None and s is not False:
            found.setdefault(loc, f"expected {expected(s)}, found {show(x)}")
    # names must be unique within probes and within actuators
    for key in ("probe", "actuator"):
        seen = {}
        for i, entry in enumerate(data.get(key) if isinstance(data.get(key), list) else ()):
            name = entry.get("name") if isinstance(entry, dict) else None
            if isinstance(name, str) and name in seen:
                found.setdefault((key, i, "name"), f"expected a name no other {key} has, found "
                                 f"{name!r} (also {where((key, seen[name]))})")
            elif isinstance(name, str):
                seen[name] = i
    return [f"{source}: {where(loc) + ': ' if loc else ''}{text}"
            for loc, text in sorted(found.items(), key=lambda kv: _order(kv[0]))]
