"""The chord polish: Newton-like steps on the same P1 energy with one factorization, that of the
tangent at rest, kept with the operators (``polish.rest_factor``), accelerated by Anderson mixing.

With the reduced unknowns q (u = u_p + Z q) and the free residual r_f(q) = Z^T r(u), each chord
step is the fixed-point map

    G(q) = q - K0^-1 r_f(q)          (K0 = Z^T K(0) Z, factorized once per mesh)

whose fixed points are the equilibria. Alone it contracts slowly, or not at all where the
tissue stiffens or softens far from its rest tangent (the phantom pushed 4 mm at 9.6k tets
diverges); Anderson mixing of its last ``m`` iterates (type II, as ``loop.Anderson`` for the
ADMM iteration; Walker and Ni 2011) turns it into a secant method in the span of its recent
corrections: on the phantom, 4 mm on all four actuators, 6-10 steps from the rest lift to a
largest vertex step below 1e-4 mm (bench/bench_admm_accel.py). Each step costs a residual and one
back-substitution, where a Newton step assembles and factorizes a tangent.

Safeguard: an extrapolated iterate that inverts an element is replaced by the plain chord
iterate and the history restarts; an iterate whose correction grew past ``GROWTH`` times the
smallest one so far, or a non-finite one, ends the polish unconverged: the caller finishes with
the exact-tangent Newton polish from the best iterate (``driver``). Stops when the largest vertex
correction is below ``tol_mm``. Quasi-static only and without rigid tips: the contact's penalty
stiffness is not in the rest tangent (those solves use the Newton polish). Units: mm, mN.
"""
from __future__ import annotations

import numpy as np

from .mechanics import det_cof

GROWTH = 10.0
"""A chord correction this many times larger than the smallest one so far ends the polish
(diverging: the Newton polish takes over)."""


def _valid(ops, u) -> bool:
    if ops.law.model == "linear-elastic":
        return True
    J, _ = det_cof(ops.grad(u) + np.eye(ops.d))
    return bool(np.all(J > 0))


def chord(ops, u, fext, factor, *, tol_mm: float, max_iter: int, anderson: int = 5,
          it0: int = 0, hist=None, callback=None):
    """Chord steps with the factorization ``factor`` (its ``solve(b)``) of the reduced tangent
    at rest, Anderson-mixed over ``anderson`` iterates, from u (mm, (N,)) with its prescribed
    part as it is. Returns (u, iterations, converged): the last iterate, or the one with the
    smallest correction if the steps diverged (module docstring)."""
    Z, ZT = ops.red.Z, ops.red.ZT
    q = ZT @ u
    ub = u - Z @ q
    dF, dG = [], []
    f_prev = g_prev = None
    best_q, best_step = q, np.inf
    for k in range(1, int(max_iter) + 1):
        r = ZT @ ops.residual(ub + Z @ q, fext)
        f = -factor.solve(r)                 # the chord correction: G(q) - q
        g = q + f
        step = ops.step_norm(f)
        if hist is not None:
            hist["newton_step_mm"].append(step)
        if not np.isfinite(step) or step > GROWTH * best_step:
            return ub + Z @ best_q, k, False
        if step < best_step:
            best_q, best_step = g, step
        if callback is not None:
            callback(it0 + k, (ub + Z @ g).reshape(-1, ops.d))
        if step < tol_mm and _valid(ops, ub + Z @ g):
            return ub + Z @ g, k, True
        if f_prev is not None and anderson > 0:
            dF.append(f - f_prev)
            dG.append(g - g_prev)
            if len(dF) > anderson:
                dF.pop(0)
                dG.pop(0)
        f_prev, g_prev = f, g
        q = g
        if dF:
            DF, DG = np.array(dF), np.array(dG)
            gram = DF @ DF.T
            gamma = np.linalg.solve(gram + (1e-10 * np.trace(gram) + 1e-300) * np.eye(len(gram)),
                                    DF @ f)
            q_acc = g - gamma @ DG
            if _valid(ops, ub + Z @ q_acc):
                q = q_acc
            else:   # an extrapolation that inverts an element: the plain step, history restarts
                dF.clear()
                dG.clear()
    return ub + Z @ best_q, int(max_iter), False
