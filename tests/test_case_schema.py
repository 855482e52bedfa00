"""The case-file schema and the loader's contract: any input either loads or raises CaseError, one
line per fault naming the file and the key (``FILE: [table].key: expected ..., found ...``)."""
import json
import math
import re
import tomllib

import pytest
from case_texts import (
    BOX,
    CASES,
    EVERY_TYPE,
    INDENTER,
    MESH_FILE,
    PHANTOM,
    RECTANGLE,
    ROOT,
    load_text,
    message,
)

from tissue_reference.errors import CaseError, CaseReadError, ReadError
from tissue_reference.meshes import builders
from tissue_reference.model.case import (
    ACTUATOR_TYPES,
    BOUNDARY_TYPES,
    CONTACT_TYPES,
    MATERIAL_MODELS,
    TIP_SHAPES,
    TIP_STARTS,
    Actuator,
    load_case,
)
from tissue_reference.model.case_doc import case_file_markdown
from tissue_reference.model.case_file import PROBE_TOLERANCE
from tissue_reference.model.case_schema import SCHEMA_PATH, case_schema, schema_errors


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
    reference = p["reference"]["properties"]
    assert reference["tip_start"]["enum"] == list(TIP_STARTS)
    assert reference["measured"]["items"]["properties"]["tip_start"]["enum"] == list(TIP_STARTS)
    point = case_schema()["$defs"]["probe"]["properties"]["point"]["description"]
    assert float(re.search(r"at most ([0-9.e-]+) of", point)[1]) == PROBE_TOLERANCE


def test_schema_defaults_are_the_code_defaults():
    from tissue_reference.model.case import Boundary, Material
    from tissue_reference.model.case_parts import OGDEN_FIELDS

    material = case_schema()["properties"]["material"]["properties"]
    defaults = {k: v["default"] for k, v in material.items() if "default" in v}
    assert defaults == {k: v for k, v in vars(Material()).items() if v is not None}
    # every field described (Ogden's lists under the case file's keys mu and alpha)
    assert {OGDEN_FIELDS.get(k, k) for k in material} == set(vars(Material()))
    assert case_schema()["$defs"]["boundary"]["properties"]["type"]["default"] == \
        Boundary("r").type


def test_schema_ships_as_package_data():
    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert SCHEMA_PATH.name in pyproject["tool"]["setuptools"]["package-data"]["tissue_reference.model"]
    assert "jsonschema" in " ".join(pyproject["project"]["dependencies"])


def test_case_file_reference_is_generated_from_the_schema():
    """docs/case-file.md is tools/schema_doc.py's output; regenerate it after a schema change."""
    assert (ROOT / "docs" / "case-file.md").read_text(encoding="utf-8") == case_file_markdown()


# --------------------------------------------------------------------------- valid cases
@pytest.mark.parametrize("path", CASES, ids=[p.stem for p in CASES])
def test_every_shipped_case_validates_and_loads(path):
    assert schema_errors(tomllib.loads(path.read_text())) == []
    case = load_case(path, size=14)
    # the phantom's targets, those of its symmetric parts on the part; the shell's one
    targets = {"phantom-indenter-half": 4, "phantom-indenter-quarter": 3,
               "phantom-quarter": 3, "thick-sphere": 1}.get(path.stem, 5)
    assert case.name == path.stem and len(case.probes) == targets


def test_case_file_guide_and_test_case_examples_validate():
    guide = (ROOT / "docs" / "case-files-guide.md").read_text()
    block = re.search(r"## An example, key by key.*?```toml\n(.*?)```", guide, re.DOTALL)[1]
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
     ("FILE: [material]: expected a table with keys model, E, nu, density, volumetric, c1, c2, c3, "
      "k, mu, alpha, found 6.0 (a number)")),
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
         "volumetric, c1, c2, c3, k, mu, alpha), found unknown key 'nuu' (did you mean 'nu'?)")]


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
