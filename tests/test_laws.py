"""The strain-energy laws of the reference against answers written here from their formulas:
the first Piola stress of a homogeneous deformation by complex-step differentiation of each
energy as the formula reads (and the simple-shear stresses in closed form), the small-strain
limit (linear elasticity with the same E and nu), and a P1 block stretched 20 % between sliding
faces, whose exact answer is homogeneous (so in the P1 space): its lateral contraction and force
against the traction-free root of the formula's stress. Units: mm, kPa, mN."""
import math

import numpy as np
import pytest
from scipy.optimize import brentq

from tissue_reference.errors import CaseError
from tissue_reference.model.case import Boundary, Case, Material, Probe

LAWS = {
    "neo-hookean": {"E": 6.0, "nu": 0.45},
    "stable-neo-hookean": {"E": 6.0, "nu": 0.45},
    "saint-venant-kirchhoff": {"E": 6.0, "nu": 0.3},
    "corotational": {"E": 6.0, "nu": 0.3},
    "mooney-rivlin": {"c1": 1.0, "c2": 0.5, "k": 30.0},
    "yeoh": {"c1": 1.2, "c2": -0.2, "c3": 0.05, "k": 40.0},
    "linear-elastic": {"E": 6.0, "nu": 0.3},
}


def _det(F):
    return (F[0, 0] * (F[1, 1] * F[2, 2] - F[1, 2] * F[2, 1])
            - F[0, 1] * (F[1, 0] * F[2, 2] - F[1, 2] * F[2, 0])
            + F[0, 2] * (F[1, 0] * F[2, 1] - F[1, 1] * F[2, 0]))


def psi_formula(F, model, p):
    """The energy density (kPa) as docs/laws.md writes it; works on complex F."""
    E, nu = p.get("E"), p.get("nu")
    if E is not None:
        mu, lam = E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))
        kappa = E / (3 * (1 - 2 * nu))
    C = F.T @ F
    J = _det(F)
    I1 = np.trace(C)
    I2 = (I1 ** 2 - np.trace(C @ C)) / 2
    b1, b2 = J ** (-2 / 3) * I1, J ** (-4 / 3) * I2
    if model == "neo-hookean":
        return mu / 2 * (b1 - 3) + kappa / 2 * (J - 1) ** 2
    if model == "mooney-rivlin":
        return p["c1"] * (b1 - 3) + p["c2"] * (b2 - 3) + p["k"] / 2 * (J - 1) ** 2
    if model == "yeoh":
        x = b1 - 3
        return p["c1"] * x + p["c2"] * x ** 2 + p["c3"] * x ** 3 + p["k"] / 2 * (J - 1) ** 2
    if model == "stable-neo-hookean":
        lp = lam + mu
        return mu / 2 * (I1 - 3) + lp / 2 * (J - 1 - mu / lp) ** 2 - mu ** 2 / (2 * lp)
    if model == "saint-venant-kirchhoff":
        Eg = (C - np.eye(3)) / 2
        return lam / 2 * np.trace(Eg) ** 2 + mu * np.sum(Eg * Eg)
    if model == "corotational":   # mu |F - R|^2 + lambda/2 tr(R^T F - I)^2, F = R U (SVD)
        W, _, Vt = np.linalg.svd(F)
        R = W @ Vt
        return mu * np.sum((F - R) ** 2) + lam / 2 * (np.trace(R.T @ F) - 3) ** 2
    eps = (F + F.T) / 2 - np.eye(3)
    return mu * np.sum(eps * eps) + lam / 2 * np.trace(eps) ** 2


def piola_formula(F, model, p):
    """dpsi/dF by complex steps of psi_formula (exact to round-off); the corotational law's in
    closed form, P = 2 mu (F - R) + lambda tr(R^T F - I) R (d tr U / dF = R), R from the SVD
    (which complex steps do not pass through)."""
    if model == "corotational":
        E, nu = p["E"], p["nu"]
        mu, lam = E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))
        W, _, Vt = np.linalg.svd(F)
        R = W @ Vt
        return 2 * mu * (F - R) + lam * (np.trace(R.T @ F) - 3) * R
    P = np.zeros((3, 3))
    for i in range(3):
        for j in range(3):
            Fc = F.astype(complex)
            Fc[i, j] += 1e-30j
            P[i, j] = psi_formula(Fc, model, p).imag / 1e-30
    return P


@pytest.fixture(scope="module")
def piola_code():
    """P(F) of the reference's own UFL energy (fem_reference.forms) for a homogeneous F on one
    cube: each component integrated over the unit cube."""
    import dolfinx
    import dolfinx.fem
    import dolfinx.mesh
    import ufl
    from mpi4py import MPI
    from petsc4py import PETSc

    from tissue_reference.fem_reference.forms import strain_energy_density

    mesh = dolfinx.mesh.create_unit_cube(MPI.COMM_SELF, 1, 1, 1)
    V = dolfinx.fem.VectorFunctionSpace(mesh, ("Lagrange", 1))
    u = dolfinx.fem.Function(V)
    dx = ufl.Measure("dx", domain=mesh, metadata={"quadrature_degree": 2})

    def piola(F, model, params):
        m = Material(model, **params)
        coeffs = {n: dolfinx.fem.Constant(mesh, PETSc.ScalarType(v))
                  for n, v in m.coefficients.items()}
        u.interpolate(lambda x: (F - np.eye(3)) @ x)
        psi, Fv = strain_energy_density(u, model, m.mu, m.kappa, m.lmbda, m.volumetric, coeffs)
        P = ufl.diff(psi, Fv)
        return np.array([[dolfinx.fem.assemble_scalar(dolfinx.fem.form(P[i, j] * dx))
                          for j in range(3)] for i in range(3)])
    return piola


GRADIENTS = {
    "uniaxial": np.diag([1.3, 0.9, 0.9]),
    "shear": np.array([[1.0, 0.4, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),
    "general": np.array([[1.1, 0.2, -0.1], [0.05, 0.95, 0.15], [-0.1, 0.1, 1.05]]),
}


@pytest.mark.parametrize("model", list(LAWS))
@pytest.mark.parametrize("which", list(GRADIENTS))
def test_each_law_gives_its_formulas_stress(piola_code, model, which):
    F = GRADIENTS[which]
    expected = piola_formula(F, model, LAWS[model])
    got = piola_code(F, model, LAWS[model])
    np.testing.assert_allclose(got, expected, rtol=1e-10, atol=1e-10 * np.abs(expected).max())


@pytest.mark.parametrize("model", list(LAWS))
def test_simple_shear_stress_in_closed_form(piola_code, model):
    """Simple shear (J = 1): the Cauchy shear stress sigma_12 = P F^T by hand from each law."""
    g = 0.4
    F = GRADIENTS["shear"]
    p = dict(LAWS[model])
    m = Material(model, **p)
    sigma12 = (piola_code(F, model, p) @ F.T)[0, 1]
    expected = {
        "neo-hookean": m.mu * g,                                 # mu dev(B)_12
        "stable-neo-hookean": m.mu * g,                          # mu (B - I)_12
        "mooney-rivlin": 2 * g * (p.get("c1", 0) + p.get("c2", 0)),
        "yeoh": 2 * g * (p.get("c1", 0) + 2 * p.get("c2", 0) * g ** 2
                         + 3 * p.get("c3", 0) * g ** 4),
        # (F S F^T)_12 with S = lambda tr(Eg) I + 2 mu Eg, Eg = [[0, g/2], [g/2, g^2/2]]:
        "saint-venant-kirchhoff": m.mu * g + m.lmbda * g ** 3 / 2 + m.mu * g ** 3,
        # P_12 of 2 mu (F - R) + lambda (tr U - 3) R, R the rotation by atan(g/2), c its cosine,
        # tr U = 2 / c + 1:
        "corotational": (m.mu * g * (2 - 1 / math.sqrt(1 + g * g / 4))
                         + m.lmbda * g * (1 - 1 / math.sqrt(1 + g * g / 4))),
        "linear-elastic": m.mu * g,
    }[model]
    assert sigma12 == pytest.approx(expected, rel=1e-10)


@pytest.mark.parametrize("model", list(LAWS))
def test_small_strain_limit_is_linear_elasticity(piola_code, model):
    """At F = I + t H, t = 1e-6, P / t is 2 mu sym(H) + lambda tr(H) I with the law's E, nu."""
    H = GRADIENTS["general"] - np.eye(3)
    t = 1e-6
    m = Material(model, **LAWS[model])
    eps = (H + H.T) / 2
    expected = 2 * m.mu * eps + m.lmbda * np.trace(eps) * np.eye(3)
    got = piola_code(np.eye(3) + t * H, model, LAWS[model]) / t
    np.testing.assert_allclose(got, expected, atol=1e-4 * np.abs(expected).max())


def _stretched_block(material):
    from tissue_reference.meshes.builders import box

    return Case(mesh=box(5.0), material=material, name="stretched-block",
                boundaries=(Boundary("xmin", "sliding", normal=[1, 0, 0]),
                            Boundary("ymin", "sliding", normal=[0, 1, 0]),
                            Boundary("zmin", "sliding", normal=[0, 0, 1]),
                            Boundary("xmax", "displacement", value=[2.0, 0, 0],
                                     components=(0,))),
                probes=(Probe("corner", (10.0, 10.0, 10.0)),))


@pytest.mark.slow
@pytest.mark.parametrize("model,params,formulation", [
    *[(m, p, "auto") for m, p in LAWS.items()],
    ("mooney-rivlin", {"c1": 1.0, "c2": 0.5, "k": 1500.0}, "auto"),   # nu 0.499: mixed u-p
])
def test_block_stretched_20_percent_meets_the_formulas_uniaxial_answer(model, params,
                                                                      formulation):
    """The 10 mm block stretched to 12 mm between sliding faces: lateral faces free, so the
    lateral stretch t solves P_22(1.2, t) = 0 of the formula's stress; the corner moves
    10 (t - 1) mm sideways and the stretched face carries P_11 (1.2, t) x 100 mm^2."""
    from tissue_reference.fem_reference import solve

    material = Material(model, **params)

    def lateral(t):
        return piola_formula(np.diag([1.2, t, t]), model, params)[1, 1]

    t = brentq(lateral, 0.5, 1.2, xtol=1e-14)
    force = piola_formula(np.diag([1.2, t, t]), model, params)[0, 0] * 100.0
    res = solve(_stretched_block(material), formulation=formulation)
    assert res.converged
    if material.nu >= 0.49:
        assert res.discretization["formulation"] == "mixed"
    corner = res.probes["corner"]
    assert corner[0] == pytest.approx(2.0, abs=1e-9)
    np.testing.assert_allclose(corner[1:], 10.0 * (t - 1.0), rtol=1e-6)
    assert res.reactions["xmax"][0] == pytest.approx(force, rel=1e-6)   # what pulls the face


def test_case_file_names_a_law_and_its_coefficients(tmp_path):
    from tissue_reference.model.case import load_case
    from tissue_reference.model.results import material_json

    text = ('name = "mr"\n[mesh]\nbuiltin = "box"\nsize = 5.0\n[material]\n'
            'model = "mooney-rivlin"\nc1 = 1.0\nc2 = 0.5\nk = 30.0\n'
            '[[boundary]]\nregion = "xmin"\ntype = "fixed"\n')
    (tmp_path / "mr.toml").write_text(text)
    m = load_case(tmp_path / "mr.toml").material
    mu0, k = 3.0, 30.0     # 2 (c1 + c2), the bulk modulus
    assert m.E == pytest.approx(9 * k * mu0 / (3 * k + mu0))
    assert m.nu == pytest.approx((3 * k - 2 * mu0) / (2 * (3 * k + mu0)))
    assert material_json(m)["coefficients_kPa"] == {"c1": 1.0, "c2": 0.5, "k": 30.0}
    for old, new, words in (("c2 = 0.5\n", "", "needs c1, c2, k (kPa); missing: c2"),
                            ("c2 = 0.5", "c2 = -0.5", "polyconvex"),
                            ("k = 30.0\n", "k = 30.0\nE = 6.0\n", "E follows from them")):
        (tmp_path / "bad.toml").write_text(text.replace(old, new))
        with pytest.raises(CaseError) as info:
            load_case(tmp_path / "bad.toml")
        assert words in str(info.value) and "bad.toml" in str(info.value)


def test_laws_refuse_parameters_outside_their_stable_range():
    with pytest.raises(CaseError, match="polyconvex"):
        Material("mooney-rivlin", c1=1.0, c2=-0.1, k=10.0)
    with pytest.raises(CaseError, match="c2 >= 0 or c2\\^2 < 3 c1 c3"):
        Material("yeoh", c1=1.0, c2=-1.0, c3=0.1, k=10.0)   # 1 - 2x + 0.3x^2 < 0 at x = 2
    Material("yeoh", c1=1.0, c2=-0.5, c3=0.1, k=10.0)   # 0.25 < 0.3: positive for every x
    with pytest.raises(CaseError, match="bulk modulus k must be > 0"):
        Material("yeoh", c1=1.0, c2=0.0, c3=0.0, k=0.0)
    with pytest.raises(CaseError, match="compressible law: nu must be < 0.5"):
        Material("stable-neo-hookean", E=6.0, nu=0.5)
    with pytest.raises(CaseError, match="E follows from them"):
        Material("mooney-rivlin", c1=1.0, c2=0.5, k=30.0, E=6.0)
    with pytest.raises(CaseError, match="belong to other laws"):
        Material("neo-hookean", E=6.0, nu=0.45, c1=1.0)
    with pytest.raises(CaseError, match="applies to the laws"):
        Material("saint-venant-kirchhoff", E=6.0, nu=0.3, volumetric="log")


def test_a_new_E_scales_a_coefficient_law():
    from tissue_reference.fem_reference.discretization import resolve_formulation

    case = _stretched_block(Material("mooney-rivlin", c1=1.0, c2=0.5, k=30.0))
    stiffer = case.with_material(E=2 * case.material.E)
    assert stiffer.material.coefficients == {"c1": 2.0, "c2": 1.0, "k": 60.0}
    assert math.isclose(stiffer.material.nu, case.material.nu)
    with pytest.raises(CaseError, match="couples it"):
        resolve_formulation("mixed", Material("saint-venant-kirchhoff", E=6.0, nu=0.3))
    assert resolve_formulation("auto", Material("stable-neo-hookean", E=6.0, nu=0.495)) == \
        "displacement"


@pytest.mark.slow
def test_the_jacobian_of_a_mooney_rivlin_phantom_equals_central_differences():
    """J_s of A1 at a 5 mm pre-push on the phantom of a Mooney-Rivlin material (the exact
    tangent of that law's energy) against central differences of its solves: 1e-4; it is not
    the Neo-Hookean phantom's."""
    from fem_checks import jacobian_column_error

    from tissue_reference.control.plants import jacobian_at
    from tissue_reference.model.case import load_case

    case = load_case("phantom", size=14.0).with_material(
        model="mooney-rivlin", E=None, nu=None, c1=0.6, c2=0.4, k=25.0)
    assert jacobian_column_error(case, "A1", 5.0) < 1e-4
    neo = case.with_material(model="neo-hookean", E=6.0, nu=0.45, c1=None, c2=None, k=None)
    J_mr = np.asarray(jacobian_at(case, {"A1": 5.0}, fd_h=0)["J"])
    J_neo = np.asarray(jacobian_at(neo, {"A1": 5.0}, fd_h=0)["J"])
    assert np.max(np.abs(J_neo - J_mr)) > 1e-3   # the law matters


def _uniaxial_lateral(model, params):
    """The lateral stretch of the block at 1.2: P_22 (1.2, t) = 0 of the formula's stress."""
    return brentq(lambda t: piola_formula(np.diag([1.2, t, t]), model, params)[1, 1], 0.5, 1.2,
                  xtol=1e-14)


@pytest.mark.slow
def test_verify_scores_a_plugin_on_the_law_it_declares(tmp_path, capsys):
    """A plugin that returns the exact stable-neo-hookean answer of the stretched block (the
    homogeneous state, from the formula's root) and declares that law is scored against that
    law's reference (error ~0) on a neo-hookean case, with the law difference beside it: the
    distance between the two laws' exact answers at the block's far corner, 10 sqrt(2) |t - t'|
    mm; a law it cannot be scored on is said, and the case's law used."""
    from tissue_reference.verification.verify import verify

    case = _stretched_block(Material("neo-hookean", E=6.0, nu=0.45))
    snh = {"E": 6.0, "nu": 0.45}
    t_snh = _uniaxial_lateral("stable-neo-hookean", snh)
    t_nh = _uniaxial_lateral("neo-hookean", snh)

    def exact(model, t):
        def solve(case_, pushes):
            u = case_.mesh.points @ (np.diag([1.2, t, t]) - np.eye(3))
            return {"u": u, "extra": {"model": model}}
        solve.__name__ = solve.__qualname__ = f"exact_{model.replace('-', '_')}"
        return solve

    out = verify(case, {}, solvers=[exact("stable-neo-hookean", t_snh),
                                    exact("mooney-rivlin", t_snh)])
    scores = {name.rsplit(":", 1)[-1]: v for name, v in out["solvers"].items()}
    e = scores["exact_stable_neo_hookean"]
    assert e["reference_model"] == "stable-neo-hookean" and e["max_vertex_error_mm"] < 1e-7
    assert e["law_difference_mm"] == pytest.approx(10 * math.sqrt(2) * abs(t_snh - t_nh),
                                                   rel=1e-5)
    assert "the law difference, not solver error" in e["note"]
    assert "exact_stable_neo_hookean: a stable-neo-hookean solver" in capsys.readouterr().out
    mr = scores["exact_mooney_rivlin"]
    assert mr["reference_model"] == "neo-hookean" and "law_difference_mm" not in mr
    assert "coefficients (c1, c2, k) the case does not give" in mr["note"]
    assert mr["max_vertex_error_mm"] == pytest.approx(e["law_difference_mm"], rel=1e-5)


@pytest.mark.slow
def test_a_mixed_mooney_rivlin_solve_warm_started_from_vertex_values():
    """The mixed formulation recovers the pressure of a warm start given as vertex values from
    the law's own volume measure: the nearly incompressible Mooney-Rivlin block started from
    its own answer's vertex values stays at that answer."""
    from tissue_reference.fem_reference import solve

    case = _stretched_block(Material("mooney-rivlin", c1=1.0, c2=0.5, k=1500.0))
    first = solve(case)
    again = solve(case, initial=np.asarray(first.u))
    assert again.converged and first.discretization["formulation"] == "mixed"
    np.testing.assert_allclose(again.probes["corner"], first.probes["corner"], atol=1e-9)
