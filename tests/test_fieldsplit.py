"""The iterative saddle-point solver of the mixed formulation (FGMRES + Schur-complement
fieldsplit) gives the direct solver's answer."""
import numpy as np
import pytest

import tissue_reference.fem_reference as fr
from tissue_reference.model.case import load_case


@pytest.fixture(scope="module")
def case():
    return load_case("meshes/cases/phantom.toml", size=12).with_material(nu=0.49)


def test_fieldsplit_matches_the_direct_mixed_solve(case):
    a = fr.solve(case, pushes={"A1": 4.0}, formulation="mixed", linear_solver="direct")
    b = fr.solve(case, pushes={"A1": 4.0}, formulation="mixed", linear_solver="fieldsplit")
    assert b.extra["linear_solver"] == "fieldsplit" and b.converged
    # the preconditioner is lagged: built fewer times than there are Newton iterations
    assert 1 <= b.extra["preconditioner_builds"] < b.iterations
    for k in a.probes:
        assert np.linalg.norm(a.probes[k] - b.probes[k]) < 1e-8
    for r in a.reactions:
        assert np.allclose(a.reactions[r], b.reactions[r], atol=1e-6)


def test_a_lagged_preconditioner_that_stops_paying_is_rebuilt(case, monkeypatch):
    """With no growth allowed, every lagged solve that needs more iterations than its fresh one
    triggers a rebuild; the answer is the same."""
    from tissue_reference.fem_reference import saddle

    monkeypatch.setattr(saddle, "LAG_GROWTH", 0.0)
    monkeypatch.setattr(saddle, "LAG_MIN_ITS", 0)
    a = fr.solve(case, pushes={"A1": 4.0}, formulation="mixed", linear_solver="fieldsplit")
    monkeypatch.undo()
    b = fr.solve(case, pushes={"A1": 4.0}, formulation="mixed", linear_solver="fieldsplit")
    assert a.extra["preconditioner_builds"] > b.extra["preconditioner_builds"]
    for k in a.probes:
        assert np.linalg.norm(a.probes[k] - b.probes[k]) < 1e-8


def test_fieldsplit_is_for_the_mixed_formulation_only(case):
    from tissue_reference.errors import CaseError

    with pytest.raises(CaseError, match="fieldsplit"):
        fr.solve(case.with_material(nu=0.45), pushes={"A1": 1.0}, formulation="displacement",
                 linear_solver="fieldsplit")
