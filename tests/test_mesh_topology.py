"""A mesh's edge topology (``MeshData.edge_topology``) against brute force: its edges are the
vertex pairs of its cells, each cell pair points at its edge with the right orientation, and the
block CSR pattern places vertex and edge blocks where a loop over the blocks puts them."""
import numpy as np
import pytest

from tissue_reference.meshes.builders import box, rectangle
from tissue_reference.meshes.mesh import cell_pairs, cell_volumes


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


def test_reference_volumes_are_the_cell_volumes_kept():
    mesh = box(4.0)
    assert np.array_equal(mesh.reference_volumes, cell_volumes(mesh.points, mesh.cells))
    assert mesh.reference_volumes is mesh.reference_volumes
