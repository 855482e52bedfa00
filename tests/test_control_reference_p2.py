"""J_s from the reference's degree-2 exact tangent (dirichlet_jacobian with the P2 interpolation and
the regions' edge nodes) against central finite differences of degree-2 reference solves, at a
pushed (nonlinear) state of a small structured column (324 tets, no gmsh), with one target off the
mesh vertices so that the P2 edge-node weights are exercised."""
import numpy as np
import pytest

pytest.importorskip("dolfinx")

from test_control_support import column_case

from tissue_reference.control.jacobian import full_pushes, max_rel_error, p2_interpolation
from tissue_reference.control.plants import jacobian_at as compute
from tissue_reference.control.plants import reference_state


@pytest.fixture(scope="module")
def case():
    return column_case()


def test_off_vertex_probe_uses_its_cells_edge_nodes(case):
    loc = {p.name: p for p in case.probe_locations}["P"]
    assert np.all(loc.weights > 1e-3)                 # strictly inside its cell
    _, T, _ = reference_state(case, full_pushes(case), degree=2)
    row = p2_interpolation(case, T.node_points).getrow(3).toarray().ravel()   # P.x
    assert np.count_nonzero(row[3 * case.mesh.n_vertices:]) == 6


def test_degree2_dirichlet_jacobian_matches_central_fd_of_degree2_solves(case):
    state = {"A1": 3.0, "A2": 1.0}                    # 30% / 10% of the pad-to-axis width
    p2 = compute(case, state, solver="fem", degree=2, fd_h=0.01)
    assert p2["degree"] == 2 and p2["actuators"] == ["A1", "A2"]
    assert np.asarray(p2["J"]).shape == (6, 2)
    assert p2["fd_max_rel_error"] < 1e-4              # issue 4 figure (measured 3e-7)
    # the check has teeth: the degree-1 J_s of this coarse mesh differs from it by several %
    p1 = compute(case, state, solver="fem", degree=1, fd_h=0)
    assert max_rel_error(p1["J"], p2["J"]) > 1e-2
