"""How far the shipped indenter phantom's default discretization is from the converged answer,
and what it costs, against the previous default, measured in one run.

The default is what ``tissue solve meshes/cases/phantom-indenter.toml --push ...`` solves: the
case's mesh (builder, size, site_size, path_size), the case's ``[reference] degree`` and contact
rule; ``--case wide``: the same for meshes/cases/phantom-indenter-wide.toml (8 mm tips), against
its own study (``four_wide_surface`` / ``one_wide_surface``, to 15 mm, its tips started on the
curved skin); ``--case control``:
phantom-indenter-control.toml (the 5 mm tips on a coarser body, the contact scenario's plant of
control loops); ``--case quarter``: phantom-indenter-quarter.toml (all four equal, on its own
mesh: the demo's reference). Earlier defaults (``--old p1``: P1 on 1.6 mm site cells; ``--old p2``: P2 on
the whole phantom's own gmsh mesh, 3.2 mm sites, 59k unknowns; ``--old paths``: the symmetric
mesh with 2.26 mm paths, 93k unknowns) are solved in the same run, for the ratios. The converged
answer is the finest level of a refinement study shipped in
tests/data/phantom_indenter_reference.json (P2 on the phantom's symmetric parts, cells divided by
sqrt 2 per level, from bench/bench_indenter_convergence.py): by default the study with the
Gauss contact rule and refined paths (``four_gauss`` / ``one_gauss``, to 12.5 mm; 15 mm has no
converged value) where it has the push, else the nodal one (``--study nodal``: the nodal one
only). A default whose tips start on the skin's curved facets (``--tip-start surface``, the
case's ``[reference] tip_start``, or its Gauss rule's own start) is compared with the studies
started there (``*_surface``).
The spread of its levels and, where assessed, its GCI band are printed with it, so the
comparison says how well the converged value itself is known.

All four pushed on ``phantom-indenter.toml`` (meshed as ``phantom-symmetric``: the quarter's mesh
and its mirror images) are solved on the quarter phantom at the same sizes: the same discrete
problem (tests/test_mirror.py) at a quarter of the unknowns.

Per load and push (the pushes one warm-started load path): the A1 force (mN) and the targets'
displacements (mm) of each discretization, the relative difference of each to the finest level
(targets: |u - u_ref| / |u_ref|), Newton iterations, wall time, and the ratios new / old.

    .venv/bin/python bench/bench_default_accuracy.py [--loads one four] [--pushes 5 10 12.5]
        [--contact-quadrature nodal|2] [--study gauss|nodal]
        [--old [p1|p2|paths|nodal|quarter|newton|iterative|kernels|stepping]]
        [--case indenter|wide|control|half|quarter] [--tip-start nodes|surface]
        [--mesh SIZE SITE PATH [--builder phantom-symmetric]] [--rows] [--answers FILE]

``--rows`` prints the default's rows for its case file's ``[[reference.measured]]``.
``--answers FILE`` keeps the default's answers (JSON): a later run with the same file, load and
pushes compares them again, with a study refined since, without solving them again. A default
that is itself a level of the study (the half case: level 0; the same unknowns, cells, rule and
tip start) is read from the study data instead of solved.
"""
from __future__ import annotations

import argparse
import json
import time
import tomllib
from functools import partial
from pathlib import Path

import numpy as np
from study_answers import CASES, LOADS, STUDIES, errors, finest, measured_row, study_level

ROOT = Path(__file__).resolve().parents[1]


OLD = {"p1": ("old P1", 1, "phantom", (6.0, 1.6, None)),
       "p2": ("old P2", None, "phantom", (6.0, 3.2, None)),
       "paths": ("old path", None, "phantom-symmetric",
                 (6.0 * 2 ** 0.5, 3.2 * 2 ** 0.5, 1.6 * 2 ** 0.5)),
       "nodal": ("nodal", None, None, None, "nodal"),
       "quarter": ("old quarter", None, "phantom-quarter", (6.0, 3.2, 1.6)),
       "newton": ("old Newton", None, None, None),
       "iterative": ("CG+GAMG", None, None, None),
       "kernels": ("O2 kernels", None, None, None),
       "stepping": ("old steps", None, None, None)}
"""The earlier defaults of the indenter phantom and an alternative (``--old``): label, degree
(None: the case's), builder and mesh (size, site_size, path_size; mm; None: the case's), and a
contact rule where it differs. p1: P1 on 1.6 mm sites; p2 (until the symmetric mesh): P2 on the
whole phantom's own gmsh mesh with 3.2 mm sites, 59k unknowns; paths (until the paths were
refined as the quarter study's level 0): the symmetric mesh with 2.26 mm paths, the quarter
study's level -1, 93k unknowns; nodal (until the 5 mm tip cases named the Gauss rule): the
case's mesh with the contact sampled at the skin's nodes, its tips started on them; quarter
(``--case quarter``, until its bulk was meshed as the whole case's): the quarter case on 6 mm
cells with 3.2 mm sites; newton: the case's own discretization solved by Newton as it was before
the tips' tangents were factorized at every iteration (``OLD_NEWTON``); iterative (the route an
iterative P2 solver would take): the case's own discretization with each tangent solved by CG
preconditioned by smoothed aggregation AMG with the rigid-body modes as near null space
(``linear_solver="iterative"``; MUMPS where CG does not converge); kernels: the case's own
discretization with its forms compiled as dolfinx compiles them by default (-O2, without the
reference's ``fem_reference.jit.JIT_PARAMS``); stepping: the case's own discretization with the
tips' load steps as they were before the steps before the last ended after their predictor
(``OLD_STEPPING``)."""


OLD_NEWTON = {"linear_solver": "lagged", "intermediate_rtol": 1e-6}
"""Newton before (``--old newton``): each factorization reused as the GMRES preconditioner of
later tangents, the load steps before the last converged to 1e-6 (the tips' steps otherwise as
``OLD_STEPPING``), and the residual lifted by
the Dirichlet values at every assembly, also where they agree with the unknown's. Its line search
tests a trial's energy before its residual, as Newton does now (that order changes no decision,
only the cost of a refused trial)."""


OLD_STEPPING = {"tip_step": 0.2, "contact_intermediate_rtol": 1e-4, "contact_grow": 1.5}
"""The tips' load stepping before (``--old stepping``): increments of 0.2 of a tip's radius,
growing by 1.5 after a step that converged within 5 Newton iterations, each step before the last
converged to 1e-4 of its first residual (``NewtonSettings``)."""


QUARTER = ROOT / "meshes" / "cases" / "phantom-indenter-quarter.toml"
"""The quarter of the 5 mm tip phantom, its mirror planes sliding: all four pushed equally on a
case meshed as ``phantom-symmetric`` (the quarter's mesh and its mirror images) are the same
discrete problem as this case on the same sizes (tests/test_mirror.py), at a quarter of the
unknowns."""


def solve(load: str, pushes, degree: int | None, rule, case_name: str = "indenter",
          mesh: tuple | None = None, builder: str = "phantom",
          start: str | None = None, old_newton: bool = False,
          linear_solver: str | None = None, jit_params: dict | None = None,
          settings: dict | None = None) -> list[dict]:
    """The case's default discretization (or ``degree``, or the case meshed by ``builder`` with
    ``mesh`` = (size, site_size, path_size) mm; tips started as ``start``, None: the case's)
    along one load path through ``pushes``: one row per push reached. All four pushed on the 5 mm
    tip case meshed as ``phantom-symmetric`` are solved on its quarter (``QUARTER``, same sizes,
    same answer); the row then gives the whole case's cells and unknowns and A1's whole force.
    ``old_newton``: solved by Newton as it was before (``OLD_NEWTON``); ``linear_solver``: the
    reference's linear solver (None: its default); ``jit_params``: the forms' JIT parameters
    while this runs (None: the reference's ``JIT_PARAMS``); ``settings``: NewtonSettings fields
    that differ from the defaults."""
    from tissue_reference.fem_reference import jit

    kept = jit.JIT_PARAMS
    jit.JIT_PARAMS = kept if jit_params is None else jit_params
    try:
        return _solve(load, pushes, degree, rule, case_name, mesh, builder, start, old_newton,
                      linear_solver, settings or {})
    finally:
        jit.JIT_PARAMS = kept


def _solve(load, pushes, degree, rule, case_name, mesh, builder, start, old_newton,
           linear_solver, settings) -> list[dict]:
    import tissue_reference.fem_reference as fr
    from tissue_reference.errors import ConvergenceError
    from tissue_reference.fem_reference.dof_counts import entity_counts, predicted_dofs
    from tissue_reference.meshes.builders import build
    from tissue_reference.model.case import load_case

    case = load_case(CASES[case_name])
    spec = tomllib.loads(CASES[case_name].read_text())["mesh"]
    if mesh is None:
        builder = spec.get("builtin")
        mesh = (spec.get("size"), spec.get("site_size"), spec.get("path_size"))
    else:
        size, site_size, path_size = mesh
        case = case.with_mesh(build(builder, size, site_size=site_size, path_size=path_size))
    # the half and quarter cases: A1 is cut in half by the mirror plane y = 0 (the rows give
    # the whole tip)
    whole = {"cells": case.mesh.n_cells, "counts": None,
             "cut": 2.0 if case_name in ("half", "quarter") else 1.0}
    if load == "four" and builder == "phantom-symmetric" and case_name == "indenter":
        quarter = load_case(QUARTER)
        assert {a.radius for a in quarter.actuators} == {a.radius for a in case.actuators}
        size, site_size, path_size = mesh
        whole["counts"] = entity_counts(case.mesh)   # the whole mesh's, for its unknowns
        whole["cut"] = 2.0                    # A1 is cut in half by the plane y = 0
        case = quarter.with_mesh(build("phantom-quarter", size, site_size=site_size,
                                       path_size=path_size))
        print(f"  [all four on the quarter of the symmetric mesh: {case.mesh.n_cells} of "
              f"{whole['cells']} cells]", flush=True)
    pushed = [a for a in LOADS[load] if a in {b.name for b in case.actuators}]
    options = {"settings": fr.NewtonSettings(**settings)} if settings else {}
    if old_newton:
        rtol = OLD_NEWTON["intermediate_rtol"]
        options = {"linear_solver": OLD_NEWTON["linear_solver"], "settings": fr.NewtonSettings(
            **{**OLD_STEPPING, "intermediate_rtol": rtol, "contact_intermediate_rtol": rtol})}
    if linear_solver is not None:
        options["linear_solver"] = linear_solver
    s = fr.ReferenceSolver(case, degree=degree, contact_quadrature=rule, tip_start=start,
                           **options)
    if old_newton:
        s.newton.lifting_needed = lambda: True
    rows, prev = [], None

    def dofs(d: dict) -> int:
        if whole["counts"] is None:
            return d["dofs"]
        return predicted_dofs(whole["counts"], case.mesh.gdim, d["degree"], d["formulation"])

    for push in pushes:
        t0 = time.perf_counter()
        try:
            res, converged = s.solve({a: push for a in pushed}, initial=prev), True
        except ConvergenceError as exc:
            res, converged = exc.last_converged, False
        ind = res.indenters["A1"]
        rows.append({"push": push, "reached": float(ind["push"]),
                     "degree": res.discretization["degree"],
                     "rule": ind.get("quadrature"), "start": ind.get("started_on"),
                     "cells": whole["cells"],
                     "dofs": dofs(res.discretization),
                     "converged": converged,
                     "valid": bool(res.valid is not False),
                     "why": res.invalid_reason, "min_J": res.extra.get("min_J"),
                     "force": whole["cut"] * float(ind["force"]),
                     "probes": {n: np.asarray(v) for n, v in res.probes.items()},
                     "newton": res.iterations, "wall_s": time.perf_counter() - t0})
        r = rows[-1]
        print(f"  [{load} at {push:g} mm: reached {r['reached']:.2f} mm, force {r['force']:.2f} "
              f"mN, {r['newton']} Newton, {r['wall_s']:.0f} s]", flush=True)
        if not converged:
            break
        prev = res
    return rows


def answers(path: Path | None, load: str, pushes, asked: dict, solve_them) -> list[dict]:
    """The default's rows of ``load`` along ``pushes``: read from ``path`` (JSON) when it holds
    that load path, else ``solve_them()`` and written there (whole or not at all). ``asked`` (the
    case, contact rule, tip start and mesh asked for) must be the file's: answers of another
    discretization are refused, not compared."""
    if path is None:
        return solve_them()
    from tissue_reference.model.results import write_json

    kept = json.loads(path.read_text()) if path.exists() else {"asked": asked}
    if kept.get("asked") != asked:
        raise SystemExit(f"{path}: holds the answers of {kept.get('asked')}, not of {asked}")
    entry = kept.get(load)
    if entry is not None and entry["pushes"] == list(pushes):
        print(f"  [{load}: the default's answers read from {path}]", flush=True)
        return [dict(r, probes={n: np.asarray(v) for n, v in r["probes"].items()})
                for r in entry["rows"]]
    rows = solve_them()
    kept[load] = {"pushes": list(pushes), "rows": rows}
    write_json(kept, path)
    return rows


def main():
    from tissue_reference.model.case import TIP_STARTS
    from tissue_reference.tissue.common import contact_rule

    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--loads", nargs="+", choices=sorted(LOADS), default=["one", "four"])
    ap.add_argument("--pushes", type=float, nargs="+", default=[5.0],
                    help="every pushed tip (mm), one load path")
    ap.add_argument("--contact-quadrature", type=contact_rule, default=None,
                    help="contact rule of the default (default: the case's)")
    ap.add_argument("--case", choices=sorted(CASES), default="indenter",
                    help="phantom-indenter.toml (5 mm tips), phantom-indenter-wide.toml (8 mm), "
                         "phantom-indenter-control.toml (5 mm tips, a coarser body) or "
                         "phantom-indenter-half.toml (its half, A1 alone) or "
                         "phantom-indenter-quarter.toml (its quarter, all four)")
    ap.add_argument("--study", choices=["gauss", "nodal"], default="gauss",
                    help="the refinement study whose finest level is the converged answer "
                         "(the wide case has a Gauss-rule study only)")
    ap.add_argument("--tip-start", choices=TIP_STARTS, default=None,
                    help="where the default's tips start (default: the solver's: the case's, "
                         "else its contact rule's); the converged answer is then a study whose "
                         "tips started there")
    ap.add_argument("--mesh", type=float, nargs=3, metavar=("SIZE", "SITE", "PATH"),
                    help="solve the case on this mesh instead of its own (size, site_size, "
                         "path_size in mm): what another default would give")
    ap.add_argument("--builder", choices=["phantom", "phantom-symmetric"], default="phantom",
                    help="the builder of --mesh: the whole phantom's own gmsh mesh, or the "
                         "quarter's mirrored (exactly symmetric)")
    ap.add_argument("--rows", action="store_true",
                    help="print the default's [[reference.measured]] rows for its case file")
    ap.add_argument("--answers", type=Path, metavar="FILE",
                    help="keep the default's answers in FILE (JSON) and, where it already "
                         "holds a load's path, compare those instead of solving again")
    ap.add_argument("--old", nargs="?", const="p1", choices=sorted(OLD),
                    help="also solve an earlier default for the ratios: p1 (the default "
                         "without a value: P1, 1.6 mm sites), p2 (P2, 3.2 mm sites, the "
                         "whole phantom's own mesh), paths (the symmetric mesh with 2.26 mm "
                         "paths), nodal (the case's mesh, the nodal contact rule), quarter "
                         "(--case quarter on 6 mm cells, 3.2 mm sites) or newton (the case's "
                         "discretization, Newton as before: lagged factorizations, load steps "
                         "converged to 1e-6) or iterative (the case's discretization, each "
                         "tangent solved by CG + smoothed-aggregation AMG) or kernels (the "
                         "case's discretization, its forms compiled with dolfinx's default "
                         "flags) or stepping (the case's discretization, the tips' load steps "
                         "as before: 0.2 of their radius, growing, each converged to 1e-4)")
    args = ap.parse_args()
    if (args.case, args.study) not in STUDIES:
        ap.error(f"the {args.case} case has no {args.study} study")
    if args.case == "half" and args.loads != ["one"]:
        ap.error("the half case carries A1 alone (--loads one): all four are the quarter's")
    if args.case == "quarter" and args.loads != ["four"]:
        ap.error("the quarter case carries all four equally (--loads four)")
    # the case's own contact rule and tip start, for --rows (read from the file: no mesh to build)
    spec = tomllib.loads(CASES[args.case].read_text())
    reference = spec.get("reference", {})
    case_rule, case_pin = reference.get("contact_quadrature"), reference.get("tip_start")
    actuators = [a["name"] for a in spec["actuator"]]
    for load in args.loads:
        what = "A1 alone" if load == "one" else "all four"
        label = "default" if args.mesh is None else "mesh"
        asked = {"case": args.case, "contact_quadrature": args.contact_quadrature,
                "tip_start": args.tip_start, "mesh": args.mesh, "builder": args.builder}
        rows = None if args.mesh is not None else study_level(
            load, args.pushes, args.study, args.case, args.contact_quadrature, args.tip_start)
        runs = [(label, rows or answers(args.answers, load, args.pushes, asked,
                                        partial(solve, load, args.pushes, None,
                                                args.contact_quadrature, args.case, args.mesh,
                                                args.builder, args.tip_start)))]
        if args.old:
            old, degree, builder, mesh, *rule = OLD[args.old]
            runs.append((old, solve(load, args.pushes, degree,
                                    rule[0] if rule else args.contact_quadrature, args.case,
                                    mesh, builder or "phantom", args.tip_start,
                                    old_newton=args.old == "newton",
                                    linear_solver="iterative" if args.old == "iterative"
                                    else None,
                                    jit_params={} if args.old == "kernels" else None,
                                    settings=OLD_STEPPING if args.old == "stepping" else None)))
        started = runs[0][1][0]["start"]    # where the solver started the tips, every push
        for push in args.pushes:
            ref = finest(load, push, args.study, args.case, started)
            print(f"\n{what} at {push:g} mm; ", end="")
            if ref is None:
                print("no study converges at this push (three assessed levels whose changes "
                      "shrink): no converged answer to compare with")
            else:
                band = ", ".join(f"{q} {100 * g:.1f} %" for q, g in ref["gci"].items()
                                 if g is not None)
                print(f"converged answer: level {ref['level']} of the study {ref['study']!r} "
                      f"(contact rule {ref['rule']}; {ref['dofs']} unknowns on the symmetric "
                      f"part), levels {ref['levels']} valid {ref['valid']}; spread of the "
                      f"levels: force {100 * ref['spread']['force']:.1f} %, targets "
                      + ", ".join(f"{n} {100 * ref['spread'][n]:.1f} %" for n in ref["probes"])
                      + (f"; GCI bands: {band}" if band else ""))
            names = list(ref["probes"]) if ref else []
            print(f"  {'what':>8} {'deg':>3} {'rule':>5} {'cells':>7} {'dofs':>7} {'valid':>5} "
                  f"{'min J':>6} {'force_mN':>9} {'force err':>9} "
                  + " ".join(f"{n + ' err':>8}" for n in names) + f" {'newton':>6} {'wall_s':>7}")
            errs, found = {}, {}
            for name, rows in runs:
                r = next((r for r in rows if r["push"] == push), None)
                if r is None or not r["converged"]:
                    last = rows[-1]
                    print(f"  {name:>8} stopped at {last['reached']:.2f} mm: "
                          f"{last['why'] or 'its load steps did not converge'}")
                    continue
                # each run against the study started where its tips start (the header's is
                # the default's)
                own = ref if r["start"] == started else finest(load, push, args.study,
                                                               args.case, r["start"])
                if own is not ref and own is not None:
                    print(f"  {name:>8} against level {own['level']} of {own['study']!r} "
                          f"(its tips started on the {r['start']})")
                e = errors(r, own) if own else {}
                errs[name], found[name] = e, r
                print(f"  {name:>8} {r['degree']:>3} {r['rule']!s:>5} {r['cells']:>7} "
                      f"{r['dofs']:>7} {r['valid']!s:>5} {r['min_J'] or float('nan'):6.3f} "
                      f"{r['force']:9.2f} "
                      + (f"{100 * e['force']:8.2f}% " if e else f"{'-':>9} ")
                      + " ".join(f"{100 * e[n]:7.2f}%" for n in names)
                      + f" {r['newton']:>6} {r['wall_s']:7.1f}")
                if not r["valid"]:
                    print(f"           not valid: {r['why']}")
                print("           targets (mm): " + ", ".join(
                    f"{n} {np.round(v, 4).tolist()}" for n, v in r["probes"].items()))
            if args.rows and args.mesh is None and label in found:
                print(measured_row(load, push, found[label], errs[label], ref, case_rule,
                                   case_pin, actuators))
            if ref and len(errs) == 2:
                old = runs[1][0]
                worst = (max(errs[label].values()), max(errs[old].values()))
                print(f"  ratios {label} / {old}: worst error {worst[0] / worst[1]:.3f} "
                      f"({100 * worst[0]:.2f} % vs {100 * worst[1]:.2f} %), wall time "
                      f"{found[label]['wall_s'] / found[old]['wall_s']:.3f}")


if __name__ == "__main__":
    main()
