"""Boundary conditions of the ADMM solver as a reduction u = up + Z q: prescribed dofs (fixed,
displacement, affine, axis-aligned sliding) are eliminated, oblique sliding u.n = g is a
per-vertex change of basis (exact). Free dofs are ordered component-major with the vertices in
reverse Cuthill-McKee order (memory locality)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from tissue_reference.errors import CaseError


@dataclass(frozen=True)
class Reduction:
    """u = up + Z q; Z (N, nq) orthonormal columns, each on one vertex. separable: no oblique
    sliding, Z selects the plain free dofs ``plain_dofs`` (in this order)."""

    Z: sp.csr_matrix
    up: np.ndarray
    separable: bool = False
    plain_dofs: np.ndarray | None = None
    ZT: sp.csr_matrix | None = None  # Z^T (scipy's .T builds a new matrix at every use)



def vertex_rank(mesh):
    """Rank of every vertex in a reverse Cuthill-McKee ordering of the mesh graph (cached)."""
    rank = getattr(mesh, "_admm_rcm_rank", None)
    if rank is None or len(rank) != mesh.n_vertices:
        from scipy.sparse.csgraph import reverse_cuthill_mckee
        c = mesh.cells
        k = c.shape[1]
        A = sp.csr_matrix((np.ones(c.size * k, np.int8), (np.repeat(c, k, axis=1).ravel(),
                                                          np.tile(c, (1, k)).ravel())),
                          shape=(mesh.n_vertices, mesh.n_vertices))
        perm = reverse_cuthill_mckee(A, symmetric_mode=True)
        rank = np.empty(mesh.n_vertices, np.int64)
        rank[perm] = np.arange(mesh.n_vertices)
        try:
            object.__setattr__(mesh, "_admm_rcm_rank", rank)
        except (AttributeError, TypeError):
            pass
    return rank


def constraint_reduction(case) -> Reduction:
    n, d = case.mesh.n_vertices, case.mesh.gdim
    N = n * d
    c = case.constraints
    up = np.zeros(N)
    up[c.dofs] = c.values
    fixed = np.zeros(N, bool)
    fixed[c.dofs] = True
    rows_of: dict[int, list] = {}
    for verts, nrm, g in c.sliding:
        for v in np.asarray(verts).tolist():
            rows_of.setdefault(v, []).append((np.asarray(nrm, float), float(g)))
    # plain free dofs of vertices without oblique sliding
    slide_v = np.array(sorted(rows_of), dtype=np.int64)
    plain = ~fixed
    if len(slide_v):
        plain[(slide_v[:, None] * d + np.arange(d)).ravel()] = False
    plain_dofs = np.flatnonzero(plain)
    # component-major (all x dofs, then y, ...): the x-step's multi-column right-hand side
    # is then a view of the reduced vector; vertices in reverse Cuthill-McKee order (locality)
    plain_dofs = plain_dofs[np.lexsort((vertex_rank(case.mesh)[plain_dofs // d], plain_dofs % d))]
    zr, zc, zv = [plain_dofs], [np.arange(len(plain_dofs))], [np.ones(len(plain_dofs))]
    col = len(plain_dofs)
    for v in slide_v.tolist():
        R, g = [], []
        for k in range(d):
            if fixed[d * v + k]:
                e = np.zeros(d)
                e[k] = 1.0
                R.append(e)
                g.append(up[d * v + k])
        for nrm, val in rows_of[v]:
            R.append(nrm)
            g.append(val)
        R, g = np.array(R), np.array(g)
        _, s, Vt = np.linalg.svd(R)
        rank = int(np.sum(s > 1e-10 * s[0]))
        upv = np.linalg.lstsq(R, g, rcond=None)[0]
        if np.linalg.norm(R @ upv - g) > 1e-8 * max(1.0, np.abs(g).max()):
            raise CaseError(f"vertex {v}: sliding and prescribed conditions conflict "
                            f"(no displacement satisfies them, residual "
                            f"{np.linalg.norm(R @ upv - g):.3g} mm)")
        up[d * v:d * v + d] = upv
        for b in Vt[rank:]:
            zr.append(d * v + np.arange(d))
            zc.append(np.full(d, col))
            zv.append(b)
            col += 1
    Z = sp.csr_matrix((np.concatenate(zv), (np.concatenate(zr), np.concatenate(zc))), shape=(N, col))
    return Reduction(Z, up, separable=not len(slide_v), plain_dofs=plain_dofs,
                      ZT=Z.T.tocsr())
