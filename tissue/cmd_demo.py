"""``tissue demo --out out``: the main job. Builds the seed-000 phantom, solves the reference with
actuator A1 pushed 5, 10 and 15 mm, verifies the fast solvers against it, and writes everything,
with an index page, under ``out/``."""
from __future__ import annotations

import html
import importlib.util
import sys
import time
from pathlib import Path

import numpy as np

from tissue_reference.meshes.errors import CaseError, ConvergenceError
from tissue_reference.meshes.io import atomic_path, save_figure
from tissue_reference.meshes.mesh import quality
from tissue_reference.meshes.results import write_json

from .cmd_solve import solver_settings, write_outputs
from .common import add_max_cells, announce_build, check_outputs, check_pushes, real

ROOT = Path(__file__).resolve().parents[1]
CASE = ROOT / "meshes" / "cases" / "phantom.toml"


def _say(msg):
    print(f"tissue demo: {msg}", file=sys.stderr, flush=True)


def reference_series(case, out: Path, pushes_mm=(5.0, 10.0, 15.0)) -> dict:
    """A1 pushed 5, 10, 15 mm (each warm-started from the previous): fields + summary + plot."""
    import dataclasses

    import tissue_reference.fem_reference as fr
    from tissue_reference.fem_reference.estimate import error_estimate

    solver = fr.ReferenceSolver(case, degree=1)
    rows, prev, views = [], None, []
    for push in pushes_mm:
        res = solver.solve({"A1": push}, initial=prev, progress=False)
        prev = res.u
        err_field = None
        try:  # the P1 answer's discretization error, by one P2 solve on the same mesh
            est = error_estimate(case, res, pushes={"A1": push})
            res = dataclasses.replace(res, extra={**res.extra, **est.extras()})
            err_field = np.linalg.norm(np.asarray(est.enriched.u) - res.u, axis=1)
        except ConvergenceError as exc:
            _say(f"reference A1={push:g} mm: no error estimate (the P2 solve failed: {exc})")
        if push == 5.0:   # the glued patches' answers converge up to about their radius
            views = _views(case, res, err_field, out / "fem", push)
        stem = f"A1_{push:g}mm"
        # the fields and the JSON as `tissue solve` writes them (solve.schema.json)
        write_outputs(case.with_pushes({"A1": push}), res, out / "fem",
                      out / "fem" / f"{stem}.json", stem=stem,
                      settings=solver_settings("fem", estimate=True))
        rows.append({"push_mm": push, "converged": res.converged, "newton_iterations": res.iterations,
                     "load_steps": res.load_steps, "wall_time_s": res.wall_time_s,
                     "probes_mm": {k: np.asarray(v).tolist() for k, v in res.probes.items()},
                     "reaction_A1_mN": np.asarray(res.reactions["act_px"]).tolist(),
                     "strain_energy_uJ": res.strain_energy,
                     "probe_error_estimates_mm": res.extra.get("probe_error_estimates")})
        est = (res.extra.get("probe_error_estimates") or {}).get("T1")
        if est is None:
            bar = ""
        elif res.extra.get("no_converged_value"):
            bar = (f" (P2 differs by {est:.3f} mm; no error bar: past one patch radius a glued "
                   f"patch has no mesh-converged answer)")
        else:
            bar = f" +- {est:.3f} mm (estimated discretization error of this P1 answer)"
        _say(f"reference A1={push:g} mm: {res.iterations} Newton iterations, "
             f"{res.wall_time_s:.2f} s, T1 u_x = {res.probes['T1'][0]:+.3f} mm{bar}")
    _plot_series(rows, out / "fem" / "probes_vs_push.png")
    return {"case": case.name, "n_vertices": case.mesh.n_vertices, "n_cells": case.mesh.n_cells,
            "series": rows, "views": views}


def _views(case, res, err_field, folder: Path, push: float) -> list:
    """3D pictures of the deformed phantom: coloured by the displacement magnitude, and by the
    estimated discretization error (|u_P2 - u_P1| at the vertices, mm) where there is one."""
    from .views import render

    folder.mkdir(parents=True, exist_ok=True)
    pics = [render(case.mesh, res.u, np.linalg.norm(res.u, axis=1),
                   folder / f"view_A1_{push:g}mm.png", label="displacement (mm)",
                   title=f"Reference P1, A1 pushed {push:g} mm: displacement magnitude (mm)")]
    if err_field is not None:
        bar = not res.extra.get("no_converged_value")   # past it the difference bounds nothing
        pics.append(render(case.mesh, res.u, err_field, folder / f"error_A1_{push:g}mm.png",
                           label="estimated error (mm)" if bar else "|u_P2 - u_P1| (mm)",
                           title=(f"Where the P1 answer is wrong: |u_P2 - u_P1| (mm), A1 = "
                                  f"{push:g} mm" if bar else
                                  f"|u_P2 - u_P1| (mm), A1 = {push:g} mm: no error bar (no "
                                  f"mesh-converged answer past one patch radius)")))
    for p in pics:
        if p["method"] != "pyvista":
            _say(f"3D view drawn with matplotlib ({p.get('why') or 'pyvista unavailable'})")
    return pics


def _plot_series(rows, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(10, 4))
    pushes = [0.0] + [r["push_mm"] for r in rows]
    for name in rows[0]["probes_mm"]:
        ux = [0.0] + [r["probes_mm"][name][0] for r in rows]
        ax[0].plot(pushes, ux, "o-", label=name)
    ax[0].set_xlabel("A1 push (mm)")
    ax[0].set_ylabel("target u_x (mm)")
    ax[0].set_title("Targets follow actuator A1 (reference, P1)")
    ax[0].legend()
    ax[0].grid(alpha=0.3)
    ax[1].plot(pushes, [0.0] + [-r["reaction_A1_mN"][0] for r in rows], "s-k")
    ax[1].set_xlabel("A1 push (mm)")
    ax[1].set_ylabel("actuator force along push (mN)")
    ax[1].set_title("Force-displacement of actuator A1")
    ax[1].grid(alpha=0.3)
    fig.tight_layout()
    save_figure(fig, path)


def _have(module):
    return importlib.util.find_spec(module) is not None


def run(args) -> int:
    from tissue_reference.meshes.builders import MAX_CELLS, check_cell_budget, phantom
    from tissue_reference.meshes.case import load_case

    check_outputs(args, dirs=("out",))
    limit = args.max_cells if args.max_cells is not None else MAX_CELLS
    for opt, size in (("--size", args.size), ("--verify-size", args.verify_size)):
        try:
            check_cell_budget("phantom", size, limit)
        except CaseError as exc:
            raise CaseError(f"{opt} {size:g}: {exc}") from None
    for size in (args.size, args.verify_size):
        announce_build("demo", "phantom", size, limit)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    sections = []
    _say(f"building the phantom (size {args.size} mm) with gmsh")
    mesh = phantom(args.size, out=out / "phantom.msh")
    q = quality(mesh)
    case = load_case(CASE, mesh=mesh)
    sections.append(("Phantom mesh", (f"{q.n_vertices} vertices, {q.n_cells} tetrahedra, worst "
                                      f"scaled Jacobian {q.min_scaled_jacobian:.3f}, smallest "
                                      f"dihedral angle {q.min_dihedral_deg:.1f} deg: "
                                      f"<a href='phantom.msh'>phantom.msh</a>")))
    summary = {"mesh": {"size_mm": args.size, "n_vertices": q.n_vertices, "n_cells": q.n_cells,
                        "min_scaled_jacobian": q.min_scaled_jacobian,
                        "min_dihedral_deg": q.min_dihedral_deg}}
    _say("reference solves: A1 pushed 5, 10, 15 mm")
    summary["reference"] = reference_series(case, out)
    rows = "".join(
        f"<tr><td>{r['push_mm']:g}</td><td>{r['newton_iterations']}</td><td>{r['load_steps']}</td>"
        f"<td>{r['wall_time_s']:.2f}</td><td>{r['probes_mm']['T1'][0]:+.3f}</td>"
        f"<td>{-r['reaction_A1_mN'][0]:.1f}</td></tr>" for r in summary["reference"]["series"])
    sections.append(("Reference (FEniCSx, Neo-Hookean, P1)",
                     "<table border=1 cellpadding=4><tr><th>A1 push (mm)</th><th>Newton its</th>"
                     "<th>load steps</th><th>time (s)</th><th>T1 u_x (mm)</th><th>A1 force (mN)</th>"
                     f"</tr>{rows}</table><p>Fields (ParaView): <code>fem/A1_*mm.xdmf</code>, "
                     "<code>.vtu</code></p><img src='fem/probes_vs_push.png' width=800>"
                     + "".join(f"<figure><img src='fem/{Path(v['path']).name}' width=640>"
                               f"<figcaption>{html.escape(Path(v['path']).stem)} "
                               f"({v['method']})</figcaption></figure>"
                               for v in summary["reference"].get("views", []))))
    if not args.skip_verify and _have("tissue_reference.tissue.verify"):
        from tissue_reference.tissue.verify import verify

        candidates = (("admm", "tissue_reference.solvers.admm"),
                      ("admm-plain", "tissue_reference.solvers.admm"),
                      ("mass-tensor", "tissue_reference.solvers.mass_tensor"))
        solvers = tuple(s for s, m in candidates if _have(m))
        pushes = {"A1": args.verify_push, "A2": args.verify_push, "A3": args.verify_push,
                  "A4": args.verify_push}
        _say(f"verification: {', '.join(solvers)} against the reference, all actuators "
             f"{args.verify_push:g} mm (mesh size {args.verify_size} mm)")
        vcase = load_case(CASE, size=args.verify_size, max_cells=limit)
        check_pushes(vcase, pushes, "--verify-push")
        v = verify(vcase, pushes, solvers=solvers, out_dir=out / "verify",
                   json_file=out / "verify" / "verify.json")
        summary["verify"] = v
        vrows = "".join(
            f"<tr><td>{html.escape(n)}</td><td>{d['max_vertex_error_mm']:.4f}</td>"
            f"<td>{d['rms_vertex_error_mm']:.4f}</td><td>{d['iterations']}</td>"
            f"<td>{d['wall_time_s']:.3f}</td><td>{d['speedup_vs_reference']:.1f}</td></tr>"
            for n, d in v["solvers"].items())
        sections.append(("Fast solvers against the reference",
                         ("<table border=1 cellpadding=4><tr><th>solver</th><th>max vertex "
                          "error (mm)</th><th>RMS (mm)</th><th>iterations</th><th>time (s)</th>"
                          f"<th>speed-up</th></tr>{vrows}</table>"
                          "<p><a href='verify/report.html'>full verification report</a></p>")))
    summary["wall_time_s"] = time.perf_counter() - t0
    write_json(summary, out / "summary.json")
    body = "".join(f"<h2>{html.escape(t)}</h2>{b}" for t, b in sections)
    page = (f"<!doctype html><html><head><meta charset='utf-8'><title>tissue demo</title></head>"
            f"<body><h1>Soft-tissue reference toolkit: demo</h1><p>Case: seed 000 breast phantom "
            f"(<code>meshes/cases/phantom.toml</code>), total {summary['wall_time_s']:.1f} s.</p>"
            f"{body}<p>Machine-readable: <a href='summary.json'>summary.json</a></p></body></html>")
    with atomic_path(out / "report.html") as tmp:
        tmp.write_text(page)
    _say(f"done in {summary['wall_time_s']:.1f} s: open {out / 'report.html'}")
    return 0


def add_parser(sub):
    p = sub.add_parser("demo", help="build the phantom, solve, verify, write a report")
    p.add_argument("--out", default="out", help="folder for the report and every output")
    p.add_argument("--size", type=real("positive", "mm"), default=6.0,
                   help="phantom mesh size for the reference (mm)")
    p.add_argument("--verify-size", type=real("positive", "mm"), default=10.0,
                   help="mesh size of the verification run (mm; 10 ~ the seed's 1.7k tets)")
    p.add_argument("--verify-push", type=real("finite", "mm"), default=15.0,
                   help="push of all four actuators (mm)")
    add_max_cells(p, what="phantom mesh")
    p.add_argument("--skip-verify", action="store_true",
                   help="leave out the verification of the fast solvers")
    p.set_defaults(func=run)
