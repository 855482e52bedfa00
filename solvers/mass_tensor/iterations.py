"""The iterations of one Mass Tensor solve: preconditioned conjugate gradients ("pcg", block
Jacobi; "amg", an aggregation AMG V-cycle) and the seed's steepest descent ("descent", exact line
search or a fixed ``step_scale``) on P K P, their stopping rules (the seed's: the largest
per-vertex move of one iteration below ``stop_mm``; "amg": the distance still to go, estimated
from the contraction of its moves, below half of ``stop_mm``), the rounds of surface sliding
(solve on frozen tangent planes, project, refresh) and the divergence checks."""
from __future__ import annotations

import hashlib
import logging

import numpy as np
import scipy.sparse as sp

from tissue_reference.errors import SolverDivergedError

from ..admm.amg import AmgPcg
from ..spd import spd_splu
from .condensed import Compliance
from .tensors import blockdiag

log = logging.getLogger("tissue.mass_tensor")

TAIL_RATES = 4
"""The "amg" iteration estimates the distance still to go from its last move s and the largest
contraction rho of its last TAIL_RATES moves as s rho / (1 - rho), the geometric series of the
moves to come, and stops once that is below TAIL_MARGIN times ``stop_mm``."""
TAIL_MARGIN = 0.5
"""The estimate is not a bound (conjugate gradients' largest vertex moves do not contract
evenly): stopped at the estimate itself the error reached 1.02 to 2.0 times the stop on boxes
of 1.2k and 5.2k vertices at nu = 0.45; at half of it, 0.34 times (nu = 0.45), 0.62 (nu = 0.499)
and 1.11 on the 5.2k-vertex box at nu = 0.49, hence the warning near nu = 0.5
(NEAR_INCOMPRESSIBLE)."""
NEAR_INCOMPRESSIBLE = 0.48
COMPILED_MAX_ITER = 1_000_000
"""The "amg" iteration runs in the compiled kernel when at most this many iterations are left
(its moves are kept in one array of that length), else in numpy."""


def distance_to_go(steps) -> float:
    """The estimate of TAIL_RATES from a solve's largest per-vertex moves so far (mm); inf
    until there are TAIL_RATES rates, or when the moves do not contract."""
    if len(steps) <= TAIL_RATES:
        return np.inf
    last = np.asarray(steps[-TAIL_RATES - 1:], float)
    with np.errstate(divide="ignore", invalid="ignore"):
        rho = float(np.max(last[1:] / last[:-1]))
    if not rho < 1.0:
        return np.inf
    return float(last[-1]) * rho / (1.0 - rho)


class FreeVertexAmg:
    """The "amg" preconditioner of a Mass Tensor model with ``m`` (n,) prescribed directions per
    vertex: an aggregation AMG hierarchy (``solvers.admm.amg``) of the scalar matrix of the
    tensors' traces / d (a scaled P1 Laplacian) on the vertices not fully held, one V-cycle per
    displacement component, zero on the fully held ones (as Dirichlet rows they would stay
    one-vertex aggregates and stop the coarsening). A vertex with some directions prescribed
    keeps its row with that share of its diagonal added, so the matrix is definite wherever
    anything is prescribed. ``nbytes``: the hierarchy's matrices and its coarsest factor. The
    V-cycle runs in the compiled kernel when it is available (``AmgPcg.vcycle``)."""

    def __init__(self, model, m):
        d = model.gdim
        self.free = np.flatnonzero(m < d)
        self.amg = None
        self.nbytes = 0
        if not self.free.size:
            return
        dii = np.trace(model.T_ii, axis1=1, axis2=2) / d
        dij = np.trace(model.T_ij, axis1=1, axis2=2) / d
        new = np.full(model.n_vertices, -1)
        new[self.free] = np.arange(self.free.size)
        i, j = new[model.edges[:, 0]], new[model.edges[:, 1]]
        both = (i >= 0) & (j >= 0)
        i, j, dij = i[both], j[both], dij[both]
        k = self.free.size
        L = sp.csr_matrix((np.concatenate([dii[self.free] * (1.0 + m[self.free] / d), dij, dij]),
                           (np.concatenate([np.arange(k), i, j]),
                            np.concatenate([np.arange(k), j, i]))), shape=(k, k))
        self.amg = AmgPcg(L, coarse_factors=True)
        self.nbytes = self.amg.bytes

    def vcycle(self, X):
        """One V-cycle on the columns of X (n, d), zero on the fully held vertices."""
        out = np.zeros_like(X)
        if self.amg is not None:
            out[self.free] = self.amg.vcycle(X[self.free])
        return out

    @property
    def compiled(self) -> bool:
        """Whether ``iterate`` can run: the hierarchy is in the compiled kernel."""
        return self.amg is not None and self.amg.compiled

    def iterate(self, K, P, f, u, max_it, stop_mm, blowup):
        """The "amg" iteration of ``IterationState.solve_linear`` in the compiled kernel
        (``mt_amg_pcg``: the same arithmetic, no per-iteration callback): K the tensors (CSR),
        P (n, d, d) the projectors, f (n, d) the forces, u (n, d) the start with its prescribed
        part set. Returns (u, moves (mm) per iteration, status, vertex, value, r, p): status 0
        stopped by the rule, 1 max_it done, 2 non-positive r.z (value), 3 non-positive curvature
        (value), 4 vertex moved value mm (non-finite or past blowup), 5 residual grew to value;
        r and p (n, d) the last residual and search direction."""
        n, d = u.shape
        ffi, lib, levels, coarse, nc = self.amg.kernel_parts(d)
        nf = self.free.size
        u = np.array(u, dtype=np.float64, order="C")
        steps = np.empty(max(int(max_it), 1))
        work = np.empty(4 * n * d + 2 * nf * d)
        cwork = np.empty(3 * nc * d)
        n_it, bad, info = ffi.new("int *"), ffi.new("int *"), ffi.new("double *")
        kept = [np.ascontiguousarray(K.indptr, np.int32), np.ascontiguousarray(K.indices, np.int32),
                np.ascontiguousarray(K.data, np.float64), np.ascontiguousarray(P, np.float64),
                np.ascontiguousarray(self.free, np.int32), np.ascontiguousarray(f, np.float64)]

        def ptr(a):
            return ffi.cast("int *" if a.dtype == np.int32 else "double *", a.ctypes.data)

        Kp, Ki, Kx, Pp, free, fp = (ptr(a) for a in kept)
        status = lib.mt_amg_pcg(n, d, Kp, Ki, Kx, Pp, nf, free, len(self.amg.levels), levels,
                                coarse, fp, ptr(u), int(max_it), float(stop_mm), TAIL_RATES,
                                TAIL_MARGIN, float(blowup), ptr(steps), n_it, bad, info,
                                ptr(work), ptr(cwork))
        return (u, steps[:n_it[0]].tolist(), int(status), int(bad[0]), float(info[0]),
                work[:n * d].reshape(n, d), work[2 * n * d:3 * n * d].reshape(n, d))


class IterationState:
    """Iteration bookkeeping shared by the phases of one solve."""

    def __init__(self, model, f, stop_mm, max_iter, callback, step_scale, factorize=None):
        self.model, self.f, self.stop = model, f, float(stop_mm)
        self.factorize = factorize
        self.max_iter, self.callback, self.step_scale = int(max_iter), callback, step_scale
        self.K = model.matrix()
        self.it = 0
        self.steps: list = []
        self.residual = float("nan")
        self.ok = True
        ext = np.ptp(model.points, axis=0).max() if len(model.points) else 1.0
        self.blowup = 1e6 * max(1.0, ext)

    # linear algebra on (n, d) arrays
    def Kx(self, x):
        return (self.K @ x.reshape(-1)).reshape(x.shape)

    def _prec(self, types, P, method):
        """Per-vertex preconditioner blocks (n, d, d), restricted to the free directions."""
        if method == "descent":
            return P / self.model.vertex_norms()[:, None, None]
        T = self.model.T_ii
        c = np.trace(T, axis1=1, axis2=2)[:, None, None] / self.model.gdim
        NN = np.einsum("nla,nlb->nab", types.N, types.N)         # rows beyond m are zero
        Minv = np.linalg.inv(T + c * NN)
        return np.einsum("nab,nbc,ncd->nad", P, Minv, P)

    def active_planes(self, types, u):
        """Refresh tangent planes of surface-sliding vertices at their closest surface point."""
        if not types.surface_of:
            return types, 0.0
        X = self.model.points
        t = types.copy()
        moved = 0.0
        for surf in {id(s): s for s in types.surface_of.values()}.values():
            vs = np.array([v for v, s in types.surface_of.items() if s is surf], np.int64)
            y, nrm = surf.closest(X[vs] + u[vs])
            moved = max(moved, float(np.max(np.linalg.norm(y - X[vs] - u[vs], axis=1))))
            u[vs] = y - X[vs]
            t.N[vs] = 0.0
            t.N[vs, 0] = nrm
            t.m[vs] = 1
            t.g[vs] = 0.0
            t.g[vs, 0] = np.einsum("kd,kd->k", u[vs], nrm)
        return t, moved

    # surface sliding (pcg, amg): rounds of (solve on fixed tangent planes, re-project) stop as
    # stalled when the largest move of a round has not shrunk by 1% over this many rounds
    # (a vertex at a crease of the surface can cycle between two triangles' planes)
    STALL_ROUNDS = 20

    def run(self, types, u, method):
        nonlinear = bool(types.surface_of)
        lin, _ = self.active_planes(types, u)
        best, since = np.inf, 0
        while True:
            start = u.copy()
            it0 = self.it
            u = self.solve_linear(lin, u, method, refresh=types if (nonlinear and method == "descent")
                             else None)
            if not nonlinear or method == "descent" or self.it >= self.max_iter:
                return u
            lin, _ = self.active_planes(types, u)
            move = float(np.max(np.linalg.norm(u - start, axis=1)))
            if move < self.stop or self.it == it0:
                return u
            if move < 0.99 * best:
                best, since = move, 0
            else:
                since += 1
            if since >= self.STALL_ROUNDS:
                self.ok = False   # reported as not converged, with the state reached
                log.warning("mass-tensor: surface sliding stalled after %d iterations: a round "
                            "still moves a vertex %.3g mm (stopping rule %.3g mm)", self.it, move,
                            self.stop)
                return u

    def _operators(self, types, method, fold, P=None):
        """Projector P, preconditioner M and projected stiffness P K P as block-diagonal / CSR
        matrices acting on (n, d) arrays (fold: precompute P K P once for the phase; "amg"
        never does: at 185k tets the product costs as much as 10 of its iterations)."""
        P = types.projector() if P is None else P
        shape = (self.model.n_vertices, self.model.gdim)
        fold = fold and method != "amg"
        mask = np.all((types.m == 0) | (types.m == self.model.gdim))   # each vertex free or held
        Pm = blockdiag(P) if fold or not mask else None
        KP = (Pm @ self.K @ Pm).tocsr() if fold else None
        if mask:
            free = (types.m == 0).astype(float)[:, None]

            def proj(x):
                return x * free
        else:
            def proj(x):
                return (Pm @ x.reshape(-1)).reshape(shape)

        if method == "amg":
            vcycle = self._amg(types).vcycle

            def applyM(x):   # x, a residual, is in the free subspace already
                return proj(vcycle(x))
        else:
            Mm = blockdiag(self._prec(types, P, method))

            def applyM(x):
                return (Mm @ x.reshape(-1)).reshape(shape)

        def Kproj(x):   # x is in the free subspace: P K P x = P K x
            if KP is not None:
                return (KP @ x.reshape(-1)).reshape(shape)
            return proj(self.Kx(x))

        return proj, applyM, Kproj

    # direct factorizations (AMG hierarchies) kept per model (one per pattern of point types)
    KEPT_FACTORS = 4

    @staticmethod
    def _pattern(types, kind, *, normals=True):
        """The store's key of ``kind`` for the pattern of point types: which directions are
        prescribed where (normals=False: only how many per vertex)."""
        return kind + hashlib.sha1((np.ascontiguousarray(types.N).tobytes() if normals else b"")
                                   + np.ascontiguousarray(types.m).tobytes()).hexdigest()

    def _keep(self, key, made):
        """``made`` kept in the model's store under ``key``."""
        kept = self.model._factors
        while len(kept) >= self.KEPT_FACTORS:
            kept.pop(next(iter(kept)))
        kept[key] = made
        return made

    def _amg(self, types):
        """The "amg" preconditioner of ``types``' pattern (``FreeVertexAmg``), from the model's
        store or made now. It depends only on how many directions each vertex has prescribed,
        so a sliding round's new tangent planes reuse it."""
        key = self._pattern(types, "amg", normals=False)
        if key in self.model._factors:
            return self.model._factors[key]
        n, d = self.model.n_vertices, self.model.gdim
        if not np.any(types.m > 0):
            self._diverged("no direction of any vertex is prescribed: nothing holds the body",
                           np.full((n, d), np.nan))
        nu = self.model.lmbda / (2.0 * (self.model.lmbda + self.model.mu))
        if nu > NEAR_INCOMPRESSIBLE:
            log.warning("mass-tensor amg: nu = %.4g is close to 0.5, where its stopping estimate "
                        "can leave more than stop_mm to go (1.1 times it measured at nu = 0.49); "
                        "method 'direct' has no stopping error", nu)
        try:
            made = FreeVertexAmg(self.model, types.m)
        except RuntimeError as exc:   # SuperLU: the coarsest matrix is singular
            self._diverged(f"the AMG preconditioner's coarsest matrix is singular ({exc})",
                           np.full((n, d), np.nan))
        return self._keep(key, made)

    def _factor(self, types, Pm):
        """The factorization of P K P + I - P for ``types``' pattern, from the model's store or
        made now."""
        key = self._pattern(types, "")
        kept = self.model._factors
        if key in kept:
            return kept[key]
        n, d = self.model.n_vertices, self.model.gdim
        A = (Pm @ self.K @ Pm + sp.identity(n * d, format="csr") - Pm).tocsc()
        A.sort_indices()
        factor = self.factorize(A, {}) if self.factorize is not None else None
        if factor is None:
            try:
                factor = spd_splu(A)
            except RuntimeError as exc:   # singular: a free body part, nothing to hold it
                self._diverged(f"the projected stiffness is singular ({exc}): a part of the body "
                               f"free of every prescription", np.full((n, d), np.nan))
            # without pivoting U's diagonal holds the pivots of A's LDL^T: all positive iff A is
            # positive definite
            pivots = factor.U.diagonal()
            if not np.all(pivots > 0):
                bad = np.zeros(n * d)
                bad[~(pivots[factor.perm_c] > 0)] = np.inf   # pivot perm_c[k] is dof k's
                self._diverged("the stiffness is not positive definite (a non-positive pivot of "
                               "the projected tensors' factorization)", bad.reshape(n, d))
        # a sliding round's tangent planes: used once, not kept
        return factor if types.surface_of else self._keep(key, factor)

    def compliance(self, types):
        """The compliance G = P A^-1 P of ``types``' pattern (``condensed.Compliance``, on the
        direct solve's factorization of A = P K P + I - P), from the model's store or made now:
        its condensed block is kept with the factorization."""
        Pm = blockdiag(types.projector())
        factor = self._factor(types, Pm)
        key = self._pattern(types, "compliance")
        kept = self.model._factors.get(key)
        if kept is None or kept.factor is not factor:
            kept = self._keep(key, Compliance(factor, Pm, self.model.n_vertices,
                                              self.model.gdim))
        return kept

    def _direct(self, types, u):
        """One exact solve on u = u_c + P w: (P K P + I - P) w = P (f - K u_c), whose matrix is
        symmetric positive definite (the identity on the prescribed directions), factorized once
        per pattern of point types."""
        n, d = self.model.n_vertices, self.model.gdim
        Pm = blockdiag(types.projector())
        uc = types.prescribed_part()
        w = self._factor(types, Pm).solve(Pm @ (self.f - self.Kx(uc)).reshape(-1))
        new = uc + (Pm @ w).reshape(n, d)
        self.it += 1
        move = np.linalg.norm(new - u, axis=1)
        if not np.all(np.isfinite(move)) or move.max(initial=0.0) > self.blowup:
            self._diverged("the direct solve gave a non-finite or runaway displacement (a "
                           "part of the body held by nothing?)", new)
        self.steps.append(float(move.max(initial=0.0)))
        self.residual = float(np.abs(Pm @ (self.f - self.Kx(new)).reshape(-1)).max(initial=0.0))
        if self.callback is not None:
            self.callback(self.it, new)
        return new

    def solve_linear(self, types, u, method, refresh=None):
        """Iterate on u = u_c + P w until the stopping rule (refresh: re-project surfaces each
        iteration, descent only); "direct": one exact solve."""
        conjugate = method in ("pcg", "amg")
        if method == "direct":
            return self._direct(types, u)
        P = types.projector()
        proj, applyM, Kproj = self._operators(types, method, fold=refresh is None, P=P)
        u = types.prescribed_part() + proj(u)
        if method == "amg" and self.callback is None \
                and self.max_iter - self.it <= COMPILED_MAX_ITER and self.K.nnz < 2 ** 31:
            amg = self._amg(types)
            if amg.compiled:
                return self._compiled_amg(amg, u, proj, P)
        r = proj(self.f - self.Kx(u))
        z = applyM(r)
        p = z.copy()
        rz = float(np.vdot(r, z))
        r0 = max(float(np.abs(r).max(initial=0.0)), 1e-300)
        self.residual = float(np.abs(r).max(initial=0.0))
        first = len(self.steps)   # this solve's moves: "amg"'s stopping rule
        while self.it < self.max_iter:
            if rz <= 0.0:
                if rz == 0.0:
                    break
                self._diverged(f"non-positive preconditioned residual r.z = {rz:g}", r)
            self.it += 1
            if conjugate:
                q = Kproj(p)
                pq = float(np.vdot(p, q))
                if not pq > 0.0:
                    self._diverged(f"non-positive curvature p.Kp = {pq:g} (stiffness not positive "
                                   f"definite)", p)
                alpha = rz / pq
                step = alpha * p
            else:
                q = Kproj(z)
                if self.step_scale is None:
                    zq = float(np.vdot(z, q))
                    if not zq > 0.0:
                        self._diverged(f"non-positive curvature z.Kz = {zq:g}", z)
                    alpha = rz / zq
                else:
                    alpha = float(self.step_scale)
                step = alpha * z
            u = u + step
            smax_v = np.linalg.norm(step, axis=1)
            k = int(np.argmax(smax_v)) if len(smax_v) else 0
            smax = float(smax_v[k]) if len(smax_v) else 0.0
            if not np.isfinite(smax) or smax > self.blowup:
                bad = np.flatnonzero(~np.isfinite(smax_v))
                v = int(bad[0]) if bad.size else k
                raise SolverDivergedError(
                    f"mass-tensor {method}: diverged at iteration {self.it}: vertex {v} moved "
                    f"{smax_v[v]:g} mm in one iteration")
            self.steps.append(smax)
            if refresh is not None:
                types, _ = self.active_planes(refresh, u)
                proj, applyM, Kproj = self._operators(types, method, fold=False)
                r = proj(self.f - self.Kx(u))
            else:
                r = r - alpha * q
            rmax = float(np.abs(r).max(initial=0.0))
            self.residual = rmax
            if not np.isfinite(rmax) or rmax > 1e12 * r0:
                self._diverged(f"residual grew from {r0:g} to {rmax:g} mN", r)
            if self.callback is not None:
                self.callback(self.it, u)
            if smax == 0.0 or (distance_to_go(self.steps[first:]) / TAIL_MARGIN
                               if method == "amg" else smax) < self.stop:
                break
            z = applyM(r)
            rz_new = float(np.vdot(r, z))
            if conjugate:
                p = z + (rz_new / rz) * p
            rz = rz_new
        self.residual = float(np.abs(proj(self.f - self.Kx(u))).max(initial=0.0))
        return u

    def _compiled_amg(self, amg, u0, proj, P):
        """``solve_linear``'s "amg" iteration in the compiled kernel (same arithmetic, same
        stopping rule and divergence checks), with ``amg`` the pattern's ``FreeVertexAmg``."""
        u, moves, status, v, value, r, p = amg.iterate(
            self.K, P, self.f, u0, self.max_iter - self.it, self.stop, self.blowup)
        self.steps.extend(moves)
        self.it += len(moves) + (status in (3, 4))   # the failing iteration made no move
        if status == 2:
            self._diverged(f"non-positive preconditioned residual r.z = {value:g}", r)
        if status == 3:
            self._diverged(f"non-positive curvature p.Kp = {value:g} (stiffness not positive "
                           f"definite)", p)
        if status == 4:
            raise SolverDivergedError(f"mass-tensor amg: diverged at iteration {self.it}: vertex "
                                      f"{v} moved {value:g} mm in one iteration")
        if status == 5:
            r0 = max(float(np.abs(proj(self.f - self.Kx(u0))).max(initial=0.0)), 1e-300)
            self._diverged(f"residual grew from {r0:g} to {value:g} mN", r)
        self.residual = float(np.abs(proj(self.f - self.Kx(u))).max(initial=0.0))
        return u

    def _diverged(self, why, field_):
        a = np.linalg.norm(np.nan_to_num(field_, nan=np.inf), axis=1)
        v = int(np.argmax(a)) if len(a) else 0
        raise SolverDivergedError(f"mass-tensor: diverged at iteration {self.it}, vertex {v}: {why}")
