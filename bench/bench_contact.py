"""Rigid indenters with penalty contact (fem_reference/contact.py): accuracy against Hertz and
the cost of contact against the glued patches on the phantom.

1. Hertz: a rigid sphere (R = 10 mm) 0.1 mm into the quarter block ``indent-block`` (linear
   elastic, E = 6 kPa, nu = 0.45, P2): force error against F = 4/3 E* sqrt(R) d^(3/2) per cell
   size h under the tip (beta = 1e3), and per penalty beta (h = 0.5 mm), with the penetration.
2. Phantom: meshes/cases/phantom-indenter.toml (four spherical tips, radius 5 mm, frictionless)
   against meshes/cases/phantom.toml (four glued patches) on the same mesh, all four actuators
   pushed the same: wall time, Newton iterations, load steps, factorizations, force per tip;
   a contact solve that fails reports the push it reached (the last converged state).

    .venv/bin/python bench/bench_contact.py [--sizes 1 0.7 0.5 0.35] [--betas 100 1000 10000]
        [--phantom-size 4] [--pushes 5 10 15] [--skip-hertz] [--skip-phantom]

Units: mm, kPa, mN, s.
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

E, NU, R, D = 6.0, 0.45, 10.0, 0.1


def hertz_case(mesh):
    from tissue_reference.model.case import Actuator, Boundary, Case, Material

    tip = Actuator("I", "tip", (0.0, 0.0, -1.0), type="indenter", tip="sphere", radius=R,
                   point=(0.0, 0.0, 0.0), contact_region="top")
    return Case(mesh, Material("linear-elastic", E, NU),
                boundaries=[Boundary("bottom", "fixed"),
                            Boundary("xsym", "sliding", normal=(1.0, 0.0, 0.0)),
                            Boundary("ysym", "sliding", normal=(0.0, 1.0, 0.0))],
                actuators=[tip])


def hertz(sizes, betas):
    import tissue_reference.fem_reference as fr
    from tissue_reference.meshes.builders import indent_block

    f_hertz = 4.0 / 3.0 * E / (1 - NU ** 2) * math.sqrt(R) * D ** 1.5
    print(f"Hertz: sphere R = {R:g} mm, d = {D:g} mm, E = {E:g} kPa, nu = {NU:g}, P2; "
          f"F_Hertz = {f_hertz:.5f} mN, contact radius {math.sqrt(R * D):.3f} mm")
    print(f"{'h mm':>6} {'beta':>7} {'cells':>6} {'dofs':>6} {'F mN':>9} {'error %':>8} "
          f"{'pen mm':>9} {'its':>4} {'s':>6}")
    runs = [(h, 1e3) for h in sizes] + [(0.5, b) for b in betas if b != 1e3 or 0.5 not in sizes]
    meshes = {}
    for h, beta in runs:
        mesh = meshes.setdefault(h, indent_block(h))
        case = hertz_case(mesh)
        fr.solve(case, degree=2, pushes={"I": 0.2 * D}, contact_penalty=beta)  # compile forms
        t0 = time.perf_counter()
        res = fr.solve(case, degree=2, pushes={"I": D}, contact_penalty=beta)
        wall = time.perf_counter() - t0
        ind = res.indenters["I"]
        F = 4 * ind["force"]  # the quarter block
        print(f"{h:6.2f} {beta:7.0e} {mesh.n_cells:6d} {res.extra['n_dofs']:6d} {F:9.5f} "
              f"{100 * (F / f_hertz - 1):+8.2f} {ind['max_penetration']:9.2e} "
              f"{res.iterations:4d} {wall:6.1f}", flush=True)


def phantom(size, pushes):
    import tissue_reference.fem_reference as fr
    from tissue_reference.errors import ConvergenceError
    from tissue_reference.model.case import load_case

    cases = ROOT / "meshes" / "cases"
    tips = load_case(cases / "phantom-indenter.toml", size=size)
    glued = load_case(cases / "phantom.toml", mesh=tips.mesh)
    print(f"\nphantom, size {size:g} mm ({tips.mesh.n_cells} tets), P1, A1..A4 pushed alike: "
          f"glued patches vs spherical tips (radius 5 mm, frictionless, beta = 1e3)")
    print(f"{'push':>5} {'model':>8} {'s':>7} {'its':>5} {'steps':>5} {'fact':>5} "
          f"{'force A1 mN':>11} {'reached mm':>10} {'ratio':>6}")
    fr.solve(glued, pushes={"A1": 1.0})  # compile both before timing
    fr.solve(tips, pushes={"A1": 0.5})
    for push in pushes:
        p = {a.name: push for a in tips.actuators}
        t0 = time.perf_counter()
        rg = fr.solve(glued, pushes=p)
        wg = time.perf_counter() - t0
        fg = float(-rg.reactions["act_px"][0])
        print(f"{push:5.1f} {'glued':>8} {wg:7.2f} {rg.iterations:5d} {rg.load_steps:5d} "
              f"{rg.extra['factorizations']:5d} {fg:11.1f} {push:10.2f} {1.0:6.1f}", flush=True)
        t0 = time.perf_counter()
        try:
            rt = fr.solve(tips, pushes=p)
            reached = push
        except ConvergenceError as exc:
            rt = exc.last_converged
            reached = exc.load_fraction * push
        wt = time.perf_counter() - t0
        ind = rt.indenters["A1"]
        note = "" if reached == push else "  (failed beyond)"
        print(f"{push:5.1f} {'tips':>8} {wt:7.2f} {rt.iterations:5d} {rt.load_steps:5d} "
              f"{rt.extra['factorizations']:5d} {ind['force']:11.1f} {reached:10.2f} "
              f"{wt / wg:6.1f}{note}", flush=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=float, nargs="+", default=[1.0, 0.7, 0.5, 0.35])
    ap.add_argument("--betas", type=float, nargs="+", default=[1e2, 1e3, 1e4])
    ap.add_argument("--phantom-size", type=float, default=4.0)
    ap.add_argument("--pushes", type=float, nargs="+", default=[5.0, 10.0, 15.0])
    ap.add_argument("--skip-hertz", action="store_true")
    ap.add_argument("--skip-phantom", action="store_true")
    args = ap.parse_args(argv)
    if not args.skip_hertz:
        hertz(args.sizes, args.betas)
    if not args.skip_phantom:
        phantom(args.phantom_size, args.pushes)
    return 0


if __name__ == "__main__":
    sys.exit(main())
