"""Second-order (curved) geometry of a simplex mesh: the mid-edge nodes that gmsh places on the
true curved boundary when it meshes with order 2.

A MeshData keeps its linear cells (what every solver uses) and, optionally, ``curved_edges`` (k, 2
vertex ids) with ``curved_points`` (k, gdim, mm): the edges whose mid-edge node is off the straight
midpoint. Every other edge is straight. ``p2_cells`` turns that into isoparametric P2 cells in the
node order of dolfinx (basix): vertices, then edges e0..e5 = (2,3), (1,3), (1,2), (0,3), (0,2),
(0,1) on a tetrahedron, e0..e2 = (1,2), (0,2), (0,1) on a triangle.

A curved edge that would fold a cell (the quadratic map's Jacobian not positive at the cell's
nodes) is straightened, and counted: ``validate`` returns the mesh and that count.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

__all__ = ["EDGES", "FACET_EDGES", "from_high_order_cells", "p2_cells", "p2_facets", "validate"]

EDGES = {3: ((2, 3), (1, 3), (1, 2), (0, 3), (0, 2), (0, 1)), 2: ((1, 2), (0, 2), (0, 1))}
FACET_EDGES = {3: ((1, 2), (0, 2), (0, 1)), 2: ()}
# meshio's (VTK) order of the mid-edge nodes of tetra10 / triangle6 after the corners
MESHIO_EDGES = {3: ((0, 1), (1, 2), (0, 2), (0, 3), (1, 3), (2, 3)), 2: ((0, 1), (1, 2), (0, 2))}


def from_high_order_cells(points, cells_ho, gdim):
    """(corner cells, curved_edges, curved_points) from second-order cells in meshio's order
    (tetra10 / triangle6) over ``points`` (all nodes). Edges whose node is within 1e-9 of their
    length of the straight midpoint are left out (straight)."""
    nv = gdim + 1
    corners = np.asarray(cells_ho[:, :nv], np.int64)
    pairs, nodes = [], []
    for k, (a, b) in enumerate(MESHIO_EDGES[gdim]):
        pairs.append(np.sort(corners[:, [a, b]], axis=1))
        nodes.append(cells_ho[:, nv + k])
    pairs = np.concatenate(pairs)
    nodes = np.concatenate(nodes).astype(np.int64)
    pairs, first = np.unique(pairs, axis=0, return_index=True)
    x = points[nodes[first]]
    mid = 0.5 * (points[pairs[:, 0]] + points[pairs[:, 1]])
    length = np.linalg.norm(points[pairs[:, 1]] - points[pairs[:, 0]], axis=1)
    off = np.linalg.norm(x - mid, axis=1)
    if np.any(off > 2.0 * length):
        raise ValueError("second-order cells: a mid-edge node lies farther from its edge's "
                         "midpoint than twice the edge (node order not understood)")
    # an edge bent by more than half its length is too coarse for its curvature: kept straight
    keep = (off > 1e-9 * length) & (off <= 0.5 * length)
    return corners, pairs[keep], x[keep]


def _edge_index(mesh):
    """Unique edges (sorted vertex pairs), each edge's node coordinates (curved where given) and
    the (m, n_edges) edge index of every cell in EDGES order."""
    d = mesh.gdim
    cells = mesh.cells
    local = EDGES[d]
    pairs = np.concatenate([np.sort(cells[:, [a, b]], axis=1) for a, b in local])
    uniq, inv = np.unique(pairs, axis=0, return_inverse=True)
    cell_edges = inv.reshape(len(local), len(cells)).T
    X = mesh.points
    nodes = 0.5 * (X[uniq[:, 0]] + X[uniq[:, 1]])
    if mesh.geometry_order == 2:
        n = len(X)
        key = uniq[:, 0] * n + uniq[:, 1]
        ck = np.sort(mesh.curved_edges, axis=1)
        ck = ck[:, 0] * n + ck[:, 1]
        pos = np.searchsorted(key, ck)
        ok = (pos < len(key)) & (key[np.minimum(pos, len(key) - 1)] == ck)
        nodes[pos[ok]] = mesh.curved_points[ok]
    return uniq, nodes, cell_edges


def p2_cells(mesh):
    """(x, cells): node coordinates (vertices first, then one node per edge) and the (m, 10) or
    (m, 6) isoparametric cells in dolfinx's node order."""
    uniq, nodes, cell_edges = _edge_index(mesh)
    nv = mesh.n_vertices
    x = np.vstack([mesh.points, nodes])
    return x, np.hstack([mesh.cells, nv + cell_edges]), uniq


def p2_facets(mesh, facets, edges):
    """Second-order facets (k, 6) / (k, 3) of linear boundary facets (k, gdim), node ids as in
    ``p2_cells`` (``edges``: its unique edge table)."""
    d = mesh.gdim
    nv = mesh.n_vertices
    n = nv
    key = edges[:, 0] * n + edges[:, 1]
    cols = [facets]
    for a, b in FACET_EDGES[d] if d == 3 else ((0, 1),):
        pr = np.sort(facets[:, [a, b]], axis=1)
        cols.append((nv + np.searchsorted(key, pr[:, 0] * n + pr[:, 1]))[:, None])
    return np.hstack(cols)


def _p2_grad_ref(d):
    """Gradients of the P2 Lagrange basis (dolfinx order) at the P2 nodes of the reference
    simplex: array (n_points, n_basis, d)."""
    if d == 3:
        verts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    else:
        verts = np.array([[0, 0], [1, 0], [0, 1]], float)
    pts = np.vstack([verts] + [0.5 * (verts[a] + verts[b]) for a, b in EDGES[d]])
    # barycentric coordinates l0 = 1 - sum(x), l_i = x_{i-1}; gradients constant
    gl = np.vstack([-np.ones(d), np.eye(d)])

    def lam(p):
        return np.concatenate([[1 - p.sum()], p])

    out = np.zeros((len(pts), len(pts), d))
    for q, p in enumerate(pts):
        l_ = lam(p)
        for i in range(d + 1):  # vertex functions l_i (2 l_i - 1)
            out[q, i] = (4 * l_[i] - 1) * gl[i]
        for k, (a, b) in enumerate(EDGES[d]):  # edge functions 4 l_a l_b
            out[q, d + 1 + k] = 4 * (l_[a] * gl[b] + l_[b] * gl[a])
    return out


def validate(mesh, *, min_ratio=0.1):
    """Straighten curved edges of cells whose quadratic map folds or nearly folds: det of the
    Jacobian at every P2 node below ``min_ratio`` times the straight cell's. Returns (mesh,
    number of edges straightened)."""
    if mesh.geometry_order == 1:
        return mesh, 0
    d = mesh.gdim
    G = _p2_grad_ref(d)
    gl = np.vstack([-np.ones(d), np.eye(d)])  # P1 (barycentric) gradients
    straightened = 0
    for _ in range(5):
        x, cells, uniq = p2_cells(mesh)
        xc = x[cells]                                     # (m, nb, d)
        J = np.einsum("mbi,qbj->mqij", xc, G)             # (m, nq, d, d)
        det = np.linalg.det(J)
        lin = np.linalg.det(np.einsum("mbi,bj->mij", xc[:, :d + 1], gl))
        bad = np.flatnonzero((det < min_ratio * lin[:, None]).any(axis=1))
        if not len(bad):
            break
        bad_edges = np.unique(cells[bad, d + 1:] - mesh.n_vertices)
        bad_pairs = uniq[bad_edges]
        n = mesh.n_vertices
        ck = np.sort(mesh.curved_edges, axis=1)
        drop = np.isin(ck[:, 0] * n + ck[:, 1], bad_pairs[:, 0] * n + bad_pairs[:, 1])
        if not drop.any():
            break
        straightened += int(drop.sum())
        mesh = replace(mesh, curved_edges=mesh.curved_edges[~drop],
                       curved_points=mesh.curved_points[~drop])
    return mesh, straightened
