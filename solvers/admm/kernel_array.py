"""The element pass of an ADMM iteration on arrays: gather D u, z-step for every element, dual
update, residuals and the next x-step data D^T W (z - lam), written against an array module
``xp`` (numpy, or CuPy on a GPU; float64 throughout). It is the same arithmetic as the compiled
kernel (``kernel_c``): on numpy it is the element pass when no C compiler is usable, and the
element pass of the array backends (``device="gpu"``, and ``device="array-cpu"`` which runs this
code on numpy). numpy works on cache blocks of CHUNK elements, CuPy on all elements at once.

Only operations that numpy and CuPy share are used: ufuncs with ``out=``, ``einsum`` without
``out`` (CuPy's has none: see ``_dot_into``), integer-array indexing and 1-D boolean masks."""
from __future__ import annotations

import contextlib

import numpy as np

from tissue_reference.errors import NotModeledError

from .mechanics import KERNEL_LAWS

ROUNDS = 4  # z-step rounds for elements whose line search backtracked
CHUNK = 8192  # elements per cache block of the numpy ADMM loop


def _errstate(xp):
    """numpy's floating-point error state switched off (CuPy does not warn)."""
    return np.errstate(invalid="ignore", divide="ignore") if xp is np else contextlib.nullcontext()


def _dot_into(xp, a, b, out):
    """out[k] = sum_ij a_ijk b_ijk, in place (CuPy's einsum has no ``out``)."""
    if xp is np:
        np.einsum("ijk,ijk->k", a, b, out=out)
    else:
        out[...] = xp.einsum("ijk,ijk->k", a, b)


def aos(z):
    """(d, d, m) structure-of-arrays block -> (m, d, d) view."""
    return z.transpose(2, 0, 1)


def soa(H):
    """(m, d, d) -> contiguous (d, d, m)."""
    return np.ascontiguousarray(H.transpose(1, 2, 0))


class ZStep:
    """Per-element proximal step F = argmin psi(F) + rho/2 |F - Fhat|^2 (F = I + z) for all
    elements at once, on structure-of-arrays blocks (d, d, m): entry (i, J) of every element is
    one contiguous row. The ADMM loop keeps F = I + z in "extended" buffers E (5, 5, m) in 3D,
    F = E[:3, :3], whose last two rows/columns repeat the first two, so that every cofactor is a
    product of two shifted views (cof_ij = F[i+1, j+1] F[i+2, j+2] - F[i+1, j+2] F[i+2, j+1]).

    Neo-Hookean: one Newton-type step from the previous F (warm start) with the model Hessian
    M = (rho + mu J^(-2/3)) I + max(kappa (2 - 1/J), 0) cof (x) cof (the rho part and the
    volumetric part of the exact Hessian, which dominate it for rho of the order of the P-wave
    modulus), applied in closed form (Sherman-Morrison): no per-element matrices are formed,
    stored or inverted. Steps |D| <= s = ``small_step`` from states with
    J > s I1/sqrt(3) + s^2 sqrt(I1) + s^3 keep J > 0 (det(F + D) >= J - |cof||D| - |F||D|^2 -
    |D|^3, |cof| <= I1/sqrt(3)) and are taken as they are; the others get an Armijo backtracking
    on the local objective and further steps (up to ``rounds``). At a fixed point the local
    gradient vanishes, so the fixed point is exact whatever M. ``xp``: the array module of the
    blocks (numpy or CuPy)."""

    small_step = 1e-2  # |dF| below which a step from a safe state is taken unchecked

    def __init__(self, ops, rho, rounds=None, xp=np):
        rounds = ROUNDS if rounds is None else rounds
        self.xp = xp
        self.law = ops.law
        self.d = ops.d
        self.rounds = rounds
        self._buf = {}
        self.set_rho(rho)

    def set_rho(self, rho):
        mat, d = self.law, self.d
        self.rho = rho
        if mat.model == "linear-elastic":
            self.f_dev = rho / (rho + 2 * mat.mu)
            self.f_vol = rho / (rho + 2 * mat.mu + d * mat.lmbda)

    def new_state(self, k):
        """An extended buffer for F (see the class docstring) and its F view."""
        d, xp = self.d, self.xp
        E = xp.empty((5, 5, k)) if d == 3 else xp.empty((d, d, k))
        return E, E[:d, :d]

    def _scratch(self, k):
        b = self._buf.get(k)
        if b is None:
            d, xp = self.d, self.xp
            b = (xp.empty((d, d, k)), xp.empty((d, d, k)), None)
            if len(self._buf) > 2:
                self._buf.clear()
            self._buf[k] = b  # the chunk sizes of the ADMM loop
        return b

    def _parts(self, E, cof, t):
        """cof (into ``cof``), J, I1 (plane strain: + 1) of F = E[:d, :d]."""
        d, xp = self.d, self.xp
        F = E[:d, :d]
        if d == 3:
            E[3:, :3] = E[:2, :3]
            E[:, 3:] = E[:, :2]
            xp.multiply(E[1:4, 1:4], E[2:5, 2:5], out=cof)
            xp.multiply(E[1:4, 2:5], E[2:5, 1:4], out=t)
            cof -= t
            J = xp.einsum("jk,jk->k", F[0], cof[0])
            I1 = xp.einsum("ijk,ijk->k", F, F)
        else:
            cof[0, 0], cof[1, 1] = F[1, 1], F[0, 0]
            xp.negative(F[1, 0], out=cof[0, 1])
            xp.negative(F[0, 1], out=cof[1, 0])
            J = F[0, 0] * F[1, 1] - F[0, 1] * F[1, 0]
            I1 = xp.einsum("ijk,ijk->k", F, F)
            I1 += 1.0
        return J, I1

    def _phi(self, F, Fhat):
        """Local objective psi(F) + rho/2 |F - Fhat|^2 (inf where J <= 0) and J; F (d, d, k)."""
        mu, kappa, d, xp = self.law.mu, self.law.kappa, self.d, self.xp
        E, _ = self.new_state(F.shape[2])
        E[:d, :d] = F
        J, I1 = self._parts(E, xp.empty_like(F), xp.empty_like(F))
        with _errstate(xp):
            psi = 0.5 * mu * (xp.abs(J) ** (-2.0 / 3.0) * I1 - 3.0) + 0.5 * kappa * (J - 1.0) ** 2
        psi[~(J > 0)] = xp.inf
        r = F - Fhat
        return psi + 0.5 * self.rho * xp.einsum("ijk,ijk->k", r, r), J

    def __call__(self, Fhat, E, Enew):
        """Writes the new F into Enew[:d, :d] (F = E[:d, :d] is the previous one) and returns
        |F_new - F|^2 per element; Fhat (d, d, m) contiguous."""
        d, xp = self.d, self.xp
        F, Fn = E[:d, :d], Enew[:d, :d]
        if self.law.model == "linear-elastic":
            # closed form on H = F - I: skew + f_dev dev(sym H) + f_vol tr(H)/d I
            xp.add(Fhat, Fhat.transpose(1, 0, 2), out=Fn)
            Fn *= 0.5  # sym F
            skew = Fhat - Fn
            t = xp.einsum("iik->k", Fn) / d - 1.0  # tr(sym H) / d
            Fn *= self.f_dev
            Fn += skew
            for i in range(d):
                Fn[i, i] += (self.f_vol - self.f_dev) * t + (1.0 - self.f_dev)
            dz = Fn - F
            return xp.einsum("ijk,ijk->k", dz, dz)
        dsq, check, redo = self._step(Fhat, E, Fn, self._scratch(Fhat.shape[2]))
        for _ in range(self.rounds - 1):
            if not len(redo):
                break
            Es, _ = self.new_state(len(redo))
            Es[:d, :d] = Fn[:, :, redo]
            out = xp.empty((d, d, len(redo)))
            _, _, r2 = self._step(Fhat[:, :, redo], Es, out,
                                  tuple(xp.empty_like(out) for _ in range(3)))
            Fn[:, :, redo] = out
            redo = redo[r2]
        if len(check):
            dz = Fn[:, :, check] - F[:, :, check]
            dsq[check] = xp.einsum("ijk,ijk->k", dz, dz)
        return dsq

    def _step(self, Fhat, E, Fn, scratch):
        """One safeguarded model-Newton step from F = E[:d, :d] into Fn; returns (|dF|^2 of the
        full model step, indices (into this block) of the elements checked by the line search,
        of those that backtracked and may step again).

        With P = a F + b cof (a = mu J^(-2/3), b = kappa (J - 1) - a I1 / (3 J)), the local
        gradient over rho is g = (1 + a/rho) F - Fhat + (b/rho) cof, and the model step
        F - M^-1 g / ... simplifies (the F terms cancel) to
        F_new = (Fhat + (s - b/rho) cof) / (1 + a/rho), s = beta (cof:g) / (alpha + beta |cof|^2),
        cof:g = alpha d J - cof:Fhat + (b/rho) |cof|^2 (cof:F = d J)."""
        mu, kappa, rho, d = self.law.mu / self.rho, self.law.kappa / self.rho, self.rho, self.d
        xp = self.xp
        cof, t, _ = scratch
        F = E[:d, :d]
        J, I1 = self._parts(E, cof, t)
        iJ = 1.0 / J
        ar = xp.cbrt(iJ)
        ar *= ar
        ar *= mu  # a / rho
        b = I1 * ar
        b *= iJ
        b *= -1.0 / 3.0
        b += kappa * J
        b -= kappa  # b / rho
        al = ar + 1.0  # alpha, the model's diagonal (over rho)
        beta = 2.0 - iJ
        beta *= kappa
        xp.maximum(beta, 0.0, out=beta)  # the model's volumetric stiffness (over rho)
        cc = xp.einsum("ijk,ijk->k", cof, cof)
        cg = al * J
        cg *= d
        cg -= xp.einsum("ijk,ijk->k", cof, Fhat)
        cg += b * cc  # cof:g
        cg *= beta
        den = beta * cc
        den += al
        cg /= den
        cg -= b  # s - b / rho
        xp.multiply(cof, cg, out=t)
        t += Fhat
        xp.divide(t, al, out=Fn)
        xp.subtract(Fn, F, out=t)  # the model step dF
        dz2 = xp.einsum("ijk,ijk->k", t, t)
        # small steps from states with J > s I1/sqrt(3) + s^2 sqrt(I1) + s^3 keep J > 0: taken
        # as they are; the others are checked
        ds = self.small_step
        lim = xp.sqrt(I1)
        lim *= ds * ds
        lim += (ds / np.sqrt(3.0)) * I1
        lim += ds ** 3
        bad = J <= lim
        bad |= dz2 > ds * ds
        check = xp.flatnonzero(bad) if bad.any() else xp.empty(0, np.int64)
        redo = check
        if len(check):
            dz = t[:, :, check]
            # g = -M dF, so g:dF = -(alpha |dF|^2 + beta (cof:dF)^2) (times rho: unscaled)
            cd = xp.einsum("ijk,ijk->k", cof[:, :, check], dz)
            gd = -rho * (al[check] * dz2[check] + beta[check] * cd * cd)
            Fc = F[:, :, check]
            Fh = Fhat[:, :, check]
            phi0, _ = self._phi(Fc, Fh)
            tolr = 1e-13 * xp.abs(phi0)
            idx = xp.arange(len(check))
            alpha_ls = 1.0
            partial = xp.zeros(len(check), bool)
            for _ in range(40):
                Ft = Fc[:, :, idx] + alpha_ls * dz[:, :, idx]
                ph, Jt = self._phi(Ft, Fh[:, :, idx])
                ok = (Jt > 0) & (ph <= phi0[idx] + 1e-4 * alpha_ls * gd[idx] + tolr[idx])
                oki = xp.flatnonzero(ok)
                Fn[:, :, check[idx[oki]]] = Ft[:, :, oki]
                if alpha_ls < 1.0:
                    partial[idx[oki]] = True
                idx = idx[~ok]
                if not len(idx):
                    break
                alpha_ls *= 0.5
            if len(idx):  # no decrease found: keep the old F of these elements
                Fn[:, :, check[idx]] = Fc[:, :, idx]
                partial[idx] = True
            redo = check[partial]
        return dz2, check, redo


class LawZStep:
    """The z-step of the laws the closed-form ``ZStep`` does not know (``mechanics.INVARIANT_LAWS``),
    on numpy blocks (d, d, m): from the previous F, ``rounds`` safeguarded Newton steps on the
    local objective phi(F) = psi(F) + rho/2 |F - Fhat|^2 with the law's exact Hessian A + rho I
    (psi, P and A from one ``mechanics.Law.evaluate`` per step; where A + rho I is not positive
    definite, so that the step does not descend, A + (rho + |A|) I, which is), each with an
    Armijo backtracking that keeps det F > 0: one step per ADMM iteration (warm start), more
    (up to ``rounds``) only for the elements whose step backtracked. The element arrays are
    plain (d, d, m) blocks. At a fixed point the local gradient vanishes, as with ``ZStep``."""

    small_step = ZStep.small_step

    def __init__(self, ops, rho, rounds=None, xp=np):
        if xp is not np:
            raise NotModeledError(f"the ADMM solver's GPU element pass implements the laws "
                                  f"{list(KERNEL_LAWS)}; this material is {ops.law.model!r}: "
                                  f"use device='cpu'")
        self.xp = np
        self.law = ops.law
        self.d = ops.d
        self.rounds = max(1, ROUNDS if rounds is None else rounds)
        self.set_rho(rho)

    def set_rho(self, rho):
        self.rho = rho

    def new_state(self, k):
        """A buffer for F (d, d, k) and its F view (the same array)."""
        E = np.empty((self.d, self.d, k))
        return E, E

    def _phi(self, F, Fhat, psi=None):
        """phi (k,) of F (k, d, d) against Fhat (k, d, d); inf where det F <= 0. ``psi``: the
        law's energy at F where already known."""
        if psi is None:
            psi, _ = self.law.psi_J(F - np.eye(self.d))
        r = F - Fhat
        return psi + 0.5 * self.rho * np.einsum("kij,kij->k", r, r)

    def __call__(self, Fhat, E, Enew):
        """Writes the new F into Enew (F = E is the previous one) and returns |F_new - F|^2 per
        element; Fhat (d, d, m)."""
        d, rho = self.d, self.rho
        F0 = aos(E).copy()
        Fh = aos(Fhat)
        F = F0.copy()
        eye = np.eye(d)
        active = np.arange(len(F))
        for _ in range(self.rounds):
            H = F[active] - eye
            # psi, P and A from one evaluation of the law's invariants and their derivatives
            psi, _, P, A = self.law.evaluate(H)
            g = (P + rho * (F[active] - Fh[active])).reshape(len(active), -1)
            A[:, np.arange(d * d), np.arange(d * d)] += rho
            step = -np.linalg.solve(A, g[:, :, None])[:, :, 0]
            slope = np.einsum("ki,ki->k", g, step)
            bad = ~(slope < 0)
            if bad.any():   # not a descent direction: a positive definite shift
                shift = np.sqrt(np.einsum("kij,kij->k", A[bad], A[bad]))
                Ab = A[bad]
                Ab[:, np.arange(d * d), np.arange(d * d)] += shift[:, None]
                step[bad] = -np.linalg.solve(Ab, g[bad][:, :, None])[:, :, 0]
                slope[bad] = np.einsum("ki,ki->k", g[bad], step[bad])
            phi0 = self._phi(F[active], Fh[active], psi)
            tol = 1e-13 * np.abs(phi0)
            step = step.reshape(-1, d, d)
            alpha = np.ones(len(active))
            todo = np.arange(len(active))
            for _ in range(40):
                Ft = F[active[todo]] + alpha[todo, None, None] * step[todo]
                ok = self._phi(Ft, Fh[active[todo]]) <= \
                    phi0[todo] + 1e-4 * alpha[todo] * slope[todo] + tol[todo]
                F[active[todo[ok]]] = Ft[ok]
                todo = todo[~ok]
                if not len(todo):
                    break
                alpha[todo] *= 0.5
            # as ``ZStep``: only the elements whose line search backtracked step again
            active = active[alpha < 1.0]
            if not len(active):
                break
        Enew[...] = soa(F)
        dz = F - F0
        return np.einsum("kij,kij->k", dz, dz)


def zstep_for(ops, rho, rounds=None, xp=np):
    """The z-step of the operators' law: ``ZStep`` for ``mechanics.KERNEL_LAWS``, else
    ``LawZStep``."""
    return (ZStep if ops.law.kernel else LawZStep)(ops, rho, rounds, xp)


class ArrayElements:
    """The element work of one ADMM iteration (gather D u, z-step, dual update, residuals and the
    x-step data D^T W (z - lam)) on (d, d, m) blocks of the z-step's array module, in chunks of
    CHUNK elements on numpy (all elements at once otherwise). ``F``, ``lam``: the start state
    (F = I + z, scaled dual), (d, d, m), host arrays. ``dev``: where the gradient operators
    live: None for the operators' own scipy matrices (numpy), else an object with ``DZ``,
    ``DZtW`` (sparse matrices of the array module), ``h`` and ``put`` (host -> device array)."""

    def __init__(self, ops, zstep, up, F, lam, dev=None):
        d, m, xp = ops.d, ops.m, zstep.xp
        self.ops, self.zstep, self.d, self.m, self.xp = ops, zstep, d, m, xp
        if dev is None:
            self.DZ, self.DZtW, h, put = ops.DZ, ops.DZtW, ops.h, np.asarray
        else:
            self.DZ, self.DZtW, h, put = dev.DZ, dev.DZtW, dev.h, dev.put
        self.DupI = put(ops.D @ up + ops.eye_soa)  # D u_p + I
        self.E, self.F = zstep.new_state(m)
        self.Enew, self.Fnew = zstep.new_state(m)
        self.F[...] = put(F)
        lam = put(lam)
        self.lam, self.lam_new = lam, xp.empty_like(lam)
        self.w = self.F - lam  # x-step data z - lam (+ I)
        self.r, self.dsq = xp.empty(m), xp.empty(m)
        self.h2 = put(h ** 2)
        chunk = CHUNK if xp is np else max(m, 1)
        self.chunks = [(c, min(c + chunk, m)) for c in range(0, m, chunk)]
        self.scratch = {}

    def xdata(self):
        """Z^T D^T W (z - lam + I) (mN), the x-step's data term."""
        return self.DZtW @ self.w.reshape(-1)

    def halve_dual(self):
        """lam *= 1/2 (rho doubled: lam = P / rho)."""
        self.lam *= 0.5
        self.xp.subtract(self.F, self.lam, out=self.w)

    def state(self):
        """(F, lam) as one vector: the ADMM iteration's fixed-point variables
        (``loop.Anderson``)."""
        return self.xp.concatenate((self.F.reshape(-1), self.lam.reshape(-1)))

    def admissible(self, x) -> bool:
        """Whether every element's F in the state vector x has det F > 0 (linear elasticity:
        always)."""
        if self.ops.law.model == "linear-elastic":
            return True
        d = self.d
        F = x[:self.lam.size].reshape(d * d, -1)
        if d == 2:
            J = F[0] * F[3] - F[1] * F[2]
        else:
            J = (F[0] * (F[4] * F[8] - F[5] * F[7]) - F[1] * (F[3] * F[8] - F[5] * F[6])
                 + F[2] * (F[3] * F[7] - F[4] * F[6]))
        return bool((J > 0).all())

    def set_state(self, x):
        """Set (F, lam) from a vector of ``state``'s layout (and the x-step data F - lam)."""
        n = self.lam.size
        self.F[...] = x[:n].reshape(self.F.shape)
        self.lam[...] = x[n:].reshape(self.lam.shape)
        self.xp.subtract(self.F, self.lam, out=self.w)

    def update(self, q):
        """Element work after the x-step q (at the z-step's current rho); returns (r, dsq):
        h^2 |D u - z'|^2 and h^2 |z' - z|^2 per element (mm^2)."""
        d, m, zstep, xp = self.d, self.m, self.zstep, self.xp
        Hx = self.DZ @ q
        Hx += self.DupI
        Hx = Hx.reshape(d, d, m)
        lam, lam_new, w, r, dsq = self.lam, self.lam_new, self.w, self.r, self.dsq
        for c0, c1 in self.chunks:
            sl = slice(c0, c1)
            Fhat, t = self.scratch.get(c1 - c0) or self.scratch.setdefault(
                c1 - c0, (xp.empty((d, d, c1 - c0)), xp.empty((d, d, c1 - c0))))
            xp.add(Hx[:, :, sl], lam[:, :, sl], out=Fhat)
            dsq[sl] = zstep(Fhat, self.E[:, :, sl], self.Enew[:, :, sl])
            # dual update lam' = Fhat - F'; primal residual D u - z' = lam' - lam
            ln = lam_new[:, :, sl]
            xp.subtract(Fhat, self.Fnew[:, :, sl], out=ln)
            xp.subtract(ln, lam[:, :, sl], out=t)
            _dot_into(xp, t, t, r[sl])
            xp.subtract(self.Fnew[:, :, sl], ln, out=w[:, :, sl])  # next x-step's data
        r *= self.h2
        dsq *= self.h2
        self.lam, self.lam_new = lam_new, lam
        self.E, self.Enew, self.F, self.Fnew = self.Enew, self.E, self.Fnew, self.F
        return r, dsq


NumpyElements = ArrayElements  # its name as the element pass without a C compiler
