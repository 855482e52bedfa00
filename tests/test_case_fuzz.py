"""The case loader's contract under fuzzing: any input (mutated shipped cases: types changed,
keys deleted or inserted, nan / inf, huge and tiny numbers, lists for scalars, unicode, cut text)
either loads or raises CaseError, one line per fault naming the file."""
import json
import math
import tomllib
from collections import Counter

from case_texts import (
    BOX,
    CASES,
    EVERY_TYPE,
    INDENTER,
    MESH_FILE,
    RECTANGLE,
)
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tissue_reference.errors import CaseError, CaseReadError
from tissue_reference.meshes import builders
from tissue_reference.model.case import BOUNDARY_TYPES, MATERIAL_MODELS, Case, load_case

KEYS = ["name", "mesh", "file", "builtin", "size", "material", "model", "E", "nu", "density",
        "boundary", "region", "type", "value", "components", "gradient", "offset", "normal",
        "probe", "point", "actuator", "direction", "body", "gravity", "sise", "Nu", "e", "tip",
        "radius", "edge_radius", "contact", "contact_region"]
WORDS = ["base", "skin", "act_px", "act_a", "zmin", "tissue", "T1", "A1", "box", "rectangle",
         "phantom", "phantom-3", "fixed", "displacement", "affine", "sliding", "traction",
         "neo-hookean", "linear-elastic", "part.msh", "../x.msh", "", "indenter", "sphere",
         "punch", "tied"]
NUMBERS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, -0.0, 1.0, -1.0, 0.5, 0.49, -0.99, 1e308, -1e308, 1e-308, 5e-324,
                     1e-6, 6.0, 9810.0, 2.0 ** 63]),
    st.integers(-(2 ** 63), 2 ** 63 - 1),
    st.sampled_from([0, 1, 2, 3, -1]))
SCALARS = st.one_of(NUMBERS, st.booleans(), st.text(max_size=12), st.sampled_from(WORDS))
FINITE = st.one_of(st.floats(-60.0, 60.0), st.sampled_from([0.0, 1e-300, 1e300, -1e300, 0.49]))
PLAUSIBLE_WORDS = st.sampled_from(
    ["base", "skin", "act_px", "act_py", "act_nx", "act_ny", "act_a", "act_b", "act_c", "T1",
     "tissue", "xmin", "xmax", "ymin", "ymax", "zmin", "zmax", *BOUNDARY_TYPES, *MATERIAL_MODELS,
     *sorted(builders.BUILDERS)])
VALUES = st.recursive(SCALARS, lambda inner: st.one_of(
    st.lists(inner, max_size=4), st.dictionaries(st.sampled_from(KEYS) | st.text(max_size=6),
                                                 inner, max_size=3)), max_leaves=8)


def _paths(x, path=()):
    yield path
    if isinstance(x, dict):
        for k, v in x.items():
            yield from _paths(v, path + (k,))
    elif isinstance(x, list):
        for k, v in enumerate(x):
            yield from _paths(v, path + (k,))


def _toml_str(s: str) -> str:
    out = []
    for ch in s:
        if ch in '"\\':
            out.append("\\" + ch)
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04x}")
        else:
            out.append(ch)
    return '"' + "".join(out) + '"'


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf") if math.isinf(v) \
            else repr(v)
    if isinstance(v, int):
        return str(v)
    if isinstance(v, str):
        return _toml_str(v)
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return "{" + ", ".join(f"{_toml_str(k)} = {_toml_value(x)}" for k, x in v.items()) + "}"


def to_toml(data: dict) -> str:
    """TOML text of ``data``: tables as [key], lists of tables as [[key]], the rest inline."""
    head, tail = [], []
    for k, v in data.items():
        key = _toml_str(k)
        if isinstance(v, dict):
            tail.append(f"[{key}]\n" + "".join(f"{_toml_str(a)} = {_toml_value(b)}\n"
                                               for a, b in v.items()))
        elif isinstance(v, list) and v and all(isinstance(x, dict) for x in v):
            tail += [f"[[{key}]]\n" + "".join(f"{_toml_str(a)} = {_toml_value(b)}\n"
                                              for a, b in x.items()) for x in v]
        else:
            head.append(f"{key} = {_toml_value(v)}\n")
    return "".join(head) + "\n".join(tail)


def _plausible(old):
    if isinstance(old, list) and old and all(isinstance(r, list) for r in old):
        return st.integers(2, 3).flatmap(lambda n: st.lists(
            st.lists(FINITE, min_size=n, max_size=n), min_size=n, max_size=n))
    if isinstance(old, list):
        return st.lists(FINITE, min_size=2, max_size=3)
    if isinstance(old, str):
        return PLAUSIBLE_WORDS
    if isinstance(old, (int, float)) and not isinstance(old, bool):
        return FINITE | st.floats(-0.99, 0.49)
    return VALUES


def _mutate(draw, data):
    paths = list(_paths(data))
    path = draw(st.sampled_from(paths))
    parent = data
    for k in path[:-1]:
        parent = parent[k]
    op = draw(st.sampled_from(["replace", "replace", "delete", "insert", "wrap", "duplicate",
                               "word", "plausible", "plausible", "plausible"]))
    if not path:  # the root: insert a top-level key
        op = "insert"
    key = path[-1] if path else None
    if op == "replace":
        parent[key] = draw(VALUES)
    elif op == "word":
        parent[key] = draw(st.sampled_from(WORDS) | NUMBERS)
    elif op == "plausible":  # a value of the same kind, to reach the checks behind the schema
        parent[key] = draw(_plausible(parent[key]))
    elif op == "delete":
        del parent[key]
    elif op == "wrap":
        parent[key] = [parent[key]]
    elif op == "duplicate" and isinstance(parent, list):
        parent.append(json.loads(json.dumps(parent[key])))
    else:
        target = parent[key] if path else data
        if isinstance(target, dict):
            target[draw(st.sampled_from(KEYS) | st.text(max_size=6))] = draw(VALUES)
        elif isinstance(target, list):
            target.insert(draw(st.integers(0, len(target))), draw(VALUES))


BASES = [tomllib.loads(t) for t in [p.read_text() for p in CASES] + [BOX, EVERY_TYPE, RECTANGLE,
                                                                     MESH_FILE, INDENTER]]


def test_fuzz_any_input_loads_or_raises_a_case_error(tmp_path_factory, coarse_builders):
    """Mutated shipped cases (types changed, keys deleted or inserted, nan / inf, huge and tiny
    numbers, lists for scalars, unicode, cut text): load_case returns a Case or raises CaseError
    whose every line names the file; no other exception."""
    folder = tmp_path_factory.mktemp("fuzz")
    builders.box(5.0, out=folder / "part.msh")
    counts = Counter()

    @settings(max_examples=600, deadline=None, database=None, derandomize=True,
              suppress_health_check=list(HealthCheck))
    @given(st.data())
    def fuzz(d):
        data = json.loads(json.dumps(d.draw(st.sampled_from(BASES)), allow_nan=True))
        for _ in range(d.draw(st.integers(1, 4))):
            _mutate(d.draw, data)
        text = to_toml(data)
        if d.draw(st.integers(0, 9)) == 0:  # cut the text anywhere
            text = text[:d.draw(st.integers(0, len(text)))]
        path = folder / "case.toml"
        path.write_text(text, encoding="utf-8")
        counts["tried"] += 1
        try:
            case = load_case(path)
        except CaseError as exc:
            counts["rejected"] += 1
            counts["rejected: file or TOML" if isinstance(exc, CaseReadError) else
                   "rejected: content"] += 1
            lines = [ln for ln in str(exc).splitlines() if not ln.startswith("... and")]
            assert lines and all(ln.startswith(str(path)) for ln in lines), str(exc)
        else:
            assert isinstance(case, Case)
            counts["loaded"] += 1

    fuzz()
    print(f"\ncase-file fuzz: {counts['tried']} tried, {counts['rejected']} rejected "
          f"({counts['rejected: file or TOML']} unreadable TOML or mesh file, "
          f"{counts['rejected: content']} content), {counts['loaded']} loaded; "
          "no other exception type")
    assert counts["tried"] == counts["rejected"] + counts["loaded"] > 0
