"""Answers that say when they are invalid, and inputs refused before they can produce one:

- every solver reports ``inverted_cells`` and ``min_J`` of its final state, and ``valid`` False
  with ``invalid_reason`` for inverted cells or runaway growth, keeping its own ``converged``;
- the reference's answer to a displacement-controlled problem does not depend on E's magnitude
  (its Newton tolerances scale with E), and E outside [1e-9, 1e12] kPa is refused;
- a tangled, inverted or degenerate mesh file is refused before any re-orientation; a body
  ordered left-handed throughout is re-oriented;
- the cell-count estimate of the builders is calibrated against real builds.
"""
import json
import math
from pathlib import Path

import meshio
import numpy as np
import pytest

from tissue_reference.errors import CaseError, MeshQualityError
from tissue_reference.meshes.builders import box, build, estimate_cells
from tissue_reference.meshes.io import read_msh
from tissue_reference.meshes.mesh import cell_jacobians, check_tangles, deformation_state
from tissue_reference.model.case import Boundary, Case, Material, Probe, load_case
from tissue_reference.tissue.cli import main

ROOT = Path(__file__).resolve().parents[1]
PHANTOM = ROOT / "meshes" / "cases" / "phantom.toml"


# --------------------------------------------------------------------------- J and validity
def test_cell_jacobians_are_det_F_of_an_affine_displacement():
    m = box(5.0)
    F = np.array([[1.2, 0.1, 0.0], [0.0, 0.9, 0.2], [0.05, 0.0, 1.1]])
    u = m.points @ (F - np.eye(3)).T + [1.0, -2.0, 0.5]
    np.testing.assert_allclose(cell_jacobians(m.points, m.cells, u), np.linalg.det(F), rtol=1e-12)
    st = deformation_state(m, u)
    assert st["valid"] and st["inverted_cells"] == 0 and st["invalid_reason"] is None
    assert st["min_J"] == pytest.approx(np.linalg.det(F), rel=1e-12)
    mirror = m.points @ (np.diag([-1.0, 1.0, 1.0]) - np.eye(3)).T
    st = deformation_state(m, mirror)
    assert not st["valid"] and st["inverted_cells"] == m.n_cells
    assert st["invalid_reason"].startswith(f"{m.n_cells} inverted cells (J <= 0")


def test_a_non_finite_or_runaway_state_is_invalid():
    m = box(5.0)
    u = np.zeros_like(m.points)
    u[3, 0] = np.nan
    st = deformation_state(m, u)
    assert not st["valid"] and "non-finite" in st["invalid_reason"] and st["min_J"] is None
    st = deformation_state(m, np.full_like(m.points, 200.0))      # a rigid shift of 346 mm
    assert st["inverted_cells"] == 0 and not st["valid"]
    assert "runaway displacement" in st["invalid_reason"] and "17.3 mm" in st["invalid_reason"]


@pytest.fixture(scope="module")
def phantom14():
    return load_case(PHANTOM, size=14)


def test_mass_tensor_at_a_60_mm_push_converges_but_is_not_a_valid_answer(phantom14):
    from tissue_reference.solvers import mass_tensor

    res = mass_tensor.solve(phantom14, pushes={"A1": 60.0})
    assert res.converged
    assert res.extra["inverted_cells"] > 0 and res.min_J <= 0
    assert res.valid is False and "inverted cells" in res.invalid_reason
    ok = mass_tensor.solve(phantom14, pushes={"A1": 5.0})
    assert ok.valid is True and ok.extra["inverted_cells"] == 0
    assert 0 < ok.min_J < 1


def test_the_cli_writes_an_invalid_answer_marked_and_exits_1(tmp_path, capsys):
    rc = main(["solve", str(PHANTOM), "--size", "14", "--solver", "mass-tensor", "--push",
               "A1=60", "-q", "--json", str(tmp_path / "r.json"), "--out", str(tmp_path / "f")])
    err = capsys.readouterr().err
    assert rc == 1 and "not valid" in err and "inverted cells" in err and "Traceback" not in err
    d = json.loads((tmp_path / "r.json").read_text())
    assert d["converged"] is True and d["valid"] is False and d["inverted_cells"] > 0
    vtu = meshio.read(tmp_path / "f" / "displacement.vtu")
    assert vtu.cell_data["inverted"][0].sum() == d["inverted_cells"]


TRACTION = """[mesh]
builtin = "box"
size = 5.0
[material]
model = "linear-elastic"
E = 6.0
nu = 0.45
[[boundary]]
region = "zmin"
type = "fixed"
[[boundary]]
region = "zmax"
type = "traction"
value = [0.0, 0.0, -1.0e6]
"""


@pytest.mark.parametrize("solver", ["fem", "mass-tensor"])
def test_a_huge_traction_gives_runaway_growth_reported_invalid(tmp_path, solver):
    from tissue_reference import fem_reference
    from tissue_reference.solvers import mass_tensor

    (tmp_path / "t.toml").write_text(TRACTION)
    case = load_case(tmp_path / "t.toml")
    res = (fem_reference.solve if solver == "fem" else mass_tensor.solve)(case)
    assert res.converged                                 # the linear solve itself is fine
    x = res.extra
    assert res.valid is False and x["inverted_cells"] > 0 and x["max_displacement_mm"] > 1e5
    assert "runaway displacement" in res.invalid_reason and "inverted" in res.invalid_reason
    assert json.loads(json.dumps(res.to_json_dict(case)))["valid"] is False


def test_admm_and_the_degree_2_reference_report_the_state_checks(phantom14):
    from tissue_reference import fem_reference
    from tissue_reference.solvers import admm

    a = admm.solve(phantom14, pushes={"A1": 3.0})
    assert a.valid and a.extra["inverted_cells"] == 0 and 0 < a.min_J < 1
    r = fem_reference.solve(Case(box(5.0), Material("linear-elastic"), **BOX_CASE), degree=2)
    assert r.valid and r.extra["inverted_cells"] == 0
    assert "degree-2 field's J" in r.extra["J_evaluated"]


def test_a_degree_2_field_folded_between_its_vertices_is_reported_inverted():
    # every vertex at rest, every edge node moved by c along x: the straight cells through the
    # vertices are undeformed (J = 1), but the quadratic field is u = 2c (1 - sum_i l_i^2) e_x
    # (l_i the barycentric coordinates), so F = I + e_x (x) g with g = -4c sum_i l_i grad l_i,
    # J = 1 + g_x, linear in the cell: its smallest value is at a vertex k, 1 - 4c d l_k / dx
    pytest.importorskip("dolfinx")
    from tissue_reference.fem_reference import ReferenceSolver
    from tissue_reference.fem_reference.field_jacobian import cell_min_J

    m = box(2.5)
    case = Case(m, Material("neo-hookean", E=6.0, nu=0.45), **BOX_CASE)
    s = ReferenceSolver(case, degree=2)
    c = 0.5
    nodes = np.zeros((len(s.state.node_vertex), 3))
    nodes[m.n_vertices:, 0] = c
    s.set_state(nodes, exact=True)
    P = m.points[m.cells]                                    # (cells, 4, 3)
    inv = np.linalg.inv(np.transpose(P[:, 1:] - P[:, :1], (0, 2, 1)))  # rows: grad l_1..l_3
    dldx = np.concatenate([-inv[:, :, 0].sum(axis=1, keepdims=True), inv[:, :, 0]], axis=1)
    expected = 1.0 - 4.0 * c * dldx.max(axis=1)
    got = cell_min_J(s)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-10)
    folded = int(np.count_nonzero(expected <= 0))
    assert 0 < folded < m.n_cells
    st = deformation_state(m, np.zeros_like(m.points), degree=2, cell_J=got)
    assert st["inverted_cells"] == folded and not st["valid"]
    assert deformation_state(m, np.zeros_like(m.points), degree=2)["valid"]   # P1 sees nothing


# --------------------------------------------------------------------------- E scale
BOX_CASE = {"boundaries": (Boundary("zmin", "fixed"),
                           Boundary("zmax", "displacement", value=[3.0, 1.0, -2.0])),
            "probes": (Probe("P", (5.0, 5.0, 5.0)),)}


def test_a_displacement_controlled_answer_does_not_depend_on_E():
    from tissue_reference import fem_reference

    m = box(5.0)
    u = {}
    for E in (1e-6, 6.0, 6e6):
        res = fem_reference.solve(Case(m, Material("neo-hookean", E, 0.45), **BOX_CASE))
        assert res.converged and res.valid
        u[E] = res.u
    scale = np.abs(u[6.0]).max()
    for E in (1e-6, 6e6):
        assert np.abs(u[E] - u[6.0]).max() <= 1e-8 * scale, E


@pytest.mark.parametrize("E", [1e-300, 1e-10, 2e12, 1e300])
def test_E_outside_the_physical_range_is_refused(tmp_path, E):
    with pytest.raises(CaseError, match="physical range"):
        Material(E=E)
    (tmp_path / "c.toml").write_text(f'[mesh]\nbuiltin = "box"\nsize = 5.0\n[material]\n'
                                     f'E = {E!r}\n[[boundary]]\nregion = "zmin"\n')
    with pytest.raises(CaseError, match=r"\[material\]\.E: expected a finite number in "
                                        r"\[1e-09, 1e\+12\]"):
        load_case(tmp_path / "c.toml")


# --------------------------------------------------------------------------- tangled meshes
PTS = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [0.3, 0.3, 0.6], [0.2, 0.2, -1.0],
                [0.2, 0.2, 0.2], [2, 2, 2], [2, 3, 2], [2, 2, 3]], float)


def write_msh(path, cells, points=PTS):
    """A gmsh 2.2 file of tetrahedra (physical group 'tissue') over ``points``."""
    cells = np.asarray(cells)
    ones = np.ones(len(cells), int)
    meshio.write(str(path), meshio.Mesh(points, [("tetra", cells)],
                                        cell_data={"gmsh:physical": [ones],
                                                   "gmsh:geometrical": [ones]},
                                        field_data={"tissue": np.array([1, 3])}),
                 file_format="gmsh22", binary=False)
    return path


TANGLED = [
    ("fold", [[0, 1, 2, 3], [0, 1, 2, 4]], "1 pair of neighbouring cells overlap"),
    ("inverted", [[0, 1, 2, 3], [1, 0, 2, 4]], "1 of 2 cells inverted"),
    ("duplicate", [[0, 1, 2, 3], [0, 1, 2, 3]], "pairs of neighbouring cells overlap"),
    ("vertex inside", [[0, 1, 2, 3], [6, 7, 8, 9]], "1 vertex of some cells strictly inside"),
    ("flat", [[0, 1, 2, 3], [0, 1, 2, 0]], r"1 degenerate \(zero-volume\) cell of 2"),
    ("three on a facet", [[0, 1, 2, 3], [1, 0, 2, 5], [0, 1, 2, 4]],
     "1 facet shared by more than two cells"),
]


@pytest.mark.parametrize("cells,message", [t[1:] for t in TANGLED], ids=[t[0] for t in TANGLED])
def test_a_tangled_mesh_file_is_refused_with_the_count_and_worst_cell(tmp_path, cells, message):
    f = write_msh(tmp_path / "t.msh", cells)
    with pytest.raises(MeshQualityError, match=message) as err:
        read_msh(f)
    assert "t.msh" in str(err.value) and ("cell" in str(err.value))
    assert " mm" in str(err.value)                        # where: a position in mm
    (tmp_path / "c.toml").write_text('[mesh]\nfile = "t.msh"\n[[boundary]]\nregion = "tissue"\n')
    with pytest.raises(CaseError, match=r"c\.toml: \[mesh\]\.file: .*t\.msh: "):
        load_case(tmp_path / "c.toml")


def test_the_cli_refuses_a_tangled_mesh_before_solving(tmp_path, capsys):
    write_msh(tmp_path / "t.msh", [[0, 1, 2, 3], [0, 1, 2, 4]])
    (tmp_path / "c.toml").write_text('[mesh]\nfile = "t.msh"\n[[boundary]]\nregion = "tissue"\n')
    assert main(["solve", str(tmp_path / "c.toml"), "--json", str(tmp_path / "r.json")]) == 2
    err = capsys.readouterr().err
    assert "tangled mesh" in err and "t.msh" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "r.json").exists()


def test_a_left_handed_ordering_is_reoriented_not_refused(tmp_path):
    good = [[0, 1, 2, 3], [1, 0, 2, 5]]                  # share face 012, on opposite sides
    left = [[1, 0, 2, 3], [0, 1, 2, 5]]                  # the same cells, both left-handed
    a, b = read_msh(write_msh(tmp_path / "a.msh", good)), read_msh(write_msh(tmp_path / "b.msh",
                                                                             left))
    from tissue_reference.meshes.mesh import cell_volumes

    assert np.all(cell_volumes(b.points, b.cells) > 0)
    np.testing.assert_allclose(np.sort(cell_volumes(a.points, a.cells)),
                               np.sort(cell_volumes(b.points, b.cells)))


def test_builtin_meshes_pass_the_tangle_checks_including_the_overlap_search():
    m = build("shell-octant", 5.0)
    np.testing.assert_array_equal(check_tangles(m.points, m.cells, overlap=True), m.cells)


# --------------------------------------------------------------------------- cell estimate
@pytest.mark.parametrize("name,size", [("box", 1.0), ("shell-octant", 1.5), ("rectangle", 0.5)])
def test_the_cell_estimate_is_within_fifteen_percent_of_a_real_build(name, size):
    n = build(name, size).n_cells
    assert abs(estimate_cells(name, size) - n) <= 0.15 * n, (estimate_cells(name, size), n)


def test_a_build_above_the_limit_is_refused_before_gmsh_starts(monkeypatch):
    import tissue_reference.meshes.builders_gmsh as b

    monkeypatch.setattr(b, "gmsh_session", lambda *a, **k: pytest.fail("gmsh started"))
    with pytest.raises(CaseError, match=r"about 40,726,426 cells, more than the limit of "
                                        r"2,000,000"):
        build("phantom", 0.3)
    with pytest.raises(CaseError, match="more than the limit of 10"):
        build("box", 5.0, max_cells=10)
    assert math.isclose(estimate_cells("box", 2.0), 0.55 * 6 * math.sqrt(2) * 1000 / 8,
                        rel_tol=1e-12, abs_tol=1)
