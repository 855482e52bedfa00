"""A Function's values at fixed points as one sparse matrix (``point_values.evaluation_rows``)
against dolfinx's own ``Function.eval`` (which pulls each point back and tabulates the basis on
every call), on a curved (second-order geometry) shell: points inside cells and on the flat
chords of curved boundary facets, as the facet check of a solve with tips samples them.
Units: mm."""
import numpy as np
import pytest
from mpi4py import MPI

from tissue_reference.meshes.builders import shell_octant


@pytest.fixture(scope="module")
def curved():
    from tissue_reference.fem_reference.dolfinx_mesh import to_dolfinx

    return to_dolfinx(shell_octant(4.0, inner=10.0, outer=20.0), MPI.COMM_WORLD,
                      geometry_order=2).mesh


def sample_points(mesh, rng):
    """Points inside random cells and on the chords of boundary facets (between their vertices:
    off the curved facet by its sag), with their cells."""
    import dolfinx.cpp.mesh
    import dolfinx.mesh

    tdim = mesh.topology.dim
    x = mesh.geometry.x
    geo = mesh.geometry.dofmap
    n_cells = mesh.topology.index_map(tdim).size_local
    cells = rng.integers(0, n_cells, 300).astype(np.int32)
    inside = np.array([rng.dirichlet(np.ones(tdim + 1)) @ x[geo.links(c)[:tdim + 1]]
                       for c in cells])
    mesh.topology.create_connectivity(tdim - 1, tdim)
    facets = dolfinx.mesh.exterior_facet_indices(mesh.topology)[:200]
    f2c = mesh.topology.connectivity(tdim - 1, tdim)
    corners = dolfinx.cpp.mesh.entities_to_geometry(getattr(mesh, "_mesh", mesh), tdim - 1,
                                                    facets, False)[:, :tdim]
    chord = np.array([rng.dirichlet(np.ones(tdim)) @ x[c] for c in corners])
    on = np.array([f2c.links(f)[0] for f in facets], np.int32)
    return np.vstack([inside, chord]), np.concatenate([cells, on])


@pytest.mark.parametrize("degree", [1, 2, 3])
@pytest.mark.parametrize("vector", [False, True])
def test_the_matrix_gives_function_eval_values_on_curved_cells(curved, degree, vector):
    import dolfinx.fem

    from tissue_reference.fem_reference.point_values import evaluation_rows

    mesh = curved
    space = dolfinx.fem.VectorFunctionSpace if vector else dolfinx.fem.FunctionSpace
    V = space(mesh, ("Lagrange", degree))
    f = dolfinx.fem.Function(V)
    if vector:
        f.interpolate(lambda X: np.vstack([np.sin(0.3 * X[0]) * X[1], X[2] ** 2 + X[0],
                                           np.cos(0.2 * X[1]) * X[2]]))
    else:
        f.interpolate(lambda X: np.sin(0.3 * X[0]) * X[1] + X[2] ** 2 / 40)
    pts, cells = sample_points(mesh, np.random.default_rng(degree))
    bs = V.dofmap.index_map_bs
    expected = f.eval(pts, cells).reshape(len(pts), bs)
    got = evaluation_rows(V, pts, cells) @ f.x.array.reshape(-1, bs)
    scale = np.abs(expected).max()
    assert np.abs(got - expected).max() <= 1e-12 * scale
    # a degree above 1 is not the vertices' linear interpolation there: the test sees the basis
    if degree > 1:
        P1 = space(mesh, ("Lagrange", 1))
        g = dolfinx.fem.Function(P1)
        g.interpolate(f)
        assert np.abs(g.eval(pts, cells).reshape(len(pts), bs) - expected).max() > 1e-4 * scale


def test_mismatched_points_and_cells_are_refused(curved):
    import dolfinx.fem

    from tissue_reference.fem_reference.point_values import evaluation_rows

    V = dolfinx.fem.FunctionSpace(curved, ("Lagrange", 1))
    with pytest.raises(ValueError, match="3 points but 2 cells"):
        evaluation_rows(V, np.zeros((3, 3)), np.zeros(2, np.int32))
    assert evaluation_rows(V, np.zeros((0, 3)), np.zeros(0, np.int32)).shape[0] == 0
