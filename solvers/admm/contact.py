"""Frictionless rigid tips in the ADMM solver: the reference's discrete contact energy, split
into consensus blocks that ADMM handles like its elements.

Energy: the contact points of ``solvers.contact`` (``ContactSet``: the reference's discrete
contact energy at P1, Pi_c(u) = sum_p W_p k_p phi(-g(y_p)) over the points p of the contact
rule on the indenters' contact facets, y_p = X_p + S_p u). Its gradient, exact Hessian (with the
tip's curvature) and per-tip report are there, on the host; the Newton polish adds them to the
elements' (``polish``).

ADMM. Each point is a consensus block z_p ~ S_p u (a displacement, mm) with weight c_p = rho
W_p / h_f (mN/mm: about what the elements around a vertex give the x-step matrix), so the
x-step matrix gains S^T diag(c) S (x) I_d, a scalar matrix like the elements' part: the
x-step's structure (one scalar factorization for all components) is kept. The z-step of a block,
z = argmin W k phi(-g(X + z)) + c/2 |z - zhat|^2 (zhat = S u + mu, mu the scaled dual), moves
zhat outward along the tip's normal n at X + zhat by t = pen* - s, where pen* = -g(X + zhat)
and s, the penetration left, solves pen* - s = a phi'(s) with a = W k / c, in closed form:

    s = (pen* + a eps / 2) / (1 + a)                 where pen* >= eps (1 + a / 2),
    s = 2 pen* / (1 + sqrt(1 + 2 a pen* / eps))      where 0 < pen* < eps (1 + a / 2),
    t = 0                                            out of contact.

Along the normal line of a point the gap changes at unit rate and the normal stays, so this is
the block's exact stationary point; at an ADMM fixed point the total energy's gradient vanishes
on the free dofs, as for the elements. The blocks run on the backend's array module (numpy or
CuPy) beside whichever element pass the backend has.

Units: mm, kPa, mN.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from tissue_reference.model.tips import gap_and_normal

from ..contact import ContactSet, require_frictionless

__all__ = ["CONTACT_WEIGHT", "AdmmContactSet", "ContactBlocks", "ContactSet",
           "require_modeled"]

CONTACT_WEIGHT = 1.0
"""c_p = CONTACT_WEIGHT rho W_p / h_f: the contact blocks' ADMM weight (mN/mm)."""


def require_modeled(case) -> None:
    """NotModeledError when ``case`` has a tip the ADMM solver does not model (a tied one: it
    models frictionless tips)."""
    require_frictionless(case, "the ADMM solver")


class AdmmContactSet(ContactSet):
    """The contact points of a Case's indenters (``solvers.contact.ContactSet``) with their
    ADMM blocks' weights c0 (P,) mN/mm at the operators' rho (kPa), c0 = CONTACT_WEIGHT rho W / h;
    refuses a tip that is not frictionless (``require_modeled``)."""

    def __init__(self, case, rho: float, **options):
        require_modeled(case)
        super().__init__(case, **options)
        self.c0 = CONTACT_WEIGHT * rho * self.W * self.k / (self.beta * float(case.material.E))

    def scalar_matrix(self) -> sp.csr_matrix:
        """S^T diag(c0) S (n, n): the contact blocks' share of the scalar x-step matrix."""
        return (self.S.T @ sp.diags(self.c0) @ self.S).tocsr()

    def vector_matrix(self) -> sp.csr_matrix:
        """The same, (N, N) node-major (the scalar matrix times I_d)."""
        return sp.kron(self.scalar_matrix(), sp.identity(self.d), format="csr")


class ContactBlocks:
    """The contact blocks of one ADMM solve (one load or time step, the tips' ends at ``o``) on
    the array module of the backend: ``xdata`` (their share of the x-step's data), ``update``
    (gather, z-step, dual update, residuals after an x-step), ``halve_dual`` (rho doubled).
    ``u0`` (host, node-major): the start state; the blocks start with one z-step from S u0 and
    a zero dual. ``dev``: an object with ``put`` (host -> array) and ``sparse`` (the
    array module's sparse matrix constructor), or None for numpy/scipy."""

    def __init__(self, ops, cset: AdmmContactSet, up, u0, o, zstep, dev=None):
        xp = zstep.xp
        self.xp, self.zstep, self.rho0 = xp, zstep, ops.rho
        put = np.asarray if dev is None else dev.put
        mats = ops.contact_matrices()
        if dev is not None:
            mats = tuple(dev.sparse(M) for M in mats)
        self.SZ, self.Bt = mats
        d = ops.d
        Sd = ops.contact_gather
        self.base = put(cset.X.reshape(-1) + Sd @ up)          # X + S u_p, (P d,)
        self.X = put(cset.X)
        self.o, self.dirs = put(o), put(cset.dirs)
        self.flat, self.edge = put(cset.flat), put(cset.edge)
        self.Wk, self.eps, self.c0 = put(cset.Wk), put(cset.eps), put(cset.c0)
        self.d = d
        # start: one z-step from S u0 with a zero dual (the dual of the penalty's force at a
        # state the tips were just pushed into would be that force over c: hundreds of mm)
        self.z = put((Sd @ u0).reshape(-1, d))
        self.mu = xp.zeros_like(self.z)
        self.w = self.z
        self.update_from(self.z + self.X)

    def xdata(self):
        """Z^T (S^T diag(c0) (z - mu)) (x) I_d (mN): the blocks' share of the x-step's data."""
        return self.Bt @ self.w.reshape(-1)

    def halve_dual(self):
        self.mu *= 0.5
        self.w = self.z - self.mu

    def state(self):
        """(z, mu) as one vector (``loop.Anderson``)."""
        return self.xp.concatenate((self.z.reshape(-1), self.mu.reshape(-1)))

    def set_state(self, x):
        n = self.z.size
        self.z = x[:n].reshape(self.z.shape).copy()
        self.mu = x[n:].reshape(self.mu.shape).copy()
        self.w = self.z - self.mu

    def update(self, q):
        """Gather S u + mu, z-step, dual update after the x-step q; returns (r, dsq) per block:
        |S u - z'|^2 and |z' - z|^2 (mm^2)."""
        return self.update_from((self.SZ @ q + self.base).reshape(-1, self.d))

    def update_from(self, uhat):
        """The z-step and dual update from the points' positions uhat = X + S u (P, gdim)."""
        xp = self.xp
        yhat = uhat + self.mu
        g, nrm = gap_and_normal(yhat, self.o, self.dirs, self.flat, self.edge, xp=xp)
        pen = -g
        a = self.Wk / ((self.zstep.rho / self.rho0) * self.c0)
        eps = self.eps
        deep = pen >= eps * (1.0 + 0.5 * a)
        s_deep = (pen + 0.5 * a * eps) / (1.0 + a)
        s_near = 2.0 * pen / (1.0 + xp.sqrt(1.0 + 2.0 * a * xp.maximum(pen, 0.0) / eps))
        t = xp.where(pen > 0, pen - xp.where(deep, s_deep, s_near), 0.0)
        z_new = yhat - self.X + t[:, None] * nrm
        mu_new = -t[:, None] * nrm
        dm = mu_new - self.mu
        dz = z_new - self.z
        r = (dm * dm).sum(axis=1)
        dsq = (dz * dz).sum(axis=1)
        self.z, self.mu = z_new, mu_new
        self.w = z_new - mu_new
        return r, dsq
