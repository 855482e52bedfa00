"""The large-mesh x-step of the array backends: the CPU path's AMG-preconditioned conjugate
gradients (``amg.AmgPcg``) run on the arrays of ``xp`` (CuPy on a GPU, or numpy).

The hierarchy (aggregates, smoothed prolongator, Galerkin coarse matrices) is the CPU path's,
built once on the host; its matrices are copied as CSR and the Jacobi weights as columns. The
coarsest level is solved on a GPU by its dense inverse, computed there (one matrix product per
V-cycle instead of triangular solves; on 1e6 tets the aggregation stops at about 20k coarse
unknowns, 3 GiB), on numpy by the CPU path's own SuperLU factor. The iteration is
``AmgPcg``'s, stopping rules and bounds included: the ADMM x-step is warm-started from the
previous iterate and stops once its largest vertex update is below ``amg.PCG_RTOL`` of the first or
below the step tolerance, so the array backend's iterates follow the CPU path's (up to
round-off) with a few V-cycles per x-step instead of the hundreds of Jacobi-CG iterations an
exact solve takes on 1e5-1e6 tets."""
from __future__ import annotations

import numpy as np

MAX_COARSE = 30_000   # coarsest level's unknowns at most for its dense inverse on a GPU (7 GiB)


def usable(solver) -> bool:
    """Whether ``solver`` (one group of the CPU path's x-step) has a hierarchy to mirror."""
    return (bool(getattr(solver, "levels", None))
            and solver.coarse_matrix.shape[0] <= MAX_COARSE)


class ArrayAmgPcg:
    """``AmgPcg``'s PCG and V-cycle on the arrays of ``xp`` (multi-column right-hand sides):
    the array backends' x-step, and ``AmgPcg``'s own iteration on numpy without the compiled
    kernel."""

    def __init__(self, amg, xp):
        if xp is np:
            from scipy import sparse
        else:
            from cupyx.scipy import sparse
        self.xp = xp
        self.iters = amg.iters
        # the stopping rules and bounds of ``amg``'s own iteration
        self.pcg_rtol, self.step_maxit = amg.pcg_rtol, amg.step_maxit
        self.solve_maxit, self.solve_rtol = amg.solve_maxit, amg.solve_rtol
        self.A = sparse.csr_matrix(amg.A)
        self.levels = [(sparse.csr_matrix(A), xp.asarray(dw), sparse.csr_matrix(P),
                        sparse.csr_matrix(R)) for A, dw, P, R in amg.levels]
        if xp is np:
            self.Ainv = None
            self._coarse_lu = amg.lu
        else:
            self.Ainv = xp.linalg.inv(xp.asarray(amg.coarse_matrix.toarray()))
        self.iterations = 0       # PCG iterations (statistics)
        self.last_update = 0.0    # largest vertex update (mm) of the last PCG iteration
        self.nbytes = sum(12 * M.nnz + 4 * M.shape[0] for lv in self.levels
                          for M in (lv[0], lv[2], lv[3])) \
            + (0 if self.Ainv is None else 8 * self.Ainv.size)

    def vcycle(self, B):
        """One V-cycle from zero on the columns of B (n, k): a symmetric positive definite
        approximation of A^-1 B, the preconditioner of the PCG below and of other solvers'."""
        return self._vcycle(B)

    def _vcycle(self, b, level=0):
        if level == len(self.levels):
            if self.Ainv is None:
                return self._coarse_lu.solve(np.asfortranarray(b))
            return self.Ainv @ b
        A, dw, P, R = self.levels[level]
        x = dw * b
        r = b - A @ x
        x += P @ self._vcycle(R @ r, level + 1)
        r = b - A @ x
        r *= dw
        x += r
        return x

    def pcg(self, B, X, maxit, rtol, step_tol=0.0):
        """PCG from X (updated in place) to a relative residual ``rtol`` per column, at most
        ``maxit`` iterations; with ``step_tol`` > 0 also stopped (after ``iters``) once the
        largest vertex update is below step_tol or ``pcg_rtol`` times the first."""
        xp, A = self.xp, self.A
        r = B - A @ X
        stop = rtol * xp.sqrt(xp.einsum("ij,ij->j", B, B))
        z = self._vcycle(r)
        p = z
        rz = xp.einsum("ij,ij->j", r, z)
        lim = 0.0
        for it in range(maxit):
            Ap = A @ p
            pAp = xp.einsum("ij,ij->j", p, Ap)
            alpha = xp.where(pAp > 0, rz / xp.where(pAp > 0, pAp, 1.0), 0.0)
            dx = alpha * p
            X += dx
            r -= alpha * Ap
            if it == maxit - 1 or bool(xp.all(xp.sqrt(xp.einsum("ij,ij->j", r, r)) <= stop)):
                break
            if step_tol > 0:
                dmax = float(xp.einsum("ij,ij->i", dx, dx).max())
                if it == 0:
                    lim = max(step_tol ** 2, (self.pcg_rtol ** 2) * dmax)
                if it + 1 >= self.iters and dmax <= lim:
                    break
            z = self._vcycle(r)
            rzn = xp.einsum("ij,ij->j", r, z)
            beta = xp.where(rz > 0, rzn / xp.where(rz > 0, rz, 1.0), 0.0)
            p = z + beta * p
            rz = rzn
        self.iterations += it + 1
        self.last_update = float(xp.sqrt(xp.einsum("ij,ij->i", dx, dx).max()))
        return X

    def solve(self, B):
        """K X = B to a relative residual of ``solve_rtol`` (from zero)."""
        return self.pcg(B, self.xp.zeros_like(B), self.solve_maxit, self.solve_rtol)

    def step(self, B, X0, tol_mm):
        """The ADMM x-step from X0 (see ``AmgPcg.step``)."""
        return self.pcg(B, X0.copy(), self.step_maxit, 0.0, tol_mm)
