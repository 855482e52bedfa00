"""Second-order (curved) geometry: mid-edge nodes on the true surface, isoparametric cells in the
reference, folding edges straightened. Checked against exact volumes and surface positions."""
import numpy as np
import pytest
from mpi4py import MPI

from tissue_reference.meshes.builders import box, shell_octant
from tissue_reference.meshes.curved import p2_cells, validate
from tissue_reference.meshes.mesh import MeshData

A, B = 10.0, 20.0


@pytest.fixture(scope="module")
def shell():
    return shell_octant(2.5, inner=A, outer=B)


def test_builtin_curved_mesh_has_its_edge_nodes_on_the_spheres(shell):
    assert shell.geometry_order == 2
    r = np.linalg.norm(shell.curved_points, axis=1)
    on = np.minimum(abs(r - A), abs(r - B))
    assert on.max() < 1e-9 * B
    # every edge of the two spherical surfaces is curved, nothing else is
    f = np.concatenate([shell.facet_regions["inner"], shell.facet_regions["outer"]])
    e = np.unique(np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [0, 2]]]), axis=1),
                  axis=0)
    assert len(shell.curved_edges) == len(e)


def volume(md, order):
    import dolfinx.fem
    import ufl

    from tissue_reference.fem_reference.dolfinx_mesh import to_dolfinx

    mesh = to_dolfinx(md, MPI.COMM_WORLD, geometry_order=order).mesh
    one = dolfinx.fem.Constant(mesh, 1.0)
    return dolfinx.fem.assemble_scalar(dolfinx.fem.form(one * ufl.dx(domain=mesh, metadata={
        "quadrature_degree": 4})))


def test_isoparametric_volume_converges_to_the_exact_shell_volume_much_faster(shell):
    exact = np.pi / 6 * (B ** 3 - A ** 3)
    straight = volume(shell, 1)
    curved = volume(shell, 2)
    assert abs(straight / exact - 1) > 2e-3  # the polyhedron misses 0.36 % of the volume
    assert abs(curved / exact - 1) < 1e-4


def test_box_has_no_curved_edges_and_p2_cells_are_straight_midpoints():
    m = box(5.0)
    assert m.geometry_order == 1
    x, cells, _ = p2_cells(m)
    mids = 0.5 * (x[cells[:, 2]] + x[cells[:, 3]])  # edge e0 = (2, 3) in dolfinx's order
    np.testing.assert_allclose(x[cells[:, 4]], mids)


def test_an_edge_node_that_folds_its_cell_is_straightened():
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    cells = np.array([[0, 1, 2, 3]])
    good = MeshData(pts, cells, curved_edges=np.array([[0, 1]]),
                    curved_points=np.array([[0.5, -0.05, 0.0]]))
    bad = MeshData(pts, cells, curved_edges=np.array([[0, 1], [1, 2]]),
                   curved_points=np.array([[0.5, -0.05, 0.0], [0.1, 0.1, 0.0]]))
    assert validate(good)[1] == 0
    fixed, n = validate(bad)
    assert n >= 1 and fixed.geometry_order <= 2
    assert validate(fixed)[1] == 0
