"""Newton on the indenter phantom: how many halvings of a correction the energy line search may
try before it takes the correction regardless (``NewtonSettings.line_search``), and whether the
correction after a halved one drops the tips' curvature from Newton's matrix
(``contact_curvature_after_halving``).

The half phantom (meshes/cases/phantom-indenter-half.toml), P2, A1 pushed 5 mm, at size 6 mm
with 3.2 mm sites (``--level 1``: every size / sqrt 2), solved with each setting in one run:
(4 halvings, exact tangent: the former default), (8, exact), (8, curvature dropped: the
default). Prints Newton iterations, load steps, cut-backs, wall time and the force, and the
ratios against the first setting.

    .venv/bin/python bench/bench_indenter_newton.py [--push 5] [--level 0]
"""
from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--push", type=float, default=5.0, help="A1 push (mm)")
    ap.add_argument("--level", type=int, default=0, help="0: 3.2 mm sites; 1: 2.26 mm")
    args = ap.parse_args()

    import tissue_reference.fem_reference as fr
    from tissue_reference.meshes.builders import build
    from tissue_reference.meshes.case import load_case

    case = load_case(ROOT / "meshes" / "cases" / "phantom-indenter-half.toml")
    r = 2.0 ** (-args.level / 2)
    case = dataclasses.replace(case, mesh=build("phantom-half", 6.0 * r, site_size=3.2 * r))
    rows = []
    for ls, curv in ((4, "keep"), (8, "keep"), (8, "drop")):
        st = fr.NewtonSettings(line_search=ls, contact_curvature_after_halving=curv)
        s = fr.ReferenceSolver(case, degree=2, settings=st)
        t0 = time.perf_counter()
        res = s.solve({"A1": args.push})
        wall = time.perf_counter() - t0
        failed = len(res.history["iterate_load"]) and sum(
            1 for a, b in zip(res.history["iterate_load"], res.history["iterate_load"][1:])
            if b < a)
        rows.append((f"{ls}/{curv}", res.iterations, res.load_steps, failed, wall,
                     2.0 * res.extra["indenters"]["A1"]["force"]))
    print(f"indenter half phantom, P2, {case.mesh.n_cells} cells, A1 = {args.push:g} mm")
    print(f"{'halvings/curvature':>18} {'newton':>6} {'steps':>5} {'cutbacks':>8} "
          f"{'wall_s':>7} {'force_mN':>12}")
    for name, its, steps, failed, wall, force in rows:
        print(f"{name:>18} {its:6d} {steps:5d} {failed:8d} {wall:7.1f} {force:12.6f}")
    base = rows[0]
    for r in rows[1:]:
        print(f"{base[0]} vs {r[0]}: {base[1] / r[1]:.2f}x Newton iterations, "
              f"{base[4] / r[4]:.2f}x wall time, force differs by "
              f"{abs(r[5] / base[5] - 1):.1e}")


if __name__ == "__main__":
    main()
