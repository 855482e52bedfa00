"""Closed-loop steering of an internal target (seed 000 section IV-B) and its open-loop baseline.

One step (quasi-static, ``dt_s`` seconds of the time axis each):
  1. the controller's model is re-linearized at the current pushes: J_s = dirichlet_jacobian at the
     model's own nonlinear solution (the model may differ from the plant: coarser mesh, E off by a
     factor, another solver);
  2. the MPC (eq. 25) returns push increments du >= 0 (mm);
  3. the plant (any solver of the project, nonlinear) is re-solved at the new pushes, warm-started
     from its previous displacement, and the target position is measured (optional Gaussian noise,
     seeded, mm).

Open loop (``control.open_loop``): pushes u_open from the *initial* J_s by eq. 22 (least travel,
push only), applied with the closed loop's time profile, no feedback.

Preload (``LoopSettings.preload_mm``): every actuator starts pushed in by its preload (mm from the
position where the Case puts it at rest), as the seed's actuators start in contact with the
phantom. A rigid head that only touches the skin at rest carries nothing to first order (J_s = 0
there: ``phantom-seed``'s flat punches on the curved skin), so a loop that linearizes at its
start needs one. Before step 0 the plant and the model are both solved at the preload (the
plant's warm state, the model's first linearization), the target's preloaded position is x_0 and
the task's goal is measured from it. Push-only with a preload: every increment is >= 0, so no
actuator ever goes back past its preload; the pushes recorded (``LoopResult.pushes``) are total
pushes from rest (preload included: the rows start at the preload), the push limit
(``MPCSettings.max_travel``) bounds those totals (the range where answers converge is a depth
from rest), ``max_retraction_mm`` is the largest decrease between consecutive rows (the first
from the preload) and the open loop's eq. 22 pushes u_open are increments beyond the preload.

When the plant cannot be solved at the pushes the controller asks for, the loop stops there with
LoopStopped: the step, the pushes, the plant's reason and the history up to that step.

Metrics on the controlled coordinates of the task (free ones excluded), with the noise-free plant
position: error e_k = ||mask * (x_goal - x_k)||_2 (mm); ITAE (eq. 26) = sum_k t_k e_k dt (mm s^2,
rectangle rule); steady-state error = e at the last step (mm).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from tissue_reference.errors import CaseError, ConvergenceError
from tissue_reference.meshes.io import save_figure

from .controllability import UnreachableGoalError, inverse_push, task_goal
from .jacobian import dirichlet_jacobian
from .mpc import MPCSettings, PushOnlyMPC
from .open_loop import open_loop_json, run_open_loop
from .plant_step import (
    KeptAnswers,
    check_prescribed,
    itae,
    measure,
    outside_range,
    solve_checked,
    step_line,
    target_errors,
)

__all__ = [
    "LinearizedModel",
    "LoopResult",
    "LoopSettings",
    "LoopStopped",
    "check_prescribed",
    "itae",
    "run_closed_loop",
    "solve_checked",
]


@dataclass(frozen=True)
class LoopSettings:
    """steps: MPC updates; dt_s: time per step (s); noise_mm: std of the measurement noise (mm);
    seed: RNG seed of the noise; reach_tol_mm: goal-reachability tolerance (mm); open_loop: also
    run the open-loop baseline; mpc: MPCSettings; task_mm: how far a seed task moves the target
    along each controlled axis (mm; the seed's 5).

    Parameters
    ----------
    steps : int
        MPC updates.
    dt_s : float
        Time per step (s).
    noise_mm : float
        Standard deviation of the measurement noise (mm).
    seed : int
        RNG seed of the noise.
    reach_tol_mm : float
        Goal-reachability tolerance (mm).
    open_loop : bool
        Also run the open-loop baseline.
    mpc : MPCSettings
        The controller's settings.
    task_mm : float
        How far a seed task moves the target along each controlled axis (mm).
    preload_mm : float or dict
        Where each actuator starts, pushed in from rest (mm, >= 0): one number for every
        actuator, or actuator name -> mm (actuators not named start at 0).
    """

    steps: int = 60
    dt_s: float = 1.0
    noise_mm: float = 0.0
    seed: int = 0
    reach_tol_mm: float = 1e-6
    open_loop: bool = True
    mpc: MPCSettings = field(default_factory=MPCSettings)
    task_mm: float = 5.0
    preload_mm: float | dict = 0.0

    def __post_init__(self):
        if not (isinstance(self.steps, (int, np.integer)) and not isinstance(self.steps, bool)
                and self.steps >= 1):
            raise CaseError(f"loop setting steps must be an integer >= 1, got steps={self.steps!r}")
        for name in ("dt_s", "reach_tol_mm", "task_mm"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise CaseError(f"loop setting {name} must be > 0, got {name}={v!r}")
        if not (isinstance(self.noise_mm, (int, float)) and np.isfinite(self.noise_mm)
                and self.noise_mm >= 0):
            raise CaseError(f"loop setting noise_mm must be >= 0 mm, "
                            f"got noise_mm={self.noise_mm!r}")
        if not isinstance(self.mpc, MPCSettings):
            raise CaseError(f"loop setting mpc must be an MPCSettings, "
                            f"got {type(self.mpc).__name__}")
        pre = self.preload_mm
        items = pre.items() if isinstance(pre, dict) else [(None, pre)]
        for name, v in items:
            if isinstance(v, bool) or not (isinstance(v, (int, float, np.integer, np.floating))
                                           and np.isfinite(v) and v >= 0):
                what = "preload_mm" if name is None else f"preload_mm[{name!r}]"
                raise CaseError(f"loop setting {what} must be a push >= 0 mm, got {v!r}")
        if isinstance(pre, dict):
            object.__setattr__(self, "preload_mm", {str(k): float(v) for k, v in pre.items()})
        else:
            object.__setattr__(self, "preload_mm", float(pre))

    def preload(self, actuators) -> np.ndarray:
        """The preload (mm) of each of ``actuators`` (names, in order); CaseError for a preload
        of an actuator not among them."""
        acts = list(actuators)
        if not isinstance(self.preload_mm, dict):
            return np.full(len(acts), self.preload_mm)
        unknown = sorted(set(self.preload_mm) - set(acts))
        if unknown:
            raise CaseError(f"preload of {unknown}: no such actuator; actuators: {acts}")
        return np.array([self.preload_mm.get(a, 0.0) for a in acts])


class LinearizedModel:
    """The controller's model: a Case, a nonlinear solve and its tangent.

    solve(case, pushes, initial_u) -> SolveResult; tangent(case, u) -> CSR K (mN/mm, P1,
    node-major, Case numbering; evaluated on ``case.with_pushes(pushes)``).
    ``jacobian(pushes)`` -> (gdim, n_act) block of the target (mm/mm) at the model's solution:
    the Dirichlet sensitivity of glued patches from K, or, when ``sensitivity`` is given,
    ``sensitivity(case, pushes, u, target)`` (e.g. rigid indenters: ``control.plants``).
    """

    def __init__(self, case, solve, tangent, target: str, sensitivity=None):
        case.probe(target)
        self.case, self.solve, self.tangent, self.target = case, solve, tangent, target
        self.sensitivity = sensitivity
        self._u = None
        self.solve_time_s = 0.0
        self.retries: list[str] = []

    def jacobian(self, pushes: dict, u=None) -> np.ndarray:
        """u: the model's displacement at these pushes when already known (model = plant)."""
        t0 = time.perf_counter()
        if u is None:
            r = solve_checked(self.solve, self.case, pushes, self._u, "controller model",
                              self.retries)
            u = r.u
        self._u = np.asarray(u)
        if self.sensitivity is not None:
            J = self.sensitivity(self.case, pushes, self._u, self.target)
            self.solve_time_s += time.perf_counter() - t0
            return J
        pushed = self.case.with_pushes(pushes)
        K = self.tangent(pushed, self._u)
        J = dirichlet_jacobian(pushed, K, targets=[self.target]).J
        self.solve_time_s += time.perf_counter() - t0
        return J


SSE_GOAL_MM = 0.05
"""The steady-state error (mm) a closed loop must end within to have settled on its goal
(Table I's criterion; ``LoopResult.settled``)."""


@dataclass(frozen=True)
class LoopResult:
    """time_s (steps + 1,), s; target (steps + 1, gdim) plant positions, mm; error_mm (steps + 1,);
    pushes (steps + 1, n_act) cumulative pushes, mm; itae (mm s^2); steady_state_error_mm;
    ``settled``: within SSE_GOAL_MM of the goal at the end;
    max_retraction_mm (largest decrease of any push, >= 0, the first step's from the preload);
    mpc_ms per step; open_loop: dict of the
    baseline (same keys, or None); goal (gdim,) absolute target position, mm; mask.
    ``extra["outside_range"]``: why the closed loop's pushes left the range where the plant's or
    the model's answers converge (``plant_step.outside_range``; the open loop's own under
    ``open_loop["outside_range"]``), [] when they did not: a loop outside it computed numbers
    that no converged answer stands behind. ``extra["preload_mm"]``: the pushes the loop started
    from (n_act,), mm (``pushes[0]``); ``extra["at_push_limit"]``: the actuators that ended at
    the push limit (``MPCSettings.max_travel``), [] without one: a loop that ends there short of
    its goal could not reach it within the limit."""

    time_s: np.ndarray
    target: np.ndarray
    error_mm: np.ndarray
    pushes: np.ndarray
    itae: float
    steady_state_error_mm: float
    max_retraction_mm: float
    mpc_ms: np.ndarray
    goal: np.ndarray
    mask: np.ndarray
    actuators: tuple
    target_name: str
    task: int
    open_loop: dict | None = None
    wall_time_s: float = 0.0
    extra: dict = field(default_factory=dict)

    @property
    def settled(self) -> bool:
        """Whether the loop ended within SSE_GOAL_MM (mm) of its goal: its steady-state error
        is at most that."""
        return bool(self.steady_state_error_mm <= SSE_GOAL_MM)

    def to_json_dict(self, meta: dict | None = None) -> dict:
        """The keys of ``tissue mpc --json``; ``meta`` (case, plant, model, mismatch, settings:
        ``control.plants.loop_metadata``) first."""
        ol = self.open_loop or {}
        return {**(meta or {}), "target": self.target_name, "task": int(self.task),
                "actuators": list(self.actuators), "goal_mm": self.goal.tolist(),
                "controlled": self.mask.tolist(),
                "steps": int(len(self.time_s) - 1), "itae": float(self.itae),
                "steady_state_error_mm": float(self.steady_state_error_mm),
                "settled": self.settled, "sse_goal_mm": SSE_GOAL_MM,
                "max_retraction_mm": float(self.max_retraction_mm),
                "preload_mm": [float(v) for v in self.extra.get("preload_mm",
                                                                 np.zeros(len(self.actuators)))],
                "at_push_limit": list(self.extra.get("at_push_limit", [])),
                "mpc_step_median_ms": float(np.median(self.mpc_ms)) if len(self.mpc_ms) else 0.0,
                "open_loop": open_loop_json(ol),
                "time_s": self.time_s.tolist(), "target_error_mm": self.error_mm.tolist(),
                "target_position_mm": self.target.tolist(),
                "actuator_positions_mm": self.pushes.tolist(),
                "mpc_step_ms": self.mpc_ms.tolist(),
                "outside_range": list(self.extra.get("outside_range", [])),
                "plant_retries": list(self.extra.get("plant_retries", [])),
                "plant_kept_steps": int(self.extra.get("plant_kept_steps", 0)),
                "model_retries": list(self.extra.get("model_retries", [])),
                "wall_time_s": float(self.wall_time_s)}


class LoopStopped(ConvergenceError):
    """The plant could not be solved at the pushes the controller asked for: the closed loop
    stopped at ``step`` (1-based, of ``steps``) with ``pushes_mm`` asked. ``history``: the steps
    it reached (``time_s``, ``target_error_mm``, ``target_position_mm``,
    ``actuator_positions_mm``, ``goal_mm``, ``controlled``); ``to_json_dict()`` gives them with
    the step, the pushes and the ITAE so far (a lower bound of the loop's)."""

    def __init__(self, message, *, step: int, steps: int, pushes_mm, history: dict):
        super().__init__(message)
        self.step, self.steps = int(step), int(steps)
        self.pushes_mm = np.asarray(pushes_mm, float).tolist()
        self.history = history

    @classmethod
    def at(cls, step, settings, pushes, S, X, x_goal, mask, exc):
        """The stop at ``step`` after the states ``S`` (pushes) and ``X`` (target) reached."""
        S, X = np.array(S), np.array(X)
        t = settings.dt_s * np.arange(len(S))
        err = target_errors(x_goal, X, mask)
        history = {"time_s": t.tolist(), "target_error_mm": err.tolist(),
                   "target_position_mm": X.tolist(), "actuator_positions_mm": S.tolist(),
                   "goal_mm": np.asarray(x_goal, float).tolist(),
                   "controlled": np.asarray(mask, bool).tolist(),
                   "itae_so_far": itae(t, err, settings.dt_s)}
        asked = np.round(np.asarray(pushes, float), 3).tolist()
        return cls(f"closed loop stopped at step {step}/{settings.steps}, pushes {asked} mm asked "
                   f"(target error {err[-1]:.4g} mm at the step before): {exc}", step=step,
                   steps=settings.steps, pushes_mm=pushes, history=history)

    def to_json_dict(self) -> dict:
        return {"failed_at_step": self.step, "steps": self.steps,
                "failed_pushes_mm": self.pushes_mm,
                "last_error_mm": self.history["target_error_mm"][-1], **self.history}


def run_closed_loop(plant, plant_case, model: LinearizedModel, target: str, task: int, *,
                    settings: LoopSettings = LoopSettings(), goal=None,
                    progress=None) -> LoopResult:
    """Steer ``target`` of ``plant_case`` by seed task 1, 2 or 3 (or an explicit ``goal``
    displacement (gdim,) mm with NaN on free coordinates) with the push-only MPC.
    ``progress(line)``, when given, gets a line per closed- and open-loop step (a plant solve
    on a fine mesh with contact takes minutes).

    plant(case, pushes, initial_u) -> SolveResult (nonlinear, mm). Raises UnreachableGoalError
    (with the closest reachable displacement) when the goal lies outside the positive span of the
    initial J_s; LoopStopped (a ConvergenceError) when the plant cannot be solved at the pushes
    asked, with the history up to that step; CaseError naming a missing target or actuator, or
    a preload beyond the push limit. With ``settings.preload_mm`` the plant and the model are
    first solved at the preload, and the goal is measured from the target's preloaded position
    (module docstring).
    """
    t_start = time.perf_counter()
    plant_case.probe(target)
    acts = tuple(a.name for a in plant_case.actuators)
    macts = tuple(a.name for a in model.case.actuators)
    if macts != acts:
        raise CaseError(f"model actuators {list(macts)} differ from the plant's {list(acts)}")
    if model.target != target:
        raise CaseError(f"model target {model.target!r} differs from the plant target {target!r}")
    d = plant_case.mesh.gdim
    if goal is None:
        dgoal, mask = task_goal(task, d, settings.task_mm)
    else:
        g = np.asarray(goal, float).reshape(-1)
        if g.shape != (d,):
            raise CaseError(f"goal must have {d} components (NaN = free), got {goal!r}")
        mask = np.isfinite(g)
        dgoal = np.where(mask, g, 0.0)
    same = model.case is plant_case and model.solve is plant
    plant = KeptAnswers(plant)   # a load this run solved before gives its answer back
    na = len(acts)
    preload = settings.preload(acts)
    limit = settings.mpc.max_travel
    if limit is not None and np.any(preload > limit):
        raise CaseError(f"preload {dict(zip(acts, preload.tolist()))} mm: beyond the push limit "
                        f"max_travel={limit:g} mm")
    s = preload.copy()
    pushes = dict(zip(acts, s.tolist()))
    r = plant(plant_case, pushes, None)
    x0 = measure(r, target, plant_case, pushes)
    u_prev = r.u
    x_goal = x0 + dgoal
    J0 = model.jacobian(pushes, u=r.u if same else None)
    # reachability (eq. 22 residual) and the open-loop pushes from the initial J_s
    u_open, p_star, residual = inverse_push(J0[mask], dgoal[mask])
    if residual > settings.reach_tol_mm:
        closest = np.zeros(d)
        closest[mask] = p_star
        raise UnreachableGoalError(
            f"target {target!r}: goal displacement {dgoal[mask].tolist()} mm (task {task}) is "
            f"outside the positive span of the actuators' J_s; closest reachable "
            f"{p_star.tolist()} mm with pushes {dict(zip(acts, u_open.round(4).tolist()))}",
            closest=closest, pushes=u_open)
    # the open loop gets what a real actuator can do: the eq. 22 pushes clamped to the push
    # limit; a clamped baseline is flagged infeasible (it cannot reach the goal by construction)
    u_open_raw = np.asarray(u_open, float).copy()
    if limit is not None:
        u_open = np.clip(u_open, 0.0, limit - preload)
    rng = np.random.default_rng(settings.seed)
    mpc = PushOnlyMPC(na, mask, settings.mpc)
    plant_retries: list[str] = []
    S = [s.copy()]
    X = [x0.copy()]
    y = x0 + (rng.normal(0.0, settings.noise_mm, d) if settings.noise_mm > 0 else 0.0)
    J = J0
    model_ms = []   # per step: the model's update to the pushes and its Jacobian (ms)
    for k in range(settings.steps):
        if k > 0:
            tm = time.perf_counter()
            J = model.jacobian(pushes, u=u_prev if same else None)
            model_ms.append((time.perf_counter() - tm) * 1e3)
        st = mpc.step(J, y, x_goal, s)
        s = s + st.du
        pushes = dict(zip(acts, s.tolist()))
        tk = time.perf_counter()
        try:
            r = solve_checked(plant, plant_case, pushes, u_prev, "plant", plant_retries)
            x = measure(r, target)
        except ConvergenceError as exc:
            raise LoopStopped.at(k + 1, settings, s, S, X, x_goal, mask, exc) from exc
        u_prev = r.u
        y = x + (rng.normal(0.0, settings.noise_mm, d) if settings.noise_mm > 0 else 0.0)
        S.append(s.copy())
        X.append(x)
        if progress is not None:
            progress(step_line("closed loop", k + 1, settings.steps, s, x_goal - x, mask,
                               time.perf_counter() - tk))
    S, X = np.array(S), np.array(X)
    t = settings.dt_s * np.arange(settings.steps + 1)
    err = target_errors(x_goal, X, mask)
    retract = float(max(0.0, -np.diff(S, axis=0).min())) if len(S) > 1 else 0.0
    closed_s = time.perf_counter() - t_start
    ol = None
    if settings.open_loop:
        ol = run_open_loop(plant, plant_case, acts, target, u_open, S, x_goal, mask, t, settings,
                           progress, preload=preload)
        ol["u_open_unclamped"] = u_open_raw
        ol["clamped"] = bool(np.any(np.abs(u_open_raw - u_open) > 1e-12))
        ol["outside_range"] = outside_range(plant_case, model.case, acts, ol["pushes"])
    wall = time.perf_counter() - t_start
    return LoopResult(t, X, err, S, itae(t, err, settings.dt_s), float(err[-1]), retract,
                      np.array(mpc.solve_ms), x_goal, mask, acts, target, task, ol, wall,
                      {"model_time_s": model.solve_time_s, "J0": J0, "closed_loop_s": closed_s,
                       "open_loop_s": wall - closed_s, "plant_retries": plant_retries,
                       "plant_kept_steps": plant.kept,
                       "model_retries": list(model.retries), "model_step_ms": model_ms,
                       "outside_range": outside_range(plant_case, model.case, acts, S),
                       "preload_mm": preload,
                       "at_push_limit": [] if limit is None else
                       [a for a, v in zip(acts, S[-1]) if v >= limit - 1e-6]})


def plot_response(result: LoopResult, path, *, title=None):
    """Time response of the target's controlled coordinates (closed, open, desired) and of the
    actuator pushes (seed Figs. 8-13 analog), PNG written whole or not at all."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    t = result.time_s
    for c in np.flatnonzero(result.mask):
        lab = "xyz"[c]
        ax[0].plot(t, result.target[:, c], "b-", label=f"closed loop {lab}")
        if result.open_loop is not None:
            xo = result.open_loop["target"]
            ax[0].plot(t[:len(xo)], xo[:, c], "r--", label=f"open loop {lab}"
                       + ("" if result.open_loop["converged"] else " (plant failed)"))
        ax[0].axhline(result.goal[c], color="g", lw=1, label=f"desired {lab}")
    ax[0].set_ylabel("target position (mm)")
    ax[0].legend(fontsize=8)
    for j, a in enumerate(result.actuators):
        ax[1].plot(t, result.pushes[:, j], label=a)
    ax[1].set_ylabel("actuator push (mm)")
    ax[1].set_xlabel("time (s)")
    ax[1].legend(fontsize=8)
    fig.suptitle(title or f"target {result.target_name}, task {result.task}")
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
    return path
