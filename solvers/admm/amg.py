"""The iterative x-step of large meshes: conjugate gradients on the scalar x-step matrix,
preconditioned with an aggregation AMG V-cycle built here (O(n) work and memory; a direct
factor's fill grows like n^1.4-1.5 on these 3D meshes). The iteration runs in the compiled
kernel (``amg_pcg`` of admm_kernel.c) when it is available, else in numpy (same arithmetic)."""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from tissue_reference.solvers import ckernel

from ..spd import spd_splu
from .amg_array import ArrayAmgPcg
from .kernel_c import use_kernel

PCG_RTOL = 0.3  # PCG x-step: ... or below PCG_RTOL times its first update
STEP_MAXIT = 25  # PCG iterations of one x-step at most
SOLVE_MAXIT, SOLVE_RTOL = 500, 1e-12  # a full solve (harmonic lift): its bounds


def strength_aggregates(A):
    """Smoothed-aggregation aggregates (Vanek, Mandel, Brezina 1996) on the graph of the
    strength matrix A (CSR): roots whose neighbourhood is still free, then the leftovers joined
    to a neighbouring aggregate, then isolated ones. Returns (agg (n,), number of aggregates).
    In the compiled kernel when it is available (``amg_aggregates``: the same greedy order, so
    the same aggregates), else in Python (``python_aggregates``)."""
    if not use_kernel():
        return python_aggregates(A)
    ffi, lib = ckernel.load()
    n = A.shape[0]
    ip = np.ascontiguousarray(A.indptr, np.int32)
    ind = np.ascontiguousarray(A.indices, np.int32)
    agg, first = np.empty(n, np.int64), np.empty(n, np.int64)
    na = lib.amg_aggregates(n, ffi.cast("int *", ip.ctypes.data),
                            ffi.cast("int *", ind.ctypes.data),
                            ffi.cast("int64_t *", agg.ctypes.data),
                            ffi.cast("int64_t *", first.ctypes.data))
    return agg, int(na)


def python_aggregates(A):
    """``strength_aggregates`` in Python."""
    n = A.shape[0]
    ip, ind = A.indptr.tolist(), A.indices.tolist()
    agg = [-1] * n
    na = 0
    for i in range(n):
        if agg[i] >= 0:
            continue
        nb = ind[ip[i]:ip[i + 1]]
        if all(agg[j] < 0 for j in nb):
            for j in nb:
                agg[j] = na
            agg[i] = na
            na += 1
    first = list(agg)
    for i in range(n):
        if first[i] < 0:
            for j in ind[ip[i]:ip[i + 1]]:
                if first[j] >= 0:
                    agg[i] = first[j]
                    break
    for i in range(n):
        if agg[i] < 0:
            agg[i] = na
            na += 1
    return np.asarray(agg, dtype=np.int64), na


class AmgPcg:
    """Preconditioned conjugate gradients on an SPD scalar matrix (the x-step matrix of a large
    mesh), multi-column, with an aggregation AMG V-cycle (strength theta = 0.08; Jacobi-smoothed
    prolongator on the finest level, plain aggregation below: smoothed coarse operators densify,
    at 185k tets the third level had 456 nonzeros per row and cost 40% of a V-cycle, 1.5x
    slower per warm-started x-step for the same PCG iterations; one pre/post damped-Jacobi
    sweep, omega = 4 / (3 rho(D^-1 A)); coarsened to 500 unknowns or until aggregation stalls
    (about 20k on 1e6 tets), the coarsest level solved directly) as
    preconditioner. Work and memory are O(n) (a direct factor's fill grows like n^(4/3) and more
    on 3D meshes). With the compiled kernel the PCG and V-cycle run in C (``amg_pcg``, all
    right-hand sides at once, the coarsest level by its dense inverse, or with
    ``coarse_factors`` by SuperLU's factors, for any number of levels and coarsest size),
    otherwise in numpy (``amg_array``'s iteration on numpy, coarsest level by SuperLU); same
    arithmetic. ``vcycle`` applies the preconditioner alone. ``step``
    is the ADMM x-step: ``iters`` PCG
    iterations warm-started from the previous x (inexact; the x-step matrix is constant and at
    an ADMM fixed point the warm start solves it, so the fixed point is unchanged); ``solve``
    iterates to a relative residual of SOLVE_RTOL."""

    theta = 0.08
    pcg_rtol, step_maxit = PCG_RTOL, STEP_MAXIT
    solve_maxit, solve_rtol = SOLVE_MAXIT, SOLVE_RTOL
    coarse = 500
    smooth_levels = 1  # levels with a smoothed prolongator (below: plain aggregation)

    def __init__(self, A, iters=1, coarse_factors=False):
        self.iters = iters
        self.count = [0, 0]  # PCG calls, PCG iterations (statistics)
        self.last_update = 0.0  # largest vertex update (mm) of the last PCG iteration
        A = A.tocsr()
        self.A = A
        self.levels = []
        while A.shape[0] > self.coarse:
            n = A.shape[0]
            C = A.tocoo()
            dg = np.sqrt(np.abs(A.diagonal()))
            keep = (np.abs(C.data) >= self.theta * dg[C.row] * dg[C.col]) | (C.row == C.col)
            S = sp.csr_matrix((C.data[keep], (C.row[keep], C.col[keep])), shape=A.shape)
            agg, na = strength_aggregates(S)
            if na > 0.6 * n:  # no real coarsening left
                break
            T = sp.csr_matrix((np.ones(n), (np.arange(n), agg)), shape=(n, na))
            dinv = 1.0 / A.diagonal()
            x = np.random.default_rng(0).random(n)
            lam = 1.0
            for _ in range(15):  # power iteration for rho(D^-1 A)
                y = dinv * (A @ x)
                lam = float(np.linalg.norm(y))
                x = y / lam
            P = (T - sp.diags((4.0 / 3.0 / lam) * dinv) @ (A @ T)).tocsr() \
                if len(self.levels) < self.smooth_levels else T.tocsr()
            R = P.T.tocsr()
            self.levels.append((A, ((4.0 / 3.0 / lam) * dinv)[:, None], P, R))
            A = (R @ A @ P).tocsr()
        self.coarse_matrix = A
        self.lu = spd_splu(A.tocsc())
        self._arrays = None   # the numpy iteration (amg_array), built on first use
        mats = [lv[k] for lv in self.levels for k in (0, 2, 3)]
        self.bytes = sum(12 * M.nnz + 4 * M.shape[0] for M in mats) + 12 * (
            self.lu.L.nnz + self.lu.U.nnz)
        self.nnz = sum(M.nnz for M in mats)
        self.untracked_bytes = 12 * (self.lu.L.nnz + self.lu.U.nnz)  # coarsest-level SuperLU
        # the compiled iteration: a hierarchy with levels and a coarsest matrix small enough for
        # its dense inverse, or (coarse_factors) any hierarchy, its coarsest level solved with
        # SuperLU's factors in C
        usable = (coarse_factors or (self.levels and A.shape[0] <= 2000)) \
            and self.A.nnz < 2 ** 31   # the kernel's int32 indices
        self._c = self._compiled(A, coarse_factors) if (usable and use_kernel()) else None
        if self._c is not None and not coarse_factors:   # and the coarsest's dense inverse
            self.bytes += 8 * A.shape[0] ** 2

    def _compiled(self, Ac, coarse_factors):
        """The hierarchy as the compiled kernel's level structs (int32 CSR arrays kept alive
        here) and its coarsest level's direct solve: the dense inverse of the coarsest matrix
        (<= 2000 unknowns), or with ``coarse_factors`` SuperLU's factors (its direct solve in
        the numpy V-cycle: the two agree to round-off)."""
        ffi, lib = ckernel.load()
        keep = []

        def arr(a, dtype=np.float64, kind="double *"):
            a = np.ascontiguousarray(a, dtype=dtype)
            keep.append(a)
            return ffi.cast(kind, a.ctypes.data)

        def csr(M):
            return (arr(M.indptr, np.int32, "int *"), arr(M.indices, np.int32, "int *"),
                    arr(M.data))

        lv = ffi.new("amg_level[]", len(self.levels))
        for s, (A, dw, P, R) in zip(lv, self.levels):
            s.n = A.shape[0]
            s.Ap, s.Ai, s.Ax = csr(A)
            s.Pp, s.Pi, s.Px = csr(P)
            s.Rp, s.Ri, s.Rx = csr(R)
            s.dw = arr(dw.ravel())
        co = ffi.new("amg_coarse *")
        co.nc = Ac.shape[0]
        if coarse_factors:
            L, U = self.lu.L.tocsc(), self.lu.U.tocsc()
            co.Lp, co.Li, co.Lx = csr(L)     # CSC arrays: the same three
            co.Up, co.Ui, co.Ux = csr(U)
            co.Ld, co.Ud = arr(L.diagonal()), arr(U.diagonal())
            co.perm_r = arr(self.lu.perm_r, np.int32, "int *")
            co.perm_c = arr(self.lu.perm_c, np.int32, "int *")
        else:
            co.Ainv = arr(np.linalg.inv(Ac.toarray()))
        return {"ffi": ffi, "lib": lib, "lv": lv, "co": co, "keep": keep, "nc": Ac.shape[0],
                "scratch": {}}

    def _scratch(self, k):
        """The compiled kernel's work arrays for k columns, made on first use and kept: per
        level (x, r, b), the PCG's, the coarsest level's, and the last update's cell."""
        c = self._c
        if k > 8:
            raise ValueError("compiled PCG: at most 8 right-hand sides")
        sc = c["scratch"].get(k)
        if sc is None:  # per-level scratch (x, r, b), PCG work and coarsest-level work
            bufs = [np.empty((3, lvl[0].shape[0] * k)) for lvl in self.levels]
            sc = c["scratch"][k] = (bufs, np.empty(4 * self.A.shape[0] * k),
                                    np.empty(3 * c["nc"] * k), c["ffi"].new("double *"))
        if c.get("k") != k:   # the level structs point at this k's scratch
            for s, b in zip(c["lv"], sc[0]):
                s.x, s.r, s.b = (c["ffi"].cast("double *", b[j].ctypes.data) for j in range(3))
            c["k"] = k
        return sc

    @property
    def compiled(self) -> bool:
        """Whether the hierarchy is in the compiled kernel."""
        return self._c is not None

    def kernel_parts(self, k):
        """The compiled hierarchy for an iteration of the caller's own in the kernel, on k
        columns: (ffi, lib, level structs, coarsest solve, coarsest size), the level structs
        pointing at k columns' scratch. Only when ``compiled``."""
        c = self._c
        self._scratch(k)
        return c["ffi"], c["lib"], c["lv"], c["co"], c["nc"]

    def vcycle(self, B):
        """One V-cycle on the columns of B (n, k): the preconditioner alone, compiled when the
        kernel is (k <= 8), else ``amg_array``'s (same arithmetic)."""
        if B.ndim != 2 or B.shape[0] != self.A.shape[0]:
            raise ValueError(f"vcycle: B must be ({self.A.shape[0]}, k), got {B.shape}")
        if self._c is None or B.shape[1] > 8:
            if self._arrays is None:
                self._arrays = ArrayAmgPcg(self, np)
            return self._arrays.vcycle(B)
        c = self._c
        ffi = c["ffi"]
        _, _, cwork, _ = self._scratch(B.shape[1])
        B = np.ascontiguousarray(B, dtype=np.float64)
        X = np.empty_like(B)
        c["lib"].amg_vcycle(len(self.levels), c["lv"], c["co"], B.shape[1],
                            ffi.cast("double *", B.ctypes.data),
                            ffi.cast("double *", X.ctypes.data),
                            ffi.cast("double *", cwork.ctypes.data))
        return X

    def _pcg_compiled(self, B, X, maxit, rtol, step_tol):
        c = self._c
        ffi, k = c["ffi"], B.shape[1]
        _, work, cwork, last = self._scratch(k)
        B = np.ascontiguousarray(B, dtype=np.float64)
        X = np.array(X, dtype=np.float64, order="C")
        n_it = c["lib"].amg_pcg(
            len(self.levels), c["lv"], c["co"], k,
            ffi.cast("double *", B.ctypes.data), ffi.cast("double *", X.ctypes.data),
            maxit, rtol, step_tol, PCG_RTOL, self.iters,
            ffi.cast("double *", work.ctypes.data), ffi.cast("double *", cwork.ctypes.data), last)
        self.count[0] += 1
        self.count[1] += n_it
        self.last_update = float(last[0])
        return X

    def _pcg(self, B, X, maxit, rtol, step_tol=0.0):
        if self._c is not None and self.levels:   # the compiled PCG's matrix is level 0's
            return self._pcg_compiled(B, X, maxit, rtol, step_tol)
        if self._arrays is None:   # the iteration the array backends run, here on numpy
            self._arrays = ArrayAmgPcg(self, np)
        it = self._arrays
        before = it.iterations
        X = it.pcg(B, X, maxit, rtol, step_tol)
        self.count[0] += 1
        self.count[1] += it.iterations - before
        self.last_update = it.last_update
        return X

    def solve(self, B):
        B = np.ascontiguousarray(B)
        return self._pcg(B, np.zeros_like(B), SOLVE_MAXIT, SOLVE_RTOL)

    def step(self, B, X0, tol_mm):
        """At least ``iters`` PCG iterations from X0, then until the largest vertex update is
        below tol_mm (mm) or PCG_RTOL times the first one (at most 25)."""
        return self._pcg(np.ascontiguousarray(B), np.array(X0, order="C"), STEP_MAXIT, 0.0,
                         tol_mm)

