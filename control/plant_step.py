"""What a closed loop and its open-loop baseline share: one plant solve checked against the case
(converged, valid, at the pushes asked; a warm start that fails is retried cold), the target
measured on it, the ITAE of an error history, and the progress line of a step. Units: mm, s.
"""
from __future__ import annotations

import numpy as np

from tissue_reference.errors import ConvergenceError
from tissue_reference.model.converged_range import unconverged_load

__all__ = ["KeptAnswers", "check_prescribed", "itae", "measure", "outside_range",
           "solve_checked", "step_line", "target_errors"]


def itae(t, e, dt) -> float:
    """Eq. 26, rectangle rule: sum t_k |e_k| dt (t in s, e in mm)."""
    return float(np.sum(np.asarray(t) * np.abs(np.asarray(e)) * dt))


def target_errors(x_goal, X, mask) -> np.ndarray:
    """Distance to the goal on the controlled coordinates of each target position in ``X``
    ((steps, gdim), mm): ||mask * (x_goal - x_k)||_2."""
    return np.linalg.norm((np.asarray(x_goal) - np.asarray(X))[:, mask], axis=1)


class KeptAnswers:
    """A plant's solve(case, pushes, initial) that keeps its last answer: asked again at exactly
    its pushes (the same case), it gives that answer back instead of solving the same problem
    again. The plant is a deterministic solve, so a second solve would only agree with the
    first to its tolerance; on the reference it costs a few Newton iterations (a P2 plant step
    of phantom-seed at unchanged pushes: 7-10 s). A loop meets it where it holds its pushes: a
    closed loop at the push limit or settled, an open loop once the closed loop's travel stops.
    Only the last answer is kept: a plant warm-starts from its own last answer as a whole
    (``control.plants.full_warm_start``: a P2 state's edge nodes, the tips' positions), which
    an earlier one given back would break. ``kept``: the answers given back."""

    def __init__(self, solve):
        self.solve = solve
        self.kept = 0
        self._last = None

    def __call__(self, case, pushes, initial):
        key = (id(case), tuple(sorted((str(a), float(p)) for a, p in pushes.items())))
        if self._last is not None and self._last[0] == key:
            self.kept += 1
            return self._last[1]
        r = self.solve(case, pushes, initial)
        self._last = (key, r)
        return r


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
    runaway growth: ``valid``) and meets the Case's prescriptions at ``pushes`` (actuator
    patches at their pushes, fixed regions at 0): a solver that reports success with the previous
    step's boundary values, or with a folded mesh, is caught here, not differentiated or
    measured."""
    if not r.converged:
        raise ConvergenceError(f"{who} solve did not converge at pushes {pushes} "
                               f"(residual {r.residual:g})")
    if getattr(r, "valid", None) is False:
        raise ConvergenceError(f"{who} state at pushes {pushes} is not valid: "
                               f"{r.invalid_reason}")
    c = case.with_pushes(pushes).constraints
    if len(c.dofs):
        u = np.asarray(r.u, float).reshape(-1)
        gap = float(np.abs(u[c.dofs] - c.values).max())
        if gap > rtol * max(1.0, float(np.abs(c.values).max())):
            raise ConvergenceError(f"{who} solve reported success at pushes {pushes} but its state "
                                   f"misses the prescribed displacements by {gap:.3g} mm "
                                   f"({getattr(r, 'solver', '?')} solver)")


def measure(r, target, case=None, pushes=None):
    """The probe ``target`` of solve result ``r`` (mm); with ``case`` and ``pushes`` checked by
    :func:`check_prescribed` first, otherwise only for convergence."""
    if case is not None:
        check_prescribed(case, pushes, r, "plant")
    elif not r.converged:
        raise ConvergenceError(f"plant solve did not converge (residual {r.residual:g})")
    return np.asarray(r.probes[target], float)


def step_line(what, k, n, pushes, error, mask, seconds) -> str:
    """One progress line: the step, the pushes, the distance to the goal, the plant's time."""
    return (f"{what} step {k}/{n}: pushes {np.round(np.asarray(pushes, float), 3).tolist()} mm, "
            f"target error {np.linalg.norm(np.asarray(error)[mask]):.4g} mm, plant "
            f"{seconds:.1f} s")


def outside_range(plant_case, model_case, acts, pushes) -> list[str]:
    """Why the loop's pushes ``pushes`` ((steps, n_act) mm, actuators ``acts``) left the range
    where the plant's or the model's answers converge (``model.converged_range``), one line per
    actuator and side, each at the actuator's deepest push; [] when they stayed inside."""
    P = np.asarray(pushes, float).reshape(-1, len(acts))
    if not len(P):
        return []
    deepest = {a: float(P[np.argmax(np.abs(P[:, j])), j]) for j, a in enumerate(acts)}
    sides = [("plant", plant_case)] if model_case is plant_case else \
        [("plant", plant_case), ("model", model_case)]
    return [f"{side}: {why}" for side, case in sides for why in unconverged_load(case, deepest)]
