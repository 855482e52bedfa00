"""The mixed u-p (Taylor-Hood P2/P1) reference for nearly incompressible tissue, against answers
computed here independently of the solver:

- patch tests: homogeneous states with the closed-form first Piola stress of seed 000 eq. 14,
  P = mu J^(-2/3) (F - I1/3 F^-T) + kappa J (J - 1) F^-T, and the pressure p = -kappa (J - 1);
- the thick sphere (an octant, inner surface pushed out radially, outer surface free) against the
  radial equilibrium ODE d P_rR / dR + 2 (P_rR - P_tt) / R = 0 solved with scipy's solve_bvp.
Units: mm, kPa, mN.
"""
import numpy as np
import pytest
from scipy.integrate import solve_bvp
from scipy.optimize import brentq

import tissue_reference.fem_reference as fr
from tissue_reference.errors import CaseError
from tissue_reference.meshes.builders import box, shell_octant
from tissue_reference.model.case import Boundary, Case, Material

A, B, UA = 10.0, 20.0, 2.0  # shell radii and the inner surface's radial push, mm
E = 6.0
L = 10.0


def principal_piola(l1, l2, mu, kappa):
    """First Piola stresses (P_11, P_22) of seed 000 eq. 14 at principal stretches (l1, l2, l2)."""
    J = l1 * l2 * l2
    I1 = l1 ** 2 + 2 * l2 ** 2
    a = mu * J ** (-2 / 3)
    return (a * (l1 - I1 / (3 * l1)) + kappa * (J - 1) * J / l1,
            a * (l2 - I1 / (3 * l2)) + kappa * (J - 1) * J / l2)


def thick_sphere(mu, kappa):
    """Radial solution r(R) of the shell A <= R <= B with r(A) = A + UA and P_rR(B) = 0.

    State (r, P_rR); lambda_r = r' is recovered from P_rR by Newton at each point (P_rR is
    monotone in lambda_r). Returns (u(B), P_rR(A))."""
    def lam_r(P, r, R):
        x = np.ones_like(r)
        for _ in range(50):
            h = 1e-7
            f = principal_piola(x, r / R, mu, kappa)[0] - P
            df = (principal_piola(x + h, r / R, mu, kappa)[0]
                  - principal_piola(x - h, r / R, mu, kappa)[0]) / (2 * h)
            x = x - f / df
        return x

    def rhs(R, y):
        r, P = y
        l1 = lam_r(P, r, R)
        P1, P2 = principal_piola(l1, r / R, mu, kappa)
        return np.vstack([l1, -2.0 / R * (P1 - P2)])

    R = np.linspace(A, B, 200)
    guess = np.vstack([R + UA * (A / R) ** 2, np.zeros_like(R)])
    sol = solve_bvp(rhs, lambda ya, yb: np.array([ya[0] - A - UA, yb[1]]), R, guess, tol=1e-10,
                    max_nodes=100000)
    assert sol.success, sol.message
    return float(sol.sol(B)[0] - B), float(sol.sol(A)[1])


def incompressible_sphere(mu):
    """Closed form of the incompressible Neo-Hookean shell: r^3 = R^3 + (A + UA)^3 - A^3 and
    sigma_rr(a) = int_a^b 2 mu (l_r^2 - l_t^2) / r dr (radial equilibrium, sigma_rr(b) = 0).
    Returns (u(B), P_rR(A) = sigma_rr(a) (a / A)^2)."""
    from scipy.integrate import quad

    a = A + UA
    c = a ** 3 - A ** 3
    b = (B ** 3 + c) ** (1 / 3)

    def integrand(r):
        R = (r ** 3 - c) ** (1 / 3)
        return 2 * mu * ((R / r) ** 4 - (r / R) ** 2) / r

    s_a = quad(integrand, a, b, epsabs=0, epsrel=1e-12)[0]
    return b - B, s_a * (a / A) ** 2


def solve_shell(size, nu, formulation, curved=None):
    """FE solve of the octant (P2 on curved, isoparametric cells unless curved=False); returns
    (result, mean radial displacement of the outer nodes, the radial generalized reaction
    sum_i f_i . X_i / A over the inner nodes)."""
    mat = Material("neo-hookean", E=E, nu=nu)
    bcs = [Boundary("xsym", "sliding", normal=[1, 0, 0]),
           Boundary("ysym", "sliding", normal=[0, 1, 0]),
           Boundary("zsym", "sliding", normal=[0, 0, 1]),
           # u = UA X / A: the radial push on the sphere |X| = A, a uniform scaling of the surface
           Boundary("inner", "affine", gradient=(UA / A * np.eye(3)).tolist(), offset=[0, 0, 0])]
    case = Case(mesh=shell_octant(size), material=mat, boundaries=bcs, name="thick-sphere")
    s = fr.ReferenceSolver(case, degree=2, formulation=formulation, curved=curved)
    res = s.solve()
    assert res.converged
    X = s.node_points()
    r = np.linalg.norm(X, axis=1)
    f = s.internal_forces().reshape(-1, 3)
    inner = r < A * (1 + 1e-3)  # inner vertices and the edge nodes of inner facets (just inside)
    outer = np.abs(r - B) < 1e-6 * B
    u_out = np.sum(res.node_u[outer] * X[outer], axis=1) / B
    return res, float(u_out.mean()), float(np.sum(f[inner] * X[inner]) / A)


@pytest.fixture(scope="module")
def cube():
    return box(5.0)


@pytest.mark.parametrize("nu", [0.45, 0.4999])
def test_mixed_uniaxial_patch_test_is_exact(cube, nu):
    mat = Material("neo-hookean", E=E, nu=nu)
    stretch = 1.15
    bcs = [Boundary("xmin", "sliding", normal=[1, 0, 0]),
           Boundary("ymin", "sliding", normal=[0, 1, 0]),
           Boundary("zmin", "sliding", normal=[0, 0, 1]),
           Boundary("xmax", "displacement", value=[(stretch - 1) * L, 0, 0], components=(0,))]
    case = Case(mesh=cube, material=mat, boundaries=bcs, name="patch")
    res = fr.solve(case, degree=2, formulation="mixed")
    lat = brentq(lambda t: principal_piola(stretch, t, mat.mu, mat.kappa)[1], 0.5, 1.5, xtol=1e-15)
    F = np.diag([stretch, lat, lat])
    np.testing.assert_allclose(res.u, cube.points @ (F - np.eye(3)).T, atol=1e-9)
    P11 = principal_piola(stretch, lat, mat.mu, mat.kappa)[0]
    np.testing.assert_allclose(res.reactions["xmax"][0], P11 * L * L, rtol=1e-8)
    J = stretch * lat * lat
    np.testing.assert_allclose(res.pressure, -mat.kappa * (J - 1), rtol=1e-7)
    assert res.discretization["formulation"] == "mixed"
    assert res.discretization["pressure_degree"] == 1


def test_mixed_shear_patch_test_with_affine_boundary_is_exact(cube):
    mat = Material("neo-hookean", E=E, nu=0.4999)
    F = np.array([[1.0, 0.2, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])  # isochoric: J = 1
    faces = ["xmin", "xmax", "ymin", "ymax", "zmin", "zmax"]
    bcs = [Boundary(f, "affine", gradient=(F - np.eye(3)).tolist()) for f in faces]
    res = fr.solve(Case(mesh=cube, material=mat, boundaries=bcs, name="shear"), degree=2,
                   formulation="mixed")
    np.testing.assert_allclose(res.u, cube.points @ (F - np.eye(3)).T, atol=1e-9)
    np.testing.assert_allclose(res.pressure, 0.0, atol=1e-8 * mat.mu)
    # strain energy of the isochoric shear: mu/2 (I1 - 3) per unit volume
    np.testing.assert_allclose(res.strain_energy, mat.mu / 2 * 0.2 ** 2 * L ** 3, rtol=1e-9)


def test_auto_picks_mixed_for_nearly_incompressible_and_refuses_p1(cube):
    mat = Material("neo-hookean", E=E, nu=0.495)
    case = Case(mesh=cube, material=mat, boundaries=[Boundary("zmin", "fixed")], name="auto")
    assert fr.resolve_formulation("auto", mat) == "mixed"
    assert fr.resolve_formulation("auto", Material(nu=0.45)) == "displacement"
    with pytest.raises(CaseError, match="needs degree=2 or 3"):
        fr.ReferenceSolver(case, degree=1)
    with pytest.raises(CaseError, match="formulation must be one of"):
        fr.ReferenceSolver(case, degree=2, formulation="hybrid")


@pytest.mark.slow
def test_nearly_incompressible_thick_sphere_matches_the_radial_ode():
    """nu = 0.4999 (kappa / mu = 1.5e4). Mixed P2/P1 on curved cells is within 0.1 % of the ODE;
    on straight (faceted) cells the polyhedral surface is the error (~1.8 %, falling as h^2);
    displacement P2 locks: its reaction is ~10 % off on the same curved mesh."""
    mat = Material("neo-hookean", E=E, nu=0.4999)
    u_ref, P_ref = thick_sphere(mat.mu, mat.kappa)
    G_ref = -P_ref * A ** 2 * np.pi / 2  # virtual work of the inner support for delta u = e_R
    res, u_out, G = solve_shell(2.5, 0.4999, "mixed")
    assert res.discretization["geometry_order"] == 2
    assert abs(u_out / u_ref - 1) < 1e-3 and abs(G / G_ref - 1) < 1e-3, (u_out, u_ref, G, G_ref)
    errs = []
    for size in (2.5, 1.5):
        _, u_s, G_s = solve_shell(size, 0.4999, "mixed", curved=False)
        errs.append((abs(u_s / u_ref - 1), abs(G_s / G_ref - 1)))
    assert errs[0][0] > 10 * abs(u_out / u_ref - 1) and errs[0][1] > 10 * abs(G / G_ref - 1)
    assert errs[0][0] > 2.0 * errs[1][0] and errs[0][1] > 2.0 * errs[1][1], errs
    _, _, G_disp = solve_shell(2.5, 0.4999, "displacement")
    # the locking the mixed formulation removes: ~10 % on the same curved mesh
    assert abs(G_disp / G_ref - 1) > 100 * abs(G / G_ref - 1)


def test_thick_sphere_ode_matches_the_incompressible_closed_form():
    """Check of the test's own ODE: as kappa -> inf, incompressibility alone gives
    r(R)^3 = R^3 + (A + UA)^3 - A^3, whatever the shear law."""
    mu = E / 3
    u_ref, _ = thick_sphere(mu, 1e5 * mu)
    u_closed = ((B ** 3 + (A + UA) ** 3 - A ** 3) ** (1 / 3)) - B
    assert abs(u_ref - u_closed) < 1e-4 * u_closed  # O(mu / kappa) compressibility


def test_mixed_control_jacobian_matches_finite_differences_of_mixed_solves():
    """J_s from the saddle-point tangent (pressure condensed by the solve) against central
    differences of nonlinear mixed solves, nu = 0.4999, at a pushed state."""
    from tissue_reference.control.dof_maps import p2_interpolation, p2_region_nodes
    from tissue_reference.control.jacobian import dirichlet_jacobian, fd_jacobian
    from tissue_reference.model.case import Actuator, Probe

    mat = Material("neo-hookean", E=E, nu=0.4999)
    case = Case(mesh=box(3.0), material=mat, boundaries=[Boundary("zmin", "fixed")],
                probes=[Probe("T", (5.0, 5.0, 5.0)), Probe("S", (9.0, 3.0, 7.0))],
                actuators=[Actuator("A1", "zmax", (0.0, 0.0, -1.0))], name="block")
    s = fr.ReferenceSolver(case, formulation="mixed")
    state = {"A1": 1.5}
    res = s.solve(state)
    T = s.tangent(res, pushes=state)
    assert T.formulation == "mixed" and T.internal_dofs == case.mesh.n_vertices
    jac = dirichlet_jacobian(case.with_pushes(state), T.K, P=p2_interpolation(case, T.node_points),
                             region_nodes=p2_region_nodes(case, T.node_points),
                             internal_dofs=T.internal_dofs)
    fd = fd_jacobian(lambda c, pushes, initial: s.solve(pushes, case=c, initial=initial), case,
                     state, h=0.01, initial=res)
    np.testing.assert_allclose(jac.J, fd.J, atol=1e-6 * np.abs(fd.J).max())


@pytest.mark.slow
def test_incompressible_thick_sphere_matches_the_closed_form():
    """nu = 0.5 exactly (1/kappa = 0: p is the Lagrange multiplier of J = 1)."""
    mat = Material("neo-hookean", E=E, nu=0.5)
    u_ref, P_ref = incompressible_sphere(mat.mu)
    G_ref = -P_ref * A ** 2 * np.pi / 2
    res, u_out, G = solve_shell(2.5, 0.5, "mixed")
    assert res.discretization["formulation"] == "mixed"
    assert abs(u_out / u_ref - 1) < 1e-3 and abs(G / G_ref - 1) < 1e-3, (u_out, u_ref, G, G_ref)


def test_incompressible_uniaxial_patch_test_is_exact(cube):
    """nu = 0.5: lateral stretch exactly l^(-1/2), P_11 = mu (l - l^-2)."""
    mat = Material("neo-hookean", E=E, nu=0.5)
    stretch = 1.2
    bcs = [Boundary("xmin", "sliding", normal=[1, 0, 0]),
           Boundary("ymin", "sliding", normal=[0, 1, 0]),
           Boundary("zmin", "sliding", normal=[0, 0, 1]),
           Boundary("xmax", "displacement", value=[(stretch - 1) * L, 0, 0], components=(0,))]
    res = fr.solve(Case(mesh=cube, material=mat, boundaries=bcs, name="incompressible"))
    lat = stretch ** -0.5
    F = np.diag([stretch, lat, lat])
    np.testing.assert_allclose(res.u, cube.points @ (F - np.eye(3)).T, atol=1e-9)
    np.testing.assert_allclose(res.reactions["xmax"][0],
                               mat.mu * (stretch - stretch ** -2) * L * L, rtol=1e-8)


def test_fast_solvers_and_the_displacement_reference_refuse_an_incompressible_material(cube):
    from tissue_reference.solvers import admm, mass_tensor

    case = Case(mesh=cube, material=Material("neo-hookean", E=E, nu=0.5),
                boundaries=[Boundary("zmin", "fixed")], name="incompressible")
    with pytest.raises(CaseError, match="incompressible"):
        fr.ReferenceSolver(case, degree=2, formulation="displacement")
    with pytest.raises(CaseError, match="incompressible"):
        admm.solve(case)
    with pytest.raises(CaseError, match="incompressible"):
        mass_tensor.solve(case.with_material(model="linear-elastic"))


@pytest.mark.parametrize("formulation", ["displacement", "mixed"])
def test_degree_3_patch_test_is_exact(cube, formulation):
    """P3 (and P3/P2 Taylor-Hood) reproduce a homogeneous deformation and its closed-form force."""
    mat = Material("neo-hookean", E=E, nu=0.45)
    stretch = 1.1
    bcs = [Boundary("xmin", "sliding", normal=[1, 0, 0]),
           Boundary("ymin", "sliding", normal=[0, 1, 0]),
           Boundary("zmin", "sliding", normal=[0, 0, 1]),
           Boundary("xmax", "displacement", value=[(stretch - 1) * L, 0, 0], components=(0,))]
    res = fr.solve(Case(mesh=cube, material=mat, boundaries=bcs, name="p3"), degree=3,
                   formulation=formulation)
    lat = brentq(lambda t: principal_piola(stretch, t, mat.mu, mat.kappa)[1], 0.5, 1.5, xtol=1e-15)
    F = np.diag([stretch, lat, lat])
    np.testing.assert_allclose(res.u, cube.points @ (F - np.eye(3)).T, atol=1e-9)
    np.testing.assert_allclose(res.node_u, res.node_points @ (F - np.eye(3)).T,
                               atol=1e-9)
    P11 = principal_piola(stretch, lat, mat.mu, mat.kappa)[0]
    np.testing.assert_allclose(res.reactions["xmax"][0], P11 * L * L, rtol=1e-8)
