"""The Newton polish and the tangent lift, on the host: Newton steps on the same P1 energy with
the exact tangent (``AdmmOperators.reduced_tangent``, assembled into a cached CSR pattern of the
reduced unknowns), a backtracking line search on the energy keeping J > 0; and the lift that
carries the interior along with a boundary increment by one linear solve with the tangent."""
from __future__ import annotations

import numpy as np

from ..line_search import backtrack
from .factor import sym_splu
from .loop import check_J, diverged_error
from .operators import vertex_norm_max

LINE_SEARCH_TRIES = 40
"""Steps the polishes' line searches try (1, 1/2, ..., 2^-39) before giving up."""

REST_TANGENT_KEPT_DOFS = 100_000
"""The tangent at rest (without contact) is factorized once and kept with the operators up to this
many reduced unknowns (about 33k vertices; a lift from rest, every cold solve's first load step,
then costs one back-substitution, and the chord polish needs no factorization of its own);
above it each lift factorizes its own, so no larger factor is held between solves. On the
phantom at 185k tets (92k reduced unknowns) the kept factorization and element matrices hold
about 1 GiB (965 MiB; the Cholesky factor has 71M nonzeros), and a cold chord-polished solve
takes 3.0 s instead of 10.4 s (bench/bench_admm_accel.py --rest-tangent --sizes 1.8 --only
chord, which prints the memory).
Each operator set ``operators.prepare`` caches (those of the last 4 meshes) keeps its own;
``operators.OPERATOR_CACHE.clear()`` frees them."""


def _contact_hessian(ops, u, tips, curvature=True):
    """The rigid tips' contact Hessian at u (N, N) with the tips' ends at ``tips`` (without
    the tips' curvature term unless ``curvature``), or None."""
    if tips is None or ops.contact is None:
        return None
    return ops.contact.hessian(u, tips, curvature)


def rest_factor(ops, factorize=None):
    """(element matrices Ke, factorization) of the reduced tangent at rest (without contact):
    kept with the operators up to REST_TANGENT_KEPT_DOFS reduced unknowns, built anew above."""
    kept = ops.rest_tangent
    if kept is not None and kept[0] is factorize:
        return kept[1], kept[2]   # the same matrix at every call, factorized alike
    Kr, Ke = ops.reduced_tangent(np.zeros(ops.N))
    # a cache of its own: a hook that refactorizes a cached factorization of the same pattern in
    # place (``fem_reference.cholmod_factor``) would otherwise turn the kept factorization into
    # that of the next tangent the lifts or the polish factorize
    factor = sym_splu(Kr, {}, factorize)
    if ops.nq <= REST_TANGENT_KEPT_DOFS:
        ops.rest_tangent = (factorize, Ke, factor)
    return Ke, factor


def tangent_lift(ops, u, up, it, factorize=None, tips=None, rest=None):
    """u with its prescribed part moved to up's values and the interior moved by the linearized
    (tangent at u, with the tips at ``tips``) response to that boundary change. From rest it
    takes the factorization of ``rest()`` (default: ``rest_factor``, kept when small)."""
    Z = ops.red.Z
    zu = ops.red.ZT @ u
    delta = up - (u - Z @ zu)
    if not np.any(delta):
        return u
    Hc = _contact_hessian(ops, u, tips)
    at_rest = not np.any(u) and (Hc is None or not Hc.nnz)
    try:
        if at_rest:
            Ke, factor = rest() if rest is not None else rest_factor(ops, factorize)
        else:
            Kr, Ke = ops.reduced_tangent(u, extra=Hc)
            factor = sym_splu(Kr, ops.factor_cache, factorize)
        Kd = ops.apply_elements(Ke, delta)
        if Hc is not None:
            Kd = Kd + Hc @ delta
        rhs = -(ops.red.ZT @ Kd)
        s = factor.solve(rhs)
    except RuntimeError as exc:
        raise diverged_error(f"singular tangent in the boundary lift ({exc})", it, -1) from None
    cand = up + Z @ (zu + s)
    # keep elements valid: halve the interior part until no element inverts
    for _ in range(20):
        if ops.valid(cand):
            return cand
        s = 0.5 * s
        cand = up + Z @ (zu + s)
    return cand


def total_energy(ops, u, fext, inertia, tips=None, values=None):
    e, J = ops.energy(u, fext, tips, values)
    if inertia is not None:
        mdt, ut = inertia
        e += 0.5 * float((u - ut) @ (mdt * (u - ut)))
    return e, J


def valid_energy(ops, u, fext, inertia, tips=None):
    """The total energy (uJ) at u (``total_energy``), None where an element is inverted (J <= 0):
    a line search's trial (``solvers.line_search.backtrack``)."""
    e, J = total_energy(ops, u, fext, inertia, tips)
    return e if J is None or np.all(J > 0) else None


def energy_gradient(ops, u, fext, inertia, tips=None, values=None):
    """Gradient (mN) of the total energy at u: internal forces minus f_ext, plus the tips'
    contact forces (``tips``: their ends at the contact points) and inertia; ``values``: the
    law's ``ops.law_values(u)`` where known."""
    r = ops.residual(u, fext, tips, values)
    if inertia is not None:
        mdt, ut = inertia
        r = r + mdt * (u - ut)
    return r


def newton(ops, u, fext, inertia, *, tol_mm, max_iter, it0, hist, callback, factorize=None,
            tips=None):
    """Newton on the same P1 energy (exact tangent, backtracking on the energy, J > 0), with
    the rigid tips' contact where ``tips`` gives their ends. With contact, the iteration matrix
    leaves the tips' curvature out (positive semi-definite: a descent direction however far
    from the answer) until a full step is taken, and again after a step that had to be
    halved; the exact tangent near the answer converges quadratically."""
    Z, d = ops.red.Z, ops.d
    k = 0
    exact = tips is None or ops.contact is None
    for k in range(1, max_iter + 1):
        # the law's energy, stress and tangent at u from one evaluation (numpy laws)
        values = ops.law_values(u)
        r = energy_gradient(ops, u, fext, inertia, tips, values)
        rr = ops.red.ZT @ r
        Kr, _ = ops.reduced_tangent(u, None if inertia is None else inertia[0],
                                    _contact_hessian(ops, u, tips, exact), values)
        try:
            dq = -sym_splu(Kr, ops.factor_cache, factorize).solve(rr)
        except RuntimeError as exc:
            raise diverged_error(f"singular tangent in the Newton polish ({exc})", it0 + k, -1) from None
        du = Z @ dq
        e0, _ = total_energy(ops, u, fext, inertia, tips, values)
        values = None
        r0 = float(np.linalg.norm(rr))

        def trial(alpha, u=u, du=du):
            x = u + alpha * du
            return valid_energy(ops, x, fext, inertia, tips), x

        def residual_falls(alpha, x, r0=r0):
            # merit where the energy does not fall (tangent indefinite): the free residual's
            # decrease
            r1 = float(np.linalg.norm(ops.red.ZT @ energy_gradient(ops, x, fext, inertia, tips)))
            return r1 < (1.0 - 1e-4 * alpha) * r0

        taken = backtrack(trial, e0, float(rr @ dq), tries=LINE_SEARCH_TRIES,
                          fallback=residual_falls)
        if taken is None:
            H = ops.grad(u + du)
            check_J(ops, H, it0 + k, "the Newton polish")
            raise diverged_error("Newton polish line search found no energy decrease", it0 + k,
                                 int(np.argmax(np.abs(rr))) // d)
        alpha, u = taken.t, taken.state
        exact = alpha == 1.0
        step = vertex_norm_max(alpha * du, d)
        hist["max_step_mm"].append(step)
        hist["newton_step_mm"].append(step)
        if callback is not None:
            callback(it0 + k, u.reshape(-1, d))
        if step < tol_mm:
            break
    return u, k
