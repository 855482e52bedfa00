"""Newton on the indenter phantom: the energy line search's settings (``NewtonSettings``), each
solving the same case in one run, with the ratios against the first.

Settings (``--settings``, any of):
  halve4   4 halvings of a correction before it is taken regardless, exact tangent
  keep8    8 halvings, exact tangent
  halve8   8 halvings, the correction after a halved one without the tips' curvature
  interp   halve8 with each shorter step the minimizer of the energy's quadratic fit
  shift    halve8 with the Levenberg-Marquardt shift of a tangent that is indefinite or whose
           correction does not descend (the default)
  both     shift and interp

Models: ``--model half`` (meshes/cases/phantom-indenter-half.toml, forces doubled) or ``whole``
(phantom-indenter.toml); ``--load one`` pushes A1, ``four`` all four actuators; the mesh is the
phantom's own (or its half's) gmsh mesh, at ``--level 0`` size 6 mm with 3.2 mm sites (the whole
case's default before its symmetric mesh), every size / sqrt 2 per level; P2.
Prints Newton iterations, tangent shifts, load steps, cut-backs, wall time, the A1 force and
T1, and the ratios against the first setting.

    .venv/bin/python bench/bench_indenter_newton.py [--model half] [--load one] [--push 5]
        [--level 0] [--settings halve8 shift]
"""
from __future__ import annotations

import argparse
import dataclasses
import itertools
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

SETTINGS = {
    "halve4": {"line_search": 4, "contact_curvature_after_halving": "keep",
               "descent_shift": 0.0, "interpolate": False},
    "keep8": {"contact_curvature_after_halving": "keep", "descent_shift": 0.0,
              "interpolate": False},
    "halve8": {"descent_shift": 0.0, "interpolate": False},
    "interp": {"descent_shift": 0.0, "interpolate": True},
    "shift": {},
    "both": {"interpolate": True},
}


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", choices=("half", "whole"), default="half")
    ap.add_argument("--load", choices=("one", "four"), default="one")
    ap.add_argument("--push", type=float, default=5.0, help="push of each pushed actuator (mm)")
    ap.add_argument("--level", type=int, default=0, help="0: 3.2 mm sites; 1: 2.26 mm")
    ap.add_argument("--settings", nargs="+", choices=list(SETTINGS), default=["halve8", "shift"])
    args = ap.parse_args()

    import tissue_reference.fem_reference as fr
    from tissue_reference.meshes.builders import build
    from tissue_reference.meshes.case import load_case

    name = "phantom-indenter-half" if args.model == "half" else "phantom-indenter"
    case = load_case(ROOT / "meshes" / "cases" / f"{name}.toml")
    r = 2.0 ** (-args.level / 2)
    builtin = "phantom-half" if args.model == "half" else "phantom"
    case = dataclasses.replace(case, mesh=build(builtin, 6.0 * r, site_size=3.2 * r))
    pushed = ["A1"] if args.load == "one" else [a.name for a in case.actuators]
    factor = 2.0 if args.model == "half" else 1.0  # the half model carries half of A1's force
    rows = []
    for key in args.settings:
        st = fr.NewtonSettings(**SETTINGS[key])
        s = fr.ReferenceSolver(case, degree=2, settings=st)
        t0 = time.perf_counter()
        res = s.solve({a: args.push for a in pushed})
        wall = time.perf_counter() - t0
        loads = res.history["iterate_load"]
        cutbacks = sum(1 for a, b in itertools.pairwise(loads) if b < a)
        rows.append((key, res.iterations, res.extra["tangent_shifts"], res.load_steps, cutbacks,
                     wall, factor * res.extra["indenters"]["A1"]["force"], res.probes["T1"]))
    print(f"indenter {args.model} phantom, P2, {case.mesh.n_cells} cells, "
          f"{res.extra['n_dofs']} unknowns, {'+'.join(pushed)} = {args.push:g} mm")
    print(f"{'settings':>8} {'newton':>6} {'shifts':>6} {'steps':>5} {'cutbacks':>8} "
          f"{'wall_s':>7} {'A1 force_mN':>12}  T1 (mm)")
    for key, its, shifts, steps, cut, wall, force, t1 in rows:
        print(f"{key:>8} {its:6d} {shifts:6d} {steps:5d} {cut:8d} {wall:7.1f} {force:12.6f}  "
              f"[{t1[0]:.6f}, {t1[1]:.6f}, {t1[2]:.6f}]")
    base = rows[0]
    for r in rows[1:]:
        dt1 = max(abs(a - b) for a, b in zip(r[7], base[7]))
        print(f"{base[0]} vs {r[0]}: {base[1] / r[1]:.2f}x Newton iterations, "
              f"{base[5] / r[5]:.2f}x wall time; force differs by {abs(r[6] / base[6] - 1):.1e}, "
              f"T1 by {dt1:.1e} mm")


if __name__ == "__main__":
    main()
