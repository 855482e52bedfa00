"""Cotin's stiffness tensors of linear-elastic P1 simplices: one d x d tensor per vertex (T_ii)
and one per edge (T_ij), precomputed once from the barycentric gradients and cell measures, and
the block-sparse helpers that turn (n, d, d) blocks into CSR matrices on node-major dofs
(dof = d*i + c)."""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp


def barycentric_gradients(points: np.ndarray, cells: np.ndarray):
    """Barycentric gradients (m, d+1, d) in 1/mm and cell measures (m,) in mm^d."""
    x = points[cells]
    D = x[:, 1:] - x[:, :1]                      # (m, d, d) rows = edge vectors from vertex 0
    d = points.shape[1]
    det = np.linalg.det(D)
    vol = np.abs(det) / (6.0 if d == 3 else 2.0)
    inv = np.linalg.inv(D)                       # grad lambda_k (k>=1) = column k-1 of inv
    g = np.empty((len(cells), d + 1, d))
    g[:, 1:] = np.transpose(inv, (0, 2, 1))
    g[:, 0] = -g[:, 1:].sum(axis=1)
    return g, vol


def stiffness_tensors(points, cells, mu: float, lmbda: float):
    """Cotin's per-vertex and per-edge stiffness tensors.

    points (n, d) mm, cells (m, d+1), mu and lmbda in kPa. Returns ``(T_ii, edges, T_ij)``:
    T_ii (n, d, d) and T_ij (e, d, d) in mN/mm, edges (e, 2) with edges[:, 0] < edges[:, 1];
    the block of row j, column i is T_ij^T.
    """
    points = np.asarray(points, float)
    cells = np.asarray(cells, np.int64)
    n, d = points.shape
    g, vol = barycentric_gradients(points, cells)
    eye = np.eye(d)

    def block(a, b):
        ga, gb = g[:, a], g[:, b]
        k = (lmbda * ga[:, :, None] * gb[:, None, :] + mu * gb[:, :, None] * ga[:, None, :]
             + mu * np.einsum("mk,mk->m", ga, gb)[:, None, None] * eye)
        return k * vol[:, None, None]

    T_ii = np.zeros((n, d * d))
    for a in range(d + 1):
        kaa = block(a, a).reshape(-1, d * d)
        for c in range(d * d):
            T_ii[:, c] += np.bincount(cells[:, a], kaa[:, c], minlength=n)
    ii, jj, blocks = [], [], []
    for a in range(d + 1):
        for b in range(a + 1, d + 1):
            kab = block(a, b)
            i, j = cells[:, a], cells[:, b]
            swap = i > j
            kab[swap] = np.transpose(kab[swap], (0, 2, 1))
            ii.append(np.where(swap, j, i))
            jj.append(np.where(swap, i, j))
            blocks.append(kab.reshape(-1, d * d))
    ii, jj = np.concatenate(ii), np.concatenate(jj)
    blocks = np.concatenate(blocks)
    key = ii * n + jj
    uniq, inv = np.unique(key, return_inverse=True)
    T_ij = np.empty((len(uniq), d * d))
    for c in range(d * d):
        T_ij[:, c] = np.bincount(inv, blocks[:, c], minlength=len(uniq))
    edges = np.stack([uniq // n, uniq % n], axis=1)
    return T_ii.reshape(n, d, d), edges, T_ij.reshape(-1, d, d)



def bsr_from_blocks(rows, cols, data, n, d):
    order = np.lexsort((cols, rows))
    rows, cols, data = rows[order], cols[order], data[order]
    indptr = np.r_[0, np.cumsum(np.bincount(rows, minlength=n))]
    return sp.bsr_matrix((data, cols, indptr), shape=(d * n, d * n)).tocsr()


def blockdiag(B):
    """(n, d, d) blocks -> block-diagonal CSR matrix (n d, n d)."""
    n, d, _ = B.shape
    return sp.bsr_matrix((B, np.arange(n), np.arange(n + 1)), shape=(n * d, n * d)).tocsr()

