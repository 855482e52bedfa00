"""ADMM with rigid tips against the P1 reference on the indenter phantom (its default mesh,
32k tets, the case's Gauss contact rule and surface start): agreement, iterations and time of
ADMM + Newton polish (its tangents by CHOLMOD, as ``tissue verify`` runs it), of plain ADMM and
of ADMM with Anderson acceleration, beside the reference's cold P1 solve, in one run.

    python bench/bench_admm_contact.py            # A1 = 5 mm, and all four at 5 mm
    python bench/bench_admm_contact.py --push 10  # another push (mm)

Each line: the load, the solver, its time (s), iterations, the largest vertex difference from
the P1 reference (mm) and the time ratio reference / solver (> 1: faster than the reference).
"""
import argparse
import time

import numpy as np

import tissue_reference.fem_reference as fr
from tissue_reference.model.case import load_case
from tissue_reference.solvers import admm


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--push", type=float, default=5.0, help="mm (default 5)")
    ap.add_argument("--plain-iterations", type=int, default=20000,
                    help="plain ADMM's iteration limit per load step (default 20000)")
    args = ap.parse_args()
    case = load_case("phantom-indenter")
    print(f"phantom-indenter: {case.mesh.n_cells} tets, {case.mesh.n_vertices} vertices")
    fr.solve(case, degree=1, pushes={"A1": 0.1})    # compile the forms once (not timed)
    for pushes in ({"A1": args.push}, {a: args.push for a in ("A1", "A2", "A3", "A4")}):
        name = "+".join(pushes) + f" = {args.push:g} mm"
        t = time.perf_counter()
        ref = fr.solve(case, degree=1, pushes=pushes)   # from rest, forms compiled
        t_ref = time.perf_counter() - t
        print(f"{name}: reference P1 {t_ref:7.2f} s, {ref.iterations} Newton iterations, "
              f"force A1 {ref.indenters['A1']['force']:.4f} mN")
        # the polish's tangents by CHOLMOD, as tissue solve and tissue verify run it
        runs = (("ADMM + polish", {"factorize": fr.cholmod_factor}),
                ("plain ADMM", {"polish": False, "tol_mm": 1e-5,
                                "max_iter": args.plain_iterations}),
                ("Anderson(5)", {"polish": False, "tol_mm": 1e-5, "anderson": 5,
                                 "max_iter": args.plain_iterations}))
        for label, kw in runs:
            t = time.perf_counter()
            res = admm.solve(case, pushes=pushes, **kw)
            dt = time.perf_counter() - t
            print(f"{name}: {label:13s} {dt:7.2f} s, {res.extra['admm_iterations']} ADMM + "
                  f"{res.extra['newton_iterations']} Newton iterations, converged "
                  f"{res.converged}, max |u - u_ref| {np.abs(res.u - ref.u).max():.2e} mm, "
                  f"force A1 {res.indenters['A1']['force']:.4f} mN, "
                  f"reference / ADMM time x{t_ref / dt:.2f}")


if __name__ == "__main__":
    main()
