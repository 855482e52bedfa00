"""ADMM as the controller's model (control.plants.ADMM_CONTROL_OPTIONS): the states it returns
along a push sequence with sub-mm steps meet the prescribed pushes, and J_s from its tangent matches
central finite differences of its own solves."""
import numpy as np
import pytest
from test_control_support import column_case

from tissue_reference.control.jacobian import (
    dirichlet_jacobian,
    fd_jacobian,
    full_pushes,
    max_rel_error,
)
from tissue_reference.control.loop import check_prescribed
from tissue_reference.control.plants import plant_for
from tissue_reference.solvers.admm import tangent_stiffness


@pytest.fixture(scope="module")
def case():
    return column_case()


def test_warm_started_sequence_meets_the_pushes(case):
    admm = plant_for("admm")
    u = None
    for a in (0.0, 1.5, 3.0, 3.2, 3.3, 3.35):      # steps of 1.5 mm down to 0.05 mm
        p = full_pushes(case, {"A1": a, "A2": a / 3})
        r = admm(case, p, u)
        check_prescribed(case, p, r, "admm")
        u = r.u


def test_admm_model_jacobian_matches_central_fd_of_its_solves(case):
    admm = plant_for("admm")
    st = full_pushes(case, {"A1": 3.0, "A2": 1.0})
    r = admm(case, st, None)
    pushed = case.with_pushes(st)
    J = dirichlet_jacobian(pushed, tangent_stiffness(pushed, r.u))
    fd = fd_jacobian(admm, case, st, h=0.01, initial=r.u)
    assert max_rel_error(J.J, fd.J) < 1e-4
    assert np.abs(J.J).max() > 0.1


@pytest.mark.slow
def test_admm_model_follows_the_reference_branch_under_opposing_pushes():
    # phantom (model mesh of the mismatch runs), A1 and A3 squeezing along x: the ADMM model's
    # warm-started sequence must end on the reference's solution (a 1000-iteration ADMM stage
    # ended on a stationary point with 17% more strain energy)
    pytest.importorskip("dolfinx")
    from test_control_support import phantom

    import tissue_reference.fem_reference as fr

    case = phantom()
    case = case.with_material(E=1.2 * case.material.E)      # the mismatch runs' model
    admm = plant_for("admm")
    u = None
    for a in (0, 3, 6, 9, 12, 15, 18, 20, 22, 23, 24, 25):
        p = full_pushes(case, {"A1": a, "A3": a / 2, "A4": a * 2.27 / 26.2})
        r = admm(case, p, u)
        check_prescribed(case, p, r, "admm")
        u = r.u
    ref = fr.solve(case, pushes=p)
    assert r.strain_energy == pytest.approx(ref.strain_energy, rel=1e-6)
    np.testing.assert_allclose(r.probes["T1"], ref.probes["T1"], atol=1e-5)
