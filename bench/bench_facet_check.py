"""The facet check of a solve with tips: the displacement at the contact facets' sample points
by ``Function.eval`` (a pull-back and a basis tabulation per point on every call, as the check
was) against one sparse product with the rows ``point_values.evaluation_rows`` builds once (as it
is), on a shipped case's reference at a solved state, in one run: the cost of one check per
indenter, the one-off cost of the rows, and the largest difference of the values.

    .venv/bin/python bench/bench_facet_check.py [--case phantom-seed] [--push 3] [--repeat 5]
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--case", default="phantom-seed")
    ap.add_argument("--push", type=float, default=3.0, help="every actuator's push (mm)")
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()

    import tissue_reference.fem_reference as fr
    from tissue_reference.fem_reference.point_values import evaluation_rows
    from tissue_reference.model.case import load_case

    case = load_case(ROOT / "meshes" / "cases" / f"{args.case}.toml")
    solver = fr.ReferenceSolver(case)
    t0 = time.perf_counter()
    solver.solve({a.name: args.push for a in case.actuators})
    print(f"{args.case}: all actuators at {args.push:g} mm solved in "
          f"{time.perf_counter() - t0:.1f} s; {solver.timings.factorizations} factorizations")
    gdim = solver.gdim
    arr = solver.u.x.array
    total_eval = total_mat = total_build = 0.0
    print(f"{'indenter':>8} {'samples':>8} {'eval_ms':>8} {'matrix_ms':>9} {'build_ms':>8} "
          f"{'ratio':>7} {'max_diff_mm':>11}")
    for ind in solver.contact.indenters:
        pts, cells = ind._samples, ind._sample_cells
        t = time.perf_counter()
        M = evaluation_rows(solver.V, pts, cells)
        build = time.perf_counter() - t
        t = time.perf_counter()
        for _ in range(args.repeat):
            by_eval = np.asarray(solver.u.eval(pts, cells))[:, :gdim]
        t_eval = (time.perf_counter() - t) / args.repeat
        t = time.perf_counter()
        for _ in range(args.repeat):
            by_matrix = M @ arr.reshape(-1, gdim)
        t_mat = (time.perf_counter() - t) / args.repeat
        diff = float(np.abs(by_eval - by_matrix).max())
        total_eval, total_mat, total_build = total_eval + t_eval, total_mat + t_mat, \
            total_build + build
        print(f"{ind.name:>8} {len(pts):8d} {1e3 * t_eval:8.1f} {1e3 * t_mat:9.2f} "
              f"{1e3 * build:8.1f} {t_eval / t_mat:7.0f} {diff:11.1e}")
    print(f"one facet check, all indenters: {1e3 * total_eval:.0f} ms by eval, "
          f"{1e3 * total_mat:.1f} ms by the matrix ({total_eval / total_mat:.0f}x); the rows "
          f"cost {1e3 * total_build:.0f} ms once, {total_build / total_eval:.1f} checks by eval")


if __name__ == "__main__":
    main()
