"""The demo (``tissue demo --out out``), the main job. The seed-000 phantom pressed by its four push-only
actuators as rigid spherical tips (frictionless contact, the model with mesh-converged answers):
the reference solves all four tips pushed 5, 10 and 12.5 mm on the phantom's quarter (the whole
phantom's answer under that symmetric load), each answer with its measured distance from the
converged answers; the fast solvers are verified against the reference on the tip phantom meshed
for control; everything is written, with an index page, under ``out/``."""
from __future__ import annotations

import html
import sys
import time
from functools import partial
from pathlib import Path

import numpy as np

from tissue_reference.meshes.builders import MAX_CELLS
from tissue_reference.meshes.html_page import Raw, image, page, table, write_page
from tissue_reference.meshes.io import save_figure
from tissue_reference.meshes.mesh import quality
from tissue_reference.model.case import load_case
from tissue_reference.model.results import write_json
from tissue_reference.verification.verify import verify

from .common import check_pushes
from .solve_outputs import solver_settings, write_outputs
from .verify_report import write_report
from .views import render

CASE = "phantom-indenter-quarter"
"""The reference's case: the tip phantom cut by its two mirror planes (both sliding)."""
VERIFY_CASE = "phantom-indenter-control"
"""The fast solvers' case: the whole tip phantom, its body coarser, its tip sites as fine."""
PUSHES_MM = (5.0, 10.0, 12.5)
"""The tips' pushes. The 5 mm tips have converged answers up to 12.5 mm (docs/verification.md);
the seed's 15 mm needs the 8 mm tips of meshes/cases/phantom-indenter-wide.toml."""
MIRRORED = 2.0
"""The quarter's tips A1 and A2 are halves of the whole phantom's (its mirror planes cut them):
a whole tip's force is this times the quarter's."""


def _say(msg):
    print(f"tissue demo: {msg}", file=sys.stderr, flush=True)


def _accuracy(res) -> tuple[dict | None, str]:
    """The measured accuracy of a reference answer (its case's ``[reference.measured]`` row,
    ``fem_reference.measured``) and one line saying what it is, or why there is none."""
    # lazy: fem_reference loads dolfinx and PETSc (0.7 s of start-up)
    from tissue_reference.fem_reference.measured import accuracy_line, error_bar

    row = res.extra.get("measured_accuracy")
    line = accuracy_line(res.entries()) or "none: this discretization was not measured"
    if row and row.get("converged", True):
        bar = error_bar(row)
        return {"force": row.get("force"), "probes": row["probes"], "against": row["against"],
                **({"band": row["band"], "error_bar": bar} if bar else {})}, line
    return None, line


def reference_series(case, out: Path, pushes_mm=PUSHES_MM, *, degree=None,
                     progress=True) -> dict:
    """All tips pushed each of ``pushes_mm`` in turn (each solve warm-started from the last):
    fields, solve outputs, the measured accuracy of each answer, a plot and a 3D view."""
    # lazy: fem_reference loads dolfinx and PETSc (0.7 s of start-up)
    import tissue_reference.fem_reference as fr

    tips = [a.name for a in case.actuators]
    rows, prev, views = [], None, []
    for push in pushes_mm:
        load = {name: push for name in tips}
        _say(f"reference: all tips {push:g} mm in")
        res = fr.solve(case, pushes=load, initial=prev, degree=degree, progress=progress)
        prev = res
        accuracy, line = _accuracy(res)
        forces = {name: MIRRORED * res.indenters[name]["force"] for name in tips
                  if name in res.indenters}
        stem = f"tips_{push:g}mm"
        # the fields and the JSON as `tissue solve` writes them (solve.schema.json)
        write_outputs(case.with_pushes(load), res, out / "fem", out / "fem" / f"{stem}.json",
                      stem=stem, settings=solver_settings("fem", estimate=False))
        if push == pushes_mm[0]:
            views = _views(case, res, out / "fem", push)
        rows.append({"push_mm": push, "converged": res.converged,
                     "newton_iterations": res.iterations, "load_steps": res.load_steps,
                     "wall_time_s": res.wall_time_s,
                     "probes_mm": {k: np.asarray(v).tolist() for k, v in res.probes.items()},
                     "tip_forces_mN": forces, "strain_energy_uJ": res.strain_energy,
                     "accuracy": accuracy, "accuracy_line": line,
                     "warnings": list(res.warnings)})
        t1 = float(np.linalg.norm(res.probes["T1"]))
        within = (accuracy.get("error_bar") or accuracy) if accuracy else None
        what = "the distance to the refinement study's finest level plus that level's band" \
            if accuracy and "error_bar" in accuracy else "the distance to the study's value"
        bar = (f" (force within {within['force']:.2%}, targets within {within['probes']:.2%} "
               f"of the converged answers: {what}, measured)" if accuracy
               else f" (no error bar: {line})")
        _say(f"reference, all tips {push:g} mm: {res.iterations} Newton iterations, "
             f"{res.wall_time_s:.1f} s, tip force {forces.get(tips[0], float('nan')):.1f} mN, "
             f"|u(T1)| = {t1:.3f} mm{bar}")
        for w in rows[-1]["warnings"]:
            _say(f"warning: {w}")
    _plot_series(rows, tips[0], out / "fem" / "tips_vs_push.png")
    disc = (prev.discretization or {}) if prev is not None else {}
    return {"case": case.name, "n_vertices": case.mesh.n_vertices, "n_cells": case.mesh.n_cells,
            "degree": prev.degree if prev is not None else degree, "dofs": disc.get("dofs"),
            "series": rows, "views": views}


def _views(case, res, folder: Path, push: float) -> list:
    """A 3D picture of the deformed quarter coloured by the displacement magnitude (mm)."""
    folder.mkdir(parents=True, exist_ok=True)
    pics = [render(case.mesh, res.u, np.linalg.norm(res.u, axis=1),
                   folder / f"view_tips_{push:g}mm.png", label="displacement (mm)",
                   title=f"Reference P{res.degree}, all tips {push:g} mm in (the quarter): "
                         f"displacement magnitude (mm)")]
    for p in pics:
        if p["method"] != "pyvista":
            _say(f"3D view drawn with matplotlib ({p.get('why') or 'pyvista unavailable'})")
    return pics


def _plot_series(rows, tip, path):
    """Targets' displacement and the tip's force against the push, with the measured error bars
    (none drawn for an answer that has none)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(10, 4))
    pushes = [r["push_mm"] for r in rows]
    for name in rows[0]["probes_mm"]:
        mag = [float(np.linalg.norm(r["probes_mm"][name])) for r in rows]
        err = [m * r["accuracy"]["probes"] if r["accuracy"] else 0.0 for m, r in zip(mag, rows)]
        ax[0].errorbar([0.0] + pushes, [0.0] + mag, yerr=[0.0] + err, fmt="o-", capsize=3,
                       label=name)
    ax[0].set_xlabel("push of every tip (mm)")
    ax[0].set_ylabel("target displacement |u| (mm)")
    ax[0].set_title("Targets under the four tips (reference)")
    ax[0].legend()
    ax[0].grid(alpha=0.3)
    force = [r["tip_forces_mN"].get(tip, np.nan) for r in rows]
    ferr = [f * r["accuracy"]["force"] if r["accuracy"] and r["accuracy"].get("force") else 0.0
            for f, r in zip(force, rows)]
    ax[1].errorbar([0.0] + pushes, [0.0] + force, yerr=[0.0] + ferr, fmt="s-k", capsize=3)
    ax[1].set_xlabel("push of every tip (mm)")
    ax[1].set_ylabel(f"force on tip {tip} (mN)")
    ax[1].set_title(f"Force-displacement of tip {tip}")
    ax[1].grid(alpha=0.3)
    fig.text(0.5, 0.005, "error bars: the measured distance from the converged answers "
             "(none where an answer was not measured)", ha="center", fontsize=8)
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    save_figure(fig, path)


def _reference_parts(ref: dict) -> list:
    """The reference's part of the page: what was solved, a row per push with its measured error
    bars, the plot and the 3D view."""
    def bar(r, key):
        a = r["accuracy"]
        return f"{a[key]:.2%}" if a and a.get(key) is not None else "none"

    tip = next(iter(ref["series"][0]["tip_forces_mN"]), "A1")
    rows = [(r["push_mm"], r["newton_iterations"], r["load_steps"], r["wall_time_s"],
             r["tip_forces_mN"].get(tip), bar(r, "force"),
             float(np.linalg.norm(r["probes_mm"]["T1"])), bar(r, "probes"))
            for r in ref["series"]]
    against = sorted({r["accuracy"]["against"] for r in ref["series"] if r["accuracy"]})
    notes = [f"{r['push_mm']:g} mm: no error bar: {r['accuracy_line']}"
             for r in ref["series"] if not r["accuracy"]]
    warnings = [f"{r['push_mm']:g} mm: {w}" for r in ref["series"] for w in r["warnings"]]
    return [
        Raw("<h2>Reference (FEniCSx, Neo-Hookean, frictionless rigid tips)</h2>"),
        ("Four rigid spherical tips (radius 5 mm) push the skin at the seed's actuator sites. The "
        "reference solves the quarter cut by the phantom's two mirror planes, which under all "
        "four pushed equally is the whole phantom's answer (the forces are a whole tip's): "
        f"P{ref['degree']}, {ref['dofs']} unknowns, {ref['n_cells']} cells."),
        table(["push (mm)", "Newton its", "load steps", "time (s)", f"{tip} force (mN)",
               "force within", "|u(T1)| (mm)", "targets within"], rows),
        ("Error bars: the largest measured distance from the converged answers, against "
         + "; ".join(against)) if against else None,
        *[Raw(f"<p class='warn'>{html.escape(n)}</p>") for n in notes + warnings],
        Raw("<p>Fields (ParaView): <code>fem/tips_*mm.xdmf</code>, <code>.vtu</code></p>"),
        image("fem/tips_vs_push.png", "targets and tip force against the push", width=800),
        *[image(f"fem/{Path(v['path']).name}", Path(v["path"]).stem,
                f"{Path(v['path']).stem} ({v['method']})", width=640) for v in ref["views"]],
    ]


def _verify_parts(v: dict, case_name: str) -> list:
    """The verification's part of the page: a row per fast solver, and those not scored."""
    rows = [(n, d["max_vertex_error_mm"], d["rms_vertex_error_mm"], d["iterations"],
             d["wall_time_s"], d["speedup_vs_reference"]) for n, d in v["solvers"].items()]
    skipped = [f"not scored: {why}" for why in (v.get("skipped") or {}).values()]
    return [Raw(f"<h2>Fast solvers against the reference ({html.escape(case_name)}, P1)</h2>"),
            table(["solver", "max vertex error (mm)", "RMS (mm)", "iterations", "time (s)",
                   "speed-up"], rows),
            *skipped,
            Raw("<p><a href='verify/report.html'>full verification report</a></p>")]


def run_demo(out: Path, *, pushes_mm=PUSHES_MM, size=None, degree=None, verify_size=None,
             verify_push: float = 5.0, max_cells=None, skip_verify: bool = False,
             progress: bool = True) -> dict:
    """The demo, written under ``out``: the reference series of the tip phantom's quarter
    (``reference_series``), the fast solvers verified against the P1 reference on the tip
    phantom meshed for control (``verification.verify``, all tips ``verify_push`` mm), summary.json
    and report.html. Returns the summary. Bad input (a push no tip can take, a mesh above
    ``max_cells``) raises CaseError before any solve."""
    limit = max_cells if max_cells is not None else MAX_CELLS
    out = Path(out)
    t0 = time.perf_counter()
    case = load_case(CASE, size=size, max_cells=limit)
    vcase = None
    if not skip_verify:
        vcase = load_case(VERIFY_CASE, size=verify_size, max_cells=limit)
        check_pushes(vcase, {a.name: verify_push for a in vcase.actuators}, "--verify-push")
    for push in pushes_mm:
        check_pushes(case, {a.name: push for a in case.actuators}, "--pushes")
    out.mkdir(parents=True, exist_ok=True)
    q = quality(case.mesh)
    summary = {"mesh": {"case": case.name, "size_mm": size,
                        "n_vertices": q.n_vertices, "n_cells": q.n_cells,
                        "min_scaled_jacobian": q.min_scaled_jacobian,
                        "min_dihedral_deg": q.min_dihedral_deg}}
    summary["reference"] = reference_series(case, out, tuple(pushes_mm), degree=degree,
                                            progress=progress)
    if vcase is not None:
        solvers = ("admm", "admm-plain", "admm-anderson", "mass-tensor")
        pushes = {a.name: verify_push for a in vcase.actuators}
        _say(f"verification: {', '.join(solvers)} against the P1 reference on {vcase.name}, "
             f"all tips {verify_push:g} mm")
        summary["verify"] = verify(vcase, pushes, solvers=solvers,
                                   report=partial(write_report, out / "verify"),
                                   json_file=out / "verify" / "verify.json")
    summary["wall_time_s"] = time.perf_counter() - t0
    write_json(summary, out / "summary.json")
    parts = [Raw("<h1>Soft-tissue reference toolkit: demo</h1>"),
             Raw(f"<p>Seed 000's breast phantom pressed by four rigid tips "
                 f"(<code>meshes/cases/{CASE}.toml</code>), total "
                 f"{summary['wall_time_s']:.1f} s. Mesh: {q.n_vertices} vertices, "
                 f"{q.n_cells} tetrahedra, worst scaled Jacobian {q.min_scaled_jacobian:.3f}, "
                 f"smallest dihedral angle {q.min_dihedral_deg:.1f} deg.</p>"),
             *_reference_parts(summary["reference"])]
    if "verify" in summary:
        parts += _verify_parts(summary["verify"], vcase.name)
    parts.append(Raw("<p>Machine-readable: <a href='summary.json'>summary.json</a></p>"))
    write_page(out / "report.html", page("tissue demo", parts))
    _say(f"done in {summary['wall_time_s']:.1f} s: open {out / 'report.html'}")
    return summary
