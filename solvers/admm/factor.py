"""Direct factorizations: SuperLU of the x-step matrix (SPD, symmetric ordering, no pivoting) and
of the polish's and lift's tangents (with an optional ``factorize`` hook tried first)."""
from __future__ import annotations

import numpy as np
import scipy.sparse.linalg as spla

from ..spd import spd_splu


def sym_splu(A, cache=None, factorize=None):
    """Factorization of a symmetric tangent (CSC/CSR, mN/mm) with a ``solve(b)`` method.
    ``factorize(A, cache)`` (optional, e.g. ``fem_reference.cholmod_factor``: CHOLMOD through
    PETSc, which this package does not import) is tried first; when it is absent or returns None
    (e.g. the tangent is not positive definite), SuperLU with a symmetric minimum-degree
    ordering and diagonal pivots preferred (threshold 0.01) so the ordering's fill is kept.
    ``cache``: a dict per operator set that ``factorize`` may keep its symbolic analysis in.
    RuntimeError when the matrix is singular."""
    if factorize is not None:
        f = factorize(A, {} if cache is None else cache)
        if f is not None:
            return f
    return spla.splu(A, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.01,
                     options={"SymmetricMode": True})


class Direct:
    """SuperLU of an SPD matrix; ``step`` (the ADMM x-step) is the exact solve."""

    def __init__(self, A):
        self.lu = spd_splu(A.tocsc())
        self.nnz = self.lu.L.nnz + self.lu.U.nnz
        self.bytes = 12 * self.nnz  # factor values + row indices
        self.untracked_bytes = self.bytes  # SuperLU's own memory, not seen by tracemalloc

    def solve(self, B):
        return self.lu.solve(np.asfortranarray(B))

    def step(self, B, X0, tol_mm=0.0):
        return self.solve(B)

class CoupledSolver(Direct):
    """SuperLU of the coupled reduced x-step matrix (oblique sliding)."""

    kind = "Direct"

    def solve(self, rhs, q0=None):
        return self.lu.solve(rhs)

    inexactness = 0.0

    def step(self, rhs, q0, tol_mm):
        return self.lu.solve(rhs)

