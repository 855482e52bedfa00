"""Scoring fields and solvers that are not ours (``verification.scoring``,
``verification.plugins``).

Known answers: a box under an affine boundary displacement has the affine field as its exact
solution (the P1 reference reproduces it to round-off), so a field = affine + a known perturbation
must score exactly that perturbation, whatever the field's mesh or vertex order. The norms of a
linear perturbation delta = A x over the box [0, L]^3 are integrated by hand here.
"""
import json

import meshio
import numpy as np
import pytest

from tissue_reference.errors import CaseError
from tissue_reference.meshes.builders import box
from tissue_reference.model.case import Boundary, Case, Material, Probe, load_case
from tissue_reference.verification.plugins import PluginError
from tissue_reference.verification.scoring import Field
from tissue_reference.verification.verify import tolerance_failures, verify

L = 10.0
MAT = Material("neo-hookean", E=6.0, nu=0.45)
G = np.array([[0.0, 0.08, 0.0], [0.0, 0.0, 0.0], [0.02, 0.0, -0.03]])  # displacement gradient
FACES = ["xmin", "xmax", "ymin", "ymax", "zmin", "zmax"]


def affine_case(mesh):
    return Case(mesh=mesh, material=MAT, name="affine-box",
                boundaries=tuple(Boundary(f, "affine", gradient=G.tolist(), offset=[0, 0, 0])
                                 for f in FACES),
                probes=(Probe("P", (3.0, 4.0, 5.0)), Probe("Q", (7.5, 2.5, 6.0))))


@pytest.fixture(scope="module")
def case():
    return affine_case(box(5.0))


@pytest.fixture(scope="module")
def other_mesh():
    return box(3.0)   # another gmsh mesh of the same box


def exact(x):
    return x @ G.T


def score(case, field, **kw):
    return verify(case, {}, solvers=(), field=field, **kw)["solvers"]["field"]


def write_vtu(path, points, cells, u, name="displacement"):
    meshio.write(str(path), meshio.Mesh(points, [("tetra", cells)], point_data={name: u}))


def test_the_exact_field_scores_zero_in_any_vertex_order(case, tmp_path):
    X, cells = case.mesh.points, case.mesh.cells
    e = score(case, exact(X))                                   # array, the case's order
    assert e["max_vertex_error_mm"] < 1e-9 and e["l2_error_mm"] < 1e-9
    perm = np.random.default_rng(1).permutation(len(X))
    inv = np.argsort(perm)
    write_vtu(tmp_path / "shuffled.vtu", X[perm], inv[cells], exact(X)[perm])
    e = score(case, tmp_path / "shuffled.vtu")
    assert e["matched"] == "case mesh vertices by coordinates"
    assert e["max_vertex_error_mm"] < 1e-9
    assert max(e["probe_error_mm"].values()) < 1e-9


A_PERT = np.array([[0.01, -0.02, 0.0], [0.03, 0.0, 0.01], [0.0, 0.02, -0.01]])
C_PERT = np.array([0.1, -0.2, 0.05])


def box_norms(A, c):
    """Volume L2 (mm), H1 seminorm and small-strain energy norm (sqrt(uJ), MAT's E and nu) of
    the linear field delta = A x + c over the box [0, L]^3, integrated by hand."""
    # int_box x_i x_j dV / V = L^2/4 + delta_ij L^2/12;  int x_i dV / V = L/2
    M = np.full((3, 3), L * L / 4) + np.eye(3) * L * L / 12
    l2_sq = np.einsum("ki,kj,ij->", A, A, M) + 2 * c @ A @ np.full(3, L / 2) + c @ c
    mu, lam = MAT.E / (2 * (1 + MAT.nu)), MAT.E * MAT.nu / ((1 + MAT.nu) * (1 - 2 * MAT.nu))
    eps = (A + A.T) / 2
    energy = np.sqrt(L ** 3 * (2 * mu * np.sum(eps * eps) + lam * np.trace(eps) ** 2))
    return np.sqrt(l2_sq), np.linalg.norm(A), energy


def test_a_linear_perturbation_scores_its_closed_form_norms(case, tmp_path):
    A, c = A_PERT, C_PERT
    X = case.mesh.points
    perm = np.random.default_rng(2).permutation(len(X))
    write_vtu(tmp_path / "pert.vtu", X[perm], np.argsort(perm)[case.mesh.cells],
              (exact(X) + X @ A.T + c)[perm])
    e = score(case, tmp_path / "pert.vtu")
    l2, h1, energy = box_norms(A, c)
    assert e["l2_error_mm"] == pytest.approx(l2, rel=1e-9)
    assert e["h1_seminorm_error"] == pytest.approx(h1, rel=1e-9)
    assert e["energy_norm_error_sqrt_uJ"] == pytest.approx(energy, rel=1e-9)
    d = np.linalg.norm(X @ A.T + c, axis=1)
    assert e["max_vertex_error_mm"] == pytest.approx(d.max(), rel=1e-9)
    assert e["rms_vertex_error_mm"] == pytest.approx(np.sqrt(np.mean(d ** 2)), rel=1e-9)
    for p in case.probes:
        want = np.linalg.norm(A @ np.asarray(p.point) + c)
        assert e["probe_error_mm"][p.name] == pytest.approx(want, rel=1e-9)


def test_a_zero_field_scores_the_whole_displacement(case):
    e = score(case, np.zeros((case.mesh.n_vertices, 3)))
    d = np.linalg.norm(exact(case.mesh.points), axis=1)
    assert e["max_vertex_error_mm"] == pytest.approx(d.max(), rel=1e-9)
    assert e["l2_relative_error"] == pytest.approx(1.0, rel=1e-9)


def test_a_field_on_another_mesh_is_scored_at_its_own_points(case, other_mesh, tmp_path):
    Y, cells = other_mesh.points, other_mesh.cells
    assert len(Y) != case.mesh.n_vertices
    write_vtu(tmp_path / "other.vtu", Y, cells, exact(Y))
    e = score(case, tmp_path / "other.vtu")
    assert e["matched"] == "interpolated reference" and e["n_points"] == len(Y)
    assert e["reference_interpolation"] == "P1 (exact)"
    assert e["max_vertex_error_mm"] < 1e-9 and e["l2_error_mm"] < 1e-9
    # a quadratic bump the reference (affine) does not have: the score is the bump at the points
    bump = np.zeros_like(Y)
    bump[:, 2] = 1e-3 * Y[:, 0] * (L - Y[:, 0])
    write_vtu(tmp_path / "bump.vtu", Y, cells, exact(Y) + bump)
    e = score(case, tmp_path / "bump.vtu")
    assert e["max_vertex_error_mm"] == pytest.approx(np.abs(bump[:, 2]).max(), rel=1e-9)
    # a linear tilt: the field's own interpolant at the probes is exact, so is the probe error
    tilt = np.zeros_like(Y)
    tilt[:, 2] = 1e-3 * (Y[:, 0] + 2 * Y[:, 1])
    write_vtu(tmp_path / "tilt.vtu", Y, cells, exact(Y) + tilt)
    e = score(case, tmp_path / "tilt.vtu")
    for p in case.probes:
        x = np.asarray(p.point)
        assert e["probe_error_mm"][p.name] == pytest.approx(1e-3 * (x[0] + 2 * x[1]), rel=1e-9)


def test_points_outside_the_body_are_named_or_left_out(case, other_mesh):
    Y = other_mesh.points.copy()
    Y[7] = [25.0, 5.0, 5.0]
    f = Field(u=exact(Y), points=Y, source="moved.vtu")
    with pytest.raises(CaseError, match=r"moved.vtu: 1 point\(s\) lie outside.*point 7 at \[25"
                       r".*--skip-outside"):
        score(case, f)
    e = score(case, f, outside="skip")
    assert e["outside_points"] == [7] and e["max_vertex_error_mm"] < 1e-9
    assert "l2_error_mm" not in e and "volume norms" in e["note"]


@pytest.mark.parametrize("content,match", [
    (np.zeros((5, 3)), r"one row per vertex"),
    (np.zeros(4), r"expected an \(n, 3\) displacement array, got shape \(4,\)"),
    ("nan", r"not finite at 1 point\(s\), first at row 3"),
])
def test_bad_field_files_are_named(case, tmp_path, content, match):
    p = tmp_path / "bad.npy"
    if isinstance(content, str):
        content = np.zeros((case.mesh.n_vertices, 3))
        content[3, 1] = np.nan
    np.save(p, content)
    with pytest.raises(CaseError, match=match):
        score(case, p)


def test_field_file_errors_name_the_file(case, tmp_path):
    with pytest.raises(CaseError, match="nope.vtu: no such field file"):
        score(case, tmp_path / "nope.vtu")
    X = case.mesh.points
    meshio.write(str(tmp_path / "two.vtu"), meshio.Mesh(X, [("tetra", case.mesh.cells)],
                 point_data={"a": X, "b": X}))
    with pytest.raises(CaseError, match=r"two.vtu: cannot tell which point field.*\['a', 'b'\]"):
        score(case, tmp_path / "two.vtu")
    assert score(case, tmp_path / "two.vtu", field_name="a")["max_vertex_error_mm"] > 0


# --------------------------------------------------------------------------- plugins
def test_an_independent_linear_solver_matches_the_linear_reference():
    """The example plugin (numpy/scipy P1 linear elasticity) against the dolfinx linear-elastic
    reference of the same mesh: two independent implementations of one discretization."""
    from examples.linear_plugin import solve

    ph = load_case("meshes/cases/phantom.toml", size=14.0).with_material(model="linear-elastic")
    out = verify(ph, {"A1": 2.0, "A3": 1.0}, solvers=[solve], degree=1,
                 formulation="displacement")
    e = out["solvers"]["examples.linear_plugin:solve"]
    assert e["plugin"] and e["max_vertex_error_mm"] < 1e-8
    assert set(e["probe_error_mm"]) == {p.name for p in ph.probes}


def test_plugins_by_import_path_and_entry_point(case, monkeypatch):
    import tissue_reference.verification.plugins as tp

    out = verify(case, {}, solvers=["examples.linear_plugin:solve"], degree=1)
    assert "examples.linear_plugin:solve" in out["solvers"]

    class EP:
        value = "examples.linear_plugin:solve"

        def load(self):
            from examples.linear_plugin import solve
            return solve

    monkeypatch.setattr(tp, "entry_point_solvers", lambda: {"linear-example": EP()})
    out = verify(case, {}, solvers=["linear-example"])
    assert out["solvers"]["linear-example"]["max_vertex_error_mm"] < 1e-6


def test_a_plugin_that_fails_is_named(case):
    def raises(case, pushes):
        raise RuntimeError("diverged at iteration 3")

    def wrong_shape(case, pushes):
        return np.zeros((3, 3))

    with pytest.raises(PluginError, match="raises.*RuntimeError: diverged at iteration 3"):
        verify(case, {}, solvers=[raises])
    with pytest.raises(PluginError, match=r"wrong_shape.*shape \(3, 3\); expected \("):
        verify(case, {}, solvers=[wrong_shape])
    with pytest.raises(CaseError, match="no_such_module"):
        verify(case, {}, solvers=["no_such_module:solve"])
    with pytest.raises(CaseError, match="unknown solver 'nope'"):
        verify(case, {}, solvers=["nope"])


def test_a_plugin_may_return_a_result_object(case):
    class Out:
        def __init__(self, u):
            self.u, self.iterations, self.converged = u, 7, True
            self.history = {"max_step_mm": [1.0, 0.1, 0.01]}

    out = verify(case, {}, solvers=[lambda c, p: Out(exact(c.mesh.points))])
    e = next(iter(out["solvers"].values()))
    assert e["iterations"] == 7 and e["converged"] is True and e["max_vertex_error_mm"] < 1e-9


PLUGIN_FILE = """
import numpy as np

G = np.array({G})
A = np.array({A})
C = np.array({c})


def zero(case, pushes, **options):
    return np.zeros((case.mesh.n_vertices, 3))


def perturbed(case, pushes, **options):
    return case.mesh.points @ (G + A).T + C
"""


def test_a_plugin_file_gets_the_volume_norms_of_its_vertex_field(case, tmp_path):
    """A solver named by its file (path/to/file.py:function) is scored with the L2, H1 and
    energy-norm errors of the P1 interpolant of its vertex field, as that field given as
    --field is: the zero field misses the whole affine answer G x (its error is the
    reference's own norm), the perturbed one misses A x + c; both by hand over the box."""
    f = tmp_path / "plugins" / "my_plugin.py"
    f.parent.mkdir()
    f.write_text(PLUGIN_FILE.format(G=G.tolist(), A=A_PERT.tolist(), c=C_PERT.tolist()))
    zero, perturbed = f"{f}:zero", f"{f}:perturbed"
    out = verify(case, {}, solvers=[zero, perturbed], degree=1, formulation="displacement")
    for name, (A, c) in ((zero, (G, np.zeros(3))), (perturbed, (A_PERT, C_PERT))):
        e = out["solvers"][name]
        l2, h1, energy = box_norms(A, c)
        assert e["l2_error_mm"] == pytest.approx(l2, rel=1e-9), name
        assert e["h1_seminorm_error"] == pytest.approx(h1, rel=1e-9), name
        assert e["energy_norm_error_sqrt_uJ"] == pytest.approx(energy, rel=1e-9), name
    e = out["solvers"][zero]
    for k in ("l2_relative_error", "h1_relative_error", "energy_relative_error"):
        assert e[k] == pytest.approx(1.0, rel=1e-9), k
    as_field = score(case, np.zeros((case.mesh.n_vertices, 3)), degree=1)
    for k in ("l2_error_mm", "h1_seminorm_error", "energy_norm_error_sqrt_uJ"):
        assert e[k] == pytest.approx(as_field[k], rel=1e-12), k


# --------------------------------------------------------------------------- honest scores
def test_admm_alone_and_linear_models_are_labelled(tmp_path):
    ph = load_case("meshes/cases/phantom.toml", size=14.0)
    out = verify(ph, {"A1": 2.0}, solvers=("admm", "admm-plain", "mass-tensor"))
    plain, polished = out["solvers"]["admm-plain"], out["solvers"]["admm"]
    assert plain["options"]["polish"] is False and plain["newton_iterations"] == 0
    assert polished["newton_iterations"] >= 1
    mt = out["solvers"]["mass-tensor"]
    assert mt["model"] == "linear-elastic" and "not the case's neo-hookean" in mt["note"]
    with pytest.raises(CaseError, match=r"'admm' does not take option\(s\) \['bogus'\]"):
        verify(ph, {"A1": 2.0}, solvers=("admm",), options={"admm": {"bogus": 1}})
    with pytest.raises(CaseError, match="degree and formulation choose the reference for plugin"):
        verify(ph, {"A1": 2.0}, solvers=("admm",), degree=2)


def test_the_tolerance_verdict_is_the_librarys():
    """A candidate fails a tolerance by its max vertex error above it, or by saying it did not
    converge whatever its error; no tolerance, no verdict."""
    out = {"solvers": {"a": {"max_vertex_error_mm": 0.004, "converged": True},
                       "b": {"max_vertex_error_mm": 0.006},
                       "c": {"max_vertex_error_mm": 1e-9, "converged": False},
                       "d": {"max_vertex_error_mm": 0.01, "converged": False}}}
    unstood = ("reported converged = false; an answer its own solver does not stand behind "
               "fails --tol")
    assert tolerance_failures(out, None) == []
    assert tolerance_failures(out, 0.005) == [
        ("b", "max vertex error 0.006 mm exceeds --tol 0.005 mm"),
        ("d", "max vertex error 0.01 mm exceeds --tol 0.005 mm"),
        ("c", unstood), ("d", unstood)]
    assert [n for n, _ in tolerance_failures(out, 0.1)] == ["c", "d"]


# --------------------------------------------------------------------------- command line
def test_cli_scores_a_field_written_by_solve_as_zero(tmp_path, capsys):
    from tissue_reference.tissue.cli import main

    case = "meshes/cases/phantom.toml"
    assert main(["solve", case, "--size", "14", "--push", "A1=2", "--out",
                 str(tmp_path / "s"), "-q"]) == 0
    for f in ("displacement.vtu", "displacement.xdmf"):
        js = tmp_path / f"{f}.json"
        rc = main(["verify", case, "--size", "14", "--push", "A1=2", "--field",
                   str(tmp_path / "s" / f), "--json", str(js), "--tol", "1e-6"])
        assert rc == 0
        e = json.loads(js.read_text())["solvers"]["field"]
        assert e["max_vertex_error_mm"] < 1e-9 and list(json.loads(js.read_text())["solvers"]) \
            == ["field"]
    # the same field shifted by 0.01 mm fails --tol 0.005 (exit 1), in CSV
    u = meshio.read(tmp_path / "s" / "displacement.vtu").point_data["displacement"]
    np.savetxt(tmp_path / "u.csv", u + [0.01, 0, 0], delimiter=",", header="ux,uy,uz")
    capsys.readouterr()
    rc = main(["verify", case, "--size", "14", "--push", "A1=2", "--field",
               str(tmp_path / "u.csv"), "--tol", "0.005"])
    cap = capsys.readouterr()
    assert rc == 1 and "exceeds --tol 0.005 mm" in cap.err and "max 0.01 mm" in cap.out
    # what it prints is the library's verdict on the same scores
    js = tmp_path / "u.json"
    assert main(["verify", case, "--size", "14", "--push", "A1=2", "--field",
                 str(tmp_path / "u.csv"), "--tol", "0.005", "--json", str(js)]) == 1
    why = tolerance_failures(json.loads(js.read_text()), 0.005)
    assert [n for n, _ in why] == ["field"]
    assert [ln for ln in capsys.readouterr().err.splitlines() if "--tol" in ln] == \
        [f"tissue verify: error: {n}: {w}" for n, w in why]


def test_cli_scores_a_plugin(capsys):
    from tissue_reference.tissue.cli import main

    rc = main(["verify", "meshes/cases/phantom.toml", "--size", "14", "--push", "A1=1",
               "--solvers", "examples.linear_plugin:solve", "--degree", "1"])
    out = capsys.readouterr().out
    assert rc == 0 and "examples.linear_plugin:solve" in out and "reference neo-hookean" in out


def test_a_field_on_a_finer_mesh_of_the_curved_phantom_is_scored_and_one_outside_is_not():
    """The phantom's finer mesh puts boundary points outside the coarser mesh's flat facets but
    inside the curved body (within the facets' sag, from the mesh's second-order edge nodes):
    they are scored, the volume norms too. A point 1 mm above the body is still refused."""
    coarse = load_case("phantom", size=10.0)
    fine = load_case("phantom", size=6.0).mesh
    field = Field(u=np.zeros_like(fine.points), points=fine.points, cells=fine.cells,
                  source="fine.vtu")
    out = verify(coarse, {"A1": 1.0}, solvers=[], field=field)
    scored = out["solvers"]["field"]
    assert "outside_points" not in scored and scored["l2_error_mm"] > 0
    top = fine.points[np.argmax(fine.points[:, 2])] + np.array([0.0, 0.0, 1.0])
    above = Field(u=np.zeros((1, 3)), points=top[None], source="above.vtu")
    with pytest.raises(CaseError, match="1 point\\(s\\) lie outside the body"):
        verify(coarse, {"A1": 1.0}, solvers=[], field=above)
