"""J_s from the reference's degree-2 exact tangent (dirichlet_jacobian with the P2 interpolation and
the regions' edge nodes) against central finite differences of degree-2 reference solves, at a
pushed (nonlinear) state of a small structured column (324 tets, no gmsh), with one target off the
mesh vertices so that the P2 edge-node weights are exercised."""
import numpy as np
import pytest

pytest.importorskip("dolfinx")

from test_control_support import column_case

from tissue_reference.control.dof_maps import p2_interpolation
from tissue_reference.control.jacobian import full_pushes, max_rel_error
from tissue_reference.control.plants import full_warm_start, plant_for, reference_state
from tissue_reference.control.plants import jacobian_at as compute
from tissue_reference.fem_reference import solve


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
    assert p2["fd_max_rel_error"] < 1e-4              # the Jacobian's accuracy target (measured 3e-7)
    # the check has teeth: the degree-1 J_s of this coarse mesh differs from it by several %
    p1 = compute(case, state, solver="fem", degree=1, fd_h=0)
    assert max_rel_error(p1["J"], p2["J"]) > 1e-2


def test_a_degree2_plant_warm_starts_from_its_own_full_state(case):
    # the loop hands a plant the vertex field of its previous answer; the reference plant must
    # start from that answer's full nodal state (edge nodes, pressure), and reach the same answer
    # as a cold solve: checked on a mixed P2/P1 column (nu = 0.495)
    c = case.with_material(nu=0.495)
    seen = []

    def spy(cc, pushes, initial):
        seen.append(initial)
        return solve(cc, pushes=pushes, initial=initial)

    plant = full_warm_start(spy)
    r1 = plant(c, full_pushes(c, {"A1": 1.0}), None)
    r2 = plant(c, full_pushes(c, {"A1": 1.3}), r1.u)
    assert seen[1] is r1                             # the full answer, not its vertex values
    other = np.array(r1.u, copy=True)                # a vertex field it did not produce
    plant(c, full_pushes(c, {"A1": 1.3}), other)
    assert seen[2] is other
    # an earlier answer's vertex field (a loop gives earlier answers back where a load repeats)
    plant(c, full_pushes(c, {"A1": 1.2}), r1.u)
    assert seen[3] is r1
    cold = plant_for("fem")(c, full_pushes(c, {"A1": 1.3}), None)
    assert cold.discretization["formulation"] == "mixed"
    assert np.abs(r2.u - cold.u).max() < 1e-8 * max(1.0, np.abs(cold.u).max())
    assert np.abs(r2.u).max() > 0.1                  # a real push, not the rest state
