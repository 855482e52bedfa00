"""The HTML page of a mesh-convergence study (``tissue converge --out DIR`` writes
``DIR/report.html``): what was studied, the log-log plot, and per study (one Lagrange degree)
its meshes and, for every probe (mm) and reaction (mN), the values on each level, the observed
order, whether the values are in the asymptotic range, the GCI and the Richardson value, which
is given only inside the asymptotic range.

The page reads the JSON of ``tissue converge`` (the converge schema); the plot is a PNG beside
it, linked relatively; the page is written whole or not at all.
"""
from __future__ import annotations

import html
from pathlib import Path

from tissue_reference.meshes.html_page import Raw, fmt, image, kv_table, page, table, write_page

__all__ = ["NO_EXTRAPOLATION", "REPORT", "write_converge_report"]

REPORT = "report.html"
NO_EXTRAPOLATION = "not in the asymptotic range: no extrapolated value"
DIGITS = 6  # significant digits of the values and the extrapolated value


def _components(vec: dict):
    """(component, its JSON) of a VectorConvergence's JSON, the dominant component first."""
    comps = vec.get("components") or {vec["component"]: vec}
    yield vec["component"], comps[vec["component"]]
    yield from ((c, q) for c, q in comps.items() if c != vec["component"])


def _orders(q: dict) -> str:
    return ", ".join("none" if o is None else fmt(o, 3)
                     for o in q.get("observed_orders") or []) or "none"


def _quantity_table(group: dict, unit: str, h: list, what: str, caption: str) -> list:
    """The table of ``group`` (name -> the JSON of a VectorConvergence), one row per reported
    component, and the list saying why each one is or is not in the asymptotic range."""
    rows, why = [], []
    for name, vec in group.items():
        for c, q in _components(vec):
            extra, gci_rel = q.get(f"extrapolated_{unit}"), q.get("gci_rel")
            inside = bool(q.get("asymptotic"))
            rows.append((
                name, c, *[fmt(v, DIGITS) for v in q[f"values_{unit}"]],
                fmt(q.get("observed_order"), 3), fmt(q.get("expected_order")),
                "yes" if inside else "no",
                fmt(extra, DIGITS) if inside and extra is not None else NO_EXTRAPOLATION,
                fmt(q.get(f"gci_{unit}"), 3),
                fmt(None if gci_rel is None else 100 * gci_rel, 3)))
            verdict = "asymptotic" if inside else NO_EXTRAPOLATION
            why.append(f"<li>{html.escape(name)} {html.escape(c)}: {verdict} "
                       f"({html.escape(str(q.get('reason') or 'no reason recorded'))}; "
                       f"observed orders, coarse to fine: {html.escape(_orders(q))}"
                       f"; GCI safety factor {html.escape(fmt(q.get('safety_factor')))})</li>")
    headers = ["name", "component", *[f"{what} at h = {fmt(x, 3)} mm ({unit})" for x in h],
               "observed order", "expected order", "asymptotic", f"extrapolated ({unit})",
               f"GCI ({unit})", "GCI (%)"]
    return [table(headers, rows, caption=caption), Raw("<ul>" + "".join(why) + "</ul>")]


def _study(st: dict) -> list:
    p = st.get("pressure_degree")
    deg = f"P{st['degree']}" + (f"/P{p}" if p is not None else "")
    h = list(st["h_mm"])
    n = len(h)
    its = list(st.get("newton_iterations") or [None] * n)
    wall = list(st.get("wall_time_s") or [None] * n)
    parts = [Raw(f"<h2>Degree {st['degree']}: {html.escape(deg)} "
                 f"{html.escape(str(st.get('formulation') or ''))}</h2>"),
             table(["level", "h (mm)", "cells", "dofs", "Newton iterations", "wall time (s)"],
                   [(k, fmt(h[k], 4), st["n_cells"][k], st["n_dofs"][k], its[k], wall[k])
                    for k in range(n)], caption="the nested meshes, coarse to fine")]
    quantities = [q for g in ("probes", "reactions") for v in (st.get(g) or {}).values()
                  for _, q in _components(v)]
    inside = sum(1 for q in quantities if q.get("asymptotic"))
    if st.get("no_converged_value"):
        parts.append(Raw("<div class='warn'><b>No converged value is known at this load</b>: "
                         + "; ".join(html.escape(w) for w in st["no_converged_value"])
                         + ". The levels and their orders are data: nothing is extrapolated "
                           "or given a band.</div>"))
    elif quantities and not inside:
        parts.append(Raw("<div class='warn'>No quantity of this study is in the asymptotic "
                         "range: there is no extrapolated value. More levels (--levels) or a "
                         "finer start (--size) may reach it; the GCI is then a wider band "
                         "(safety factor 3).</div>"))
    else:
        parts.append(f"{inside} of {len(quantities)} quantities in the asymptotic range.")
    if st.get("probes"):
        parts += [Raw("<h3>Probe displacements</h3>"),
                  *_quantity_table(st["probes"], "mm", h, "u",
                                   "displacement u: each probe's dominant component first, then every component "
                                   "of at least 1 % of it")]
    if st.get("reactions"):
        parts += [Raw("<h3>Reactions</h3>"),
                  *_quantity_table(st["reactions"], "mN", h, "F",
                                   "reaction F: the force each Dirichlet region exerts on the body, the "
                                   "dominant component first")]
    return parts


def write_converge_report(d: dict, out_dir, *, plot: str | None = "convergence.png") -> Path:
    """Write ``out_dir``/report.html for the study ``d`` (the JSON of ``tissue converge``);
    ``plot``: the log-log picture already in ``out_dir`` (left out when it is not there).
    Returns the page's path."""
    out = Path(out_dir)
    pushes = d.get("pushes_mm") or {}
    setup = {k: d.get(k) for k in ("case", "source", "size_mm", "pushes_mm", "material",
                                   "formulation", "degrees", "levels", "refinement_ratio",
                                   "h_definition", "max_cells")}
    setup["pushes_mm"] = pushes or "none"
    parts = [Raw(f"<h1>Convergence study: {html.escape(str(d.get('case')))}</h1>"),
             f"{d.get('source')}; pushes (mm): "
             + (", ".join(f"{a} = {v:g}" for a, v in pushes.items()) or "none")
             + f". {d.get('levels')} nested meshes per degree, uniform refinement (h halved "
             "per level, boundary vertices on the true geometry, every level straight-sided). "
             "Units: mm, mN. The extrapolated (Richardson) value is given only where the "
             "observed orders show the asymptotic range; GCI: the grid convergence index of the "
             "finest level, a band around its value.",
             Raw("<h2>What was studied</h2>"), kv_table(setup)]
    if plot and (out / plot).is_file():
        parts.append(image(plot, "differences between successive levels against h",
                           "|q(h) - q(h/2)| against h (log-log) for each probe (mm) and "
                           "reaction (mN), with slopes 1 and 2", 900))
    for st in d.get("studies") or []:
        parts += _study(st)
    if d.get("solver_settings"):
        parts += [Raw("<h2>Solver settings</h2>"), kv_table(d["solver_settings"])]
    return write_page(out / REPORT, page(f"tissue converge: {d.get('case')}", parts))
