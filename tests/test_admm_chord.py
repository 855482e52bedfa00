"""The chord polish of the ADMM solver (``solvers.admm.chord``): chord steps on the tangent at
rest, Anderson-mixed, against the P1 reference (dolfinx, an independent implementation of the
same discrete energy) and against a linear map whose fixed point is solved directly."""
import numpy as np
import pytest
import scipy.sparse as sp

from tissue_reference.errors import CaseError
from tissue_reference.meshes.builders import box
from tissue_reference.model.case import Boundary, Case, Material, load_case
from tissue_reference.solvers import admm
from tissue_reference.solvers.admm import chord as chord_module

PUSHES = {"A1": 4.0, "A2": 4.0, "A3": 4.0, "A4": 4.0}


@pytest.fixture(scope="module")
def phantom12():
    return load_case("meshes/cases/phantom.toml", size=12.0)


def test_chord_polish_reaches_the_reference_answer_within_its_tolerance(phantom12):
    """Default tolerance (1e-4 mm): every vertex within 1e-3 mm of the P1 reference, without the
    Newton fallback; a tighter polish tolerance brings it closer."""
    from tissue_reference.fem_reference import solve as fem_solve
    ref = fem_solve(phantom12, degree=1, pushes=PUSHES)
    res = admm.solve(phantom12, pushes=PUSHES, polish="chord")
    assert res.converged and res.extra["chord_fallbacks"] == []
    assert res.extra["polish"] == "chord"
    err = np.abs(res.u - ref.u).max()
    assert err < 1e-3
    tight = admm.solve(phantom12, pushes=PUSHES, polish="chord", polish_tol_mm=1e-7,
                       polish_max_iter=60)
    assert tight.converged and tight.extra["chord_fallbacks"] == []
    assert np.abs(tight.u - ref.u).max() < min(1e-5, err)
    for k in ref.probes:
        assert np.linalg.norm(tight.probes[k] - ref.probes[k]) < 1e-5


def test_diverging_chord_steps_hand_over_to_the_newton_polish(phantom12, monkeypatch):
    """With the divergence rule made to trip at the second step, every load step ends in the
    Newton polish, which finds the reference's answer; the hand-overs are listed."""
    from tissue_reference.fem_reference import solve as fem_solve
    monkeypatch.setattr(chord_module, "GROWTH", 0.0)
    ref = fem_solve(phantom12, degree=1, pushes=PUSHES)
    res = admm.solve(phantom12, pushes=PUSHES, polish="chord", polish_tol_mm=1e-8)
    assert res.converged
    assert len(res.extra["chord_fallbacks"]) == res.load_steps
    assert "Newton polish" in res.extra["chord_fallbacks"][0]
    assert np.abs(res.u - ref.u).max() < 1e-7


def test_chord_steps_find_a_linear_maps_fixed_point_with_a_wrong_factor():
    """r(q) = A q - b with A symmetric positive definite and the factor that of a matrix 3x
    softer in some directions (the plain chord map then diverges there): the mixed steps reach
    A^-1 b, solved directly."""
    rng = np.random.default_rng(5)
    n = 40
    Q = np.linalg.qr(rng.normal(size=(n, n)))[0]
    A = Q @ np.diag(np.linspace(1.0, 4.0, n)) @ Q.T
    K0 = Q @ np.diag(np.linspace(1.0, 4.0, n) / np.linspace(0.6, 3.0, n)) @ Q.T
    b = rng.normal(size=n)

    class Ops:     # the operators' interface the chord steps use, on a plain vector
        d = 1
        red = type("Red", (), {"Z": sp.identity(n, format="csr"),
                               "ZT": sp.identity(n, format="csr")})()
        def valid(self, u):   # linear: no cell to invert
            return True

        def residual(self, u, fext, tips=None):
            return A @ u - b

        def residual_if_valid(self, u, fext, tips=None):
            return self.residual(u, fext)

        def step_norm(self, dq):
            return float(np.abs(dq).max())

    class Factor:
        def solve(self, r):
            return np.linalg.solve(K0, r)

    # the plain chord map's rate: the largest |1 - lambda| of K0^-1 A is 2, it diverges
    rate = np.abs(1 - np.linalg.eigvals(np.linalg.solve(K0, A))).max()
    assert rate > 1.5
    u, k, ok = chord_module.chord(Ops(), np.zeros(n), None, Factor(), tol_mm=1e-12,
                                  max_iter=200, anderson=8)
    assert ok and k < 100
    assert np.abs(u - np.linalg.solve(A, b)).max() < 1e-10
    _, _, plain_ok = chord_module.chord(Ops(), np.zeros(n), None, Factor(), tol_mm=1e-12,
                                        max_iter=200, anderson=0)
    assert not plain_ok


def test_chord_polish_is_refused_in_dynamics():
    mesh = box(5.0)
    case = Case(mesh, Material(model="neo-hookean", E=6.0, nu=0.45),
                boundaries=[Boundary("xmin", "fixed"),
                            Boundary("xmax", "displacement", value=(1.0, 0.0, 0.0))])
    with pytest.raises(CaseError, match="polish='chord'"):
        admm.solve(case, polish="chord", dynamics=admm.ImplicitEuler(dt=0.05, steps=2))
    with pytest.raises(CaseError, match="polish must be"):
        admm.solve(case, polish="newton")


def _tip_block():
    """The quarter block under a sphere of test_admm_contact (cells of 0.5 mm under the tip)."""
    from tissue_reference.meshes.builders import indent_block
    from tissue_reference.model.case import Actuator
    a = Actuator("I", "tip", (0.0, 0.0, -1.0), type="indenter", tip="sphere",
                 point=(0.0, 0.0, 0.0), contact_region="top", radius=2.0)
    return Case(indent_block(0.5), Material("neo-hookean", 6.0, 0.45, density=1e-6),
                boundaries=[Boundary("bottom", "fixed"),
                            Boundary("xsym", "sliding", normal=(1.0, 0.0, 0.0)),
                            Boundary("ysym", "sliding", normal=(0.0, 1.0, 0.0))],
                actuators=[a])


def test_chord_polish_with_a_rigid_tip_equals_the_p1_reference():
    """The chord matrix with the contact stiffness of the points in contact, refactorized as they
    change: every vertex within 1e-8 mm of the reference's contact solve (dolfinx, the same
    discrete energy as UFL forms) and the same tip force."""
    import tissue_reference.fem_reference as fr
    case = _tip_block()
    push = {"I": 1.0}
    ref = fr.solve(case, degree=1, pushes=push, contact_quadrature=2,
                   settings=fr.NewtonSettings(rtol=1e-12, atol=1e-12))
    res = admm.solve(case, pushes=push, contact_quadrature=2, polish="chord",
                     polish_tol_mm=1e-9, polish_max_iter=80)
    assert ref.converged and res.converged and res.valid
    assert res.extra["polish"] == "chord" and res.extra["chord_iterations"] > 0
    assert res.extra["chord_refactorizations"] >= 1
    assert np.abs(res.u - ref.u).max() < 1e-8
    assert res.indenters["I"]["force"] == pytest.approx(ref.indenters["I"]["force"], rel=1e-7)


def test_chord_polish_releases_the_skin_when_the_tip_retracts():
    """Pushed 1 mm, then pulled back 0.5 mm above its start from that state: the skin returns
    to rest (its steps to 1e-10 mm), with no force and no contact."""
    case = _tip_block()
    pressed = admm.solve(case, pushes={"I": 1.0}, polish="chord")
    assert pressed.converged and pressed.indenters["I"]["contact_area"] > 0
    back = admm.solve(case, pushes={"I": -0.5}, initial=pressed, polish="chord",
                      polish_tol_mm=1e-10)
    ind = back.indenters["I"]
    assert back.converged and np.abs(back.u).max() < 1e-9
    assert ind["force"] == 0.0 and ind["contact_area"] == 0.0


def test_the_kept_rest_factorization_survives_later_factorizations_of_the_same_pattern(
        phantom12):
    """CHOLMOD's hook refactorizes a cached factorization of the same sparsity pattern in place:
    after a solve whose later lifts and Newton polish factorize other tangents, the kept
    factorization still solves the tangent at rest."""
    from tissue_reference.fem_reference import cholmod_factor
    from tissue_reference.solvers.admm import operators

    operators.OPERATOR_CACHE.clear()
    res = admm.solve(phantom12, pushes={"A1": 5.0, "A2": 5.0}, factorize=cholmod_factor,
                     load_steps=2, lift=True)
    assert res.converged and res.extra["newton_iterations"] > 0
    ops = operators.prepare(phantom12.with_pushes({"A1": 5.0, "A2": 5.0}))
    kept = ops.rest_tangent
    assert kept is not None and kept[0] is cholmod_factor
    K0 = ops.reduced_tangent(np.zeros(ops.N))[0]
    x = np.random.default_rng(0).normal(size=K0.shape[0])
    assert np.abs(kept[2].solve(K0 @ x) - x).max() < 1e-8 * np.abs(x).max()
