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

Safeguard: an extrapolated iterate that inverts an element, or whose correction is longer than
the last one taken, is replaced by the plain chord iterate and the history restarts; an iterate
whose correction grew past ``GROWTH`` times the smallest one so far, or a non-finite one, ends
the polish unconverged: the caller finishes with the exact-tangent Newton polish from the best
iterate (``driver``). Stops when the largest vertex correction is below ``tol_mm``.
Quasi-static only and without rigid tips: the contact's penalty stiffness is not in the rest
tangent (those solves use the Newton polish). Units: mm, mN.
"""
from __future__ import annotations

import numpy as np

from .loop import Anderson

GROWTH = 10.0
"""A chord correction this many times larger than the smallest one so far ends the polish
(diverging: the Newton polish takes over)."""


def chord(ops, u, fext, factor, *, tol_mm: float, max_iter: int, anderson: int = 5,
          it0: int = 0, hist=None, callback=None):
    """Chord steps with the factorization ``factor`` (its ``solve(b)``) of the reduced tangent
    at rest, Anderson-mixed over ``anderson`` iterates (``loop.Anderson``, whose own safeguard
    drops an extrapolation whose correction grew), from u (mm, (N,)) with its prescribed part as
    it is. Returns (u, iterations, converged): the last iterate, or the one with the smallest
    correction if the steps diverged (module docstring)."""
    Z, ZT = ops.red.Z, ops.red.ZT
    ub = u - Z @ (ZT @ u)
    mix = Anderson(anderson)
    mix.x = q = ZT @ u
    best_q, best_step = q, np.inf
    for k in range(1, int(max_iter) + 1):
        r = ops.residual_if_valid(ub + Z @ q, fext)
        if r is None:
            if mix.accelerated:
                mix.refuse()   # an extrapolation that inverts an element: the plain step
                q = mix.x
            r = ops.residual(ub + Z @ q, fext)
        f = -factor.solve(ZT @ r)   # the chord correction
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
        if step < tol_mm and ops.valid(ub + Z @ g):
            return ub + Z @ g, k, True
        mix.step(g)   # an extrapolation is tested with the next residual
        q = mix.x
    return ub + Z @ best_q, int(max_iter), False
