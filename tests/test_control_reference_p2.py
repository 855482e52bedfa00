"""J_s from the reference's degree-2 exact tangent (dirichlet_jacobian with the P2 interpolation and
the regions' edge nodes) against central finite differences of degree-2 reference solves, at a
pushed (nonlinear) state of a small structured column (324 tets, no gmsh), with one target off the
mesh vertices so that the P2 edge-node weights are exercised."""
import numpy as np
import pytest

pytest.importorskip("dolfinx")

from control.jacobian import full_pushes, max_rel_error, p2_interpolation  # noqa: E402
from meshes.case import Actuator, Boundary, Case, Material, Probe  # noqa: E402
from meshes.mesh import MeshData  # noqa: E402
from tissue.cmd_jacobian import compute, reference_state  # noqa: E402

L, H = 10.0, 20.0   # mm


def column(n=3, nz=6) -> MeshData:
    """[0, L]^2 x [0, H] cut into n x n x nz cubes of 6 (Kuhn) tets; facet regions: ``base``
    (z = 0), ``pad_x`` (x = L, y < L/2, z > H/2), ``pad_y`` (y = L, x < L/2, z > H/2): the two pads
    share no vertex with each other or with the base."""
    xs, zs = np.linspace(0, L, n + 1), np.linspace(0, H, nz + 1)
    X = np.array([(x, y, z) for z in zs for y in xs for x in xs])

    def vid(i, j, k):
        return (k * (n + 1) + j) * (n + 1) + i
    kuhn = [(0, 1, 3, 7), (0, 1, 5, 7), (0, 2, 3, 7), (0, 2, 6, 7), (0, 4, 5, 7), (0, 4, 6, 7)]
    cells = []
    for k in range(nz):
        for j in range(n):
            for i in range(n):
                c = [vid(i + a, j + b, k + e) for e in (0, 1) for b in (0, 1) for a in (0, 1)]
                cells += [[c[q] for q in t] for t in kuhn]
    cells = np.array(cells)
    e = X[cells[:, 1:]] - X[cells[:, :1]]
    neg = np.einsum("ij,ij->i", np.cross(e[:, 0], e[:, 1]), e[:, 2]) < 0
    cells[neg] = cells[neg][:, [1, 0, 2, 3]]
    faces = np.sort(np.concatenate([cells[:, f] for f in ([0, 1, 2], [0, 1, 3], [0, 2, 3],
                                                          [1, 2, 3])]), axis=1)
    uniq, count = np.unique(faces, axis=0, return_counts=True)
    bnd = uniq[count == 1]
    P = X[bnd]
    tol = 1e-9
    top = P[:, :, 2] > H / 2 - tol
    regions = {"base": bnd[np.all(np.abs(P[:, :, 2]) < tol, axis=1)],
               "pad_x": bnd[np.all((np.abs(P[:, :, 0] - L) < tol) & (P[:, :, 1] < L / 2) & top,
                                   axis=1)],
               "pad_y": bnd[np.all((np.abs(P[:, :, 1] - L) < tol) & (P[:, :, 0] < L / 2) & top,
                                   axis=1)]}
    return MeshData(X, cells, facet_regions=regions, cell_regions={"tissue": np.arange(len(cells))})


@pytest.fixture(scope="module")
def case():
    return Case(mesh=column(), material=Material("neo-hookean", E=6.0, nu=0.45),
                boundaries=(Boundary("base", "fixed"),),
                actuators=(Actuator("A1", "pad_x", (-1.0, 0.0, 0.0)),
                           Actuator("A2", "pad_y", (0.0, -1.0, 0.0))),
                probes=(Probe("T1", (5.0, 5.0, 15.0)), Probe("P", (4.3, 6.1, 13.7))),
                name="column")


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
