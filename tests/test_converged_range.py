"""Loads past the range in which answers are known to converge under refinement: a glued patch
pushed deeper than one patch radius (its rim is singular), a rigid tip deeper than 2.5 of its
radii. There the reference states that no mesh-converged answer is known, whatever the mesh, so
an error estimate is printed as the difference it is and not as an error bar, and the adaptive
loop refuses to certify an accuracy. Units: mm."""
import json
import math

import numpy as np
import pytest

import tissue_reference.fem_reference as fr
from tissue_reference.errors import CaseError
from tissue_reference.fem_reference.adapt import solve_to_accuracy
from tissue_reference.meshes.mesh import MeshData
from tissue_reference.model.case import RIM_J_WARN, Actuator, Case, load_case
from tissue_reference.model.case_variants import GLUED_CONVERGED_RADII, patch_radius
from tissue_reference.tissue.cli import main

CASE = "meshes/cases/phantom.toml"


def _disc(radius: float, arc: float, n: int = 12) -> MeshData:
    """A fan of triangles over a disc (arc = 2 pi) or half disc (arc = pi) in z = 0, with one
    tetrahedron per triangle up to an apex: the region "disc"."""
    k = n if arc == 2 * math.pi else n + 1
    t = np.arange(k) * arc / n
    ring = np.column_stack([radius * np.cos(t), radius * np.sin(t), np.zeros(k)])
    pts = np.vstack([[0.0, 0.0, 0.0], ring, [0.0, 0.0, radius]])
    apex = len(pts) - 1
    tri = [(0, 1 + i, 1 + (i + 1) % k) for i in range(n)]
    cells = np.array([(*f, apex) for f in tri])
    return MeshData(pts, cells, facet_regions={"disc": np.array(tri)})


@pytest.mark.parametrize("arc", [2 * math.pi, math.pi], ids=["disc", "half disc"])
def test_patch_radius_is_the_discs_also_when_a_mirror_plane_halves_it(arc):
    assert patch_radius(_disc(5.0, arc), "disc") == pytest.approx(5.0, rel=1e-12)


@pytest.fixture(scope="module")
def coarse():
    return load_case(CASE, size=14.0)


def test_the_range_is_decided_by_the_push_and_the_patch_not_by_the_mesh(coarse):
    r = patch_radius(coarse.mesh, coarse.actuator("A1").region)
    assert 4.5 < r < 6.0                                  # the phantom's 10 mm discs
    inside = GLUED_CONVERGED_RADII * r * 0.99
    assert coarse.with_pushes({"A1": inside}).glued_unconverged() == {}
    r2 = patch_radius(coarse.mesh, coarse.actuator("A2").region)   # each patch by its own
    deep = coarse.with_pushes({"A1": 10.0, "A2": 0.99 * r2}).glued_unconverged()
    assert list(deep) == ["A1"] and "no mesh-converged answer" in deep["A1"]
    linear = coarse.with_material(model="linear-elastic").with_pushes({"A1": 10.0})
    assert linear.glued_unconverged() == {}              # a linear answer scales with its push


def test_a_coarse_mesh_that_hides_the_rim_still_says_there_is_no_error_bar(coarse):
    """At 10 mm the coarse mesh keeps every rim cell above the J warning, so the rim check alone
    would say nothing; the push says it."""
    res = fr.solve(coarse, pushes={"A1": 10.0})
    assert res.converged and res.min_J > RIM_J_WARN
    why = res.no_converged_value
    assert len(why) == 1 and "'A1'" in why[0]
    assert any("no mesh-converged answer" in w for w in res.warnings)
    near = fr.solve(coarse, pushes={"A1": 2.0})
    assert not near.no_converged_value and near.warnings == ()


def test_the_command_line_prints_a_difference_not_an_error_bar(tmp_path, capsys):
    out = tmp_path / "deep.json"
    # an answer past the range where answers converge: written, and exit status 1
    assert main(["solve", CASE, "--size", "14", "--push", "A1=10", "--estimate", "-q",
                 "--json", str(out)]) == 1
    assert out.is_file()
    text = capsys.readouterr()
    probes = [ln for ln in text.out.splitlines() if ln.strip().startswith("probe ")]
    assert probes and all("no error bar" in ln and "+-" not in ln for ln in probes)
    assert "refining will not settle it" in text.err and "--accuracy 0.01" not in text.err
    assert main(["solve", CASE, "--size", "14", "--push", "A1=2", "--estimate", "-q"]) == 0
    probes = [ln for ln in capsys.readouterr().out.splitlines()
              if ln.strip().startswith("probe ")]
    assert probes and all("+-" in ln and "no error bar" not in ln for ln in probes)


def test_the_adaptive_loop_refuses_to_certify_such_a_load(coarse):
    with pytest.raises(CaseError, match="'A1' pushed 10 mm"):
        solve_to_accuracy(coarse, {"A1": 10.0}, accuracy=0.01, progress=False)
    tip = Actuator("I", coarse.actuator("A1").region, (-1.0, 0.0, 0.0), type="indenter",
                   tip="sphere", radius=2.0)
    case = Case(coarse.mesh, coarse.material, boundaries=coarse.boundaries, actuators=[tip],
                probes=coarse.probes)
    with pytest.raises(CaseError, match="'I' pushed 6 mm, more than 2.5"):
        solve_to_accuracy(case, {"I": 6.0}, accuracy=0.01, progress=False)


STRIP = """
name = "strip"
[mesh]
builtin = "rectangle"
size = 2.5
[material]
model = "neo-hookean"
E = 6.0
nu = 0.3
[[boundary]]
region = "xmin"
type = "fixed"
[[actuator]]
name = "P"
region = "xmax"
direction = [-1.0, 0.0]
[[probe]]
name = "M"
point = [5.0, 5.0]
"""


@pytest.mark.parametrize("push,limited", [(4.0, False), (5.5, True)])
def test_a_refinement_study_extrapolates_nothing_past_the_range(tmp_path, capsys, push, limited):
    """The square's pushed side (10 mm: radius 5 mm) at 4 mm keeps the study's verdicts; at
    5.5 mm, past one radius, every quantity is reported without extrapolation or band."""
    case = tmp_path / "strip.toml"
    case.write_text(STRIP)
    out = tmp_path / "c.json"
    assert main(["converge", str(case), "--levels", "3", "--push", f"P={push}", "-q",
                 "--json", str(out)]) == 0
    text = capsys.readouterr().out
    st = json.loads(out.read_text())["studies"][0]
    qs = [c for g in ("probes", "reactions") for v in st[g].values()
          for c in v["components"].values()]
    assert ("NO CONVERGED VALUE" in text) == limited == ("no_converged_value" in st)
    if limited:
        assert all(q["gci_rel"] is None and q["extrapolated_" + ("mm" if "extrapolated_mm" in q
                                                                   else "mN")] is None
                   and not q["asymptotic"] for q in qs)
    else:
        assert any(q["gci_rel"] is not None for q in qs)


def test_verifying_a_field_at_such_a_load_says_the_reference_is_no_converged_answer(coarse):
    from tissue_reference.verification.verify import verify

    zero = np.zeros_like(coarse.mesh.points)
    deep = verify(coarse, {"A1": 10.0}, solvers=(), field=zero)
    assert "'A1'" in deep["reference"]["no_converged_value"][0]
    near = verify(coarse, {"A1": 2.0}, solvers=(), field=zero)
    assert "no_converged_value" not in near["reference"]


def test_verify_at_such_a_load_exits_1_and_within_it_0(tmp_path, capsys):
    """Scores against a reference with no converged answer behind it: exit status 1."""
    plugin = tmp_path / "zero.py"
    plugin.write_text("import numpy as np\n\n\ndef solve(case, pushes, **options):\n"
                      "    return np.zeros((case.mesh.n_vertices, case.mesh.gdim))\n")
    args = ["verify", CASE, "--size", "14", "--solvers", f"{plugin}:solve", "-q"]
    assert main(args + ["--push", "A1=10"]) == 1
    assert "not with a converged answer" in capsys.readouterr().err
    assert main(args + ["--push", "A1=2"]) == 0


def test_the_rim_warning_reads_a_degree_2_fields_own_J(monkeypatch):
    """A P2 rim cell can fold between its vertices: the warning reads the field's J, not the
    straight cell's through the vertex displacements. At A1 = 4 mm on the coarse phantom the
    field's smallest rim J (0.46) is below the vertex one (0.62); with the threshold set between
    them, only a warning that reads the field fires."""
    import tissue_reference.model.case_variants as variants
    from tissue_reference.meshes.mesh import cell_jacobians

    c = load_case(CASE, size=14.0)
    monkeypatch.setattr(variants, "RIM_J_WARN", 0.55)
    r = fr.solve(c, pushes={"A1": 4.0}, degree=2)
    rim = np.isin(c.mesh.cells, c.mesh.region_vertices(c.actuator("A1").region)).any(axis=1)
    assert cell_jacobians(c.mesh.points, c.mesh.cells, r.u)[rim].min() > 0.55
    lines = [w for w in r.warnings if "'A1'" in w]
    assert len(lines) == 1 and "compressed to J = 0.4" in lines[0]
    assert r.valid is True


@pytest.mark.parametrize("name", ["admm", "mass-tensor"])
def test_the_fast_solvers_say_a_glued_patch_is_past_its_radius_themselves(coarse, name):
    """The fast solvers put the glued-patch warning in their own answer, as the reference does:
    A1 pushed 10 mm (1.9 of its radius) is past the range, 2 mm is inside it, and a
    linear-elastic tissue, whose answer scales with the push, has no such range."""
    from tissue_reference.solvers.registry import solver

    deep = solver(name).solve(coarse, pushes={"A1": 10.0})
    assert len(deep.warnings) == 1
    assert deep.warnings[0].startswith("glued patch 'A1' pushed 10 mm")
    assert "no mesh-converged answer" in deep.warnings[0]
    assert solver(name).solve(coarse, pushes={"A1": 2.0}).warnings == ()
    linear = coarse.with_material(model="linear-elastic")
    assert solver(name).solve(linear, pushes={"A1": 10.0}).warnings == ()


def test_the_command_line_prints_the_fast_solvers_own_warning(coarse, tmp_path, capsys):
    from tissue_reference.solvers.registry import solver

    res = solver("mass-tensor").solve(coarse, pushes={"A1": 10.0})
    out = tmp_path / "mt.json"
    assert main(["solve", CASE, "--size", "14", "--solver", "mass-tensor", "--push", "A1=10",
                 "-q", "--json", str(out)]) == 1
    err = capsys.readouterr().err
    assert [ln for ln in err.splitlines() if ln.startswith("tissue solve: warning: ")] == \
        [f"tissue solve: warning: {w}" for w in res.warnings]
    assert json.loads(out.read_text())["warnings"] == list(res.warnings)
