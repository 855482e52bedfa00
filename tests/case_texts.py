"""Case-file texts and fixtures shared by the case-file tests: small cases of every kind (a box,
every boundary type, a 2-D rectangle, a mesh file, an indenter) and the builtin meshes built once
at a coarse size (``COARSE``; the fixture ``coarse_builders`` is in conftest.py)."""
from pathlib import Path

import pytest

from tissue_reference.errors import CaseError
from tissue_reference.model.case import load_case

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
