"""Push-only model predictive control of seed 000 (eq. 23-25), built once with CasADi, stepped many
times.

Model (eq. 23): x_{k+1} = x_k + J_s du_k, x = target position (mm, gdim coordinates), du = push
increments of the actuators along their directions (mm), J_s (gdim, n_act) mm/mm a *parameter*
(re-linearized every step by the caller).

QP solved every step (eq. 25, condensed over the horizon, decision variables du_0 .. du_{Np-1}):

    min 1/2 sum_{h=1}^{Np} (x_h - x_ref)^T Q (x_h - x_ref) + 1/2 sum_{h=0}^{Np-1} du_h^T R du_h
    s.t. du_h >= 0                          (push only: an actuator never retracts, ever)
         du_h <= max_step                   (optional, mm per step)
         s + sum_h du_h <= max_travel       (optional, mm; s = current pushes)

Decision on "u_i . d_i >= 0": the seed's u is the per-step displacement variation delta x_c
(eq. 23), so the constraint is imposed on every increment; cumulative pushes are then
non-decreasing and non-negative from the rest state -- zero retraction by construction.
Q = q diag(mask): a free coordinate of the task (and z) is not weighted. Units: Q in 1/mm^2, R in
1/mm^2 (only their ratio matters).

Weights relative to the model's gain (``weights="gain"``): R = r g^2 I with g the largest singular
value of the weighted J_s at each step (mm of target motion per mm of push). The closed loop's
speed then depends on q / r alone, not on how far a push moves the target: seed 000 tuned Q = 3 I,
R = 2 I "experimentally ... so that convergence is fast" on its phantom; on a body whose targets
move 0.05 mm per mm of push, the same absolute R makes every step close about 2 % of the error (one
coordinate, horizon 5; 1 % with a model that over-predicts the plant twice), so a loop of 60 steps
is still closing.
``weights="absolute"`` (default) is eq. 25 with the numbers as given.

Built once with ``casadi.qpsol`` (parameters J_s, x, x_ref, s); the default conic plugin is
qpOASES (active set: exact to round-off at its solution), checked against HiGHS and a bounded
least-squares solve in the tests.
"""
from __future__ import annotations

import contextlib
import io
import math
import re
import sys
import time
from dataclasses import dataclass

import numpy as np

from tissue_reference.errors import CaseError, ConvergenceError

__all__ = ["WEIGHTS", "MPCSettings", "MPCStep", "PushOnlyMPC"]

WEIGHTS = ("absolute", "gain")
"""How R is read: as given (1/mm^2), or relative to the squared gain of the weighted J_s."""

_PLUGIN_OPTS = {
    "qpoases": {"printLevel": "none", "sparse": False, "enableRegularisation": False},
    "highs": {"highs": {"output_flag": False, "primal_feasibility_tolerance": 1e-10,
                        "dual_feasibility_tolerance": 1e-10}},
    "osqp": {"osqp": {"verbose": False, "eps_abs": 1e-10, "eps_rel": 1e-10, "max_iter": 100000,
                      "polish": True}},
    "daqp": {},
    "proxqp": {"proxqp": {"eps_abs": 1e-10}},
    "qrqp": {"print_iter": False, "print_header": False},
}

# qpOASES prints its copyright banner from every QProblem constructor, printLevel "none" or not
# (casadi builds one when the solver is built and another on its first call); casadi's Python
# module writes it through sys.stdout. Only this block is dropped: anything else printed passes.
_QPOASES_BANNER = re.compile(
    r"^\n*qpOASES -- An Implementation of the Online Active Set Strategy\.\n"
    r".*?See the GNU Lesser General Public License for more details\.\n\n*",
    re.DOTALL | re.MULTILINE)


@contextlib.contextmanager
def quiet_qpoases():
    """Drop qpOASES's copyright banner from what casadi prints to sys.stdout inside the block;
    every other line (and every exception, and stderr) goes through unchanged."""
    buf = io.StringIO()
    try:
        with contextlib.redirect_stdout(buf):
            yield
    finally:
        rest = _QPOASES_BANNER.sub("", buf.getvalue())
        if rest:
            sys.stdout.write(rest)


def _positive(name, value, *, allow_none=False, integer=False):
    if value is None and allow_none:
        return
    ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool) \
        and math.isfinite(value) and value > 0
    if integer:
        ok = ok and float(value) == int(value)
    if not ok:
        kind = "integer" if integer else "number"
        raise CaseError(f"MPC setting {name} must be a positive {kind}"
                        f"{' or None' if allow_none else ''}, got {name}={value!r}")


@dataclass(frozen=True)
class MPCSettings:
    """horizon Np (steps); q, r: weights of Q = q diag(mask) and R = r I (1/mm^2); max_step (mm per
    step) and max_travel (mm, total push per actuator): optional limits; solver: a casadi conic
    plugin; weights: "absolute" (R = r I) or "gain" (R = r g^2 I, g the largest singular value of
    the weighted J_s: the loop's speed independent of the body's gain). Seed 000: Np = 5,
    Q = 3 I, R = 2 I.

    Parameters
    ----------
    horizon : int
        Prediction horizon Np (steps).
    q : float
        Weight of the target error (1/mm^2).
    r : float
        Weight of the push increments (1/mm^2).
    max_step : float or None
        Largest push increment per step (mm); None: no limit.
    max_travel : float or None
        Largest total push per actuator (mm); None: no limit.
    solver : str
        A casadi conic plugin (default "qpoases").
    weights : str
        "absolute" or "gain" (as above).
    """

    horizon: int = 5
    q: float = 3.0
    r: float = 2.0
    max_step: float | None = None
    max_travel: float | None = None
    solver: str = "qpoases"
    weights: str = "absolute"

    def __post_init__(self):
        _positive("horizon", self.horizon, integer=True)
        _positive("q", self.q)
        _positive("r", self.r)
        _positive("max_step", self.max_step, allow_none=True)
        _positive("max_travel", self.max_travel, allow_none=True)
        if self.weights not in WEIGHTS:
            raise CaseError(f"MPC setting weights must be one of {list(WEIGHTS)}, "
                            f"got weights={self.weights!r}")
        import casadi as ca

        if not isinstance(self.solver, str) or not ca.has_conic(self.solver):
            avail = [p for p in _PLUGIN_OPTS if ca.has_conic(p)]
            raise CaseError(f"MPC setting solver={self.solver!r} is not a casadi conic plugin "
                            f"available here; available: {avail}")


@dataclass(frozen=True)
class MPCStep:
    """du: first increment applied (mm, >= 0); plan: (Np, n_act) planned increments (mm);
    predicted: (Np, gdim) predicted target positions (mm); cost; solve_ms: wall time of the QP
    call."""

    du: np.ndarray
    plan: np.ndarray
    predicted: np.ndarray
    cost: float
    solve_ms: float


class PushOnlyMPC:
    """The QP of eq. 25 built once for (n_outputs, n_actuators) and a mask of weighted outputs.

    ``step(J_s, x, x_ref, pushes)`` returns the next increments; the previous plan (shifted) warm
    starts the next call.
    """

    def __init__(self, n_actuators: int, mask, settings: MPCSettings = MPCSettings()):
        import casadi as ca

        if not isinstance(settings, MPCSettings):
            raise CaseError(f"settings must be an MPCSettings, got {type(settings).__name__}")
        mask = np.asarray(mask, bool).reshape(-1)
        if not mask.any():
            raise CaseError("MPC output mask weights no coordinate (every coordinate free)")
        if int(n_actuators) < 1:
            raise CaseError(f"n_actuators must be >= 1, got {n_actuators!r}")
        self.settings = s = settings
        self.na = na = int(n_actuators)
        self.ny = ny = len(mask)
        self.mask = mask
        Np = s.horizon
        du = ca.SX.sym("du", na * Np)
        J = ca.SX.sym("J", ny, na)
        x0 = ca.SX.sym("x0", ny)
        xr = ca.SX.sym("xr", ny)
        s0 = ca.SX.sym("s0", na)
        r = ca.SX.sym("r")
        Q = ca.DM(np.diag(s.q * mask.astype(float)))
        cost = 0
        x = x0
        cum = ca.SX.zeros(na)
        for h in range(Np):
            dh = du[h * na:(h + 1) * na]
            cum = cum + dh
            x = x + ca.mtimes(J, dh)
            e = x - xr
            cost += 0.5 * ca.mtimes([e.T, Q, e]) + 0.5 * r * ca.sumsqr(dh)
        qp = {"x": du, "p": ca.vertcat(ca.vec(J), x0, xr, s0, r), "f": cost}
        if s.max_travel is not None:
            qp["g"] = s0 + cum
        opts = {"error_on_fail": False, "print_problem": False, "print_time": False}
        opts.update(_PLUGIN_OPTS.get(s.solver, {}))
        with quiet_qpoases():
            self._solver = ca.qpsol("mpc", s.solver, qp, opts)
        self._ubx = np.full(na * Np, np.inf if s.max_step is None else s.max_step)
        self._warm = np.zeros(na * Np)
        self._pred = ca.Function("pred", [du, J, x0], [ca.horzcat(*[
            x0 + ca.mtimes(J, sum((du[k * na:(k + 1) * na] for k in range(h + 1)), ca.DM.zeros(na)))
            for h in range(Np)]).T])
        self.solve_ms: list[float] = []

    def reset(self):
        self._warm[:] = 0.0
        self.solve_ms.clear()

    def push_weight(self, J_s) -> float:
        """The R = r_eff I used with this J_s (1/mm^2): r, or r g^2 with g the largest singular
        value of the weighted rows of J_s; r itself when those rows are all zero."""
        if self.settings.weights == "absolute":
            return float(self.settings.r)
        g = float(np.linalg.norm(np.asarray(J_s, float)[self.mask], 2))
        return float(self.settings.r) * g * g if g > 0.0 else float(self.settings.r)

    def step(self, J_s, x, x_ref, pushes=None) -> MPCStep:
        """J_s (ny, na) mm/mm; x current target position (ny,) mm; x_ref desired position (ny,) mm;
        pushes current total pushes (na,) mm (needed with max_travel). Raises ConvergenceError when
        the QP solver fails."""
        J_s = np.asarray(J_s, float)
        if J_s.shape != (self.ny, self.na):
            raise CaseError(f"J_s of shape {J_s.shape} does not match the MPC "
                            f"({self.ny}, {self.na})")
        x = np.asarray(x, float).reshape(self.ny)
        x_ref = np.asarray(x_ref, float).reshape(self.ny)
        s0 = np.zeros(self.na) if pushes is None else np.asarray(pushes, float).reshape(self.na)
        p = np.concatenate([J_s.ravel(order="F"), x, x_ref, s0, [self.push_weight(J_s)]])
        args = {"x0": self._warm, "p": p, "lbx": 0.0, "ubx": self._ubx}
        if self.settings.max_travel is not None:
            if np.any(s0 > self.settings.max_travel + 1e-12):
                raise CaseError(f"current pushes {s0.tolist()} mm exceed max_travel="
                                f"{self.settings.max_travel} mm")
            args.update(lbg=-np.inf, ubg=self.settings.max_travel)
        t0 = time.perf_counter()
        with quiet_qpoases():
            sol = self._solver(**args)
        ms = 1e3 * (time.perf_counter() - t0)
        st = self._solver.stats()
        if not st.get("success", False):
            raise ConvergenceError(f"MPC QP ({self.settings.solver}) failed: "
                                   f"{st.get('return_status')}")
        self.solve_ms.append(ms)
        z = np.asarray(sol["x"]).ravel()
        plan = np.maximum(z.reshape(self.settings.horizon, self.na), 0.0)  # bound round-off only
        self._warm = np.concatenate([z[self.na:], z[-self.na:]])
        pred = np.asarray(self._pred(plan.ravel(), J_s, x))
        return MPCStep(plan[0].copy(), plan, pred, float(sol["f"]), ms)
