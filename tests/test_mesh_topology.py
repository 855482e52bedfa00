"""A mesh's edge topology (``MeshData.edge_topology``) against brute force: its edges are the
vertex pairs of its cells, each cell pair points at its edge with the right orientation, and the
block CSR pattern places vertex and edge blocks where a loop over the blocks puts them."""
import numpy as np
import pytest

from tissue_reference.meshes.builders import box, rectangle
from tissue_reference.meshes.mesh import cell_pairs


@pytest.mark.parametrize("mesh", [box(4.0), rectangle(2.0)], ids=["3d", "2d"])
def test_edges_pairs_and_block_pattern_against_brute_force(mesh):
    top = mesh.edge_topology
    assert mesh.edge_topology is top                              # computed once, kept
    n, d = mesh.n_vertices, mesh.gdim
    pairs = {tuple(sorted((int(c[a]), int(c[b])))) for c in mesh.cells
             for a, b in zip(*cell_pairs(d))}
    assert [tuple(e) for e in top.edges.tolist()] == sorted(pairs)
    a, b = cell_pairs(d)
    first, second = mesh.cells[:, a].reshape(-1), mesh.cells[:, b].reshape(-1)
    e = top.edges[top.pair_edge]
    lo, hi = np.where(top.pair_flipped, second, first), np.where(top.pair_flipped, first, second)
    assert np.array_equal(e[:, 0], lo) and np.array_equal(e[:, 1], hi)
    rng = np.random.default_rng(2)
    T_ii, T_ij = rng.standard_normal((n, d, d)), rng.standard_normal((len(top.edges), d, d))
    dense = np.zeros((n * d, n * d))
    for v in range(n):
        dense[d * v:d * v + d, d * v:d * v + d] = T_ii[v]
    for k, (i, j) in enumerate(top.edges.tolist()):
        dense[d * i:d * i + d, d * j:d * j + d] = T_ij[k]
        dense[d * j:d * j + d, d * i:d * i + d] = T_ij[k].T
    K = top.block_csr(T_ii, T_ij)
    assert K.has_sorted_indices and np.array_equal(K.toarray(), dense)


def test_the_kept_volumes_give_the_jacobians_of_the_deformed_cells():
    """``deformation_state`` divides by the kept reference volumes: its smallest J is the
    smallest ratio of deformed to reference cell measure, computed here from determinants."""
    from tissue_reference.meshes.mesh import deformation_state
    for mesh in (box(4.0), rectangle(2.0)):
        u = 0.3 * np.random.default_rng(1).standard_normal(mesh.points.shape)
        x0, x1 = mesh.points[mesh.cells], (mesh.points + u)[mesh.cells]
        J = (np.linalg.det(x1[:, 1:] - x1[:, :1]) / np.linalg.det(x0[:, 1:] - x0[:, :1]))
        state = deformation_state(mesh, u)
        assert state["min_J"] == pytest.approx(J.min(), rel=1e-10)
        assert state["inverted_cells"] == int(np.count_nonzero(J <= 0))


def test_a_mesh_owns_read_only_copies_of_its_arrays():
    """A caller's arrays changed after the mesh was made do not change it (nor what it keeps),
    and the mesh's own cannot be changed in place."""
    from tissue_reference.meshes.mesh import MeshData
    ref = box(4.0)
    pts, cells = ref.points.copy(), ref.cells.copy()
    mesh = MeshData(pts, cells)
    vol = mesh.reference_volumes.copy()
    pts *= 2.0
    cells[:] = cells[::-1]
    assert np.array_equal(mesh.points, ref.points) and np.array_equal(mesh.cells, ref.cells)
    assert np.array_equal(mesh.reference_volumes, vol)
    with pytest.raises(ValueError, match="read-only"):
        mesh.points[0, 0] = 1.0


def test_a_vertex_id_out_of_range_is_named_with_its_cell():
    from tissue_reference.errors import CaseError
    from tissue_reference.meshes.mesh import edge_topology
    mesh = box(4.0)
    cells = mesh.cells.copy()
    cells[7, 2] = mesh.n_vertices + 3
    with pytest.raises(CaseError, match=rf"cell 7 has \[{mesh.n_vertices + 3}\]"):
        edge_topology(cells, mesh.n_vertices)
