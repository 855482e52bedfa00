"""Operators of the ADMM solver, precomputed once per Case structure (mesh, material,
constrained dof set, rho, dt): the per-element gather matrix D (H = D u, structure-of-arrays
rows), the weights w_e^2 = rho V_e, the lumped mass of implicit-Euler dynamics, the x-step
matrix Mx = D^T W^2 D (+ M/dt^2) and, for the CPU x-step, its factorization.

x-step solver of the CPU path: without oblique sliding, D^T W^2 D (+ M/dt^2) is a scalar matrix
times I_d in node-major order, so one scalar SuperLU factorization per distinct free-vertex set
serves all components (multi-column solves; the reduced unknowns are ordered component-major,
so the right-hand side is a view, no gather); with oblique sliding the reduced coupled matrix is
factorized. From PCG_MIN (4000) free vertices on (about 20k tets) the scalar matrix is not
factorized (a direct factor's fill and solve time grow like n^1.4-1.5 on these 3D meshes: 28M
factor entries, 320 MiB and 130 ms per solve at 185k tets; at 50k tets SuperLU's solve took 12 ms,
CG 6 ms) but solved by conjugate gradients preconditioned with an aggregation AMG V-cycle
(``amg``): the x-step is then inexact, warm-started from the previous iterate and stopped when
its largest vertex update is below PCG_RTOL (0.3) times the first one or below XSTEP_TOL (0.1)
times the ADMM tolerance; the ADMM stopping rule also requires the last CG update below
``tol_mm``. The x-step matrix is constant, so at an ADMM fixed point the warm start solves it
exactly and the fixed point (the answer) is unchanged. The factorization is built with the
operators (``factor=True``, the CPU path) or on first use of ``AdmmOperators.lu``."""
from __future__ import annotations

import time
from collections import OrderedDict
from dataclasses import replace

import numpy as np
import scipy.sparse as sp

from tissue_reference.errors import CaseError

from .amg import AmgPcg
from .constraints import constraint_reduction, vertex_rank
from .contact import AdmmContactSet
from .factor import CoupledSolver, Direct
from .kernel_c import KernelForces, use_kernel
from .mechanics import assemble, case_parts, det_closed_form, element_K

PCG_MIN = 4000  # free vertices from which the x-step is solved by AMG-preconditioned CG
PCG_ITERS = 1  # least warm-started PCG iterations per ADMM x-step
XSTEP_TOL = 0.1  # PCG x-step: largest vertex update (mm) below XSTEP_TOL * tol_mm


def vertex_norm_max(du, d):
    """Largest vertex norm (mm) of a node-major displacement du."""
    du = du.reshape(-1, d)
    return float(np.sqrt(np.einsum("ij,ij->i", du, du).max(initial=0.0)))


def scalar_laplacian(kin, rho, n):
    """sum_e rho V_e G_e G_e^T (n, n): D^T W^2 D = this (x) I_d in node-major order."""
    k = kin.G.shape[1]
    Ke = rho * kin.V[:, None, None] * np.einsum("maj,mbj->mab", kin.G, kin.G)
    cells = kin.dofs[:, ::kin.d] // kin.d
    rows = np.repeat(cells, k, axis=1).ravel()
    cols = np.tile(cells, (1, k)).ravel()
    return sp.csr_matrix((Ke.ravel(), (rows, cols)), shape=(n, n))


class ComponentSolver:
    """Solves the reduced x-step system when it is block diagonal per displacement component:
    one scalar solver per distinct free-vertex set (SuperLU, or AMG-preconditioned CG from
    PCG_MIN free vertices on), the components sharing a set solved together as a multi-column
    right-hand side. ``step(rhs, q0)`` is the x-step (warm-started from q0 for CG)."""

    def __init__(self, Ls, plain_dofs, d):
        comp = plain_dofs % d
        groups = {}
        for c in range(d):
            pos = np.flatnonzero(comp == c)
            verts = plain_dofs[pos] // d
            groups.setdefault(verts.tobytes(), (verts, []))[1].append(pos)
        self.groups = []
        for verts, poss in groups.values():
            A = Ls[verts][:, verts]
            sol = AmgPcg(A, PCG_ITERS) if len(verts) >= PCG_MIN else Direct(A)
            self.groups.append((sol, np.stack(poss, axis=1)))
        self.nnz = sum(g.nnz for g, _ in self.groups)
        self.bytes = sum(g.bytes for g, _ in self.groups)
        self.untracked_bytes = sum(g.untracked_bytes for g, _ in self.groups)
        self.kind = "+".join(sorted({type(g).__name__.strip("_") for g, _ in self.groups}))
        # one group over all components in component-major order: no gather/scatter
        self.whole = None
        if len(self.groups) == 1:
            pos = self.groups[0][1]
            if pos.size == len(plain_dofs) and np.array_equal(
                    pos, np.arange(pos.size).reshape(pos.shape[1], -1).T):
                self.whole = pos.shape

    def solve(self, rhs, q0=None, tol_mm=0.0):
        if self.whole is not None:
            nv, nc = self.whole
            g = self.groups[0][0]
            B = rhs.reshape(nc, nv).T
            X = g.solve(B) if q0 is None else g.step(B, q0.reshape(nc, nv).T, tol_mm)
            return np.ascontiguousarray(X.T).reshape(-1)
        out = np.empty_like(rhs)
        for g, pos in self.groups:
            out[pos] = g.solve(rhs[pos]) if q0 is None else g.step(rhs[pos], q0[pos], tol_mm)
        return out

    def step(self, rhs, q0, tol_mm):
        """The ADMM x-step: exact (SuperLU) or warm-started from q0 to vertex updates below
        tol_mm (mm) (CG)."""
        return self.solve(rhs, q0, tol_mm)

    @property
    def inexactness(self):
        """Error proxy (mm) of the last x-step: the largest vertex update of the last CG
        iteration (0 for SuperLU)."""
        return max((getattr(g, "last_update", 0.0) for g, _ in self.groups), default=0.0)


class AdmmOperators:
    """Everything precomputed once per Case structure (mesh, material, constrained dof set,
    rho, dt): D, the x-step matrix (and, ``factor``: its factorization now, else on first use
    of ``lu``), the reduction u = up + Z q. ``device_data``: per-backend copies of the
    operators (e.g. on a GPU), kept by ``backends``."""

    def __init__(self, case, *, rho: float | None = None, dt: float | None = None,
                 factor: bool = True, contact: dict | None = None):
        t0 = time.perf_counter()
        self.mesh = case.mesh
        kin, law = case_parts(case)
        self.kin, self.law = kin, law
        n, d = case.mesh.n_vertices, kin.d
        self.n, self.d, self.N, self.m = n, d, n * d, len(kin.V)
        mat = case.material
        if rho is None:
            rho = mat.kappa + 4.0 * mat.mu / 3.0  # = lambda + 2 mu, the P-wave modulus
        if not (np.isfinite(rho) and rho > 0):
            raise CaseError(f"ADMM rho must be > 0 kPa, got {rho!r}")
        self.rho = float(rho)
        self.red = constraint_reduction(case)
        Z = self.red.Z
        m = self.m
        # the ADMM loop's element order: by the reverse Cuthill-McKee rank of their first
        # vertex (memory locality of the products with D on large meshes); internal element k
        # is mesh element elem_order[k]
        self.elem_order = eo = np.argsort(vertex_rank(case.mesh)[case.mesh.cells].min(axis=1),
                                          kind="stable")
        self.h = kin.V[eo] ** (1.0 / d)
        # D: (m*d*d, N) with H_flat = D u, rows in structure-of-arrays order (i, J, k): H_iJ of
        # (internal) element k at (d i + J) m + k
        rows = (np.arange(m)[:, None, None, None] + np.arange(d)[None, None, :, None] * d * m
                + np.arange(d)[None, None, None, :] * m)  # (m, a, i, J)
        rows = np.broadcast_to(rows, (m, d + 1, d, d))
        cols = np.broadcast_to(kin.dofs[eo].reshape(m, d + 1, d)[:, :, :, None],
                               (m, d + 1, d, d))
        vals = np.broadcast_to(kin.G[eo][:, :, None, :], (m, d + 1, d, d))
        D = sp.csr_matrix((vals.ravel(), (rows.ravel(), cols.ravel())), shape=(m * d * d, self.N))
        self.D = D
        w2 = self.rho * np.tile(kin.V[eo], d * d)
        self.w2 = w2
        self.DZ = (D @ Z).tocsr()
        self.eye_soa = np.repeat(np.eye(d).ravel(), m)  # I of every element, (d, d, m) flat
        self.DZtW = (self.DZ.T.multiply(w2[None, :])).tocsr()
        self.DZtW_I = self.DZtW @ self.eye_soa  # the identity's share of the x-step data
        L = (D.T.multiply(w2[None, :]) @ D).tocsr()
        self.L = L
        self.dt = dt
        self.mass = None
        # rigid tips: their contact blocks' share S^T diag(c) S (x) I_d of the x-step matrix
        self.contact = AdmmContactSet(case, self.rho, **(contact or {})) if case.indenters() \
            else None
        self._contact_mats = None
        if self.contact is not None:
            L = L + self.contact.vector_matrix()
        Mx = L
        if dt is not None:
            mv = np.zeros(n)
            np.add.at(mv, case.mesh.cells.ravel(), np.repeat(mat.density * kin.V / (d + 1), d + 1))
            self.mass = np.repeat(mv, d)
            Mx = L + sp.diags(self.mass / dt ** 2)
        self.Mx = Mx.tocsr()
        self.nq = Z.shape[1]
        self._kpat = None  # reduced tangent's CSR pattern (built on first use)
        self._Dm = None  # gradient operator in mesh element order (built on first use)
        self._kernel_forces = None  # the compiled internal forces (False: none; first use)
        self.factor_cache = {}  # kept by ``factorize`` (e.g. a symbolic analysis)
        # (factorize hook, element matrices, factorization) of the tangent at rest without
        # contact: a lift from rest (every cold solve's first load step) needs no other
        self.rest_tangent = None
        self.device_data = {}
        self._lu = None
        self.setup_s = time.perf_counter() - t0
        if factor:
            self._lu = self._factor_xstep()

    def _factor_xstep(self):
        """The CPU x-step solver (its setup time is added to ``setup_s``)."""
        t0 = time.perf_counter()
        if self.red.separable:
            # no oblique sliding: the x-step matrix is (rho scalar P1 Laplacian [+ M/dt^2]) x I_d;
            # factorize the scalar matrix once per distinct set of free vertices
            Ls = scalar_laplacian(self.kin, self.rho, self.n)
            if self.contact is not None:
                Ls = Ls + self.contact.scalar_matrix()
            if self.dt is not None:
                Ls = Ls + sp.diags(self.mass[::self.d] / self.dt ** 2)
            lu = ComponentSolver(Ls.tocsr(), self.red.plain_dofs, self.d)
        else:
            lu = CoupledSolver(self.red.ZT @ self.Mx @ self.red.Z)
        self.setup_s += time.perf_counter() - t0
        return lu

    @property
    def lu(self):
        """The CPU x-step solver (``step``, ``solve``, ``inexactness``), built on first use."""
        if self._lu is None:
            self._lu = self._factor_xstep()
        return self._lu

    def law_values(self, u):
        """The law's psi, P and A at u (``mechanics.LawValues``) from one evaluation, for
        ``energy``, ``residual`` and ``reduced_tangent`` at the same u; None for the laws of the
        compiled element pass, whose forces come from that pass."""
        return None if self.law.kernel else self.law.evaluate(self.grad(u))

    def reduced_tangent(self, u, diag=None, extra=None, values=None):
        """(Z^T (K(u) + diag(diag) + extra) Z as CSC, element matrices Ke): the tangent of the
        P1 energy on the reduced unknowns; ``extra`` (N, N) sparse, e.g. the contact's Hessian,
        whose entries couple dofs of one cell; ``values``: ``law_values(u)`` where known.
        Without oblique sliding it is assembled straight into a CSR pattern computed once (the
        matrix is symmetric, so its CSR arrays are its CSC)."""
        A = values.A if values is not None else self.law.tangent(self.grad(u))
        Ke = element_K(self.kin, A)
        Z = self.red.Z
        if not self.red.separable:
            K = assemble(self.kin, Ke, self.N)
            if diag is not None:
                K = K + sp.diags(diag)
            if extra is not None:
                K = K + extra
            return (self.red.ZT @ K @ Z).tocsc(), Ke
        if self._kpat is None:
            nq = self.nq
            ridx = np.full(self.N, -1, np.int64)
            ridx[self.red.plain_dofs] = np.arange(nq)
            R = ridx[self.kin.dofs]
            nd = R.shape[1]
            rows = np.repeat(R, nd, axis=1).ravel()
            cols = np.tile(R, (1, nd)).ravel()
            valid = (rows >= 0) & (cols >= 0)
            ukey, pos = np.unique(rows[valid] * nq + cols[valid], return_inverse=True)
            indptr = np.concatenate([[0], np.cumsum(np.bincount(ukey // nq, minlength=nq))])
            dpos = np.searchsorted(ukey, np.arange(nq) * (nq + 1))
            self._kpat = (pos.astype(np.int32 if len(ukey) < 2 ** 31 else np.int64), valid,
                          indptr, (ukey % nq).astype(np.int32), len(ukey), dpos, ukey, ridx)
        pos, valid, indptr, indices, nnz, dpos, ukey, ridx = self._kpat
        data = np.bincount(pos, weights=Ke.reshape(-1)[valid], minlength=nnz)
        if diag is not None:
            data[dpos] += diag[self.red.plain_dofs]
        if extra is not None and extra.nnz:
            E = extra.tocoo()
            r, c = ridx[E.row], ridx[E.col]
            keep = (r >= 0) & (c >= 0)
            at = np.searchsorted(ukey, r[keep] * self.nq + c[keep])
            np.add.at(data, at, E.data[keep])
        return sp.csc_matrix((data, indices, indptr), shape=(self.nq, self.nq)), Ke

    def _mesh_gradient(self):
        """(D_m, D_m^T): the gradient operator in mesh element order with rows (k, i, J) (H of
        element k at k d^2 + d i + J), CSR; built on first use."""
        if self._Dm is None:
            kin, m, d = self.kin, self.m, self.d
            rows = np.broadcast_to((np.arange(m)[:, None, None, None] * d * d
                                    + np.arange(d)[None, None, :, None] * d
                                    + np.arange(d)[None, None, None, :]), (m, d + 1, d, d))
            cols = np.broadcast_to(kin.dofs.reshape(m, d + 1, d)[:, :, :, None], (m, d + 1, d, d))
            vals = np.broadcast_to(kin.G[:, :, None, :], (m, d + 1, d, d))
            Dm = sp.csr_matrix((vals.ravel(), (rows.ravel(), cols.ravel())),
                               shape=(m * d * d, self.N))
            self._Dm = (Dm, Dm.T.tocsr())
        return self._Dm

    def grad(self, u):
        """H_e = grad u (m, d, d), mesh element order (as ``mechanics.displacement_gradient``,
        one sparse product)."""
        return (self._mesh_gradient()[0] @ u.reshape(-1)).reshape(self.m, self.d, self.d)

    def valid(self, u) -> bool:
        """Whether no cell of the displacement u (mm, (N,)) is inverted (det F > 0 in every
        cell); always True for linear elasticity, whose energy has no such bound."""
        if self.law.model == "linear-elastic":
            return True
        return bool(np.all(det_closed_form(self.grad(u) + np.eye(self.d)) > 0))

    def scatter(self, Pv):
        """Nodal forces sum_e Pv_e : grad N_a (node-major, (N,)) of Pv (m, d, d) (as
        ``mechanics.scatter_forces``, one sparse product)."""
        return self._mesh_gradient()[1] @ Pv.reshape(-1)

    def apply_elements(self, Ke, v):
        """K v (full dofs, mN) from element matrices Ke, without assembling K."""
        fe = np.einsum("mab,mb->ma", Ke, v[self.kin.dofs])
        return np.bincount(self.kin.dofs.ravel(), weights=fe.ravel(), minlength=self.N)

    def energy(self, u, fext, tips=None, values=None) -> tuple:
        """(E, J): the P1 energy sum_e V_e psi_e - f_ext . u (uJ) at displacement u (mm), plus
        the rigid tips' contact energy where ``tips`` gives their ends; inf where a cell is
        inverted. J: the cells' det F (None for linear elasticity). ``values``:
        ``law_values(u)`` where known."""
        psi, J = (values.psi, values.J) if values is not None else self.law.psi_J(self.grad(u))
        e = float(self.kin.V @ psi) - float(fext @ u)
        if tips is not None and self.contact is not None:
            e += self.contact.energy(u, tips)
        return e, J

    def _forces(self, u, fext, values=None):
        """(internal minus external nodal forces at u, whether no cell of u is inverted): the
        compiled pass (``kernel_c.KernelForces``) where the kernel is built, else numpy's
        stress (``values.P`` where given) and two sparse products (the same arithmetic)."""
        if values is not None:
            r = self.scatter(self.kin.V[:, None, None] * values.P) - fext
            return r, values.J is None or bool(np.all(values.J > 0))
        if self._kernel_forces is None:
            self._kernel_forces = KernelForces(self) if use_kernel() and self.law.kernel \
                else False
        if self._kernel_forces:
            r = np.zeros(self.N)
            r -= fext
            return r, self._kernel_forces.add(u, r) > 0
        P, J = self.law.stress(self.grad(u))
        r = self.scatter(self.kin.V[:, None, None] * P) - fext
        return r, J is None or bool(np.all(J > 0))

    def residual(self, u, fext, tips=None, values=None) -> np.ndarray:
        """Internal minus external nodal forces (mN, full node-major) at displacement u (mm),
        plus the rigid tips' contact forces where ``tips`` gives their ends
        (``contact.ContactSet.origins``): the gradient of the P1 energy, zero on the free dofs
        at equilibrium. ``values``: ``law_values(u)`` where known."""
        r, _ = self._forces(u, fext, values)
        return self._with_contact(r, u, tips)

    def residual_if_valid(self, u, fext, tips=None):
        """``residual(u, fext, tips)``, or None where a cell of u is inverted (det F <= 0, the
        test of ``valid``): one pass serves both."""
        r, ok = self._forces(u, fext)
        return self._with_contact(r, u, tips) if ok else None

    def _with_contact(self, r, u, tips):
        """r plus the rigid tips' contact forces at u where ``tips`` gives their ends."""
        if tips is not None and self.contact is not None:
            r = r + self.contact.gradient(u, tips)
        return r

    def residuals(self, U, fext) -> np.ndarray:
        """``residual`` of each column of U ((N, k) mm) at once, (N, k) mN: one sparse product
        for the gradients, one stress evaluation and one for the forces (a batch of directional
        differences costs about what two single residuals do)."""
        U = np.asarray(U, float).reshape(self.N, -1)
        k, m, d = U.shape[1], self.m, self.d
        Dm, DmT = self._mesh_gradient()
        H = (Dm @ U).reshape(m, d, d, k).transpose(3, 0, 1, 2).reshape(k * m, d, d)
        P, _ = self.law.stress(H)
        Pv = (np.tile(self.kin.V, k)[:, None, None] * P).reshape(k, m * d * d).T
        return DmT @ Pv - np.asarray(fext, float).reshape(-1, 1)

    def tangent_products(self, u, tips=None):
        """V -> K V ((N, k) mm -> (N, k) mN): products with the exact tangent K at u from the
        elements' material tangents, without assembling K (one tangent evaluation here, then
        two sparse products and a batch of small ones per call); with ``tips``, K includes the
        contact's exact Hessian (assembled: it lives on the contact surface only)."""
        m, dd = self.m, self.d * self.d
        A = self.law.tangent(self.grad(u)) * self.kin.V[:, None, None]
        Dm, DmT = self._mesh_gradient()
        Hc = self.contact.hessian(u, tips) if tips is not None and self.contact is not None \
            else None

        def apply(V):
            V = np.asarray(V, float).reshape(self.N, -1)
            G = (Dm @ V).reshape(m, dd, V.shape[1])
            KV = DmT @ np.matmul(A, G).reshape(m * dd, V.shape[1])
            return KV if Hc is None else KV + Hc @ V
        return apply

    def prescribed(self, case) -> np.ndarray:
        """The prescribed part u_p (mm, full node-major) of the displacement for ``case``'s
        boundary values (a Case of this structure: other pushes, the same regions)."""
        return particular(case, self)

    @property
    def contact_gather(self) -> sp.csr_matrix:
        """S (x) I_d (P gdim, N): the contact points' displacements (point-major) from u."""
        return self._contact_matrices()[0]

    def contact_matrices(self):
        """(S_d Z, Z^T S_d^T diag(c0)): the contact blocks' gather from the reduced unknowns
        and scatter of their x-step data (S_d = S (x) I_d); built on first use."""
        return self._contact_matrices()[1:]

    def _contact_matrices(self):
        if self._contact_mats is None:
            c = self.contact
            Sd = sp.kron(c.S, sp.identity(self.d), format="csr")
            Bt = (self.red.ZT @ Sd.T @ sp.diags(np.repeat(c.c0, self.d))).tocsr()
            self._contact_mats = (Sd, (Sd @ self.red.Z).tocsr(), Bt)
        return self._contact_mats

    def step_norm(self, dq):
        """Largest vertex displacement (mm) of the reduced increment dq."""
        whole = getattr(self.lu, "whole", None)
        if whole is not None:  # component-major plain dofs, every component on the same vertices
            dq = dq.reshape(whole[1], whole[0])
            return float(np.sqrt(np.einsum("ij,ij->j", dq, dq).max(initial=0.0)))
        return vertex_norm_max(self.red.Z @ dq, self.d)


OPERATOR_CACHE: OrderedDict[tuple, AdmmOperators] = OrderedDict()


def structure_key(case, rho, dt, contact):
    c = case.constraints
    sl = tuple((np.asarray(v).tobytes(), tuple(np.asarray(nr, float).round(14))) for v, nr, _ in
               c.sliding)
    tips = tuple(replace(a, push=0.0) for a in case.indenters())
    return (id(case.mesh), c.dofs.tobytes(), sl, case.material, rho, dt, tips,
            case.reference_contact_quadrature, case.reference_tip_start,
            tuple(sorted((contact or {}).items())))


def prepare(case, *, rho: float | None = None, dt: float | None = None,
            factor: bool = True, contact: dict | None = None) -> AdmmOperators:
    """The per-Case operators (x-step factorization included unless ``factor`` is False: then
    it is built on first use), cached for the last 4 Case structures: a Case differing only in
    prescribed values or pushes reuses them. ``contact``: the options of the tips' contact
    (``contact.AdmmContactSet``: rule, penalty, tip_start; None for the case's defaults)."""
    key = structure_key(case, rho, dt, contact)
    ops = OPERATOR_CACHE.get(key)
    if ops is not None and ops.mesh is case.mesh:
        OPERATOR_CACHE.move_to_end(key)
        return ops
    ops = AdmmOperators(case, rho=rho, dt=dt, factor=factor, contact=contact)
    OPERATOR_CACHE[key] = ops
    while len(OPERATOR_CACHE) > 4:
        OPERATOR_CACHE.popitem(last=False)
    return ops


def particular(case, ops: AdmmOperators) -> np.ndarray:
    """Prescribed part u_p (mm) of the displacement for this Case's boundary values."""
    c = case.constraints
    if c.sliding:
        return constraint_reduction(case).up
    up = np.zeros(ops.N)
    up[c.dofs] = c.values
    return up

