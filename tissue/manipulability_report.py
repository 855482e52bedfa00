"""The HTML page of ``tissue manipulability --out DIR`` (``DIR/report.html``): the maps the
command drew (``manipulability.png``), per case and task the median manipulability index over
the grid points where the task's goal is reachable, its largest value and where, the task that
is reachable nowhere said so, and the case and settings the maps were computed with.

The page reads the data of the ``manipulability_CASE.json`` files (one dict per case); every
file is written whole or not at all.
"""
from __future__ import annotations

import html
from pathlib import Path

import numpy as np

from tissue_reference.meshes.html_page import Raw, image, kv_table, page, table, write_page

__all__ = ["GOALS", "task_summary", "write_manipulability_report"]

GOALS = {1: "x -5, y free", 2: "y -5, x free", 3: "x +5, y +5"}
"""The seed's three tasks: the target's goal in the section's plane (mm)."""


def task_summary(d: dict, task: int) -> dict:
    """Of the map of ``task`` in ``d`` (the JSON of one case): grid points inside the body and
    where the goal is reachable, the median and largest index over those (None where reachable
    nowhere) and the grid point of the largest (x, y in mm)."""
    index = np.array([[np.nan if v is None else v for v in row]
                      for row in d[f"task{task}"]["index"]], float).reshape(len(d["y"]), -1)
    inside = int(np.count_nonzero(np.asarray(d["inside"], bool)))
    finite = np.isfinite(index)
    s = {"task": task, "goal": GOALS.get(task, ""), "inside": inside,
         "reachable": int(np.count_nonzero(finite)), "median": None, "max": None, "at": None}
    if finite.any():
        iy, ix = np.unravel_index(np.nanargmax(index), index.shape)
        s.update(median=float(np.median(index[finite])), max=float(index[iy, ix]),
                 at=[float(d["x"][ix]), float(d["y"][iy])])
    return s


def _case_part(d: dict) -> list:
    rows = [task_summary(d, t) for t in (1, 2, 3) if f"task{t}" in d]
    parts = [Raw(f"<h2>{html.escape(str(d['case']))}</h2>"), table(
        ["task", "goal (mm)", "grid points inside (count)", "reachable at (count)",
         "median index (mm/mm)", "largest index (mm/mm)", "largest at x, y (mm)"],
        [(s["task"], s["goal"], s["inside"], s["reachable"],
          "reachable nowhere" if s["median"] is None else s["median"],
          "" if s["max"] is None else s["max"],
          "" if s["at"] is None else f"{s['at'][0]:g}, {s['at'][1]:g}") for s in rows],
        caption=f"the index over the grid points where the task's goal is reachable "
                f"(actuators {', '.join(d.get('actuators', []))})")]
    nowhere = [s["task"] for s in rows if s["reachable"] == 0]
    if nowhere:
        parts.append(Raw("<div class='warn'>" + "; ".join(
            f"Task {t} ({html.escape(GOALS.get(t, ''))} mm) is reachable nowhere on this section: "
            "no combination of pushes moves the target that way" for t in nowhere) + "</div>"))
    parts.append(kv_table({"source": d.get("source"), "solver": d.get("solver"),
                           "material": d.get("material"),
                           "discretization": d.get("discretization")},
                          caption="the case and its discretization"))
    return parts


def write_manipulability_report(datas: list[dict], out_dir, *, maps_png: str | None,
                                settings: dict) -> Path:
    """Write ``out_dir``/report.html for the maps ``datas`` (the JSON of each case, in the
    order drawn); ``maps_png``: the picture of the maps already in ``out_dir``; ``settings``:
    what the command ran with. Returns the page's path."""
    out = Path(out_dir)
    names = ", ".join(str(d["case"]) for d in datas)
    parts = [Raw(f"<h1>Manipulability: {html.escape(names)}</h1>"),
             ("The manipulability index (seed 000 eq. 21) at a point of the section is the "
             "distance the target moves towards the task's goal per mm of total actuator travel "
             "(mm/mm), of the push-only least-travel solution at the rest state; empty where the "
             "point is outside the body or the goal is out of reach. Grid spacing "
             f"{settings.get('spacing_mm')} mm, section z = {settings.get('plane_z_mm')} mm.")]
    if maps_png and (out / maps_png).is_file():
        parts.append(image(maps_png, "manipulability maps of every case and task",
                           "the maps: one row per case, one column per task (common colour "
                           "scale)", 900))
    for d in datas:
        parts += _case_part(d)
    parts += [Raw("<h2>Settings</h2>"), kv_table(settings)]
    return write_page(out / "report.html", page(f"tissue manipulability: {names}", parts))
