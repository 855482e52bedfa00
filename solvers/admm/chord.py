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

Rigid tips (``tips``: their ends at the contact points): the residual includes the contact
forces, and the chord matrix is the tangent at rest plus the contact Hessian without the tips'
curvature (``ContactSet.hessian(..., curvature=False)``: positive semi-definite, so the matrix
stays positive definite) of the points in contact at the state it is factorized at; with no
point in contact it is the kept rest factorization. It is factorized anew (counted in
``stats["refactorizations"]``) at the start state where points are in contact, whenever the
set of points in contact at the chord's state changes (the history restarts), and, from the
best iterate, when the steps stop contracting (no correction below the smallest since the last
factorization for ``STALL`` steps, or one past ``GROWTH`` times it); at most
``MAX_REFACTORIZATIONS`` times a polish, after which the steps go on with the last matrix and
the rules above end the polish unconverged. Quasi-static only (no inertia in the matrix).
Units: mm, mN.
"""
from __future__ import annotations

import numpy as np

from ..line_search import backtrack
from .factor import sym_splu
from .loop import Anderson
from .polish import LINE_SEARCH_TRIES, valid_energy

GROWTH = 10.0
"""A chord correction this many times larger than the smallest one so far ends the polish
(diverging: the Newton polish takes over)."""


STALL = 3
"""With rigid tips: this many chord corrections in a row none smaller than the smallest since the
last factorization refactorize the chord matrix at the best iterate."""

MAX_REFACTORIZATIONS = 20
"""With rigid tips: the most factorizations of the chord matrix with contact in one polish."""


class _ContactChord:
    """The chord matrix with rigid tips (module docstring): the rest factorization where no point
    is in contact, else the rest tangent plus the contact Hessian without the tips' curvature of
    the points in contact, factorized by ``sym_splu`` with ``factorize``."""

    def __init__(self, ops, tips, rest, factorize):
        self.ops, self.tips, self.rest, self.factorize = ops, tips, rest, factorize
        self.on = None
        self.factor = rest
        self.count = 0

    def refactor(self, u, same=True) -> bool:
        """The matrix at u; False (the matrix kept) past MAX_REFACTORIZATIONS, or where no point
        is in contact at u nor was before and not ``same`` (the rest matrix again)."""
        ops = self.ops
        on = ops.contact.active(u, self.tips)
        if not len(on):
            if not same and self.on is not None and not len(self.on):
                return False
            self.on, self.factor = on, self.rest
            return True
        if self.count >= MAX_REFACTORIZATIONS:
            return False
        Hc = ops.contact.hessian(u, self.tips, curvature=False)
        Kr, _ = ops.reduced_tangent(np.zeros(ops.N), extra=Hc)
        self.factor = sym_splu(Kr, ops.factor_cache, self.factorize)
        self.on = on
        self.count += 1
        return True


def chord(ops, u, fext, factor, *, tol_mm: float, max_iter: int, anderson: int = 5,
          it0: int = 0, hist=None, callback=None, tips=None, factorize=None, stats=None):
    """Chord steps with the factorization ``factor`` (its ``solve(b)``) of the reduced tangent
    at rest, Anderson-mixed over ``anderson`` iterates (``loop.Anderson``, whose own safeguard
    drops an extrapolation whose correction grew), from u (mm, (N,)) with its prescribed part as
    it is. ``tips``: the rigid tips' ends at the contact points (None: no contact), the chord
    matrix then refactorized with the points in contact (module docstring; ``factorize`` the
    factorization hook, the count added to ``stats["refactorizations"]``). Returns (u,
    iterations, converged): the last iterate, or the one with the smallest correction if the
    steps diverged (module docstring)."""
    Z, ZT = ops.red.Z, ops.red.ZT
    if tips is not None and getattr(ops, "contact", None) is None:
        tips = None
    ub = u - Z @ (ZT @ u)
    mix = Anderson(anderson)
    mix.x = q = ZT @ u
    best_q, best_step = q, np.inf
    cm = None
    if tips is not None:
        cm = _ContactChord(ops, tips, factor, factorize)
        cm.refactor(u)
    since, stalled = np.inf, 0   # the smallest correction since the last factorization

    def restart(q_new, same=True):
        """The chord matrix at q_new, the history restarted there; False where none is made."""
        nonlocal mix, since, stalled
        if not cm.refactor(ub + Z @ q_new, same):
            return False
        mix = Anderson(anderson)
        mix.x = q_new
        since, stalled = np.inf, 0
        return True

    try:
        for k in range(1, int(max_iter) + 1):
            r = ops.residual_if_valid(ub + Z @ q, fext, tips)
            if r is None:
                if mix.accelerated:
                    mix.refuse()   # an extrapolation that inverts an element: the plain step
                    q = mix.x
                r = ops.residual(ub + Z @ q, fext, tips)
            if cm is not None:
                on_q = ops.contact.active(ub + Z @ q, tips)
                if not np.array_equal(on_q, cm.on):
                    restart(q)   # the points in contact changed: the matrix of the new set
            rf = ZT @ r
            f = -(cm.factor if cm is not None else factor).solve(rf)   # the chord correction
            g = q + f
            step = ops.step_norm(f)
            if hist is not None:
                hist["newton_step_mm"].append(step)
            if not np.isfinite(step) or step > GROWTH * best_step:
                if cm is not None and np.isfinite(best_step) and restart(best_q, False):
                    q = best_q   # diverging: the matrix at the best iterate, from there
                    continue
                return ub + Z @ best_q, k, False
            crossing = cm is not None and not np.array_equal(
                on_q, ops.contact.active(ub + Z @ g, tips))
            if crossing:
                # the correction moves points into or out of contact, where the chord matrix
                # does not hold: backtracked on the energy, every cell kept valid (Armijo with
                # the slope rf . f: a descent direction, the matrix is positive definite), the
                # history restarted after it
                e0, _ = ops.energy(ub + Z @ q, fext, tips)
                taken = backtrack(
                    lambda alpha, q=q, f=f: (
                        valid_energy(ops, ub + Z @ (q + alpha * f), fext, None, tips), None),
                    e0, float(rf @ f), tries=LINE_SEARCH_TRIES)
                if taken is None:
                    return ub + Z @ best_q, k, False
                g = q + taken.t * f
            if step < best_step:
                best_q, best_step = g, step
            if step < since:
                since, stalled = step, 0
            else:
                stalled += 1
            if callback is not None:
                callback(it0 + k, (ub + Z @ g).reshape(-1, ops.d))
            if step < tol_mm and ops.valid(ub + Z @ g):
                return ub + Z @ g, k, True
            if cm is not None and stalled >= STALL and restart(best_q, False):
                q = best_q   # not contracting: the matrix at the best iterate, from there
                continue
            if crossing:
                mix = Anderson(anderson)
                mix.x = q = g
                continue
            mix.step(g)   # an extrapolation is tested with the next residual
            q = mix.x
        return ub + Z @ best_q, int(max_iter), False
    finally:
        if stats is not None and cm is not None:
            stats["refactorizations"] = stats.get("refactorizations", 0) + cm.count
