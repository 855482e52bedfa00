"""The HTML page of ``tissue jacobian --out DIR`` (``DIR/report.html``, beside
``DIR/jacobian.json``): whether the state is valid, J_s as a table (a row per target coordinate,
a column per actuator, mm of target displacement per mm of push), its check against central
finite differences, the state's pushes, the kind of actuator, the discretization and settings,
and a heat map of |J_s| (``DIR/jacobian.png``).

The page reads the JSON of ``tissue jacobian --json``; every file is written whole or not at all.
"""
from __future__ import annotations

import html
from pathlib import Path

import numpy as np

from tissue_reference.meshes.html_page import Raw, image, kv_table, page, table, write_page
from tissue_reference.meshes.io import save_figure

__all__ = ["KINDS", "plot_jacobian", "write_jacobian_report"]

KINDS = {"glued patch": "glued patches: the targets' sensitivity to the patch's prescribed "
                        "displacement (Dirichlet sensitivity of the exact tangent)",
         "indenter": "rigid indenters: the targets' sensitivity to each tip's travel with the "
                     "contact of the state"}


def plot_jacobian(d: dict, path) -> Path:
    """A heat map of |J_s| (mm/mm), a row per target coordinate, a column per actuator, each
    cell labelled with the signed value; PNG written whole."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    J = np.asarray(d["J"], float).reshape(len(d["rows"]), len(d["actuators"]))
    fig, ax = plt.subplots(figsize=(3.2 + 1.1 * J.shape[1], 1.6 + 0.32 * J.shape[0]))
    im = ax.imshow(np.abs(J), cmap="viridis", aspect="auto", vmin=0.0)
    ax.set_xticks(range(J.shape[1]), d["actuators"])
    ax.set_yticks(range(J.shape[0]), d["rows"])
    big = np.abs(J).max(initial=0.0)
    for (i, j), v in np.ndenumerate(J):
        ax.text(j, i, f"{v:+.3g}", ha="center", va="center", fontsize=7,
                color="black" if abs(v) > 0.6 * big else "white")
    ax.set_xlabel("actuator")
    ax.set_title(f"|J_s| of {d['case']}")
    fig.colorbar(im, ax=ax, label="|J_s| (mm/mm)")
    fig.tight_layout()
    path = Path(path)
    save_figure(fig, path)
    return path


def _status(d: dict) -> Raw:
    if d.get("state_valid", True):
        return Raw("<div class='valid'><b>Valid state</b>: no inverted cells at the pushes "
                   "linearized at</div>")
    return Raw("<div class='invalid'><b>Not valid</b>: the state at these pushes is "
               f"{html.escape(str(d.get('state_invalid_reason')))}; J_s is of an invalid "
               "state</div>")


def _fd_part(d: dict) -> Raw:
    if d.get("fd_max_rel_error") is None:
        return Raw("<p>Not checked against finite differences (--fd-h 0).</p>")
    return table(["check", "value"],
                 [("largest difference to central differences (relative)",
                   d["fd_max_rel_error"]),
                  ("central-difference step (mm)", d["fd_h_mm"])],
                 caption="J_s against central finite differences of the same solver's "
                         "nonlinear solves (every actuator stepped by ± the step)",
                 row_headers=True)


def write_jacobian_report(d: dict, out_dir) -> Path:
    """Write ``out_dir``/report.html and jacobian.png of ``d`` (the JSON of ``tissue jacobian``).
    Returns the page's path."""
    out = Path(out_dir)
    J = np.asarray(d["J"], float).reshape(len(d["rows"]), len(d["actuators"]))
    kind = d.get("actuator_kind")
    parts = [Raw(f"<h1>Control Jacobian: {html.escape(str(d['case']))}</h1>"),
             (f"J_s: the displacement of each target coordinate per mm of each actuator's push "
             f"(mm/mm) at the state below, from the exact tangent of {d['solver']} "
             f"({d['formulation']}, degree {d['degree']})."), _status(d),
             Raw("<h2>J_s (mm/mm)</h2>"),
             table(["target coordinate"] + [f"{a} (mm/mm)" for a in d["actuators"]],
                   [(r, *row) for r, row in zip(d["rows"], J.tolist())], row_headers=True,
                   caption="rows: target.coordinate; columns: actuators"),
             _fd_part(d)]
    png = plot_jacobian(d, out / "jacobian.png")
    parts.append(image(png.name, "heat map of |J_s|", "|J_s|, each cell labelled with the "
                       "signed value (mm/mm)", 560))
    parts += [Raw("<h2>State</h2>"),
              table(["actuator", "push (mm)", "column of J_s"],
                    [(a, v, "yes" if a in d["actuators"] else "no (held)")
                     for a, v in d["state_pushes"].items()],
                    caption="every actuator's push at the state (held there)"),
              Raw("<p>Actuator kind: <b>" + html.escape(str(kind)) + "</b>"
                  + (" (" + html.escape(KINDS[kind]) + ")" if kind in KINDS else "") + "</p>"),
              Raw("<h2>Case and discretization</h2>"),
              kv_table({"source": d.get("source"), "targets": ", ".join(d.get("targets", [])),
                        "material": d.get("material"),
                        "discretization": d.get("discretization"), "solver": d.get("solver")}),
              Raw("<h2>Solver settings</h2>"), kv_table(d.get("solver_settings") or {})]
    return write_page(out / "report.html", page(f"tissue jacobian: {d['case']}", parts))
