"""Cotin's stiffness tensors of linear-elastic P1 simplices: one d x d tensor per vertex (T_ii)
and one per edge (T_ij), precomputed once from the barycentric gradients and cell measures, and
the block-diagonal CSR matrix of (n, d, d) blocks on node-major dofs (dof = d*i + c)."""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from tissue_reference.errors import CaseError
from tissue_reference.meshes.mesh import cell_pairs, check_cell_ids, edge_topology
from tissue_reference.solvers import ckernel

from ..admm.kernel_c import use_kernel


def _degenerate(cells, bad: int, count: int, d: int) -> CaseError:
    return CaseError(f"{count} cell(s) of zero {'volume' if d == 3 else 'area'} (cell {bad}, "
                     f"vertices {cells[bad].tolist()}): the Mass Tensor method needs "
                     f"non-degenerate simplices")


def barycentric_gradients(points: np.ndarray, cells: np.ndarray):
    """Barycentric gradients (m, d+1, d) in 1/mm and cell measures (m,) in mm^d."""
    x = points[cells]
    D = x[:, 1:] - x[:, :1]                      # (m, d, d) rows = edge vectors from vertex 0
    d = points.shape[1]
    g = np.empty((len(cells), d + 1, d))
    if d == 3:   # grad lambda_k = (e_{k+1} x e_{k+2}) / det, the cofactors of D
        cof = np.stack([np.cross(D[:, 1], D[:, 2]), np.cross(D[:, 2], D[:, 0]),
                        np.cross(D[:, 0], D[:, 1])], axis=1)
        det = np.einsum("mi,mi->m", D[:, 0], cof[:, 0])
    else:
        det = np.linalg.det(D)
    bad = np.flatnonzero(~(np.abs(det) > 0))
    if bad.size:
        raise _degenerate(cells, int(bad[0]), bad.size, d)
    if d == 3:
        g[:, 1:] = cof / det[:, None, None]
        vol = np.abs(det) / 6.0
    else:
        vol = np.abs(det) / 2.0
        g[:, 1:] = np.transpose(np.linalg.inv(D), (0, 2, 1))   # column k-1 of D^-1
    g[:, 0] = -g[:, 1:].sum(axis=1)
    return g, vol


def stiffness_tensors(points, cells, mu: float, lmbda: float, topology=None):
    """Cotin's per-vertex and per-edge stiffness tensors.

    points (n, d) mm, cells (m, d+1), mu and lmbda in kPa; topology: the cells'
    ``meshes.mesh.EdgeTopology`` (made here when None). Returns ``(T_ii, edges, T_ij)``: T_ii
    (n, d, d) and T_ij (e, d, d) in mN/mm, edges (e, 2) with edges[:, 0] < edges[:, 1]; the
    block of row j, column i is T_ij^T.

    Every cell's block is linear in the outer product of its vertices' gradients,
    K^c_ab = lambda O + mu O^T + mu tr(O) I with O = V_c g_a g_b^T, so the products O are
    summed per vertex and per edge first (in the compiled kernel when it is available, else in
    numpy: the same sums) and the tensors formed once per vertex and edge.
    """
    points = np.asarray(points, float)
    cells = np.asarray(cells, np.int64)
    if topology is None:
        topology = edge_topology(cells, len(points))   # which checks the cells' vertex ids
    else:
        check_cell_ids(cells, len(points))
        _check_topology(topology, cells, points.shape)
    e = len(topology.edges)
    S_ii, S_e = (_compiled_sums if use_kernel() else _numpy_sums)(points, cells, topology)
    # a cell's pair (a, b) whose first vertex is its edge's second entered transposed
    S = S_e[:e] + np.transpose(S_e[e:], (0, 2, 1))
    return _tensors(S_ii, mu, lmbda), topology.edges, _tensors(S, mu, lmbda)


def _check_topology(topology, cells, shape):
    """CaseError when ``topology`` is not an EdgeTopology of ``cells`` on ``shape`` points."""
    (n, d), m = shape, len(cells)
    p = d * (d + 1) // 2   # vertex pairs per cell
    e = len(topology.edges)
    faults = [what for what, bad in (
        ("cell pairs", len(topology.pair_edge) != m * p or len(topology.pair_flipped) != m * p),
        ("edge ids", m > 0 and not 0 <= topology.pair_edge.min() <= topology.pair_edge.max() < e),
        ("edge vertices", e > 0 and not 0 <= topology.edges.min() <= topology.edges.max() < n),
        ("matrix rows", len(topology.indptr) != n * d + 1)) if bad]
    if faults:
        raise CaseError(f"the topology given does not belong to these {m} cells on {n} vertices "
                        f"(its {', '.join(faults)} do not match): pass the mesh's own "
                        f"(MeshData.edge_topology) or none")


def _numpy_sums(points, cells, topology):
    """The summed products per vertex (n, d, d) and per edge slot (2 e, d, d)."""
    n, d = points.shape
    g, vol = barycentric_gradients(points, cells)
    gs = g * np.sqrt(vol)[:, None, None]                      # sqrt(V_c) grad lambda_a
    flat = cells.reshape(-1)
    S_ii = np.empty((n, d, d))
    for a in range(d):
        for b in range(a, d):   # symmetric: g g^T per vertex
            S_ii[:, a, b] = S_ii[:, b, a] = np.bincount(
                flat, (gs[:, :, a] * gs[:, :, b]).reshape(-1), minlength=n)
    A, B = cell_pairs(d)
    e = len(topology.edges)
    slot = topology.pair_edge + e * topology.pair_flipped
    ga, gb = gs[:, A].reshape(-1, d), gs[:, B].reshape(-1, d)
    S_e = np.empty((2 * e, d, d))
    for a in range(d):
        for b in range(d):
            S_e[:, a, b] = np.bincount(slot, ga[:, a] * gb[:, b], minlength=2 * e)
    return S_ii, S_e


def _compiled_sums(points, cells, topology):
    """``_numpy_sums`` in the compiled kernel (``mt_tensor_sums``): one pass over the cells."""
    ffi, lib = ckernel.load()
    n, d = points.shape
    e = len(topology.edges)
    S_ii, S_e = np.zeros((n, d, d)), np.zeros((2 * e, d, d))
    pts = np.ascontiguousarray(points, np.float64)
    cl = np.ascontiguousarray(cells, np.int64)
    pe = np.ascontiguousarray(topology.pair_edge, np.int64)
    fl = np.ascontiguousarray(topology.pair_flipped, np.uint8)
    bad = lib.mt_tensor_sums(d, len(cl), ffi.cast("int64_t *", cl.ctypes.data),
                             ffi.cast("double *", pts.ctypes.data),
                             ffi.cast("int64_t *", pe.ctypes.data),
                             ffi.cast("uint8_t *", fl.ctypes.data), e,
                             ffi.cast("double *", S_ii.ctypes.data),
                             ffi.cast("double *", S_e.ctypes.data))
    if bad >= 0:
        barycentric_gradients(pts, cl)   # raises naming the first and counting all, as numpy does
        raise _degenerate(cl, int(bad), 1, d)   # the two formulas differ in the last bit here
    return S_ii, S_e


def _tensors(S, mu, lmbda):
    """lambda S + mu S^T + mu tr(S) I of summed outer products S (k, d, d)."""
    d = S.shape[1]
    T = lmbda * S
    T += mu * np.ascontiguousarray(np.transpose(S, (0, 2, 1)))
    tr = mu * np.trace(S, axis1=1, axis2=2)
    for c in range(d):
        T[:, c, c] += tr
    return T


def blockdiag(B):
    """(n, d, d) blocks -> block-diagonal CSR matrix (n d, n d)."""
    n, d, _ = B.shape
    return sp.bsr_matrix((B, np.arange(n), np.arange(n + 1)), shape=(n * d, n * d)).tocsr()

