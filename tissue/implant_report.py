"""The HTML page of ``tissue implant --out DIR`` (``DIR/report.html``): the plan (input, implant
shape, volume, side, its dimensions and placement), the tissue mesh and its boundary points,
the Mass Tensor solve, the surface distances (the reference comparison, the Neo-Hookean one,
the post-operative skin after ICP) and the distance picture the command rendered.

The page reads the JSON of ``tissue implant --json``; it is written whole or not at all.
"""
from __future__ import annotations

import html
from pathlib import Path

from tissue_reference.meshes.html_page import Raw, fmt, image, kv_table, page, table, write_page

__all__ = ["distance_rows", "write_implant_report"]

NO_ICP = "not needed (same mesh)"
"""The ICP columns of a comparison on one mesh: its vertices correspond, no registration."""


def distance_rows(d: dict) -> list[tuple]:
    """The surface-distance comparisons of ``d``: (what, d_max mm, mean mm, ICP RMS mm, ICP
    iterations), those that were computed."""
    rows = []
    if d.get("d_max_mm") is not None:
        rows.append(("Mass Tensor vs the linear FEM reference", d["d_max_mm"],
                     d["mean_distance_mm"], NO_ICP, NO_ICP))
    nh = d.get("neo_hookean")
    if nh:
        rows.append(("Mass Tensor vs the Neo-Hookean FEM reference", nh["d_max_mm"],
                     nh["mean_distance_mm"], NO_ICP, NO_ICP))
    po = d.get("postop")
    if po:
        rows.append(("post-operative skin (after ICP) vs the prediction", po["d_max_mm"],
                     po["mean_distance_mm"], po["icp_rms_mm"], po["icp_iterations"]))
    return rows


def _plan(d: dict) -> Raw:
    imp, inp = d.get("implant") or {}, d.get("input") or {}
    w, h, p = (d.get("implant_dimensions_mm") or [None] * 3)[:3]
    return table(["plan", "value"], [
        ("input", "synthetic torso (known muscle)" if inp.get("synthetic") else
         f"skin {inp.get('skin')}"),
        ("thickness estimates (mm)", fmt(inp.get("thickness_mm")) or "the synthetic torso's"),
        ("implant shape", imp.get("shape")), ("side", imp.get("side")),
        ("volume (cm³)", imp.get("volume_cc")),
        ("base width (mm)", w), ("height (mm)", h), ("projection (mm)", p),
        ("placement centre (mm)", fmt(d.get("placement_centre_mm"))),
        ("centre asked, seen from the front (mm)", fmt(imp.get("at_mm")) or "under the breast"),
    ], row_headers=True)


def _mesh(d: dict) -> Raw:
    pts = d.get("points") or {}
    rows = [("tetrahedra (count)", d.get("n_cells")), ("vertices (count)", d.get("n_vertices"))]
    rows += [(f"{k.replace('_', ' ')} points (count)", v) for k, v in pts.items()]
    size = (d.get("solver_settings") or {}).get("tissue_size_mm")
    rows.append(("mesh size (mm)", "the planner's default" if size is None else size))
    return table(["mesh", "value"], rows, row_headers=True)


def _solve(d: dict) -> Raw:
    rows = [("solver", d.get("solver")), ("converged", d.get("converged")),
            ("Mass Tensor iterations (count)", d.get("iterations")),
            ("implant placement iterations (count)", d.get("implant_iterations")),
            ("Mass Tensor wall time (s)", d.get("wall_time_s"))]
    if d.get("reference_wall_time_s") is not None:
        rows.append(("reference wall time (s)", d["reference_wall_time_s"]))
    if d.get("max_vertex_difference_mm") is not None:
        rows.append(("largest vertex displacement difference to the reference (mm)",
                     d["max_vertex_difference_mm"]))
    if d.get("muscle_thickness_error_mm") is not None:
        rows.append(("muscle surface error under the implant (mm)",
                     d["muscle_thickness_error_mm"]))
    rows += [(f"time: {k} (s)", v) for k, v in (d.get("timings_s") or {}).items()]
    return table(["solve", "value"], rows, row_headers=True)


def write_implant_report(d: dict, out_dir, *, distance_png: str | None = None) -> Path:
    """Write ``out_dir``/report.html of the plan ``d`` (the JSON of ``tissue implant``);
    ``distance_png``: the distance picture already in ``out_dir``. Returns the page's path."""
    out = Path(out_dir)
    imp = d.get("implant") or {}
    title = (f"{fmt(imp.get('volume_cc'))} cm³ {imp.get('shape')} implant, "
             f"{imp.get('side')} side")
    parts = [Raw(f"<h1>Implant plan: {html.escape(title)}</h1>"),
             ("Seed 001's planning: the Mass Tensor Method moves the tissue onto the implant "
              "through boundary points; the prediction is compared with the FEM reference on "
              "the same mesh and boundary conditions. Units: mm, s, cm³ (= cc)."),
             Raw("<h2>Plan</h2>"), _plan(d), Raw("<h2>Mesh</h2>"), _mesh(d),
             Raw("<h2>Solve</h2>"), _solve(d), Raw("<h2>Surface distances</h2>")]
    rows = distance_rows(d)
    if rows:
        parts.append(table(["comparison", "d_max (mm)", "mean distance (mm)", "ICP RMS (mm)",
                            "ICP iterations (count)"], rows, caption=d.get("compared")))
    else:
        parts.append("No surface distances: the reference comparison was not run "
                     "(--no-reference) and no post-operative skin was given.")
    if distance_png and (out / distance_png).is_file():
        parts.append(image(distance_png, "distance on the predicted skin",
                           "distance of the predicted skin to the compared surface (mm) over the "
                           f"breast region (rendered with {d.get('render_backend')})", 640))
    parts += [Raw("<h2>Material and settings</h2>"),
              kv_table({"material": d.get("material"),
                        "solver settings": d.get("solver_settings")}),
              Raw("<p>Fields: <a href='tissue.vtu'>tissue.vtu</a> (displacements, point types), "
                  "<a href='implant.vtu'>implant.vtu</a>"
                  + (", <a href='skin_distance.vtu'>skin_distance.vtu</a>"
                     if (out / "skin_distance.vtu").is_file() else "") + "</p>")]
    return write_page(out / "report.html", page(f"tissue implant: {title}", parts))
