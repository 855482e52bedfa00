"""The ADMM iteration loop of one load step (or one time step), whatever the backend: x-step,
element pass, residuals, history, the stopping rule, divergence checks and the rho adaptation.

Stopping rule (mm): primal = max_e h_e |D_e u - z_e|, dual = (rho/rho0) max_e h_e |z_e^k -
z_e^(k-1)| (h_e = V_e^(1/gdim), a length); both below ``tol_mm`` (and, with an iterative
x-step, its last CG update below ``tol_mm``). Quasi-static solves double rho (up to 64 rho0;
free: the x-step matrix is rho times a fixed one) when the primal residual stagnates over 25
iterations (nonconvex elements can cycle between two local z-step minima); the changes are listed
in ``history["rho_changes"]``."""
from __future__ import annotations

import math
import time

import numpy as np

from tissue_reference.errors import SolverDivergedError

from .contact import ContactBlocks
from .kernel_array import aos, soa
from .mechanics import det_cof

RHO_MAX = 64.0  # rho doubles on stagnation up to this multiple of its start value


def diverged_error(msg, it, elem):
    """SolverDivergedError naming the iteration and the element (a number) or other place."""
    where = f"element {elem}" if isinstance(elem, (int, np.integer)) else elem
    return SolverDivergedError(f"ADMM diverged at iteration {it}: {msg} ({where})")


def check_J(ops, H, it, what):
    if ops.law.model == "linear-elastic":
        if not np.all(np.isfinite(H)):
            e = int(np.flatnonzero(~np.isfinite(H.reshape(len(H), -1)).all(axis=1))[0])
            raise diverged_error(f"non-finite displacement gradient in {what}", it, e)
        return
    J, _ = det_cof(H + np.eye(ops.d))
    bad = ~(J > 0)
    if bad.any():
        e = int(np.argmin(np.where(np.isfinite(J), J, -np.inf)))
        raise diverged_error(f"{int(bad.sum())} inverted element(s) in {what}, J = {J[e]:.3g} "
                        f"<= 0", it, e)


def _start(ops, be, up, u0):
    """The reduced start q (host) and the start state F = I + D u, lam = P(F) / rho ((d, d, m),
    host): u0 with its boundary moved to up's values and the interior carried along with the
    harmonic (x-step matrix) extension of that change."""
    Z, m, d = ops.red.Z, ops.m, ops.d
    zu0 = ops.red.ZT @ u0
    delta = up - (u0 - Z @ zu0)
    q = zu0 - be.harmonic(ops.red.ZT @ (ops.Mx @ delta)) if np.any(delta) else zu0
    F = (ops.DZ @ q + ops.D @ up + ops.eye_soa).reshape(d, d, m)  # I + D u
    if ops.law.model != "linear-elastic":
        # elements the prescribed values invert in the start state start from F = I
        J, _ = det_cof(aos(F))
        F[:, :, ~(J > 0.05)] = np.eye(d)[:, :, None]
    P, _ = ops.law.stress(aos(F) - np.eye(d))
    return q, F, soa(P) / ops.rho


class Anderson:
    """Anderson acceleration (type II, Walker and Ni 2011) of the ADMM iteration seen as a
    fixed-point map G of its element and contact variables x = (z, lam) (Zhang, Peng, Ouyang and
    Deng 2019, "Accelerating ADMM for Efficient Simulation and Optimization"): with f_k =
    G(x_k) - x_k and the last ``m`` differences dF, dG of f and G,

        gamma = argmin |f_k - dF gamma|,    x_(k+1) = G(x_k) - dG gamma

    (the normal equations, their Gram matrix updated by one row per iteration).

    Safeguard (theirs for ADMM, which does not decrease the energy monotonically): an
    accelerated iterate whose fixed-point residual |G(x) - x| exceeds the last accepted one's,
    or that inverts an element (det F <= 0), is dropped for the plain iterate G(x_k) it
    replaced, and the history restarts. ``xp``: the array module."""

    def __init__(self, m: int, xp=np):
        self.m, self.xp = int(m), xp
        self.DF = self.DG = None
        self.reset()

    def reset(self):
        self.k = 0                # differences held (the last min(k, m) rows, a ring)
        self.gram = np.zeros((self.m, self.m))
        self.f_prev = self.g_prev = None
        self.x = None             # the map's input at this iteration
        self.fnorm = None         # |f| of the last accepted iterate
        self.accelerated = False  # whether self.x came from the acceleration

    def refuse(self):
        """Drop the accelerated iterate just proposed for the plain one, G(x_k), and restart
        the history (an element the extrapolation inverts)."""
        g = self.g_prev
        self.reset()
        self.x = g

    def step(self, g):
        """The next iterate from g = G(self.x) (the object g is kept: pass a fresh array);
        None when the accelerated input self.x is rejected (``x`` is then the plain iterate
        to continue from)."""
        xp = self.xp
        if self.x is None:
            self.x = g
            return g
        f = g - self.x
        fn = float(xp.sqrt(f @ f))
        if self.accelerated and self.fnorm is not None and fn > self.fnorm:
            self.refuse()
            return None
        self.fnorm = fn
        if self.f_prev is not None and self.m > 0:
            if self.DF is None or self.DF.shape[1] != len(f):
                self.DF = xp.empty((self.m, len(f)))
                self.DG = xp.empty((self.m, len(f)))
            i = self.k % self.m
            xp.subtract(f, self.f_prev, out=self.DF[i])
            xp.subtract(g, self.g_prev, out=self.DG[i])
            self.k += 1
            n = min(self.k, self.m)
            row = self.DF[:n] @ self.DF[i]
            row = np.asarray(row.get() if hasattr(row, "get") else row, float)
            self.gram[i, :n] = row
            self.gram[:n, i] = row
        self.f_prev, self.g_prev = f, g
        n = min(self.k, self.m)
        if n == 0:
            self.x, self.accelerated = g, False
            return g
        rhs = self.DF[:n] @ f
        rhs = np.asarray(rhs.get() if hasattr(rhs, "get") else rhs, float)
        G = self.gram[:n, :n]
        gamma = np.linalg.solve(G + (1e-10 * np.trace(G) + 1e-300) * np.eye(n), rhs)
        x = g - xp.asarray(gamma) @ self.DG[:n]
        self.x, self.accelerated = x, True
        return x


class _WithContact:
    """The element pass and the rigid tips' contact blocks (``contact.ContactBlocks``) as one:
    their x-step data add up, their residuals are listed together (elements first)."""

    def __init__(self, elements, blocks):
        self.elements, self.blocks = elements, blocks

    def xdata(self):
        return self.elements.xdata() + self.blocks.xdata()

    def halve_dual(self):
        self.elements.halve_dual()
        self.blocks.halve_dual()

    def state(self):
        return self.blocks.xp.concatenate((self.elements.state(), self.blocks.state()))

    def set_state(self, x):
        n = len(x) - 2 * self.blocks.z.size
        self.elements.set_state(x[:n])
        self.blocks.set_state(x[n:])

    def admissible(self, x) -> bool:
        return self.elements.admissible(x[:len(x) - 2 * self.blocks.z.size])

    def update(self, q):
        r, dsq = self.elements.update(q)
        rc, dc = self.blocks.update(q)
        xp = self.blocks.xp
        return xp.concatenate([r, rc]), xp.concatenate([dsq, dc])


def _where(ops, i):
    """'element k' (the mesh's number) for residual entry i, or 'contact point p' past the
    elements."""
    i = int(i)
    return f"element {int(ops.elem_order[i])}" if i < ops.m else f"contact point {i - ops.m}"


def run_admm(ops, up, rhs_extra, u0, *, tol_mm, max_iter, callback, it0, progress, hist, be,
          tips=None, anderson: int = 0):
    """ADMM iterations from u0 on the backend ``be`` (``backends.backend``). rhs_extra: f_ext
    (+ M u_tilde / dt^2), mN. tips: the ends of the rigid tips at every contact point
    (``contact.ContactSet.origins``), with indenters. anderson: the history of Anderson
    acceleration (``Anderson``; 0: the plain iteration). Returns (u, iters, converged), u on the
    host. The loop works with F = I + z and Fhat = I + D u + lam, (d, d, m) blocks."""
    Z, d = ops.red.Z, ops.d
    xp = be.xp
    q, F, lam = _start(ops, be, up, u0)
    zstep = be.zstep(ops.rho)
    rhs_f = be.put(ops.red.ZT @ rhs_extra)
    # x-step right-hand side constant: boundary values, and D^T W I (F = I + z)
    rhs_up = be.put(-(ops.red.ZT @ (ops.Mx @ up)) - ops.DZtW_I)
    rho0 = rho = ops.rho
    adapt = ops.dt is None  # without a mass term the x-step matrix is rho * (fixed matrix)
    rho_max = RHO_MAX * rho0
    window_primal = np.inf
    big = 1e3 * float(np.ptp(ops.mesh.points, axis=0).max())
    rhs_c = rhs_f + rhs_up
    elements = be.elements(zstep, up, F, lam)
    if ops.contact is not None and ops.contact.P:
        elements = _WithContact(elements, ContactBlocks(ops, ops.contact, up, up + Z @ q, tips,
                                                        zstep, be.dev))
    q = be.put(q)
    aa = Anderson(anderson, xp) if anderson else None
    if aa is not None:
        aa.step(elements.state())
    converged = False
    k = 0
    for k in range(1, max_iter + 1):
        q_old = q
        # x-step for the current rho: (rho/rho0) Mx0 u = rho D^T V (z - lam) + f, scaled
        rhs = elements.xdata() + rhs_c
        q = be.xstep(rhs, q, tol_mm)
        r, dsq = elements.update(q)
        primal = float(xp.sqrt(r.max()))
        # dual residual rho D^T (z^k - z^(k-1)) (Boyd et al. 2011, 3.3), in mm at rho0
        dual = (rho / rho0) * float(xp.sqrt(dsq.max()))
        step = be.step_norm(q - q_old)
        hist["primal"].append(primal)
        hist["dual"].append(dual)
        hist["max_step_mm"].append(step)
        hist["admm_clock_s"].append(time.perf_counter())
        if not (math.isfinite(primal) and math.isfinite(dual) and math.isfinite(step)):
            bad = be.get(~(xp.isfinite(r) & xp.isfinite(dsq)))
            raise diverged_error("non-finite residual", it0 + k,
                            _where(ops, np.flatnonzero(bad)[0]) if bad.any() else "unknown")
        if primal > big or step > big:
            raise diverged_error(f"residual growth, primal {primal:.3g} mm", it0 + k,
                            _where(ops, xp.argmax(r)))
        if callback is not None:
            callback(it0 + k, (up + Z @ be.get(q)).reshape(-1, d))
        if progress and k % 100 == 0:
            print(f"admm {it0 + k}: primal {primal:.3e} mm, dual {dual:.3e} mm, "
                  f"step {step:.3e} mm", flush=True)
        if primal < tol_mm and dual < tol_mm and be.inexactness < tol_mm:
            converged = True
            break
        if aa is not None:
            nxt = aa.step(elements.state())
            if aa.accelerated and not elements.admissible(aa.x):
                aa.refuse()           # an extrapolation that inverts an element: the plain one
            if nxt is None or aa.accelerated:   # (a plain step leaves the state as it is)
                elements.set_state(aa.x)
        if adapt and k % 25 == 0:
            # stagnation (e.g. a nonconvex element cycling between two local z minima): double
            # rho (more consensus, convex local problems); lam = P / rho is rescaled
            if primal > 0.9 * window_primal and rho < rho_max:
                elements.halve_dual()
                if aa is not None:
                    aa.reset()
                    aa.step(elements.state())
                rho *= 2.0
                zstep.set_rho(rho)
                rhs_c = (rho0 / rho) * rhs_f + rhs_up
                hist.setdefault("rho_changes", []).append((it0 + k, rho))
            window_primal = primal
    return up + Z @ be.get(q), k, converged
