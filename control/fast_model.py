"""The controller's P1 model updated in milliseconds: the same Neo-Hookean P1 energy that the
ADMM model minimizes (``solvers.admm``: its operators, residual and tangent), moved from one MPC
step's pushes to the next by a chord Newton with a lagged factorization, and its control Jacobian
by the same factorization with iterative refinement. A full ADMM solve starts it and takes over
whenever the chord iterations stall.

Glued patches: the pushes s (mm) prescribe u_p(s) = u_p0 + E s on the actuators' dofs (E: one
column per actuator, its direction on its region's dofs; every other prescribed dof is fixed).
Rigid tips (frictionless contact, ``solvers.admm.contact``): a push moves a tip, no dof (E's
column is zero), and the residual carries the contact forces of the tips where s puts them;
their derivative C_a = d r / d s_a (``ContactSet.push_derivative``) joins K E_a below, and K
includes the contact's exact Hessian. A tip pushed less than ``press_widths`` of its penalty's
smoothing widths (one that touches the skin without pressing: a zero Jacobian column) is
linearized at that depth, as the reference's model is (``control.plants.PRESS_WIDTHS``).
With the free coordinates q (u = u_p(s) + Z q) the model's state solves r_f(q, s) = Z^T r(u) = 0.

State update from s to s' = s + ds, each step, with the factorization F of K_r = Z^T K Z at some
earlier state (K: the tangent of the P1 energy):

    predictor   q' = q + X ds                       (X = dq/ds, the last step's sensitivities)
    chord       q' <- q' - F^-1 r_f(q', s')          until the largest vertex step < tol_mm

Sensitivities X at the new state (they give the Jacobian): d r_f / d s = 0 along the solution,
K_r X_a + Z^T K E_a = 0 for each actuator a. Refinement from the last X, each sweep

    X_a <- X_a - F^-1 g_a,   g_a = Z^T K (Z X_a + E_a)  (the free residual's derivative along
                                                         the direction (Z X_a + E_a))

where K v comes from the elements' material tangents at the state without assembling K
(``AdmmOperators.tangent_products``: one tangent evaluation per step). Sweeps stop when the correction
is below REFINE_TOL of X; the Jacobian of a target is then J = P (Z X + E) (P: the probe's P1
interpolation), mm of target per mm of push, the derivative of the model's state exactly as
``control.jacobian.dirichlet_jacobian`` computes it from the assembled tangent.

The factorization is rebuilt at the current state when a chord iteration (a refinement sweep)
contracts by less than REFACTOR_RATE and, at that rate, would not reach its tolerance (REFINE_TOL)
with SPARE_ITERATIONS of its MAX_ITERATIONS to spare. When the chord iterations still do not
converge, or a cell inverts, the state comes from a full ADMM solve (polish to 1e-7 mm; warm,
then cold); sensitivities that do not converge after a refactorization raise ConvergenceError.
Units: mm, mN.
"""
from __future__ import annotations

import numbers
import time

import numpy as np

from tissue_reference.errors import CaseError, ConvergenceError
from tissue_reference.solvers.admm import prepare
from tissue_reference.solvers.admm import solve as admm_solve
from tissue_reference.solvers.admm.factor import sym_splu

from .dof_maps import probe_matrix
from .plant_step import solve_checked

__all__ = ["ADMM_CONTROL_OPTIONS", "REFACTOR_RATE", "REFINE_TOL", "FastModel"]

# ADMM as a control plant/model: the ADMM stage hands over to the Newton polish (part of
# solvers.admm.solve, iteration budget left to the solver: 20 per load step) which finishes to
# 1e-7 mm, the accuracy finite differences and J_s need; lift=True starts every load step from the
# tangent lift of the new boundary values. Measured on the phantom (size 12, model of the mismatch
# runs): a tight ADMM stage (tol 1e-6, or 1000 iterations per load step) cost up to 24 s per step
# above ~21 mm pushes, and at A1 = 25, A3 = 12.5 mm its polish settled on a stationary point with
# 17% more strain energy than the reference's solution on the same mesh; the default hand-over
# finds the reference's solution (tests/test_control_admm_model.py). With lift="auto" a sub-mm step
# whose polish restarted returned the previous step's boundary values flagged converged (caught by
# control.loop.check_prescribed).
ADMM_CONTROL_OPTIONS = {"tol_mm": 1e-2, "polish": True, "polish_tol_mm": 1e-7, "lift": True}

REFACTOR_RATE = 0.25
"""A chord iteration or a refinement sweep that shrinks its correction by less than this factor
rebuilds the factorization at the current state."""
REFINE_TOL = 1e-5
"""Refinement of the sensitivities stops when its correction is below this fraction of them (the
Jacobian is then within about that of the exact one at the state: a hundredth of the 1e-3 a
controller needs)."""
STATE_TOL_MM = 1e-6
"""The model's state is solved until the largest vertex step is below this (mm); a state that far
off moves the Jacobian by about 1e-6 relative."""
MAX_ITERATIONS = 12
MAX_REFACTORS = 3
"""With rigid tips, the chord iterations of one update refactorize at most this often (a tip's
contact set changes as it moves)."""
LINE_SEARCH = 20
SPARE_ITERATIONS = 2
"""A chord iteration (a refinement sweep) that contracts by less than REFACTOR_RATE refactorizes
only when, at the rate of its last two steps, it would not reach its state_tol_mm (REFINE_TOL) with
this many of its MAX_ITERATIONS to spare: a factorization costs as much as 36 to 80
back-substitutions (the phantom at 1.7k and 9.6k tets, SuperLU and CHOLMOD), so a slow but
steady iteration goes on with the factorization it has (on the phantom at 185k tets, +0.5 mm
from 4 mm: 7 chord steps at rates 0.36, 0.10, 0.30, 0.13, 0.25, 0.16 where a refactorization
took 5.9 s)."""


def _late(k: int, step: float, prev: float, tol: float) -> bool:
    """Whether iteration ``k`` (from 0), whose correction ``step`` follows ``prev``, would not
    reach ``tol`` at their rate with SPARE_ITERATIONS of MAX_ITERATIONS to spare."""
    rate = step / prev
    if not rate < 1.0:
        return True
    return k + 1 + np.log(tol / step) / np.log(rate) > MAX_ITERATIONS - SPARE_ITERATIONS


class FastModel:
    """The controller's model (``control.loop.LinearizedModel``'s interface: ``case``,
    ``target``, ``jacobian(pushes, u=None)``, ``solve_time_s``, ``retries``) on glued patches,
    updated by the chord Newton of the module docstring (``chord_iterations``: their count over
    every update). ``timings`` (ms per call of ``jacobian``): "state" (the state update),
    "jacobian" (sensitivities and J), "factor".
    ``factorize``: the factorization hook of its tangents and of its full ADMM solves' polish,
    as ``solvers.admm.solve`` takes it (e.g. ``fem_reference.cholmod_factor``: on the phantom
    at 9.6k tets it factorizes the tangent in about 60 ms against SuperLU's 200 ms, and
    back-substitutes in 0.7 ms against 2.5 ms); None: SuperLU, and SuperLU wherever the hook
    declines (a tangent that is not positive definite). ``state_tol_mm``: the chord iterations
    stop at a largest vertex step below this (default STATE_TOL_MM, where the state moves the
    Jacobian by about 1e-6 relative; 1e-3 mm, the accuracy the fast solvers are held to
    against the reference, takes about half the iterations)."""

    def __init__(self, case, target: str, press_widths: float = 0.0, factorize=None,
                 state_tol_mm: float = STATE_TOL_MM):
        if isinstance(state_tol_mm, bool) or not (isinstance(state_tol_mm, numbers.Real)
                                                  and 0 < state_tol_mm < 1):
            raise CaseError(f"state_tol_mm must be in (0, 1) mm, got {state_tol_mm!r}")
        case.probe(target)
        self.state_tol_mm = float(state_tol_mm)
        self.case, self.target = case, target
        self.press_widths = float(press_widths)
        self.sensitivity = None
        self.solve = None   # no solve of its own a plant could share
        self.retries: list[str] = []
        self.solve_time_s = 0.0
        self.timings: list[dict] = []
        self.refactorizations = 0
        self.fallbacks = 0
        self.chord_iterations = 0   # chord iterations of every update so far
        self.acts = [a.name for a in case.actuators]
        self._ops = None
        self._q = None
        self._s = None
        self._X = None
        self._F = None
        self._P = probe_matrix(case, [target])
        self._factor_ms = 0.0
        self._tip_cols = []   # the actuator index of each tip of the operators' contact set
        self._factorize = factorize
        self._factor_cache = {}   # the hook's own: it may refactorize its last factorization

    # -------------------------------------------------------------- pieces
    def _setup(self, pushes):
        """(operators, prescribed u_p) at ``pushes``; for new operators also the push columns
        E (N, n_act) and the external forces, kept, and the factorization dropped."""
        pushed = self.case.with_pushes(pushes)
        ops = prepare(pushed)
        up = ops.prescribed(pushed)
        if self._ops is not ops:
            self._ops = ops
            self._F = None
            zero = ops.prescribed(self.case.with_pushes(dict.fromkeys(self.acts, 0.0)))
            self._E = np.column_stack([
                ops.prescribed(self.case.with_pushes(
                    {a: (1.0 if a == b else 0.0) for a in self.acts})) - zero
                for b in self.acts])
            self._fext = pushed.external_forces(1.0)
            cset = ops.contact
            self._tip_cols = [] if cset is None else [self.acts.index(t.name) for t in cset.tips]
        return ops, up

    def _tips(self, ops, s):
        """The tips' ends at every contact point with the pushes s (actuator order), or None
        without tips."""
        return None if ops.contact is None else ops.contact.origins(np.asarray(s)[self._tip_cols])

    def _pressing(self, pushes: dict) -> dict:
        """``pushes`` with each tip at 0 <= push < press_widths smoothing widths pushed to that
        depth (module docstring)."""
        if not self.case.indenters() or self.press_widths <= 0:
            return pushes
        ops, _ = self._setup(pushes)
        return ops.contact.pressed(pushes, self.press_widths)

    def _factor(self, ops, u, tips=None):
        t0 = time.perf_counter()
        Kr, _ = ops.reduced_tangent(u, extra=None if tips is None else ops.contact.hessian(u, tips))
        try:
            self._F = sym_splu(Kr.tocsc(), self._factor_cache, self._factorize)
        except RuntimeError as exc:
            raise ConvergenceError(f"the fast model's tangent is singular: {exc}") from None
        self.refactorizations += 1
        self._factor_ms += (time.perf_counter() - t0) * 1e3

    def _full_solve(self, pushes):
        """A full ADMM solve (polish to 1e-7 mm) at ``pushes``: the start, and the fallback."""
        ops, up = self._setup(pushes)
        warm = None if self._q is None else up + ops.red.Z @ self._q
        if warm is not None and not ops.valid(warm):
            warm = None   # the last state carried to these pushes folds cells: start cold

        start = None if self._s is None else dict(zip(self.acts, self._s.tolist()))

        def solve(case, p, initial):
            return admm_solve(case, pushes=p, initial=initial,
                              initial_pushes=start if initial is not None else None,
                              factorize=self._factorize, **ADMM_CONTROL_OPTIONS)

        # a warm start that fails is retried cold, as the solve-based model does
        r = solve_checked(solve, self.case, pushes,
                          None if warm is None else warm.reshape(-1, ops.d),
                          "controller model", self.retries)
        u = np.asarray(r.u, float).reshape(-1)
        self._q = ops.red.ZT @ (u - up)
        self._s = np.array([float(pushes.get(a, 0.0)) for a in self.acts])
        self._X = None
        return ops, up, u

    # -------------------------------------------------------------- the update
    def _chord(self, ops, up, q, tips=None):
        """q solving the free residual from ``q`` (chord iterations; the tips' ends at ``tips``);
        None when they stall or the state is not valid (an inverted cell). With tips each
        correction must lower the energy (halved until it does; a correction that is no
        descent direction, from a factorization the contact set has left behind, is solved
        again with the tangent at the current state)."""
        Z, ZT = ops.red.Z, ops.red.ZT
        prev = None
        refactors = 0
        limit = 1 if tips is None else MAX_REFACTORS
        for k in range(MAX_ITERATIONS):
            self.chord_iterations += 1
            u = up + Z @ q
            rr = ZT @ ops.residual(u, self._fext, tips)
            dq = -self._F.solve(rr)
            if tips is not None:
                dq = self._descend(ops, up, q, rr, dq, tips)
                if dq is None and refactors < limit:
                    try:
                        self._factor(ops, u, tips)
                    except ConvergenceError:
                        return None
                    refactors += 1
                    dq = self._descend(ops, up, q, rr, -self._F.solve(rr), tips)
                if dq is None:
                    return None
            step = ops.step_norm(dq)
            if not np.isfinite(step):
                return None
            q = q + dq
            if step < self.state_tol_mm:
                return q if ops.valid(up + Z @ q) else None
            if prev is not None and step > REFACTOR_RATE * prev and refactors < limit and \
                    _late(k, step, prev, self.state_tol_mm):
                try:
                    self._factor(ops, up + Z @ q, tips)
                except ConvergenceError:   # a singular tangent on the way: the full solve
                    return None
                refactors += 1
            prev = step
        return None

    def _descend(self, ops, up, q, rr, dq, tips):
        """dq shortened until it lowers the energy with no inverted cell (Armijo), or None
        when it is no descent direction or no length does."""
        slope = float(rr @ dq)
        if not (slope < 0):
            return None
        Z = ops.red.Z
        e0, _ = ops.energy(up + Z @ q, self._fext, tips)
        alpha = 1.0
        for _ in range(LINE_SEARCH):
            e1, J = ops.energy(up + Z @ (q + alpha * dq), self._fext, tips)
            if (J is None or np.all(J > 0)) and e1 <= e0 + 1e-4 * alpha * slope + 1e-13 * abs(e0):
                return alpha * dq
            alpha *= 0.5
        return None

    def _refine(self, ops, u, tips=None):
        """The sensitivities X (nq, n_act) at state u (the tips' ends at ``tips``), from the
        last ones; None when stalled."""
        Z, ZT = ops.red.Z, ops.red.ZT
        KV = ops.tangent_products(u, tips)
        C = 0.0
        if tips is not None:
            C = np.zeros_like(self._E)
            C[:, self._tip_cols] = ops.contact.push_derivative(u, tips)
        if self._X is None:   # first: one solve with the factorization gives a start
            X = -self._F.solve(ZT @ (KV(self._E) + C))
        else:
            X = self._X.copy()
        prev = None
        refactored = False
        for k in range(MAX_ITERATIONS):
            dX = -self._F.solve(ZT @ (KV(Z @ X + self._E) + C))
            X = X + dX
            change = float(np.abs(dX).max()) / max(float(np.abs(X).max()), 1e-300)
            if change < REFINE_TOL:
                return X
            if prev is not None and change > REFACTOR_RATE * prev and not refactored and \
                    _late(k, change, prev, REFINE_TOL):
                self._factor(ops, u, tips)
                refactored = True
            prev = change
        return None

    def jacobian(self, pushes: dict, u=None) -> np.ndarray:
        """(gdim, n_act) mm/mm: the target's sensitivity to the pushes at the model's state at
        ``pushes`` (``u`` is ignored: this model keeps its own state)."""
        t0 = time.perf_counter()
        self._factor_ms = 0.0
        pushes = self._pressing(pushes)
        s = np.array([float(pushes.get(a, 0.0)) for a in self.acts])
        ops, up = self._setup(pushes)
        tips = self._tips(ops, s)
        q = None
        if self._q is not None and self._F is not None:
            q0 = self._q if self._X is None or self._s is None else \
                self._q + self._X @ (s - self._s)
            q = self._chord(ops, up, q0, tips)
        if q is None:
            if self._q is not None:
                self.fallbacks += 1
                self.retries.append(f"fast model at pushes {pushes}: chord iterations stalled; "
                                    f"full ADMM solve")
            ops, up, u_full = self._full_solve(pushes)
            self._factor(ops, u_full, tips)
            q = self._q
        t1 = time.perf_counter()
        u_new = up + ops.red.Z @ q
        X = self._refine(ops, u_new, tips)
        if X is None:
            self._factor(ops, u_new, tips)
            self._X = None
            X = self._refine(ops, u_new, tips)
            if X is None:
                raise ConvergenceError(f"the fast model's sensitivities did not converge at "
                                       f"pushes {pushes}")
        self._q, self._s, self._X = q, s, X
        J = np.asarray(self._P @ (ops.red.Z @ X + self._E))
        t2 = time.perf_counter()
        self.timings.append({"state": (t1 - t0) * 1e3, "jacobian": (t2 - t1) * 1e3,
                             "factor": self._factor_ms})
        self.solve_time_s += t2 - t0
        return J

    @property
    def u(self) -> np.ndarray:
        """The model's current state (mm, (n_vertices, gdim))."""
        if self._q is None:
            raise CaseError("the fast model has no state yet: call jacobian(pushes) first")
        pushed = self.case.with_pushes(dict(zip(self.acts, self._s.tolist())))
        ops = self._ops
        return (ops.prescribed(pushed) + ops.red.Z @ self._q).reshape(-1, ops.d)
