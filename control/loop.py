"""Closed-loop steering of an internal target (seed 000 section IV-B) and its open-loop baseline.

One step (quasi-static, ``dt_s`` seconds of the time axis each):
  1. the controller's model is re-linearized at the current pushes: J_s = dirichlet_jacobian at the
     model's own nonlinear solution (the model may differ from the plant: coarser mesh, E off by a
     factor, another solver);
  2. the MPC (eq. 25) returns push increments du >= 0 (mm);
  3. the plant (any solver of the project, nonlinear) is re-solved at the new pushes, warm-started
     from its previous displacement, and the target position is measured (optional Gaussian noise,
     seeded, mm).

Open loop: pushes u_open from the *initial* J_s by eq. 22 (least travel, push only), applied with
the closed loop's time profile u_open(t_k) = u_open * phi_k,
phi_k = sum_i s_i(t_k) / sum_i s_i(t_end) (non-decreasing, so the open loop never retracts
either), no feedback.

Metrics on the controlled coordinates of the task (free ones excluded), with the noise-free plant
position: error e_k = ||mask * (x_goal - x_k)||_2 (mm); ITAE (eq. 26) = sum_k t_k e_k dt (mm s^2,
rectangle rule); steady-state error = e at the last step (mm).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from tissue_reference.meshes.errors import CaseError, ConvergenceError

from .controllability import UnreachableGoalError, inverse_push, task_goal
from .jacobian import dirichlet_jacobian
from .mpc import MPCSettings, PushOnlyMPC

__all__ = [
    "LinearizedModel",
    "LoopResult",
    "LoopSettings",
    "check_prescribed",
    "itae",
    "run_closed_loop",
]


def itae(t, e, dt) -> float:
    """Eq. 26, rectangle rule: sum t_k |e_k| dt (t in s, e in mm)."""
    return float(np.sum(np.asarray(t) * np.abs(np.asarray(e)) * dt))


@dataclass(frozen=True)
class LoopSettings:
    """steps: MPC updates; dt_s: time per step (s); noise_mm: std of the measurement noise (mm);
    seed: RNG seed of the noise; reach_tol_mm: goal-reachability tolerance (mm); open_loop: also
    run the open-loop baseline; mpc: MPCSettings; task_mm: how far a seed task moves the target
    along each controlled axis (mm; the seed's 5)."""

    steps: int = 60
    dt_s: float = 1.0
    noise_mm: float = 0.0
    seed: int = 0
    reach_tol_mm: float = 1e-6
    open_loop: bool = True
    mpc: MPCSettings = field(default_factory=MPCSettings)
    task_mm: float = 5.0

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


@dataclass(frozen=True)
class LoopResult:
    """time_s (steps + 1,), s; target (steps + 1, gdim) plant positions, mm; error_mm (steps + 1,);
    pushes (steps + 1, n_act) cumulative pushes, mm; itae (mm s^2); steady_state_error_mm;
    max_retraction_mm (largest decrease of any push, >= 0); mpc_ms per step; open_loop: dict of the
    baseline (same keys, or None); goal (gdim,) absolute target position, mm; mask."""

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

    def to_json_dict(self, meta: dict | None = None) -> dict:
        """The keys of ``tissue mpc --json``; ``meta`` (case, plant, model, mismatch, settings:
        ``control.plants.loop_metadata``) first."""
        ol = self.open_loop or {}
        return {**(meta or {}), "target": self.target_name, "task": int(self.task),
                "actuators": list(self.actuators), "goal_mm": self.goal.tolist(),
                "controlled": self.mask.tolist(),
                "steps": int(len(self.time_s) - 1), "itae": float(self.itae),
                "steady_state_error_mm": float(self.steady_state_error_mm),
                "max_retraction_mm": float(self.max_retraction_mm),
                "mpc_step_median_ms": float(np.median(self.mpc_ms)) if len(self.mpc_ms) else 0.0,
                "open_loop": _open_loop_json(ol),
                "time_s": self.time_s.tolist(), "target_error_mm": self.error_mm.tolist(),
                "target_position_mm": self.target.tolist(),
                "actuator_positions_mm": self.pushes.tolist(),
                "mpc_step_ms": self.mpc_ms.tolist(),
                "plant_retries": list(self.extra.get("plant_retries", [])),
                "model_retries": list(self.extra.get("model_retries", [])),
                "wall_time_s": float(self.wall_time_s)}


def solve_checked(solve, case, pushes, initial, who: str, retries: list | None = None):
    """solve(case, pushes, initial) checked by :func:`check_prescribed`; when a warm-started solve
    fails (ConvergenceError or a state that misses the pushes) it is retried once cold
    (initial=None: the solver's own load path from the rest state) -- a warm start from a state far
    from the new pushes can leave the solver's basin where the cold load path does not (reference,
    phantom size 8: A2 = 52 mm converges cold, not warm-started from the previous open-loop step).
    ``retries`` collects the warm failures' messages."""
    try:
        r = solve(case, pushes, initial)
        check_prescribed(case, pushes, r, who)
        return r
    except ConvergenceError as exc:
        if initial is None:
            raise
        if retries is not None:
            retries.append(f"{who} at pushes {pushes}: {exc}")
    r = solve(case, pushes, None)
    check_prescribed(case, pushes, r, who + " (cold retry)")
    return r


def check_prescribed(case, pushes, r, who: str, *, rtol=1e-9):
    """Raise ConvergenceError unless solve result ``r`` is converged, valid (no inverted cells, no
    runaway growth: ``extra["valid"]``) and meets the Case's prescriptions at ``pushes`` (actuator
    patches at their pushes, fixed regions at 0): a solver that reports success with the previous
    step's boundary values, or with a folded mesh, is caught here, not differentiated or
    measured."""
    if not r.converged:
        raise ConvergenceError(f"{who} solve did not converge at pushes {pushes} "
                               f"(residual {r.residual:g})")
    extra = getattr(r, "extra", None) or {}
    if extra.get("valid", True) is False:
        raise ConvergenceError(f"{who} state at pushes {pushes} is not valid: "
                               f"{extra.get('invalid_reason')}")
    c = case.with_pushes(pushes).constraints
    if len(c.dofs):
        u = np.asarray(r.u, float).reshape(-1)
        gap = float(np.abs(u[c.dofs] - c.values).max())
        if gap > rtol * max(1.0, float(np.abs(c.values).max())):
            raise ConvergenceError(f"{who} solve reported success at pushes {pushes} but its state "
                                   f"misses the prescribed displacements by {gap:.3g} mm "
                                   f"({getattr(r, 'solver', '?')} solver)")


def _open_loop_json(ol):
    """The open-loop baseline: ``status`` "completed", "infeasible" (its pushes were clamped to
    the push limit: it cannot reach the goal) or "failed" (the plant could not be solved at its
    pushes; ``failed_at_step``, ``failure``), or "not run"."""
    if not ol:
        return {"status": "not run", "itae": None, "steady_state_error_mm": None}
    status = "failed" if not ol["converged"] else (
        "infeasible" if ol.get("clamped") else "completed")
    out = {"status": status, "itae": float(ol["itae"]),
           "steady_state_error_mm": ol["steady_state_error_mm"],
           "converged": bool(ol["converged"]), "u_open_mm": np.asarray(ol["u_open"]).tolist(),
           "clamped": bool(ol.get("clamped", False)),
           "u_open_unclamped_mm": np.asarray(ol.get("u_open_unclamped", ol["u_open"])).tolist(),
           "time_s": np.asarray(ol["time_s"], float).tolist(),
           "target_error_mm": np.asarray(ol["error_mm"], float).tolist(),
           "actuator_positions_mm": np.asarray(ol["pushes"], float).tolist()}
    if not ol["converged"]:
        out.update({"itae_is_lower_bound": True, "failed_at_step": ol["failed_at_step"],
                    "failed_pushes_mm": ol["failed_pushes_mm"],
                    "last_error_mm": ol["last_error_mm"], "failure": ol["failure"]})
    return out


def _measure(r, target, case=None, pushes=None):
    if case is not None:
        check_prescribed(case, pushes, r, "plant")
    elif not r.converged:
        raise ConvergenceError(f"plant solve did not converge (residual {r.residual:g})")
    return np.asarray(r.probes[target], float)


def run_closed_loop(plant, plant_case, model: LinearizedModel, target: str, task: int, *,
                    settings: LoopSettings = LoopSettings(), goal=None,
                    progress=None) -> LoopResult:
    """Steer ``target`` of ``plant_case`` by seed task 1, 2 or 3 (or an explicit ``goal``
    displacement (gdim,) mm with NaN on free coordinates) with the push-only MPC.
    ``progress(line)``, when given, gets a line per closed- and open-loop step (a plant solve
    on a fine mesh with contact takes minutes).

    plant(case, pushes, initial_u) -> SolveResult (nonlinear, mm). Raises UnreachableGoalError
    (with the closest reachable displacement) when the goal lies outside the positive span of the
    initial J_s; CaseError naming a missing target or actuator.
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
    na = len(acts)
    s = np.zeros(na)
    pushes = dict(zip(acts, s.tolist()))
    r = plant(plant_case, pushes, None)
    x0 = _measure(r, target, plant_case, pushes)
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
    limit = settings.mpc.max_travel
    if limit is not None:
        u_open = np.clip(u_open, 0.0, limit)
    rng = np.random.default_rng(settings.seed)
    mpc = PushOnlyMPC(na, mask, settings.mpc)
    plant_retries: list[str] = []
    S = [s.copy()]
    X = [x0.copy()]
    y = x0 + (rng.normal(0.0, settings.noise_mm, d) if settings.noise_mm > 0 else 0.0)
    J = J0
    for k in range(settings.steps):
        if k > 0:
            J = model.jacobian(pushes, u=u_prev if same else None)
        st = mpc.step(J, y, x_goal, s)
        s = s + st.du
        pushes = dict(zip(acts, s.tolist()))
        tk = time.perf_counter()
        r = solve_checked(plant, plant_case, pushes, u_prev, "plant", plant_retries)
        x = _measure(r, target)
        u_prev = r.u
        y = x + (rng.normal(0.0, settings.noise_mm, d) if settings.noise_mm > 0 else 0.0)
        S.append(s.copy())
        X.append(x)
        if progress is not None:
            progress(_step_line("closed loop", k + 1, settings.steps, s, x_goal - x, mask,
                                time.perf_counter() - tk))
    S, X = np.array(S), np.array(X)
    t = settings.dt_s * np.arange(settings.steps + 1)
    err = np.linalg.norm((x_goal - X)[:, mask], axis=1)
    retract = float(max(0.0, -np.diff(S, axis=0).min())) if len(S) > 1 else 0.0
    closed_s = time.perf_counter() - t_start
    ol = None
    if settings.open_loop:
        ol = _open_loop(plant, plant_case, acts, target, u_open, S, x_goal, mask, t, settings,
                        progress)
        ol["u_open_unclamped"] = u_open_raw
        ol["clamped"] = bool(np.any(np.abs(u_open_raw - u_open) > 1e-12))
    wall = time.perf_counter() - t_start
    return LoopResult(t, X, err, S, itae(t, err, settings.dt_s), float(err[-1]), retract,
                      np.array(mpc.solve_ms), x_goal, mask, acts, target, task, ol, wall,
                      {"model_time_s": model.solve_time_s, "J0": J0, "closed_loop_s": closed_s,
                       "open_loop_s": wall - closed_s, "plant_retries": plant_retries,
                       "model_retries": list(model.retries)})


def _step_line(what, k, n, pushes, error, mask, seconds) -> str:
    return (f"{what} step {k}/{n}: pushes {np.round(np.asarray(pushes, float), 3).tolist()} mm, "
            f"target error {np.linalg.norm(np.asarray(error)[mask]):.4g} mm, plant "
            f"{seconds:.1f} s")


def _open_loop(plant, plant_case, acts, target, u_open, S, x_goal, mask, t, settings,
               progress=None):
    """The eq. 22 pushes from the initial J_s applied along the closed loop's time profile.

    When the plant cannot be solved at some open-loop pushes (the baseline asks for pushes the
    tissue model cannot take), the run stops there: ``converged`` False, ``failed_at_step`` and
    ``failed_pushes_mm`` set, ``itae`` summed over the steps reached (a lower bound of the open
    loop's ITAE), ``steady_state_error_mm`` None (never reached) and ``last_error_mm`` the error
    at the last step solved."""
    total = S[-1].sum()
    phi = np.clip(S.sum(axis=1) / total, 0.0, 1.0) if total > 0 else np.ones(len(S))
    SO, XO = [], []
    u_prev = None
    failed = None
    retries: list[str] = []
    for k, f in enumerate(phi):
        so = f * u_open
        tk = time.perf_counter()
        try:
            po = dict(zip(acts, so.tolist()))
            r = solve_checked(plant, plant_case, po, u_prev, "open-loop plant", retries)
            x = _measure(r, target)
        except ConvergenceError as exc:
            failed = {"failed_at_step": k, "failed_pushes_mm": so.tolist(), "failure": str(exc)}
            break
        u_prev = r.u
        SO.append(so)
        XO.append(x)
        if progress is not None:
            progress(_step_line("open loop", k, len(phi) - 1, so, x_goal - x, mask,
                                time.perf_counter() - tk))
    SO, XO = np.array(SO), np.array(XO)
    eo = np.linalg.norm((x_goal - XO)[:, mask], axis=1)
    ol = {"itae": itae(t[:len(eo)], eo, settings.dt_s), "error_mm": eo, "pushes": SO,
          "time_s": t[:len(eo)],
          "target": XO, "u_open": u_open, "converged": failed is None, "retries": retries,
          "steady_state_error_mm": float(eo[-1]) if failed is None else None,
          "last_error_mm": float(eo[-1]) if len(eo) else None}
    if failed is not None:
        ol.update(failed)
    return ol


def plot_response(result: LoopResult, path, *, title=None):
    """Time response of the target's controlled coordinates (closed, open, desired) and of the
    actuator pushes (seed Figs. 8-13 analog), PNG written whole or not at all."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from tissue_reference.meshes.io import save_figure

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
