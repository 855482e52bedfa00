"""Newton on the indenter phantom: the energy line search's and the load stepping's settings
(``NewtonSettings``), each solving the same case in one run, with the ratios against the first.

Settings (``--settings``, any of); all but the last three as they were before Newton's matrix
left the tips' curvature out far from the answer (``contact_curvature_below = inf``) and before
the tips' first load steps grew to 0.2 of their radius (``tip_step = 0.1``):
  halve4   4 halvings of a correction before it is taken regardless, exact tangent
  keep8    8 halvings, exact tangent
  halve8   8 halvings, the correction after a halved one without the tips' curvature
  interp   halve8 with each shorter step the minimizer of the energy's quadratic fit
  shift    halve8 with the Levenberg-Marquardt shift of a tangent that is indefinite or whose
           correction does not descend (the default before the next three)
  both     shift and interp
  far      shift, and Newton's matrix without the tips' curvature while the residual is above
           1e-4 of the load step's first (``contact_curvature_below``)
  step     shift with the tips' first load steps 0.2 of their radius (``tip_step``)
  default  far and step (the default)
  step04   the default with the tips' first load steps 0.4 of their radius
  step1    the default with the tips' first load steps a whole radius
  secant   the default with the secant predictor (linear extrapolation of the last two states)
  tight    the default with the load steps before the last converged to 1e-6 of their first
           residual instead of 1e-4 (``intermediate_rtol``; the default until a failed solve
           converged its last state as an answer)
  bent     the default with the line search's trials also bent along the tips
           (``follow_tips``: a node pressed into a tip keeps its linearized gap)

Models: ``--model half`` (meshes/cases/phantom-indenter-half.toml, forces doubled) or ``whole``
(phantom-indenter.toml); ``--load one`` pushes A1, ``four`` all four actuators; the mesh is the
phantom's own (or its half's) gmsh mesh, at ``--level 0`` size 6 mm with 3.2 mm sites (the whole
case's default before its symmetric mesh), every size / sqrt 2 per level; P2. ``--case NAME``
instead solves meshes/cases/NAME.toml as shipped (its own mesh, degree and contact rule; a tip
cut by a mirror plane has its force doubled), e.g. ``--case phantom-indenter --load one``: the
default solve of ``tissue solve meshes/cases/phantom-indenter.toml --push A1=5``.
Prints Newton iterations, tangent shifts, load steps, cut-backs, factorizations, wall time, the
A1 force and T1, and the ratios against the first setting.

    .venv/bin/python bench/bench_indenter_newton.py [--model half] [--load one] [--push 5 ...]
        [--level 0] [--settings shift default] [--case NAME] [--contact-quadrature nodal|2]
"""
from __future__ import annotations

import argparse
import itertools
import math
import time
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

BEFORE = {"contact_curvature_below": math.inf, "tip_step": 0.1}
SETTINGS = {
    "halve4": {**BEFORE, "line_search": 4, "contact_curvature_after_halving": "keep",
               "descent_shift": 0.0, "interpolate": False},
    "keep8": {**BEFORE, "contact_curvature_after_halving": "keep", "descent_shift": 0.0,
              "interpolate": False},
    "halve8": {**BEFORE, "descent_shift": 0.0, "interpolate": False},
    "interp": {**BEFORE, "descent_shift": 0.0, "interpolate": True},
    "shift": BEFORE,
    "both": {**BEFORE, "interpolate": True},
    "far": {"tip_step": 0.1},
    "step": {"contact_curvature_below": math.inf},
    "default": {},
    "step04": {"tip_step": 0.4},
    "step1": {"tip_step": 1.0},
    "secant": {"predictor": "secant"},
    "tight": {"intermediate_rtol": 1e-6},
    "bent": {"follow_tips": True},
}


def main():
    from tissue_reference.tissue.common import contact_rule

    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", choices=("half", "whole"), default="half")
    ap.add_argument("--load", choices=("one", "four"), default="one")
    ap.add_argument("--push", type=float, nargs="+", default=[5.0],
                    help="push of each pushed actuator (mm); several: one warm-started path")
    ap.add_argument("--contact-quadrature", type=contact_rule, default=None,
                    help="contact rule (default: the case's)")
    ap.add_argument("--level", type=int, default=0, help="0: 3.2 mm sites; 1: 2.26 mm")
    ap.add_argument("--settings", nargs="+", choices=list(SETTINGS), default=["shift", "default"])
    ap.add_argument("--case", help="solve meshes/cases/CASE.toml as shipped instead of --model")
    args = ap.parse_args()

    import tissue_reference.fem_reference as fr
    from tissue_reference.errors import ConvergenceError
    from tissue_reference.meshes.builders import build
    from tissue_reference.model.case import load_case

    if args.case:
        path = ROOT / "meshes" / "cases" / f"{args.case}.toml"
        case, degree = load_case(path), None
        cut = tomllib.loads(path.read_text())["mesh"]["builtin"] in ("phantom-half",
                                                                      "phantom-quarter")
        factor = 2.0 if cut else 1.0   # A1 is cut in half by the plane y = 0
    else:
        name = "phantom-indenter-half" if args.model == "half" else "phantom-indenter"
        r = 2.0 ** (-args.level / 2)
        builtin = "phantom-half" if args.model == "half" else "phantom"
        case = load_case(ROOT / "meshes" / "cases" / f"{name}.toml",
                         mesh=build(builtin, 6.0 * r, site_size=3.2 * r))
        degree = 2
        factor = 2.0 if args.model == "half" else 1.0  # the half carries half of A1's force
    pushed = ["A1"] if args.load == "one" else [a.name for a in case.actuators]
    rows = {}
    for key in args.settings:
        st = fr.NewtonSettings(**SETTINGS[key])
        s = fr.ReferenceSolver(case, degree=degree, settings=st,
                               contact_quadrature=args.contact_quadrature)
        rows[key], prev = [], None
        for push in args.push:   # one warm-started load path
            t0 = time.perf_counter()
            try:
                res, done = s.solve({a: push for a in pushed}, initial=prev), True
            except ConvergenceError as exc:
                res, done = exc.last_converged, False
            wall = time.perf_counter() - t0
            loads = res.history["iterate_load"]
            reached = float(res.indenters["A1"]["push"])
            rows[key].append({
                "push": push, "reached": reached, "done": done, "newton": res.iterations,
                "shifts": res.extra["tangent_shifts"], "steps": res.load_steps,
                "cutbacks": sum(1 for a, b in itertools.pairwise(loads) if b < a),
                "factor": s.timings.factorizations, "wall": wall,
                "force": factor * res.indenters["A1"]["force"], "T1": res.probes["T1"]})
            print(f"  [{key} at {push:g} mm: {'reached' if done else 'stopped at'} {reached:.2f} "
                  f"mm, {res.iterations} Newton iterations, {wall:.0f} s]", flush=True)
            if not done:
                break
            prev = res
    model = args.case or f"{args.model} phantom level {args.level}"
    rule = res.indenters["A1"]["quadrature"]
    print(f"indenter {model}, P{res.degree}, contact rule {rule}, {case.mesh.n_cells} cells, "
          f"{res.extra['n_dofs']} unknowns, {'+'.join(pushed)} pushed")
    print(f"{'settings':>8} {'push':>5} {'newton':>6} {'shifts':>6} {'steps':>5} {'cutbacks':>8} "
          f"{'factor':>6} {'wall_s':>7} {'A1 force_mN':>12}  T1 (mm)")
    for key, path in rows.items():
        for r in path:
            t1 = r["T1"]
            print(f"{key:>8} {r['push']:5g} {r['newton']:6d} {r['shifts']:6d} {r['steps']:5d} "
                  f"{r['cutbacks']:8d} {r['factor']:6d} {r['wall']:7.1f} {r['force']:12.6f}  "
                  f"[{t1[0]:.6f}, {t1[1]:.6f}, {t1[2]:.6f}]"
                  + ("" if r["done"] else f"  stopped at {r['reached']:.2f} mm"))
    base_key = args.settings[0]
    base = rows[base_key]
    for key, path in list(rows.items())[1:]:
        for a, b in zip(base, path):
            if not (a["done"] and b["done"]):
                continue
            dt1 = max(abs(x - y) for x, y in zip(a["T1"], b["T1"]))
            print(f"{a['push']:g} mm, {base_key} vs {key}: {a['newton'] / b['newton']:.2f}x Newton "
                  f"iterations, {a['wall'] / b['wall']:.2f}x wall time; force differs by "
                  f"{abs(b['force'] / a['force'] - 1):.1e}, T1 by {dt1:.1e} mm")
        total = [sum(r["wall"] for r in p if r["done"]) for p in (base, path)]
        if all(r["done"] for r in base + path) and len(base) == len(path) > 1:
            print(f"whole path, {base_key} vs {key}: {total[0] / total[1]:.2f}x wall time "
                  f"({total[0]:.0f} vs {total[1]:.0f} s)")

if __name__ == "__main__":
    main()
