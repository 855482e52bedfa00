"""Cotin's stiffness tensors of linear-elastic P1 simplices: one d x d tensor per vertex (T_ii)
and one per edge (T_ij), precomputed once from the barycentric gradients and cell measures, and
the block-sparse helpers that turn (n, d, d) blocks into CSR matrices on node-major dofs
(dof = d*i + c)."""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from tissue_reference.meshes.errors import CaseError


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
        raise CaseError(f"{bad.size} cell(s) of zero {'volume' if d == 3 else 'area'} (cell "
                        f"{int(bad[0])}, vertices {cells[bad[0]].tolist()}): the Mass Tensor "
                        f"method needs non-degenerate simplices")
    if d == 3:
        g[:, 1:] = cof / det[:, None, None]
        vol = np.abs(det) / 6.0
    else:
        vol = np.abs(det) / 2.0
        g[:, 1:] = np.transpose(np.linalg.inv(D), (0, 2, 1))   # column k-1 of D^-1
    g[:, 0] = -g[:, 1:].sum(axis=1)
    return g, vol


def stiffness_tensors(points, cells, mu: float, lmbda: float):
    """Cotin's per-vertex and per-edge stiffness tensors.

    points (n, d) mm, cells (m, d+1), mu and lmbda in kPa. Returns ``(T_ii, edges, T_ij)``:
    T_ii (n, d, d) and T_ij (e, d, d) in mN/mm, edges (e, 2) with edges[:, 0] < edges[:, 1];
    the block of row j, column i is T_ij^T.

    Every cell's block is linear in the outer product of its vertices' gradients,
    K^c_ab = lambda O + mu O^T + mu tr(O) I with O = V_c g_a g_b^T, so the products O are
    summed per vertex and per edge first and the tensors formed once per vertex and edge.
    """
    points = np.asarray(points, float)
    cells = np.asarray(cells, np.int64)
    n, d = points.shape
    g, vol = barycentric_gradients(points, cells)
    gs = g * np.sqrt(vol)[:, None, None]                      # sqrt(V_c) grad lambda_a
    outer = (gs[:, :, :, None] * gs[:, :, None, :]).reshape(-1, d * d)
    flat = cells.reshape(-1)
    S = np.empty((n, d * d))
    for c in range(d * d):
        S[:, c] = np.bincount(flat, outer[:, c], minlength=n)
    T_ii = _tensors(S.reshape(n, d, d), mu, lmbda)
    A, B = np.triu_indices(d + 1, 1)
    i, j = cells[:, A].reshape(-1), cells[:, B].reshape(-1)
    uniq, inv = np.unique(np.minimum(i, j) * n + np.maximum(i, j), return_inverse=True)
    e = len(uniq)
    # a cell's pair (a, b) with i > j is edge (j, i): its product sums into the second half of
    # the bins and enters transposed
    slot = inv + e * (i > j)
    ga, gb = gs[:, A].reshape(-1, d), gs[:, B].reshape(-1, d)
    S = np.empty((2 * e, d, d))
    for a in range(d):
        for b in range(d):
            S[:, a, b] = np.bincount(slot, ga[:, a] * gb[:, b], minlength=2 * e)
    S = S[:e] + np.transpose(S[e:], (0, 2, 1))
    edges = np.stack([uniq // n, uniq % n], axis=1)
    return T_ii, edges, _tensors(S, mu, lmbda)


def _tensors(S, mu, lmbda):
    """lambda S + mu S^T + mu tr(S) I of summed outer products S (k, d, d)."""
    d = S.shape[1]
    T = lmbda * S
    T += mu * np.ascontiguousarray(np.transpose(S, (0, 2, 1)))
    tr = mu * np.trace(S, axis1=1, axis2=2)
    for c in range(d):
        T[:, c, c] += tr
    return T


def bsr_from_blocks(rows, cols, data, n, d):
    """(k, d, d) blocks at distinct (rows, cols) -> CSR matrix (n d, n d)."""
    order = np.argsort(np.asarray(rows, np.int64) * n + cols)
    rows, cols, data = rows[order], cols[order], data[order]
    indptr = np.r_[0, np.cumsum(np.bincount(rows, minlength=n))]
    return sp.bsr_matrix((data, cols, indptr), shape=(d * n, d * n)).tocsr()


def blockdiag(B):
    """(n, d, d) blocks -> block-diagonal CSR matrix (n d, n d)."""
    n, d, _ = B.shape
    return sp.bsr_matrix((B, np.arange(n), np.arange(n + 1)), shape=(n * d, n * d)).tocsr()

