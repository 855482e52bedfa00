"""The HTML page of one closed loop (``tissue mpc --out DIR`` writes
``DIR/mpc_TARGET_taskN.html``): the status, closed against open loop (ITAE, steady-state error,
retraction, final pushes), the time response and the target error over time, what the open
loop did, and the loop's settings and model-plant mismatch.

The page reads the JSON of ``tissue mpc --json`` (``LoopResult.to_json_dict``); its pictures are
PNG files beside it, linked relatively; every file is written whole or not at all.
"""
from __future__ import annotations

import html
from pathlib import Path

import numpy as np

from tissue_reference.meshes.html_page import Raw, fmt, image, kv_table, page, table, write_page
from tissue_reference.meshes.io import save_figure

__all__ = ["mpc_stem", "plot_errors", "write_mpc_report"]


def mpc_stem(target: str, task: int) -> str:
    """The name shared by a loop's page and pictures: ``mpc_T1_task1``."""
    return f"mpc_{target}_task{task}"


def plot_errors(d: dict, path) -> Path:
    """Distance of the target to its goal (mm, log scale) against time (s), closed and open
    loop, PNG written whole."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3.6))
    pos = lambda a: np.where(np.asarray(a, float) > 0, np.asarray(a, float), np.nan)
    ax.semilogy(d["time_s"], pos(d["target_error_mm"]), "b-", label="closed loop (MPC)")
    ol = d.get("open_loop") or {}
    if ol.get("time_s"):
        ax.semilogy(ol["time_s"], pos(ol["target_error_mm"]), "r--",
                    label=f"open loop (eq. 22, {ol['status']})")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("target error (mm)")
    ax.set_title(f"target {d['target']}, task {d['task']}: distance to the goal")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    path = Path(path)
    save_figure(fig, path)
    return path


def _status(d: dict) -> Raw:
    st = d.get("status")
    if st in ("completed", "outside range"):
        ok = d["settled"] and st == "completed"   # the loop's verdict (LoopResult.settled)
        cls, text = ("valid" if ok else "invalid"), (
            f"<b>Completed</b>: steady-state error {d['steady_state_error_mm']:.3g} mm "
            f"({'within' if d['settled'] else 'above'} {d['sse_goal_mm']:g} mm), ITAE "
            f"{d['itae']:.4g} mm·s², largest retraction {d['max_retraction_mm']:.3g} mm")
        if st == "outside range":
            text += ("<br><b>Outside the range where answers converge</b>: " +
                     "; ".join(html.escape(w) for w in d.get("outside_range", [])) +
                     ". These figures have no converged answer behind them.")
    elif st == "unreachable":
        cls, text = "invalid", (f"<b>Unreachable goal</b>: {html.escape(str(d.get('error')))}"
                                f" (closest reachable: {html.escape(fmt(d.get('closest_reachable_mm')))}"
                                " mm)")
    else:
        cls, text = "invalid", f"<b>Failed</b>: {html.escape(str(d.get('error')))}"
    return Raw(f"<div class='{cls}'>{text}</div>")


def _open_loop_text(ol: dict) -> str:
    st = ol.get("status")
    if st == "completed":
        return "The open loop (the eq. 22 pushes of the initial Jacobian) completed."
    if st == "infeasible":
        return (f"The open loop is infeasible: its eq. 22 pushes {fmt(ol.get('u_open_unclamped_mm'))}"
                f" mm were clamped to the push limit (--max-travel), to "
                f"{fmt(ol.get('u_open_mm'))} mm.")
    if st == "outside range":
        return ("The open loop completed, but its pushes left the range where answers converge ("
                + "; ".join(ol.get("outside_range", [])) + "): its ITAE is no baseline.")
    if st == "failed":
        return (f"The open loop failed at step {ol.get('failed_at_step')}: the plant could not be "
                f"solved at pushes {fmt(ol.get('failed_pushes_mm'))} mm ({ol.get('failure')}); "
                "its ITAE is a lower bound.")
    return "The open loop was not run."


_META = ("case", "source", "plant", "model", "plant_cells", "model_cells", "plant_material",
         "model_material", "plant_gravity_mm_s2", "model_gravity_mm_s2", "mismatch", "scenario",
         "size", "model_case", "model_source", "model_size")


def write_mpc_report(d: dict, out_dir, *, response_png: str | None = None) -> Path:
    """Write the page of the loop ``d`` (the JSON of ``tissue mpc``, any status) in ``out_dir``
    with the error plot; ``response_png``: the time-response picture already there (a name in
    ``out_dir``). Returns the page's path."""
    out = Path(out_dir)
    stem = mpc_stem(d["target"], d["task"])
    parts = [Raw(f"<h1>MPC: {html.escape(str(d.get('case')))}, target "
                 f"{html.escape(str(d['target']))}, task {d['task']}</h1>"),
             (f"Plant {d.get('plant')}, controller model {d.get('model')}. Units: mm, s; "
              "ITAE = integral of t |e(t)| dt (mm·s²)."), _status(d)]
    if d.get("status") in ("completed", "outside range"):
        ol = d.get("open_loop") or {}
        parts += [Raw("<h2>Closed against open loop</h2>"), table(
            ["loop", "status", "ITAE (mm·s²)", "steady-state error (mm)",
             "max retraction (mm)", "final pushes (mm)"],
            [("closed loop (MPC)", d["status"], d["itae"], d["steady_state_error_mm"],
              d["max_retraction_mm"], fmt(d["actuator_positions_mm"][-1])),
             ("open loop (eq. 22)", ol.get("status"),
              ("≥ " if ol.get("itae_is_lower_bound") else "") + fmt(ol.get("itae")),
              ol.get("steady_state_error_mm"), "",
              fmt((ol.get("actuator_positions_mm") or [None])[-1]))],
            caption=f"actuators {', '.join(d.get('actuators', []))}"),
            _open_loop_text(ol),
            table(["quantity", "value"],
                  [("goal (mm)", fmt(d.get("goal_mm"))),
                   ("controlled coordinates", ", ".join(
                       "xyz"[i] for i, c in enumerate(d.get("controlled", [])) if c)),
                   ("steps", d.get("steps")),
                   ("MPC step median (ms)", d.get("mpc_step_median_ms")),
                   ("wall time (s)", d.get("wall_time_s"))], row_headers=True),
            Raw("<h2>Time response</h2>")]
        if response_png and (out / response_png).is_file():
            parts.append(image(response_png, "time response of the target and the pushes",
                               "target coordinates (closed loop, open loop, goal) and actuator "
                               "pushes against time", 640))
        err = plot_errors(d, out / f"{stem}_error.png")
        parts.append(image(err.name, "target error against time",
                           "distance of the target to the goal against time", 640))
        retries = list(d.get("plant_retries") or []) + list(d.get("model_retries") or [])
        if retries:
            parts.append(Raw("<div class='warn'><b>Cold retries</b><ul>" + "".join(
                f"<li>{html.escape(str(r))}</li>" for r in retries) + "</ul></div>"))
    elif d.get("time_s"):   # a loop that stopped (LoopStopped): how far it got
        parts += [Raw("<h2>Up to the stop</h2>"), table(
            ["quantity", "value"],
            [("stopped at step", f"{d.get('failed_at_step')} of {d.get('steps')}"),
             ("pushes asked there (mm)", fmt(d.get("failed_pushes_mm"))),
             ("pushes at the step before (mm)", fmt(d["actuator_positions_mm"][-1])),
             ("target error at the step before (mm)", d.get("last_error_mm")),
             ("ITAE so far, a lower bound (mm·s²)", d.get("itae_so_far")),
             ("goal (mm)", fmt(d.get("goal_mm")))], row_headers=True)]
        err = plot_errors(d, out / f"{stem}_error.png")
        parts.append(image(err.name, "target error against time up to the stop",
                           "distance of the target to the goal against time, up to the step "
                           "the plant could not be solved at", 640))
    parts += [Raw("<h2>Settings</h2>"), kv_table(d.get("settings") or {}),
              Raw("<h2>Plant and model</h2>"),
              kv_table({k: d[k] for k in _META if k in d})]
    return write_page(out / f"{stem}.html", page(f"tissue mpc: {d['target']} task {d['task']}",
                                                 parts))
