"""The degree-2 reference tangent at a pushed (nonlinear) state is the tangent at the solver's own
P2 state: ``tangent_stiffness(case, res, degree=2)`` from the SolveResult (which carries the full
nodal state) equals the tangent the control Jacobian uses and a finite difference of the degree-2
residual, while vertex values alone (whose edge-node midpoint means are not the P2 solution) are
refused."""
import numpy as np
import pytest

pytest.importorskip("dolfinx")

from test_control_support import column_case

import tissue_reference.fem_reference as fr
from tissue_reference.control.jacobian import full_pushes
from tissue_reference.control.plants import reference_state
from tissue_reference.errors import CaseError

STATE = {"A1": 3.0, "A2": 1.0}


@pytest.fixture(scope="module")
def solved():
    case = column_case()
    st = full_pushes(case, STATE)
    res, T, _ = reference_state(case, st, degree=2)
    return case, st, res, T


def test_result_carries_the_p2_state_in_tangent_node_order(solved):
    case, _, res, T = solved
    nv = case.mesh.n_vertices
    nodes = res.node_u
    assert nodes.shape == T.node_points.shape and nodes.shape[0] > nv
    np.testing.assert_array_equal(res.node_points, T.node_points)
    np.testing.assert_array_equal(nodes[:nv], res.u)
    # arrays: the JSON form leaves them out
    assert "node_u" not in res.to_json_dict()


def test_degree2_tangent_from_the_solve_result_is_the_tangent_at_the_solution(solved):
    case, st, res, T = solved
    K = T.K                                            # the solver's own state (control Jacobian)
    for u in (res, res.node_u):
        K2 = fr.tangent_stiffness(case, u, degree=2, pushes=st).K
        assert abs(K2 - K).max() <= 1e-10 * abs(K).max()
    # the old reconstruction (edge nodes = mean of their end vertices) is far off at this state
    s = fr.ReferenceSolver(case, degree=2)
    s.set_state(res.u)                               # warm-start path: P1 field into P2
    Kmid = s.tangent(None, pushes=st).K
    assert abs(Kmid - K).max() > 1e-3 * abs(K).max()


def test_degree2_tangent_is_the_finite_difference_of_the_degree2_residual(solved):
    case, st, res, _ = solved
    s = fr.ReferenceSolver(case, degree=2)
    U = res.node_u
    K = s.tangent(U, pushes=st).K
    rng = np.random.default_rng(1)
    h = 1e-6
    nv = case.mesh.n_vertices
    # columns of edge-node dofs (what the vertex values could not say) and of vertex dofs
    cols = np.concatenate([rng.choice(np.arange(3 * nv, U.size), 4, replace=False),
                           rng.choice(3 * nv, 2, replace=False)])
    for j in cols:
        up, um = U.copy().ravel(), U.copy().ravel()
        up[j] += h
        um[j] -= h
        fd = (s.internal_forces(up.reshape(U.shape)) - s.internal_forces(um.reshape(U.shape))) \
            / (2 * h)
        col = K[:, j].toarray().ravel()
        np.testing.assert_allclose(col, fd, atol=1e-6 * np.abs(col).max())


def test_degree2_tangent_refuses_vertex_values_away_from_rest(solved):
    case, st, res, _ = solved
    with pytest.raises(CaseError, match="edge nodes"):
        fr.tangent_stiffness(case, res.u, degree=2, pushes=st)
    with pytest.raises(CaseError, match="SolveResult of a degree-2"):
        fr.ReferenceSolver(case, degree=2).internal_forces(res.u)
    # rest: midpoints are exact, vertex values (or None) still accepted
    nv = case.mesh.n_vertices
    K0 = fr.tangent_stiffness(case, np.zeros((nv, 3)), degree=2).K
    assert abs(K0 - fr.tangent_stiffness(case, degree=2).K).max() == 0
    # degree 1 keeps taking vertex values
    assert fr.tangent_stiffness(case, res.u, degree=1).K.shape == (3 * nv, 3 * nv)
