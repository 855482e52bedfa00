"""The compliance of a pattern of point types condensed on chosen vertices: G = P A^-1 P with
A = P K P + I - P the direct solve's matrix (factorized once per pattern and kept), so that
G x is the displacement of the free directions under the forces x there (mm per mN; zero along
the prescribed directions). ``Compliance`` applies G to whole fields (one back-substitution per
column) and keeps the dense block G_CC on the vertices asked for so far, grown column by column
as more are asked for: the rigid tips' contact (``contact``) acts on the skin near the tips
only, and its Newton iterations run on that block."""
from __future__ import annotations

import numpy as np

COLUMNS_PER_PASS = 256
"""Columns of G made in one pass of the factorization (a dense (N, k) block at a time)."""


class Compliance:
    """G = Pm A^-1 Pm for a factorization ``factor`` of A (``solve(b)`` on (N,) or (N, k)) and
    the block-diagonal projector Pm (CSR) of a model with n vertices in dimension d; ``nodes``:
    the vertices of the kept block, ``pos`` (n,): each vertex's place among them (-1: none),
    ``G`` (|nodes| d, |nodes| d): the block on their dofs, node-major."""

    def __init__(self, factor, Pm, n: int, d: int):
        self.factor, self.Pm, self.n, self.d = factor, Pm, int(n), int(d)
        self.nodes = np.zeros(0, np.int64)
        self.pos = np.full(self.n, -1, np.int64)
        self.G = np.zeros((0, 0))
        self.columns = 0          # columns made (back-substitutions), all passes

    @property
    def nbytes(self) -> int:
        """Bytes of the kept block (the factorization is kept, and counted, on its own)."""
        return int(self.G.nbytes)

    def apply(self, x):
        """G x for x (N,) or (N, k) node-major (mN): mm."""
        return self.Pm @ self.factor.solve(self.Pm @ x)

    def dofs(self, nodes) -> np.ndarray:
        """The node-major dofs of ``nodes``, d per vertex."""
        return (self.d * np.asarray(nodes, np.int64)[:, None] + np.arange(self.d)).reshape(-1)

    def grow(self, nodes) -> int:
        """Keep the block on ``nodes`` too: one column of G per new dof (its rows on the kept
        vertices are the new columns' by symmetry). Returns how many vertices were new."""
        nodes = np.asarray(nodes, np.int64)
        new = np.unique(nodes[self.pos[nodes] < 0])
        if not new.size:
            return 0
        m0 = self.G.shape[0]
        old_dofs, new_dofs = self.dofs(self.nodes), self.dofs(new)
        rows = np.concatenate([old_dofs, new_dofs])
        k = len(new_dofs)
        cols = np.empty((len(rows), k))
        Pc = self.Pm.tocsc()
        Pr = self.Pm[rows]
        for s in range(0, k, COLUMNS_PER_PASS):
            part = new_dofs[s:s + COLUMNS_PER_PASS]
            # G e_j on the kept rows: Pm's rows there times A^-1 (Pm e_j)
            cols[:, s:s + len(part)] = Pr @ np.asarray(self.factor.solve(Pc[:, part].toarray()))
        self.columns += k
        G = np.empty((len(rows), len(rows)))
        G[:m0, :m0] = self.G
        G[:, m0:] = cols
        G[m0:, :m0] = cols[:m0].T
        G[m0:, m0:] = 0.5 * (cols[m0:] + cols[m0:].T)   # symmetric to round-off: exactly
        self.G = G
        self.pos[new] = len(self.nodes) + np.arange(len(new))
        self.nodes = np.concatenate([self.nodes, new])
        return len(new)
