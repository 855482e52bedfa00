"""What a closed loop and its open-loop baseline share: one plant solve checked against the case
(converged, valid, at the pushes asked; a warm start that fails is retried cold), the target
measured on it, the ITAE of an error history, and the progress line of a step. Units: mm, s.
"""
from __future__ import annotations

import numpy as np

from tissue_reference.errors import ConvergenceError
from tissue_reference.model.converged_range import unconverged_load

__all__ = ["PUSH_MATCH_MM", "KeptAnswers", "check_prescribed", "itae", "measure", "outside_range",
           "solve_checked", "step_line", "target_errors"]


def itae(t, e, dt) -> float:
    """Eq. 26, rectangle rule: sum t_k |e_k| dt (t in s, e in mm)."""
    return float(np.sum(np.asarray(t) * np.abs(np.asarray(e)) * dt))


def target_errors(x_goal, X, mask) -> np.ndarray:
    """Distance to the goal on the controlled coordinates of each target position in ``X``
    ((steps, gdim), mm): ||mask * (x_goal - x_k)||_2."""
    return np.linalg.norm((np.asarray(x_goal) - np.asarray(X))[:, mask], axis=1)


PUSH_MATCH_MM = 1e-9
"""Pushes within this (mm, every actuator) of a load a plant has solved are that load
(``KeptAnswers``): far below what a solve resolves (its Newton tolerance is 1e-10 of the
displacement), and above the round-off by which an open loop's pushes, built from the closed
loop's travel (``control.open_loop``), miss the closed loop's own where they are the same."""


class KeptAnswers:
    """A plant's solve(case, pushes, initial) that keeps the answers it gave in one loop run:
    asked again at a load it has solved (the same case, every push within PUSH_MATCH_MM), it
    gives that answer back instead of solving the same problem again. The plant is a
    deterministic solve, so a second solve would only agree with the first to its tolerance; on
    the reference it costs a few Newton iterations where the state is the same (a P2 plant step
    of phantom-seed at unchanged pushes: 7-10 s), and a whole load path where the open loop
    starts cold at the preload the closed loop solved first (about 45 s on phantom-seed's P2
    plant). A loop meets it where it holds its pushes (a closed loop at the push limit or
    settled, an open loop once the closed loop's travel stops), at the preload both loops start
    from, and at every step of an open loop whose eq. 22 pushes point along the closed loop's
    (one head pushed alone, or two held at the limit together): the open loop then solves
    nothing. A solve given an earlier answer's vertex field as ``initial`` starts from that
    answer as the plant keeps it (``control.plants.full_warm_start``: a P2 state's edge nodes,
    the tips' positions). ``kept``: the answers given back."""

    def __init__(self, solve):
        self.solve = solve
        self.kept = 0
        self._answers = []   # (case, actuator names, pushes (mm), answer), in solve order

    def __call__(self, case, pushes, initial):
        names = tuple(sorted(str(a) for a in pushes))
        p = np.array([float(pushes[a]) for a in sorted(pushes, key=str)])
        for c, n, q, r in reversed(self._answers):
            if c is case and n == names and np.all(np.abs(q - p) <= PUSH_MATCH_MM):
                self.kept += 1
                return r
        r = self.solve(case, pushes, initial)
        self._answers.append((case, names, p, r))
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
