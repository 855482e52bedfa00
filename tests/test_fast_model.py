"""The controller's fast model (chord Newton on the ADMM model's P1 energy, Jacobian by
refinement) follows the pushes to the state a full ADMM solve finds and gives its Jacobian:
checked against central differences of full ADMM solves (no tangent involved) and against the
Jacobian of the assembled exact tangent, along a sequence of pushes like a loop's."""
import json

import numpy as np
import pytest

from tissue_reference.control.fast_model import FastModel
from tissue_reference.control.jacobian import dirichlet_jacobian, fd_jacobian
from tissue_reference.control.plants import ADMM_CONTROL_OPTIONS, plant_for
from tissue_reference.model.case import load_case
from tissue_reference.solvers.admm import solve, tangent_stiffness
from tissue_reference.tissue.cli import main

CASE = "meshes/cases/phantom.toml"
ACTS = ("A1", "A2", "A3", "A4")


@pytest.fixture(scope="module")
def case():
    return load_case(CASE, size=12.0)


def _pushes(k):
    """A loop-like path: A1 and A3 growing by 0.1 / 0.07 mm a step, A2 starting late."""
    return {"A1": 0.5 + 0.1 * k, "A2": max(0.0, 0.05 * (k - 4)), "A3": 0.07 * k, "A4": 0.0}


@pytest.mark.parametrize("factorize", [None, "cholmod"])
def test_state_and_jacobian_match_full_solves_along_a_path(case, factorize):
    """SuperLU (the default) and CHOLMOD through the ``factorize`` hook alike."""
    hook = None
    if factorize == "cholmod":
        from tissue_reference.fem_reference import cholmod_factor
        from tissue_reference.fem_reference.factor import has_cholmod
        if not has_cholmod():
            pytest.skip("this PETSc has no CHOLMOD")
        hook = cholmod_factor
    m = FastModel(case, "T2", factorize=hook)
    admm = plant_for("admm")
    for k in range(12):
        p = _pushes(k)
        J = m.jacobian(p)
        if k not in (0, 6, 11):
            continue
        full = solve(case, pushes=p, **ADMM_CONTROL_OPTIONS)
        assert np.abs(m.u - full.u).max() < 1e-5            # mm
        pushed = case.with_pushes(p)
        exact = dirichlet_jacobian(pushed, tangent_stiffness(pushed, full.u), targets=["T2"]).J
        assert np.abs(J - exact).max() < 1e-3 * np.abs(exact).max()
        if k == 6:   # central differences of full solves: second-order error h^2 ~ 4e-4
            fd = fd_jacobian(admm, case, p, h=0.02, initial=full.u, targets=["T2"]).J
            assert np.abs(J - fd).max() < 2e-3 * np.abs(fd).max()
    assert m.fallbacks == 0 and len(m.timings) == 12
    assert all(t["state"] >= 0 and t["jacobian"] >= 0 for t in m.timings)
    # the hook's factorization is the one in use (SuperLU's has no ``ksp``)
    assert hasattr(m._F, "ksp") == (hook is not None)


def test_a_looser_state_tolerance_keeps_the_state_within_it(case):
    """``state_tol_mm=1e-3`` (the accuracy the fast solvers are held to): every state along the
    path within 1e-3 mm of a full ADMM solve's, in fewer chord iterations than the default's."""
    from tissue_reference.errors import CaseError
    counts = {}
    for tol in (1e-3, None):
        m = FastModel(case, "T2") if tol is None else \
            FastModel(case, "T2", state_tol_mm=np.float32(tol))   # any real number type
        for k in range(8):
            p = _pushes(k)
            m.jacobian(p)
            if tol is not None and k in (3, 7):
                full = solve(case, pushes=p, **ADMM_CONTROL_OPTIONS)
                assert np.abs(m.u - full.u).max() < tol
        counts[tol] = m.chord_iterations
        assert m.fallbacks == 0
    assert counts[1e-3] < counts[None]
    for bad in (0.0, 1.5, True, "1e-3"):
        with pytest.raises(CaseError, match="state_tol_mm"):
            FastModel(case, "T2", state_tol_mm=bad)


def test_a_jump_it_cannot_follow_falls_back_to_a_full_solve(case):
    """From rest to all four at 15 mm in one step (a jump no loop makes; 5 mm the chord
    iterations still follow with one refactorization): the predictor folds cells, the chord
    iterations give up and a full ADMM solve, started cold, takes over."""
    m = FastModel(case, "T1")
    m.jacobian(dict.fromkeys(ACTS, 0.0))
    far = {"A1": 15.0, "A2": 15.0, "A3": 15.0, "A4": 15.0}
    J = m.jacobian(far)
    assert m.fallbacks == 1 and "full ADMM solve" in m.retries[0]
    full = solve(case, pushes=far, **ADMM_CONTROL_OPTIONS)
    assert np.abs(m.u - full.u).max() < 1e-5
    pushed = case.with_pushes(far)
    exact = dirichlet_jacobian(pushed, tangent_stiffness(pushed, full.u), targets=["T1"]).J
    assert np.abs(J - exact).max() < 1e-3 * np.abs(exact).max()


def test_a_loop_with_the_fast_model_gives_the_solve_models_rows(tmp_path):
    base = ["mpc", CASE, "--size", "14", "--target", "T1", "--task", "1", "--steps", "8",
            "--task-mm", "0.3", "--weights", "gain", "--plant", "fem", "--model", "admm",
            "--model-E-factor", "1.2", "-q"]
    runs = {}
    for update in ("fast", "solve"):
        js = tmp_path / f"{update}.json"
        assert main(base + ["--model-update", update, "--json", str(js)]) == 0
        runs[update] = json.loads(js.read_text())
    assert runs["fast"]["model_update"] == "fast" and runs["solve"]["model_update"] == "solve"
    a = np.array(runs["fast"]["actuator_positions_mm"])
    b = np.array(runs["solve"]["actuator_positions_mm"])
    assert np.abs(a - b).max() < 1e-4 * max(1.0, np.abs(b).max())
    assert runs["fast"]["steady_state_error_mm"] == pytest.approx(
        runs["solve"]["steady_state_error_mm"], rel=1e-3, abs=1e-6)
