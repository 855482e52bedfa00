"""The thick sphere (an octant, inner surface pushed out 2 mm radially, outer free) against its
independent answers: the radial equilibrium ODE (nu < 0.5) and the closed form (nu = 0.5), both
written in tests/test_mixed.py. Prints, for each formulation x geometry x nu x mesh size, the
relative errors of the outer radial displacement and of the inner radial reaction, the dofs and
the solve time, so the locking of displacement elements and the faceting error of straight cells
are measured side by side in one run.

    .venv/bin/python bench/bench_sphere.py [--sizes 2.5 1.5] [--nus 0.45 0.4999 0.5]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--sizes", type=float, nargs="+", default=[2.5, 1.5])
    ap.add_argument("--nus", type=float, nargs="+", default=[0.45, 0.4999, 0.5])
    args = ap.parse_args()
    import test_mixed as tm

    from tissue_reference.model.case import Material

    print(f"{'nu':>7} {'formulation':>12} {'cells':>9} {'size':>5} {'u(B) err':>10} "
          f"{'reaction err':>12} {'dofs':>8} {'solve_s':>8}")
    for nu in args.nus:
        mat = Material("neo-hookean", E=tm.E, nu=nu)
        u_ref, P_ref = tm.incompressible_sphere(mat.mu) if nu >= 0.5 else \
            tm.thick_sphere(mat.mu, mat.kappa)
        G_ref = -P_ref * tm.A ** 2 * 3.141592653589793 / 2
        for form in ("displacement", "mixed"):
            if form == "displacement" and nu >= 0.5:
                continue
            for curved in (False, True):
                for size in args.sizes:
                    t0 = time.perf_counter()
                    res, u, G = tm.solve_shell(size, nu, form, curved=curved)
                    wall = time.perf_counter() - t0
                    d = res.discretization
                    print(f"{nu:7g} {form:>12} {'curved' if curved else 'straight':>9} "
                          f"{size:5g} {u / u_ref - 1:+10.2e} {G / G_ref - 1:+12.2e} "
                          f"{d['dofs']:8d} {wall:8.2f}", flush=True)


if __name__ == "__main__":
    main()
