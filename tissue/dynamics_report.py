"""The HTML page of an implicit-Euler trajectory (``tissue dynamics --out DIR`` writes
``DIR/report.html``): whether the final state is valid, the settings (time step, steps, mass,
gravity), the probe displacements and the energies against time, the probes at the final time
and a 3D view of the final deformed state.

The page reads the JSON of ``tissue dynamics`` (``cmd_dynamics.trajectory_json``); its pictures
are PNG files beside it (``dynamics_history.png``, ``final_view_u.png``), linked relatively;
every file is written whole or not at all.
"""
from __future__ import annotations

import html
from pathlib import Path

import numpy as np

from tissue_reference.meshes.html_page import Raw, fmt, image, kv_table, page, table, write_page
from tissue_reference.meshes.io import save_figure

from .solve_report import validity_block
from .views import render

__all__ = ["HISTORY_PNG", "REPORT", "VIEW_PNG", "plot_history", "write_dynamics_report"]

REPORT = "report.html"
HISTORY_PNG = "dynamics_history.png"
VIEW_PNG = "final_view_u.png"


def plot_history(d: dict, path) -> Path:
    """Probe displacements (each component and |u|, mm) and the kinetic and strain energies
    (µJ) against time (s), PNG written whole."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = np.asarray(d["times_s"], float)
    fig, ax = plt.subplots(1, 2, figsize=(11, 4))
    for k, (name, series) in enumerate((d.get("probes") or {}).items()):
        u = np.asarray(series, float).reshape(len(t), -1)
        colour = f"C{k % 10}"
        ax[0].plot(t, np.linalg.norm(u, axis=1), "-", color=colour, lw=2, label=f"{name} |u|")
        for c, style in zip(range(u.shape[1]), ("--", ":", "-.")):
            ax[0].plot(t, u[:, c], style, color=colour, lw=1, label=f"{name} u_{'xyz'[c]}")
    ax[0].plot(t, d["max_displacement_mm"], "k-", lw=0.8, alpha=0.5, label="largest |u|")
    ax[0].set_xlabel("time (s)")
    ax[0].set_ylabel("displacement (mm)")
    ax[0].set_title("probe displacement against time")
    ax[0].legend(fontsize=7, ncol=2)
    ax[1].plot(t, d["kinetic_energy_uJ"], "C0-", label="kinetic")
    ax[1].plot(t, d["strain_energy_uJ"], "C3-", label="strain")
    ax[1].set_xlabel("time (s)")
    ax[1].set_ylabel("energy (µJ)")
    ax[1].set_title("energies against time")
    ax[1].legend(fontsize=8)
    for a in ax:
        a.grid(True, alpha=0.3)
    fig.tight_layout()
    return save_figure(fig, path)


def _settings(d: dict) -> Raw:
    g = d.get("gravity_mm_s2")
    ss = d.get("solver_settings") or {}
    t = d.get("times_s") or [0.0]
    rows = [("solver", d.get("solver")), ("time step dt (s)", d.get("dt_s")),
            ("steps", d.get("steps")), ("final time (s)", t[-1]), ("mass", d.get("mass")),
            ("gravity (mm/s²)", "none" if g is None else fmt(g)),
            ("ramp steps", ss.get("ramp_steps", 0)), ("degree", d.get("degree")),
            ("total mass (kg)", d.get("total_mass_kg"))]
    return table(["setting", "value"], rows, row_headers=True)


def _summary(d: dict) -> list:
    t = np.asarray(d["times_s"], float)
    umax = np.asarray(d["max_displacement_mm"], float)
    k = int(np.argmax(umax))
    conv = d.get("step_converged") or []
    its = d.get("iterations") or [0]
    rows = [("steps converged", f"{sum(map(bool, conv))} of {len(conv)}"),
            ("iterations per step, largest", max(its)), ("iterations, all steps", sum(its)),
            ("largest displacement (mm)", umax[k]), ("time of the largest displacement (s)", t[k]),
            ("final largest displacement (mm)", umax[-1]),
            ("final kinetic energy (µJ)", d["kinetic_energy_uJ"][-1]),
            ("final strain energy (µJ)", d["strain_energy_uJ"][-1]),
            ("wall time (s)", d.get("wall_time_s"))]
    parts = [table(["quantity", "value"], rows, row_headers=True)]
    prow = []
    for name, series in (d.get("probes") or {}).items():
        u = np.asarray(series, float).reshape(len(t), -1)
        mag = np.linalg.norm(u, axis=1)
        j = int(np.argmax(mag))
        prow.append((name, *[f"{x:+.4f}" for x in u[-1]], f"{mag[-1]:.4f}", f"{mag[j]:.4f}",
                     fmt(t[j])))
    if prow:
        comps = "xyz"[:len(prow[0]) - 4]
        parts.append(table(["probe", *[f"final u_{c} (mm)" for c in comps], "final |u| (mm)",
                            "largest |u| (mm)", "at time (s)"], prow,
                           caption=f"probes at the final time t = {fmt(float(t[-1]))} s"))
    return parts


def write_dynamics_report(case, d: dict, u_final, out_dir, *, use_pyvista: bool = True) -> Path:
    """Write ``out_dir``/report.html for the trajectory ``d`` (the JSON of ``tissue dynamics``)
    of ``case`` (its pushes applied), with the final displacement ``u_final`` ((n, dim) mm at
    the case's vertices) drawn in 3D. Returns the page's path."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    final = d.get("final")
    t_end = (d.get("times_s") or [0.0])[-1]
    pushes = d.get("pushes_mm") or {}
    if final is not None:
        state = validity_block(final)
    else:
        state = Raw("<div class='invalid'><b>No final state recorded</b></div>")
    if not d.get("converged", True):
        state = Raw(state + "<div class='warn'>Not every time step converged.</div>")
    hist = plot_history(d, out / HISTORY_PNG)
    u = np.asarray(u_final, float)
    view = render(case.mesh, u, np.linalg.norm(u, axis=1), out / VIEW_PNG,
                  label="displacement magnitude (mm)", use_pyvista=use_pyvista,
                  title=f"{case.name}, {d.get('solver')}: |u| (mm) at t = {fmt(float(t_end))} s")
    files = [f for f in ("trajectory.pvd", "displacement.xdmf", "displacement.vtu")
             if (out / f).is_file()]
    links = Raw("<p>Fields (ParaView): " + ", ".join(
        f"<a href='{html.escape(f)}'>{html.escape(f)}</a>" for f in files) + "</p>") \
        if files else ""
    parts = [Raw(f"<h1>Dynamics: {html.escape(case.name)}</h1>"),
             f"{case.source or case.name}; {d.get('solver')} implicit Euler; pushes (mm): "
             + (", ".join(f"{a} = {v:g}" for a, v in pushes.items() if v) or "none")
             + ". Units: mm, s, µJ, kg.",
             Raw(f"<h2>Final state (t = {html.escape(fmt(float(t_end)))} s)</h2>"), state,
             Raw("<h2>Settings</h2>"), _settings(d),
             Raw("<h2>Trajectory</h2>"),
             image(hist.name, "probe displacement and energies against time",
                   "probe displacement (each component and |u|) and the kinetic and strain "
                   "energies against time", 900),
             *_summary(d),
             Raw("<h2>Final deformed state</h2>"),
             image(Path(view["path"]).name, "final deformed tissue coloured by |u|",
                   f"the final state coloured by |u| (mm), drawn with {view['method']}", 640),
             links]
    if d.get("solver_settings"):
        parts += [Raw("<h2>Solver settings</h2>"), kv_table(d["solver_settings"])]
    return write_page(out / REPORT, page(f"tissue dynamics: {case.name}", parts))
