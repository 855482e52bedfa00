"""The HTML page of one solve (``tissue solve --out DIR`` writes ``DIR/report.html``): whether the
answer is valid, what was solved (case, pushes, material, discretization), the probes and
reactions with their estimated discretization errors, indenter contact, 3D views of the
deformed tissue (coloured by |u| and by J = det F) and the load stepping / iteration history.

Pictures are PNG files beside the page (``STEM_view_u.png``, ``STEM_view_J.png``,
``STEM_history.png``), linked relatively; every file is written whole or not at all.
"""
from __future__ import annotations

import html
from pathlib import Path

import numpy as np

from tissue_reference.meshes.html_page import Raw, fmt, image, kv_table, page, table, write_page
from tissue_reference.meshes.io import save_figure
from tissue_reference.meshes.mesh import cell_jacobians
from tissue_reference.model.answer_warnings import ESTIMATE_WARN
from tissue_reference.solvers.registry import is_reference

from .views import start_views

__all__ = ["REPORT", "validity_block", "vertex_min_J", "write_solve_report"]

REPORT = "report.html"


def vertex_min_J(mesh, u) -> np.ndarray:
    """J = det F per vertex: the smallest over the cells around it (an inverted cell shows)."""
    cells = np.asarray(mesh.cells, np.int64)
    J = cell_jacobians(mesh.points, cells, np.asarray(u, float))
    out = np.full(len(mesh.points), np.inf)
    np.minimum.at(out, cells.ravel(), np.repeat(J, cells.shape[1]))
    return np.where(np.isfinite(out), out, 1.0)


def _history_plot(history: dict, solver: str, path: Path) -> bool:
    """The load stepping (reference: residual and Newton iterations per load step against the
    load fraction) or a fast solver's per-iteration series; False when there is nothing to
    draw."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if history.get("load_fraction"):
        lam = np.asarray(history["load_fraction"], float)
        fig, ax = plt.subplots(1, 2, figsize=(10, 3.8))
        res = np.asarray(history.get("iterate_residual") or history["residual"], float)
        tried = np.asarray(history.get("iterate_load") or lam, float)
        k = np.arange(1, len(res) + 1)
        ax[0].semilogy(k, np.where(res > 0, res, np.nan), "-", color="0.6", lw=0.8)
        dots = ax[0].scatter(k, np.where(res > 0, res, np.nan), c=tried, cmap="viridis",
                             vmin=0, vmax=1, s=14, zorder=3)
        fig.colorbar(dots, ax=ax[0], label="load fraction tried")
        ax[0].set_xlabel("Newton iterate (all load steps, failed ones included)")
        ax[0].set_ylabel("residual norm")
        ax[0].set_title("Newton residual per iteration")
        step = np.arange(1, len(lam) + 1)
        ax[1].bar(step, history["newton_iterations"], color="C1", alpha=0.6,
                  label="Newton iterations")
        ax[1].set_xlabel("load step")
        ax[1].set_ylabel("Newton iterations")
        twin = ax[1].twinx()
        twin.plot(step, lam, "ko-", label="load fraction reached")
        twin.set_ylabel("load fraction reached")
        twin.set_ylim(0, 1.05)
        ax[1].set_title("Load stepping")
    else:
        series = {k: np.asarray(v, float) for k, v in history.items()
                  if isinstance(v, list) and len(v) > 1 and not k.endswith("_s")
                  and all(isinstance(x, (int, float)) for x in v)}
        if not series:
            return False
        fig, ax0 = plt.subplots(figsize=(6.4, 4.2))
        ax = [ax0]
        for k, v in series.items():
            ax0.semilogy(np.arange(1, len(v) + 1), np.where(v > 0, v, np.nan), label=k)
        ax0.set_xlabel("iteration")
        ax0.set_ylabel("value (mm for *_mm series)")
        ax0.set_title(f"{solver}: per-iteration history")
        ax0.legend(fontsize=8)
    for a in ax:
        a.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    save_figure(fig, path)
    return True


def validity_block(d: dict) -> Raw:
    """The box that opens a page: valid (green) or not, converged or not (red), with min J,
    inverted cells, the largest displacement and the warnings of the solve result ``d``."""
    ok = d.get("valid", True) and d.get("converged", True)
    lf = d.get("load_fraction")
    if ok:
        head = "<div class='valid'><b>Valid answer</b>: converged, no inverted cells"
    elif not d.get("converged", True):
        head = ("<div class='invalid'><b>Not converged</b>: the last converged state"
                + (f" at load fraction {lf:.4f}" if isinstance(lf, float) else "") + " is shown")
    else:
        head = (f"<div class='invalid'><b>Not valid</b>: "
                f"{html.escape(str(d.get('invalid_reason') or 'no reason recorded'))}")
    facts = (f" (min J {fmt(d.get('min_J'))}, inverted cells {fmt(d.get('inverted_cells'))}, "
             f"largest displacement {fmt(d.get('max_displacement_mm'))} mm)</div>")
    warns = list(d.get("warnings") or [])
    for name, e in (d.get("probe_error_estimates") or {}).items():
        size = float(np.linalg.norm((d.get("probes") or {}).get(name, {}).get("displacement",
                                                                               [0.0])))
        if d.get("no_converged_value"):   # the glued or indenter warning above says why
            continue
        if e is not None and size > 0 and e > ESTIMATE_WARN * size:
            warns.append(f"probe {name}: estimated discretization error {e:.2g} mm is "
                         f"{e / size:.1%} of |u| (above {ESTIMATE_WARN:.0%})")
    w = ("<div class='warn'><b>Warnings</b><ul>" + "".join(
        f"<li>{html.escape(str(x))}</li>" for x in warns) + "</ul></div>") if warns else ""
    return Raw(head + facts + w)


def _what(d: dict) -> list:
    disc = d.get("discretization") or {}
    rows = [("case", d.get("case")), ("solver", d.get("solver")),
            ("vertices", d.get("n_vertices")), ("cells", d.get("n_cells"))]
    m = d.get("material") or {}
    rows += [("material model", m.get("model")), ("E (kPa)", m.get("E_kPa")),
             ("nu", m.get("nu")), ("density (kg/mm³)", m.get("density_kg_mm3"))]
    if m.get("volumetric"):
        rows.append(("volumetric law", {"quadratic": "quadratic: κ/2 (J − 1)², as seed 000",
                                        "log": "log: κ/2 (ln J)²"}.get(m["volumetric"],
                                                                      m["volumetric"])))
    if disc:
        p = disc.get("pressure_degree")
        rows += [("formulation", disc.get("formulation")),
                 ("degree", f"P{disc.get('degree')}" + (f"/P{p}" if p is not None else "")),
                 ("geometry order", disc.get("geometry_order")), ("dofs", disc.get("dofs")),
                 ("quadrature degree", disc.get("quadrature_degree"))]
    else:
        rows.append(("degree", f"P{d.get('degree')}"))
    pushes = d.get("pushes_mm") or {}
    parts = [Raw("<h2>What was solved</h2>"),
             table(["quantity", "value"], rows, row_headers=True),
             table(["actuator", "push (mm)", "type"],
                   [(a, v, (d.get("actuators") or {}).get(a, {}).get("type"))
                    for a, v in pushes.items()], caption="Actuator pushes")]
    return parts


def _answer(d: dict) -> list:
    # lazy: fem_reference loads dolfinx and PETSc (0.7 s of start-up)
    from tissue_reference.fem_reference.measured import accuracy_line

    its = d.get("newton_iterations") if is_reference(d.get("solver")) else d.get("iterations")
    rows = [("converged", d.get("converged")), ("iterations", its),
            ("load steps", d.get("load_steps")), ("load fraction", d.get("load_fraction")),
            ("wall time (s)", d.get("wall_time_s")),
            ("strain energy (µJ)", d.get("strain_energy"))]
    parts = [Raw("<h2>Answer</h2>"), table(["quantity", "value"],
                                           [r for r in rows if r[1] is not None],
                                           row_headers=True)]
    pe = d.get("probe_error_estimates") or {}
    prow = []
    for name, p in (d.get("probes") or {}).items():
        u = np.asarray(p["displacement"], float)
        size = float(np.linalg.norm(u))
        e = pe.get(name)
        rel = f"{100 * e / size:.2f}" if e is not None and size > 0 else ""
        prow.append((name, fmt(p.get("point")), *[f"{x:+.4f}" for x in u], f"{size:.4f}",
                     fmt(e, 2), rel))
    comps = ["x", "y", "z"][:int(d.get("dimension", 3))]
    # past the loads where answers converge the estimate is a difference, not an error bar
    err = "estimated error" if not d.get("no_converged_value") else \
        f"degree {int(d.get('degree', 1)) + 1} differs by"
    if prow:
        parts += [Raw("<h3>Probes</h3>"),
                  table(["probe", "point (mm)", *[f"u_{c} (mm)" for c in comps], "|u| (mm)",
                         f"{err} (mm)", f"{err} (%)"], prow)]
    re_ = d.get("reaction_error_estimates") or {}
    rrow = [(name, *[f"{x:+.3f}" for x in f], f"{np.linalg.norm(f):.3f}", fmt(re_.get(name), 2))
            for name, f in (d.get("reactions") or {}).items()]
    if rrow:
        parts += [Raw("<h3>Reactions</h3>"),
                  table(["region", *[f"F_{c} (mN)" for c in comps], "|F| (mN)",
                         f"{err} (mN)"], rrow,
                        caption="the force each support exerts on the body")]
    if pe:
        ed = d.get("estimate_discretization") or {}
        parts.append(f"Error estimate: {d.get('estimate_method')} against "
                     f"{ed.get('formulation')} P{ed.get('degree')} ({ed.get('dofs')} dofs); cost "
                     f"{fmt(d.get('estimate_cost_ratio'), 2)} x the solve."
                     + (" Not an error bar at this load: no mesh-converged answer is "
                        "known (Warnings above); the columns give the difference between the "
                        "two degrees." if d.get("no_converged_value") else ""))
    elif d.get("estimate_note"):
        parts.append(f"No error estimate: {d['estimate_note']}.")

    if line := accuracy_line(d):
        parts.append(f"Accuracy: {line}.")
    ind = d.get("indenters") or {}
    if ind:
        parts += [Raw("<h3>Indenters</h3>"),
                  table(["indenter", "push (mm)", "force (mN)", "contact area (mm²)",
                         "max penetration (mm)", "contact rule"],
                        [(n, r.get("push"), r.get("force"), r.get("contact_area"),
                          r.get("max_penetration"), _rule_text(r.get("quadrature")))
                         for n, r in ind.items()])]
    return parts


def write_solve_report(case, res, out_dir, *, data: dict | None = None, stem: str = "displacement",
                       use_pyvista: bool = True) -> Path:
    """Write ``out_dir``/report.html for the solve ``res`` of ``case`` (its pushes applied) and
    its pictures; ``data``: the solve's JSON (``res.to_json_dict(case)`` with its settings),
    ``stem``: the name of the field files beside it. Returns the page's path."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    d = data if data is not None else res.to_json_dict(case)
    u = np.asarray(res.u, float)
    title = f"{case.name}, {res.solver}"
    # the two views are drawn in one child process while the history is plotted here
    pending = start_views(case.mesh, u, [
        {"scalar": np.linalg.norm(u, axis=1), "path": out / f"{stem}_view_u.png",
         "label": "displacement magnitude (mm)",
         "title": f"{title}: displacement magnitude (mm)"},
        {"scalar": vertex_min_J(case.mesh, u), "path": out / f"{stem}_view_J.png",
         "label": "J = det F",
         "title": f"{title}: J = det F (smallest of the cells at each vertex)"},
    ], use_pyvista=use_pyvista)
    hist = out / f"{stem}_history.png"
    try:
        history = image(hist.name, "load stepping and iteration history", None, 800) \
            if _history_plot(res.history or {}, res.solver, hist) else "No iteration history."
    finally:   # the child is collected (and its folder removed) whatever the plot did
        view_u, view_J = pending.wait()
    figs = [image(Path(view_u["path"]).name, "deformed tissue coloured by |u|",
                  f"deformed tissue coloured by |u| (mm), drawn with {view_u['method']}", 640),
            image(Path(view_J["path"]).name, "deformed tissue coloured by J",
                  "J = det F, the smallest of the cells at each vertex (1: no volume change, "
                  f"<= 0: inverted), drawn with {view_J['method']}", 640)]
    files = [f for f in (f"{stem}.xdmf", f"{stem}.vtu") if (out / f).is_file()]
    links = Raw("<p>Fields (ParaView): " + ", ".join(
        f"<a href='{html.escape(f)}'>{html.escape(f)}</a>" for f in files) + "</p>") \
        if files else ""
    parts = [Raw(f"<h1>Solve: {html.escape(case.name)}</h1>"),
             f"{case.source or case.name}; pushes (mm): "
             + (", ".join(f"{a} = {v:g}" for a, v in (d.get("pushes_mm") or {}).items() if v)
                or "none") + ". Units: mm, mN, kPa, µJ, s.",
             validity_block(d), *_what(d), *_answer(d),
             Raw("<h2>Deformed tissue</h2>"), *figs,
             Raw("<h2>Convergence</h2>"), history, links]
    if d.get("solver_settings"):
        parts += [Raw("<h2>Solver settings</h2>"), kv_table(d["solver_settings"])]
    return write_page(out / REPORT, page(f"tissue solve: {case.name}", parts))


def _rule_text(rule) -> str:
    """The contact rule as the report page names it."""
    if rule is None:
        return ""
    return "nodal" if rule == "nodal" else f"Gauss, degree {rule}"
