"""``tissue solve phantom-indenter`` with all four tips pushed equally, through the library path
the command runs (``tissue.common.run_solver`` with the reference's defaults: P2, Gauss contact
rule, the automatic error estimate), solved on the symmetric part (the default: the quarter
with its mirror planes sliding, mirrored back) and on the whole mesh (``symmetry=False``,
``tissue solve --no-symmetry``), each with fresh solvers (forms compiled, nothing kept from the
other). Prints both walls, their ratio, the Newton iterations and unknowns of each, and the
largest differences of the answers (displacement field, targets, tip forces, relative).

    .venv/bin/python bench/bench_symmetric_solve.py [--push 10] [--skip-whole] [--size MM]
"""
from __future__ import annotations

import argparse
import sys

import numpy as np
from _timing import best

from tissue_reference.model.case import load_case
from tissue_reference.tissue.common import run_solver


def _solve(case, pushes, symmetry: bool):
    # lazy: fem_reference loads dolfinx and PETSc
    from tissue_reference.fem_reference.kept import forget_solvers

    return best(lambda: run_solver("fem", case, pushes=pushes, estimate="auto",
                                   symmetry=symmetry), 1, before=forget_solvers)


def _rel(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", default="phantom-indenter")
    ap.add_argument("--push", type=float, default=10.0, help="each tip's push (mm)")
    ap.add_argument("--size", type=float, default=None, help="mesh size (mm); default: the "
                    "case's")
    ap.add_argument("--skip-whole", action="store_true", help="time the reduced solve only")
    args = ap.parse_args(argv)
    case = load_case(args.case, size=args.size)
    pushes = {a.name: args.push for a in case.actuators}
    print(f"{case.name}: {case.mesh.n_cells:,} cells, every tip {args.push:g} mm")
    runs = {}
    for symmetry in (True, False) if not args.skip_whole else (True,):
        res, wall = _solve(case, pushes, symmetry)
        runs[symmetry] = (res, wall)
        sym = res.symmetry or {}
        where = (f"the part cut by {', '.join(sym['planes'])} ({sym['part_dofs']:,} unknowns)"
                 if sym.get("solved_on") == "part" else f"the whole mesh ({sym.get('why')})")
        print(f"  {'reduced' if symmetry else 'whole':8s} {wall:8.1f} s wall, "
              f"{res.iterations} Newton iterations, {res.discretization['dofs']:,} unknowns, "
              f"solved on {where}; A1 force {res.indenters['A1']['force']:.3f} mN, "
              f"|u(T1)| {np.linalg.norm(res.probes['T1']):.5f} mm", flush=True)
    if len(runs) == 2:
        (red, t_red), (whole, t_whole) = runs[True], runs[False]
        du = np.abs(red.u - whole.u).max() / np.abs(whole.u).max()
        dp = max(_rel(red.probes[k], v) for k, v in whole.probes.items())
        df = max(abs(red.indenters[k]["force"] - v["force"]) / abs(v["force"])
                 for k, v in whole.indenters.items())
        print(f"  whole / reduced: {t_whole / t_red:.2f}x; largest differences: field "
              f"{du:.2e} (of max |u|), targets {dp:.2e}, tip forces {df:.2e} (relative); "
              f"Newton iterations {red.iterations} / {whole.iterations}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
