"""The open-loop baseline of seed 000 (eq. 22): the least-travel, push-only pushes u_open from the
*initial* J_s, applied on the plant with the closed loop's time profile
u_open(t_k) = p + u_open * phi_k, phi_k = sum_i (s_i(t_k) - p_i) / sum_i (s_i(t_end) - p_i)
(p: the preload the loops start from, ``control.loop``; non-decreasing, so the open loop never
retracts either), with no feedback. Units: mm, s.
"""
from __future__ import annotations

import time

import numpy as np

from tissue_reference.errors import ConvergenceError

from .plant_step import itae, measure, solve_checked, step_line, target_errors

__all__ = ["open_loop_json", "run_open_loop"]


def run_open_loop(plant, plant_case, acts, target, u_open, S, x_goal, mask, t, settings,
                  progress=None, preload=None):
    """The eq. 22 pushes from the initial J_s applied along the closed loop's time profile,
    beyond ``preload`` (mm per actuator, the closed loop's start ``S[0]``; None: rest).

    When the plant cannot be solved at some open-loop pushes (the baseline asks for pushes the
    tissue model cannot take), the run stops there: ``converged`` False, ``failed_at_step`` and
    ``failed_pushes_mm`` set, ``itae`` summed over the steps reached (a lower bound of the open
    loop's ITAE), ``steady_state_error_mm`` None (never reached) and ``last_error_mm`` the error
    at the last step solved."""
    p0 = np.zeros(len(acts)) if preload is None else np.asarray(preload, float)
    travel = (S - p0).sum(axis=1)
    total = travel[-1]
    phi = np.clip(travel / total, 0.0, 1.0) if total > 0 else np.ones(len(S))
    SO, XO = [], []
    u_prev = None
    failed = None
    retries: list[str] = []
    for k, f in enumerate(phi):
        so = p0 + f * u_open
        tk = time.perf_counter()
        try:
            po = dict(zip(acts, so.tolist()))
            r = solve_checked(plant, plant_case, po, u_prev, "open-loop plant", retries)
            x = measure(r, target)
        except ConvergenceError as exc:
            failed = {"failed_at_step": k, "failed_pushes_mm": so.tolist(), "failure": str(exc)}
            break
        u_prev = r.u
        SO.append(so)
        XO.append(x)
        if progress is not None:
            progress(step_line("open loop", k, len(phi) - 1, so, x_goal - x, mask,
                               time.perf_counter() - tk))
    SO, XO = np.array(SO), np.array(XO)
    eo = target_errors(x_goal, XO, mask)
    ol = {"itae": itae(t[:len(eo)], eo, settings.dt_s), "error_mm": eo, "pushes": SO,
          "time_s": t[:len(eo)],
          "target": XO, "u_open": u_open, "converged": failed is None, "retries": retries,
          "steady_state_error_mm": float(eo[-1]) if failed is None else None,
          "last_error_mm": float(eo[-1]) if len(eo) else None}
    if failed is not None:
        ol.update(failed)
    return ol


def open_loop_json(ol):
    """The open-loop baseline: ``status`` "completed", "infeasible" (its pushes were clamped to
    the push limit: it cannot reach the goal), "failed" (the plant could not be solved at its
    pushes; ``failed_at_step``, ``failure``), "outside range" (it ran, but its pushes left the
    range where the plant's or the model's answers converge: ``outside_range`` says why), or
    "not run"."""
    if not ol:
        return {"status": "not run", "itae": None, "steady_state_error_mm": None}
    outside = list(ol.get("outside_range", []))
    status = "failed" if not ol["converged"] else (
        "infeasible" if ol.get("clamped") else "outside range" if outside else "completed")
    out = {"status": status, "itae": float(ol["itae"]),
           "steady_state_error_mm": ol["steady_state_error_mm"],
           "converged": bool(ol["converged"]), "u_open_mm": np.asarray(ol["u_open"]).tolist(),
           "clamped": bool(ol.get("clamped", False)), "outside_range": outside,
           "u_open_unclamped_mm": np.asarray(ol.get("u_open_unclamped", ol["u_open"])).tolist(),
           "time_s": np.asarray(ol["time_s"], float).tolist(),
           "target_error_mm": np.asarray(ol["error_mm"], float).tolist(),
           "actuator_positions_mm": np.asarray(ol["pushes"], float).tolist()}
    if not ol["converged"]:
        out.update({"itae_is_lower_bound": True, "failed_at_step": ol["failed_at_step"],
                    "failed_pushes_mm": ol["failed_pushes_mm"],
                    "last_error_mm": ol["last_error_mm"], "failure": ol["failure"]})
    return out
