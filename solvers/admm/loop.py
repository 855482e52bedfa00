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

from tissue_reference.meshes.errors import SolverDivergedError

from .contact import ContactBlocks
from .kernel_array import _aos, _soa
from .mechanics import _det_cof

RHO_MAX = 64.0  # rho doubles on stagnation up to this multiple of its start value


def _diverged(msg, it, elem):
    """SolverDivergedError naming the iteration and the element (a number) or other place."""
    where = f"element {elem}" if isinstance(elem, (int, np.integer)) else elem
    return SolverDivergedError(f"ADMM diverged at iteration {it}: {msg} ({where})")


def _check_J(ops, H, it, what):
    if ops.law.model == "linear-elastic":
        if not np.all(np.isfinite(H)):
            e = int(np.flatnonzero(~np.isfinite(H.reshape(len(H), -1)).all(axis=1))[0])
            raise _diverged(f"non-finite displacement gradient in {what}", it, e)
        return
    J, _ = _det_cof(H + np.eye(ops.d))
    bad = ~(J > 0)
    if bad.any():
        e = int(np.argmin(np.where(np.isfinite(J), J, -np.inf)))
        raise _diverged(f"{int(bad.sum())} inverted element(s) in {what}, J = {J[e]:.3g} "
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
        J, _ = _det_cof(_aos(F))
        F[:, :, ~(J > 0.05)] = np.eye(d)[:, :, None]
    P, _ = ops.law.stress(_aos(F) - np.eye(d))
    return q, F, _soa(P) / ops.rho


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


def _admm(ops, up, rhs_extra, u0, *, tol_mm, max_iter, callback, it0, progress, hist, be,
          tips=None):
    """ADMM iterations from u0 on the backend ``be`` (``backends.backend``). rhs_extra: f_ext
    (+ M u_tilde / dt^2), mN. tips: the ends of the rigid tips at every contact point
    (``contact.ContactSet.origins``), with indenters. Returns (u, iters, converged), u on the
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
            raise _diverged("non-finite residual", it0 + k,
                            _where(ops, np.flatnonzero(bad)[0]) if bad.any() else "unknown")
        if primal > big or step > big:
            raise _diverged(f"residual growth, primal {primal:.3g} mm", it0 + k,
                            _where(ops, xp.argmax(r)))
        if callback is not None:
            callback(it0 + k, (up + Z @ be.get(q)).reshape(-1, d))
        if progress and k % 100 == 0:
            print(f"admm {it0 + k}: primal {primal:.3e} mm, dual {dual:.3e} mm, "
                  f"step {step:.3e} mm", flush=True)
        if primal < tol_mm and dual < tol_mm and be.inexactness < tol_mm:
            converged = True
            break
        if adapt and k % 25 == 0:
            # stagnation (e.g. a nonconvex element cycling between two local z minima): double
            # rho (more consensus, convex local problems); lam = P / rho is rescaled
            if primal > 0.9 * window_primal and rho < rho_max:
                elements.halve_dual()
                rho *= 2.0
                zstep.set_rho(rho)
                rhs_c = (rho0 / rho) * rhs_f + rhs_up
                hist.setdefault("rho_changes", []).append((it0 + k, rho))
            window_primal = primal
    return up + Z @ be.get(q), k, converged
