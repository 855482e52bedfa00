"""The chord polish of the ADMM solver (``solvers.admm.chord``): chord steps on the tangent at
rest, Anderson-mixed, against the P1 reference (dolfinx, an independent implementation of the
same discrete energy) and against a linear map whose fixed point is solved directly."""
import numpy as np
import pytest
import scipy.sparse as sp

from tissue_reference.meshes.builders import box
from tissue_reference.meshes.case import Boundary, Case, Material, load_case
from tissue_reference.meshes.errors import CaseError
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

        def residual(self, u, fext):
            return A @ u - b

        def residual_if_valid(self, u, fext):
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


def test_chord_polish_is_refused_with_rigid_tips_and_in_dynamics():
    tips = load_case("phantom-indenter-control")
    with pytest.raises(CaseError, match="polish='chord'"):
        admm.solve(tips, pushes={"A1": 1.0}, polish="chord")
    mesh = box(5.0)
    case = Case(mesh, Material(model="neo-hookean", E=6.0, nu=0.45),
                boundaries=[Boundary("xmin", "fixed"),
                            Boundary("xmax", "displacement", value=(1.0, 0.0, 0.0))])
    with pytest.raises(CaseError, match="polish='chord'"):
        admm.solve(case, polish="chord", dynamics=admm.ImplicitEuler(dt=0.05, steps=2))
    with pytest.raises(CaseError, match="polish must be"):
        admm.solve(case, polish="newton")


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
