"""The case-file schema and the loader's contract: any input either loads or raises CaseError, one
line per fault naming the file and the key (``FILE: [table].key: expected ..., found ...``)."""
import json
import math
import re
import tomllib
from collections import Counter
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tissue_reference.meshes import builders
from tissue_reference.meshes.case import (
    ACTUATOR_TYPES,
    BOUNDARY_TYPES,
    CONTACT_TYPES,
    MATERIAL_MODELS,
    TIP_SHAPES,
    Actuator,
    Case,
    load_case,
)
from tissue_reference.meshes.case_doc import case_file_markdown
from tissue_reference.meshes.case_file import PROBE_TOLERANCE
from tissue_reference.meshes.case_schema import SCHEMA_PATH, case_schema, schema_errors
from tissue_reference.meshes.errors import CaseError, CaseReadError, ReadError

ROOT = Path(__file__).resolve().parents[1]
CASES = sorted((ROOT / "meshes" / "cases").glob("*.toml"))
PHANTOM = (ROOT / "meshes" / "cases" / "phantom.toml").read_text()
BOX = """name = "box"
[mesh]
builtin = "box"
size = 5.0
[material]
E = 6.0
nu = 0.45
[[boundary]]
region = "zmin"
type = "fixed"
[[probe]]
name = "P"
point = [5.0, 5.0, 5.0]
"""
EVERY_TYPE = BOX.replace('type = "fixed"\n', 'type = "fixed"\n' + """
[[boundary]]
region = "zmax"
type = "displacement"
value = [0.0, 0.0, -0.5]
components = [2]
[[boundary]]
region = "xmax"
type = "affine"
gradient = [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, -0.05]]
[[boundary]]
region = "xmin"
type = "sliding"
normal = [1.0, 0.0, 0.0]
[[boundary]]
region = "ymax"
type = "traction"
value = [0.0, 0.0, -0.1]
[body]
gravity = [0.0, 0.0, -9810.0]
""")
RECTANGLE = """name = "plane"
[mesh]
builtin = "rectangle"
size = 2.5
[[boundary]]
region = "ymin"
type = "fixed"
[[boundary]]
region = "ymax"
type = "traction"
value = [0.0, -0.1]
[[probe]]
name = "P"
point = [5.0, 5.0]
[[actuator]]
name = "A1"
region = "xmax"
direction = [-1.0, 0.0]
[body]
gravity = [0.0, -9810.0]
"""
MESH_FILE = BOX.replace('builtin = "box"\nsize = 5.0', 'file = "part.msh"')
INDENTER = BOX + """[[actuator]]
name = "A1"
region = "zmax"
direction = [0.0, 0.0, -1.0]
type = "indenter"
tip = "punch"
radius = 3.0
edge_radius = 0.5
point = [5.0, 5.0, 10.0]
contact = "tied"
contact_region = ["xmax", "ymax"]
[[actuator]]
name = "A2"
region = "xmin"
direction = [1.0, 0.0, 0.0]
type = "indenter"
tip = "sphere"
radius = 2.0
[[actuator]]
name = "A3"
region = "ymin"
direction = [0.0, 1.0, 0.0]
type = "patch"
"""
# coarse stand-ins for the builtin meshes: the loader is under test, not gmsh (a fuzzed tiny size
# would make gmsh mesh for hours)
COARSE = {"phantom": 14.0, "phantom-half": 14.0, "phantom-quarter": 14.0, "phantom-3": 14.0, "box": 5.0, "rectangle": 2.5, "shell-octant": 10.0,
          "indent-block": 6.0}


@pytest.fixture(scope="module")
def coarse_builders():
    """Builtin meshes built once at a coarse size, whatever size the case asks for."""
    cache = {}

    def cached(name, real):
        def build(size, *, out=None):
            if not (size > 0 and math.isfinite(size)):
                raise CaseError(f"mesh size must be a positive length in mm, got {size!r}")
            if name not in cache:
                cache[name] = real(COARSE.get(name, 6.0))
            return cache[name]
        return build

    with pytest.MonkeyPatch.context() as mp:
        for name, real in list(builders.BUILDERS.items()):
            mp.setitem(builders.BUILDERS, name, cached(name, real))
        yield cache


def load_text(tmp_path, text, name="c.toml", **kw):
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p, load_case(p, **kw)


def message(tmp_path, text, **kw):
    p = tmp_path / "c.toml"
    p.write_text(text, encoding="utf-8")
    with pytest.raises(CaseError) as err:
        load_case(p, **kw)
    return str(err.value).replace(f"{p}: ", "FILE: ")


# --------------------------------------------------------------------------- the schema itself
def _subschemas(s, path=()):
    if isinstance(s, dict):
        yield path, s
        for k, v in s.items():
            yield from _subschemas(v, path + (k,))
    elif isinstance(s, list):
        for k, v in enumerate(s):
            yield from _subschemas(v, path + (k,))


def test_schema_is_valid_draft_2020_12_and_strict_everywhere():
    from jsonschema import Draft202012Validator

    schema = json.loads(SCHEMA_PATH.read_text())
    Draft202012Validator.check_schema(schema)
    assert schema["$schema"] == "https://json-schema.org/draft/2020-12/schema"
    for path, s in _subschemas(schema):
        if s.get("type") == "object":   # strict, or a table of free names whose values are
            assert s.get("additionalProperties") is False or (   # each checked (a load's pushes)
                not s.get("properties") and isinstance(s.get("additionalProperties"), dict)), path
        for key, prop in (s.get("properties") or {}).items():
            if isinstance(prop, dict) and path[-1:] != ("if",):
                assert prop.get("description"), (path, key)


def test_schema_enums_follow_the_code():
    p = case_schema()["properties"]
    assert p["material"]["properties"]["model"]["enum"] == list(MATERIAL_MODELS)
    assert set(p["mesh"]["properties"]["builtin"]["enum"]) == set(builders.BUILDERS)
    assert case_schema()["$defs"]["boundary"]["properties"]["type"]["enum"] == list(BOUNDARY_TYPES)
    actuator = case_schema()["$defs"]["actuator"]["properties"]
    assert (actuator["type"]["enum"], actuator["tip"]["enum"], actuator["contact"]["enum"]) == \
        (list(ACTUATOR_TYPES), list(TIP_SHAPES), list(CONTACT_TYPES))
    point = case_schema()["$defs"]["probe"]["properties"]["point"]["description"]
    assert float(re.search(r"at most ([0-9.e-]+) of", point)[1]) == PROBE_TOLERANCE


def test_schema_defaults_are_the_code_defaults():
    from tissue_reference.meshes.case import Boundary, Material

    material = case_schema()["properties"]["material"]["properties"]
    assert {k: material[k]["default"] for k in material} == vars(Material())
    assert case_schema()["$defs"]["boundary"]["properties"]["type"]["default"] == \
        Boundary("r").type


def test_schema_ships_as_package_data():
    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert SCHEMA_PATH.name in pyproject["tool"]["setuptools"]["package-data"]["tissue_reference.meshes"]
    assert "jsonschema" in " ".join(pyproject["project"]["dependencies"])


def test_case_file_reference_is_generated_from_the_schema():
    """docs/case-file.md is tools/schema_doc.py's output; regenerate it after a schema change."""
    assert (ROOT / "docs" / "case-file.md").read_text(encoding="utf-8") == case_file_markdown()


# --------------------------------------------------------------------------- valid cases
@pytest.mark.parametrize("path", CASES, ids=[p.stem for p in CASES])
def test_every_shipped_case_validates_and_loads(path):
    assert schema_errors(tomllib.loads(path.read_text())) == []
    case = load_case(path, size=14)
    # the phantom's targets, those of its symmetric parts on the part
    targets = {"phantom-indenter-half": 4, "phantom-indenter-quarter": 3,
               "phantom-quarter": 3}.get(path.stem, 5)
    assert case.name == path.stem and len(case.probes) == targets


def test_readme_and_test_case_examples_validate():
    readme = (ROOT / "README.md").read_text()
    block = re.search(r"## The Case file.*?```toml\n(.*?)```", readme, re.DOTALL)[1]
    for text in (block, BOX, EVERY_TYPE, RECTANGLE, MESH_FILE, INDENTER):
        assert schema_errors(tomllib.loads(text)) == []


def test_2d_and_mesh_file_cases_load(tmp_path, coarse_builders):
    builders.box(5.0, out=tmp_path / "part.msh")
    assert load_text(tmp_path, MESH_FILE)[1].mesh.gdim == 3
    case = load_text(tmp_path, RECTANGLE)[1]
    assert case.mesh.gdim == 2 and case.actuators[0].direction == (-1.0, 0.0)


def test_indenters_and_patches_load_with_their_defaults(tmp_path, coarse_builders):
    _, case = load_text(tmp_path, INDENTER)
    punch, sphere, patch = case.actuators
    assert (punch.type, punch.tip, punch.radius, punch.edge_radius, punch.point, punch.contact,
            punch.contact_regions) == ("indenter", "punch", 3.0, 0.5, (5.0, 5.0, 10.0), "tied",
                                       ("zmax", "xmax", "ymax"))
    assert (sphere.contact, sphere.contact_regions, sphere.edge_radius) == \
        ("frictionless", ("xmin",), None)
    assert (patch.type, patch.tip, patch.contact) == ("patch", None, None)
    actuator = case_schema()["$defs"]["actuator"]["properties"]
    assert actuator["type"]["default"] == Actuator("A", "r", (1.0, 0.0, 0.0)).type
    assert actuator["contact"]["default"] == sphere.contact


def test_every_boundary_type_loads(tmp_path, coarse_builders):
    _, case = load_text(tmp_path, EVERY_TYPE)
    assert [b.type for b in case.boundaries] == ["fixed", *BOUNDARY_TYPES[1:]]
    assert case.boundaries[1].components == (2,) and case.gravity == (0.0, 0.0, -9810.0)


def test_a_probe_just_outside_is_snapped_and_a_size_override_still_works(tmp_path,
                                                                       coarse_builders):
    _, case = load_text(tmp_path, BOX.replace("[5.0, 5.0, 5.0]", "[5.0, 5.0, 10.000001]"),
                        size=5.0)
    assert 0 < case.probe_locations[0].snap_distance < PROBE_TOLERANCE * math.sqrt(300)


# --------------------------------------------------------------------------- typical mistakes
MISTAKES = [
    ("E = true", PHANTOM.replace("E = 6.0 ", "E = true"),
     "FILE: [material].E: expected a finite number in [1e-09, 1e+12], found true (a boolean)"),
    ("unknown key", PHANTOM.replace("size = 6.0", "sise = 6.0"),
     ("FILE: [mesh].sise: expected a key of [mesh] (file, builtin, size, site_size, path_size, "
      "path_reach, rim_size, base_rim_size), found unknown key 'sise' "
      "(did you mean 'size'?)")),
    ("file and builtin", PHANTOM.replace('builtin = "phantom"',
                                         'builtin = "phantom"\nfile = "part.msh"'),
     ("FILE: [mesh]: expected file or builtin, not both, found file = 'part.msh' and "
      "builtin = 'phantom'")),
    ("string direction", PHANTOM.replace("direction = [0.0, -1.0, 0.0]", 'direction = "-y"'),
     ("FILE: [[actuator]][2].direction: expected a non-zero list of 2 or 3 finite numbers, "
      "found '-y' (a string)")),
    ("probe far outside", BOX + '[[probe]]\nname = "far"\npoint = [5.0, 5.0, 1710.0]\n',
     ("FILE: [[probe]][2].point: expected a point in the body (at most 1.7e-05 mm, or an eighth "
      "of the nearest cell, outside it), found probe 'far' at [5.0, 5.0, 1710.0], 1700 mm "
      "outside the body")),
    ("unknown boundary type", PHANTOM.replace('type = "fixed"', 'type = "glued"'),
     ("FILE: [[boundary]][1].type: expected one of 'fixed', 'displacement', 'affine', "
      "'sliding', 'traction', found 'glued'")),
    ("NaN", PHANTOM.replace("nu = 0.45", "nu = nan"),
     "FILE: [material].nu: expected a finite number in (-1, 0.5], found nan"),
    ("list as name", PHANTOM.replace('name = "phantom"', 'name = ["phantom"]'),
     "FILE: name: expected a non-empty string, found ['phantom'] (a list)"),
    ("scalar as table", "material = 6.0\n" + BOX.replace("[material]\nE = 6.0\nnu = 0.45\n", ""),
     ("FILE: [material]: expected a table with keys model, E, nu, density, volumetric, found "
      "6.0 (a number)")),
    ("table as scalar", PHANTOM.replace("E = 6.0 ", "E = {value = 6.0}"),
     ("FILE: [material].E: expected a finite number in [1e-09, 1e+12], found {value = 6.0} "
      "(a table)")),
    ("unknown region", BOX.replace('region = "zmin"', 'region = "floor"'),
     ("FILE: [[boundary]][1].region: expected a region of the mesh (tissue, xmax, xmin, ymax, "
      "ymin, zmax, zmin), found unknown region 'floor'")),
    ("duplicate probe", PHANTOM.replace('name = "T3"', 'name = "T1"'),
     ("FILE: [[probe]][3].name: expected a name no other probe has, found 'T1' "
      "(also [[probe]][1])")),
    ("key of another boundary type", BOX.replace('type = "fixed"',
                                                 'type = "fixed"\nvalue = [1.0, 0.0, 0.0]'),
     ("FILE: [[boundary]][1].value: expected no value with type = 'fixed' (its keys: region, "
      "type), found value = [1.0, 0.0, 0.0]")),
    ("vector of the wrong length", BOX.replace("[5.0, 5.0, 5.0]", "[5.0, 5.0]"),
     ("FILE: [[probe]][1].point: expected a list of 3 finite numbers (the mesh is 3D), "
      "found [5.0, 5.0]")),
    ("indenter without a tip", INDENTER.replace('tip = "sphere"\n', ""),
     "FILE: [[actuator]][2].tip: expected one of 'sphere', 'punch', found nothing"),
    ("edge radius of a sphere", INDENTER.replace("radius = 2.0", "radius = 2.0\nedge_radius = 1.0"),
     ("FILE: [[actuator]][2].edge_radius: expected no edge_radius with tip = 'sphere' (its keys: "
      "name, region, direction, type, tip, radius, point, contact, contact_region), found "
      "edge_radius = 1.0")),
    ("punch edge as wide as the punch", INDENTER.replace("edge_radius = 0.5", "edge_radius = 3.0"),
     "FILE: [[actuator]][1].edge_radius: expected a finite number < radius = 3 (mm), found 3.0"),
    ("tip of a patch", INDENTER.replace('type = "patch"', 'tip = "sphere"'),
     ("FILE: [[actuator]][3].tip: expected no tip with type = 'patch' (its keys: name, region, "
      "direction, type, idle), found tip = 'sphere'")),
    ("indenter on a cell region", INDENTER.replace('["xmax", "ymax"]', '["xmax", "tissue"]'),
     ("FILE: [[actuator]][1].contact_region: expected boundary (facet) regions of the mesh (xmax, "
      "xmin, ymax, ymin, zmax, zmin), found 'tissue'")),
    ("unknown contact", INDENTER.replace('"tied"', '"sticky"'),
     "FILE: [[actuator]][1].contact: expected one of 'frictionless', 'tied', found 'sticky'"),
    ("tied sphere", INDENTER.replace("radius = 2.0", 'radius = 2.0\ncontact = "tied"'),
     ("FILE: [[actuator]][2].contact: expected 'frictionless' with tip = 'sphere', "
      "type = 'indenter', found 'tied'")),
]


@pytest.mark.parametrize("text,expected", [m[1:] for m in MISTAKES], ids=[m[0] for m in MISTAKES])
def test_typical_mistake_gives_one_line_naming_file_and_key(tmp_path, coarse_builders, text,
                                                           expected):
    got = message(tmp_path, text)
    assert got == expected
    print(got)


def test_a_directory_is_not_a_case_file(tmp_path):
    (tmp_path / "case.toml").mkdir()
    with pytest.raises(CaseReadError) as err:
        load_case(tmp_path / "case.toml")
    assert str(err.value) == f"{tmp_path / 'case.toml'}: is a directory, expected a .toml case file"


def test_toml_syntax_error_names_file_and_line(tmp_path):
    got = message(tmp_path, PHANTOM.replace("[material]", "[material"))
    line = PHANTOM.splitlines().index("[material]") + 1
    assert re.fullmatch(rf".*c\.toml:{line}:\d+: invalid TOML: .*", got), got


def test_missing_case_file_and_missing_mesh_file_are_read_errors_and_case_errors(tmp_path):
    for text in (None, '[mesh]\nfile = "nowhere.msh"\n'):
        if text is not None:
            (tmp_path / "c.toml").write_text(text)
        with pytest.raises(CaseReadError) as err:
            load_case(tmp_path / "c.toml")
        assert isinstance(err.value, ReadError) and isinstance(err.value, CaseError)
    assert str(err.value).startswith(f"{tmp_path / 'c.toml'}: [mesh].file: ")


def test_all_faults_are_reported_one_line_each(tmp_path):
    got = message(tmp_path, PHANTOM.replace("E = 6.0 ", "E = -1.0").replace("nu = 0.45", "nuu = 3"))
    assert got.splitlines() == [
        "FILE: [material].E: expected a finite number in [1e-09, 1e+12], found -1.0",
        ("FILE: [material].nuu: expected a key of [material] (model, E, nu, density, "
         "volumetric), found unknown key 'nuu' (did you mean 'nu'?)")]


# --------------------------------------------------------------------------- fuzz
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


def test_probe_on_the_true_curved_surface_is_accepted_and_one_a_cell_outside_is_not(tmp_path):
    """The phantom's skin is meshed by facets that lie inside the dome by up to h^2 / (8 R): a
    probe on the true skin (azimuth 45 deg, between two actuators) is snapped, one 10 mm outside
    is refused."""
    import numpy as np

    on_skin = builders.PHANTOM.side_point(45.0)
    out = on_skin + 10.0 * on_skin / np.linalg.norm(on_skin)
    f = tmp_path / "c.toml"
    for point, ok in ((on_skin, True), (out, False)):
        text = PHANTOM.replace("size = 6.0 ", "size = 10.0 ").replace(
            "point = [0.0, 0.0, 15.0]", f"point = {[float(v) for v in point]}")
        f.write_text(text)
        if ok:
            loc = load_case(f).probe_locations[0]
            assert loc.snap_distance > 0  # it was outside the faceted mesh, and snapped
        else:
            with pytest.raises(CaseError, match="outside the body"):
                load_case(f)
