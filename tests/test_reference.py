"""Verification of the FEniCSx reference (DESIGN.md tiers 1, 2 and 4).

Closed forms are written here independently of the solver: first Piola stress of seed 000 eq. 14,
P = mu J^(-2/3) (F - I1/3 F^-T) + kappa J (J - 1) F^-T   (kPa).
"""
import numpy as np
import pytest
from scipy.optimize import brentq

import tissue_reference.fem_reference as fr
from tissue_reference.meshes.builders import box
from tissue_reference.model.case import Boundary, Case, Material

MAT = Material("neo-hookean", E=6.0, nu=0.45)
L = 10.0  # box edge, mm
AREA = L * L


def piola_nh(F, mu, kappa):
    J = np.linalg.det(F)
    Finv_T = np.linalg.inv(F).T
    I1 = np.trace(F.T @ F)
    return mu * J ** (-2 / 3) * (F - I1 / 3 * Finv_T) + kappa * J * (J - 1) * Finv_T


@pytest.fixture(scope="module")
def cube():
    return box(5.0)


def solve_affine(mesh, boundaries, degree=1):
    case = Case(mesh=mesh, material=MAT, boundaries=boundaries, name="patch")
    return case, fr.solve(case, degree=degree)


def assert_affine(case, res, F, atol=1e-9):
    expected = case.mesh.points @ (F - np.eye(3)).T
    np.testing.assert_allclose(res.u, expected, atol=atol)


def test_uniaxial_stress_with_free_lateral_faces_is_exact_with_p1(cube):
    stretch = 1.2
    bcs = [Boundary("xmin", "sliding", normal=[1, 0, 0]), Boundary("ymin", "sliding", normal=[0, 1, 0]),
           Boundary("zmin", "sliding", normal=[0, 0, 1]),
           Boundary("xmax", "displacement", value=[(stretch - 1) * L, 0, 0], components=(0,))]
    case, res = solve_affine(cube, bcs)
    # lateral stretch from zero lateral stress
    lat = brentq(lambda t: piola_nh(np.diag([stretch, t, t]), MAT.mu, MAT.kappa)[1, 1], 0.5, 1.5,
                 xtol=1e-15)
    F = np.diag([stretch, lat, lat])
    assert res.converged
    assert_affine(case, res, F)
    P = piola_nh(F, MAT.mu, MAT.kappa)
    np.testing.assert_allclose(res.reactions["xmax"][0], P[0, 0] * AREA, rtol=1e-9)
    np.testing.assert_allclose(res.reactions["xmin"][0], -P[0, 0] * AREA, rtol=1e-9)


def test_equibiaxial_stretch_is_exact_with_p1(cube):
    s = 1.1
    bcs = [Boundary("xmin", "sliding", normal=[1, 0, 0]), Boundary("ymin", "sliding", normal=[0, 1, 0]),
           Boundary("zmin", "sliding", normal=[0, 0, 1]),
           Boundary("xmax", "displacement", value=[(s - 1) * L, 0, 0], components=(0,)),
           Boundary("ymax", "displacement", value=[0, (s - 1) * L, 0], components=(1,))]
    case, res = solve_affine(cube, bcs)
    t = brentq(lambda t: piola_nh(np.diag([s, s, t]), MAT.mu, MAT.kappa)[2, 2], 0.5, 1.5, xtol=1e-15)
    F = np.diag([s, s, t])
    assert_affine(case, res, F)
    P = piola_nh(F, MAT.mu, MAT.kappa)
    np.testing.assert_allclose(res.reactions["xmax"][0], P[0, 0] * AREA, rtol=1e-9)
    np.testing.assert_allclose(res.reactions["ymax"][1], P[1, 1] * AREA, rtol=1e-9)


@pytest.mark.parametrize("name,F", [
    ("simple_shear", np.array([[1, 0.3, 0], [0, 1, 0], [0, 0, 1.0]])),
    ("dilatation", 1.05 * np.eye(3)),
])
def test_affine_deformation_reproduced_with_closed_form_stress(cube, name, F):
    G = F - np.eye(3)
    faces = ["xmin", "xmax", "ymin", "ymax", "zmin", "zmax"]
    bcs = [Boundary(f, "affine", gradient=G.tolist(), offset=[0, 0, 0]) for f in faces]
    case, res = solve_affine(cube, bcs)
    assert_affine(case, res, F)
    P = piola_nh(F, MAT.mu, MAT.kappa)
    # the boundary nodes are shared by faces: the first region listed owns them, so compare the
    # total of all reactions (zero) and the strain energy (psi * volume) instead of one face.
    total = sum(np.asarray(v) for v in res.reactions.values())
    np.testing.assert_allclose(total, 0.0, atol=1e-8 * np.abs(P).max() * AREA)
    J = np.linalg.det(F)
    psi = MAT.mu / 2 * (J ** (-2 / 3) * np.trace(F.T @ F) - 3) + MAT.kappa / 2 * (J - 1) ** 2
    np.testing.assert_allclose(res.strain_energy, psi * L ** 3, rtol=1e-10)


def test_patch_test_also_exact_with_p2(cube):
    F = np.array([[1.05, 0.1, 0], [0, 0.97, 0.02], [0.03, 0, 1.0]])
    faces = ["xmin", "xmax", "ymin", "ymax", "zmin", "zmax"]
    bcs = [Boundary(f, "affine", gradient=(F - np.eye(3)).tolist()) for f in faces]
    case, res = solve_affine(cube, bcs, degree=2)
    assert_affine(case, res, F)


def test_tangent_equals_finite_difference_of_residual(cube):
    case = Case(mesh=cube, material=MAT, boundaries=[Boundary("zmin", "fixed")], name="fd")
    solver = fr.ReferenceSolver(case, degree=1)
    rng = np.random.default_rng(0)
    u = 0.3 * rng.standard_normal((cube.n_vertices, 3))
    u[cube.region_vertices("zmin")] = 0
    K = solver.tangent(u).K
    h = 1e-6
    for j in rng.choice(3 * cube.n_vertices, size=6, replace=False):
        up = u.copy().ravel()
        um = u.copy().ravel()
        up[j] += h
        um[j] -= h
        fd = (solver.internal_forces(up.reshape(-1, 3)) - solver.internal_forces(um.reshape(-1, 3))) / (2 * h)
        col = K[:, j].toarray().ravel()
        np.testing.assert_allclose(col, fd, atol=1e-6 * np.abs(col).max())


def test_tangent_is_in_case_vertex_numbering(cube):
    """Rigid translation is in the kernel of K and K is symmetric, in the Case's node order."""
    case = Case(mesh=cube, material=MAT, boundaries=[Boundary("zmin", "fixed")], name="k")
    t = fr.tangent_stiffness(case)
    K = t.K
    assert abs(K - K.T).max() < 1e-10 * abs(K).max()
    ones_x = np.zeros(3 * cube.n_vertices)
    ones_x[0::3] = 1
    assert np.abs(K @ ones_x).max() < 1e-10 * abs(K).max()
    # a unit displacement of vertex 0 in x creates forces only at vertex 0's mesh neighbours
    nbrs = np.unique(cube.cells[np.any(cube.cells == 0, axis=1)])
    col = K[:, 0].toarray().ravel().reshape(-1, 3)
    touched = np.flatnonzero(np.abs(col).sum(axis=1) > 0)
    assert set(touched) <= set(nbrs.tolist())
    zmin = cube.region_vertices("zmin")
    assert set(t.dirichlet_dofs.tolist()) == set((3 * zmin[:, None] + np.arange(3)).ravel().tolist())


def test_linear_elasticity_is_the_small_strain_limit_of_neo_hookean():
    from tissue_reference.model.case import load_case

    case = load_case("meshes/cases/phantom.toml", size=14)
    push = {"A1": 1e-3}
    nh = fr.solve(case, pushes=push)
    le = fr.solve(case.with_material(model="linear-elastic"), pushes=push)
    scale = np.abs(le.u).max()
    assert np.abs(nh.u - le.u).max() < 1e-3 * scale


def test_quadrature_degree_4_matches_degree_6_for_p2():
    from tissue_reference.model.case import load_case

    case = load_case("meshes/cases/phantom.toml", size=16)
    a = fr.ReferenceSolver(case, degree=2).solve({"A1": 8.0})
    b = fr.ReferenceSolver(case, degree=2, quadrature_degree=6).solve({"A1": 8.0})
    for k in a.probes:
        np.testing.assert_allclose(a.probes[k], b.probes[k], atol=2e-3 * np.abs(b.probes[k]).max())


def test_warm_start_gives_the_cold_answer():
    from tissue_reference.model.case import load_case

    case = load_case("meshes/cases/phantom.toml", size=14)
    first = fr.solve(case, pushes={"A1": 10.0})
    warm = fr.solve(case, pushes={"A1": 10.5}, initial=first.u)
    cold = fr.solve(case, pushes={"A1": 10.5})
    np.testing.assert_allclose(warm.u, cold.u, atol=1e-8)
    assert warm.iterations < cold.iterations


@pytest.mark.parametrize("mode", ["iterative", "lagged"])
def test_krylov_linear_solvers_give_the_direct_answer(mode):
    from tissue_reference.model.case import load_case

    case = load_case("meshes/cases/phantom.toml", size=16)
    a = fr.ReferenceSolver(case, linear_solver="direct").solve({"A1": 12.0, "A3": 6.0})
    s = fr.ReferenceSolver(case, linear_solver=mode)
    b = s.solve({"A1": 12.0, "A3": 6.0})
    np.testing.assert_allclose(b.u, a.u, atol=1e-8)
    np.testing.assert_allclose(b.reactions["base"], a.reactions["base"], rtol=1e-8)
    if mode == "lagged":
        # the point of the mode: fewer factorizations than Newton iterations
        assert b.extra["factorizations"] < b.iterations
        assert a.extra["factorizations"] == a.iterations


def test_a_correction_that_inverts_elements_is_halved_not_fatal():
    """All four actuators pushed 15 mm in one load step: the first Newton correction inverts
    elements at the patch rims. Without the line search the step fails and is cut back; with it
    the correction is halved and the single step converges to the same answer."""
    from tissue_reference.model.case import load_case

    case = load_case("meshes/cases/phantom.toml", size=10)
    push = {"A1": 15.0, "A2": 15.0, "A3": 15.0, "A4": 15.0}
    one_step = {"max_step_mm": 100.0}
    plain = fr.ReferenceSolver(case, settings=fr.NewtonSettings(line_search=0, **one_step))
    a = plain.solve(push)
    assert a.load_steps > 1  # the failure the line search exists for
    searched = fr.ReferenceSolver(case, settings=fr.NewtonSettings(line_search=4, **one_step))
    b = searched.solve(push)
    assert b.load_steps == 1 and b.converged
    np.testing.assert_allclose(b.u, a.u, atol=1e-8)


def test_lagged_solver_switches_to_mumps_when_the_tangent_is_not_positive_definite():
    """CHOLMOD (LL^T) cannot factorize an indefinite tangent; the lagged solver must switch to
    MUMPS LDL^T and still solve the system exactly."""
    from petsc4py import PETSc

    from tissue_reference.model.case import load_case

    case = load_case("meshes/cases/phantom.toml", size=16).with_pushes({"A1": 3.0})
    s = fr.ReferenceSolver(case, linear_solver="lagged")
    if s.linear.factor_package != "cholmod":
        pytest.skip("this PETSc has no CHOLMOD")
    bcs = [e[0] for e in s.boundary.dirichlet_bcs(case, 1.0)]
    s.newton.assemble_residual(bcs)
    s.newton.assemble_tangent(bcs)
    s.A.scale(-1.0)  # negative definite: what CHOLMOD must refuse
    assert s.linear.solve(1e-12)
    assert s.linear.factor_package == "mumps"
    r = s.b.duplicate()
    s.A.mult(s.du.vector, r)
    r.axpy(1.0, s.b)  # A du = -b
    assert r.norm() <= 1e-9 * s.b.norm()
    assert isinstance(s.linear.P, PETSc.Mat) and s.linear.P.getType() == "seqsbaij"
