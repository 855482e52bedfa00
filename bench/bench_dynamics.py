"""Implicit-Euler dynamics (seed 000 eq. 5): the reference (fem_reference.dynamics, P1, lumped
mass) against the ADMM's dynamic mode on the phantom with gravity, same mass and time step.

    .venv/bin/python bench/bench_dynamics.py [--size 10] [--steps 20] [--dt 0.005]
                                             [--push A1=5 ...] [--gravity 0 0 -9810]

Prints, from this one run: the largest vertex difference (mm) per step between the reference and
ADMM stepped one call per step (with its Newton polish, and without it at tol 1e-5 mm), the
wall-clock times (s) of the whole trajectory for each solver (minimum of ``--repeats`` runs, after
a warm-up that compiles the forms) and their ratio. Units: mm, s, mm/s^2.
"""
from __future__ import annotations

import argparse
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # single core against single core
import dataclasses
import time

import numpy as np

from tissue_reference.fem_reference import cholmod_factor
from tissue_reference.fem_reference.dynamics import simulate
from tissue_reference.model.case import load_case
from tissue_reference.solvers import admm
from tissue_reference.solvers.trajectory import admm_trajectory

CASE = "meshes/cases/phantom.toml"


def best_time(fun, repeats):
    times, res = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        res = fun()
        times.append(time.perf_counter() - t0)
    return min(times), float(np.median(times)), res


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=float, default=10.0, help="phantom mesh size (mm)")
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--dt", type=float, default=5e-3, help="time step (s)")
    ap.add_argument("--push", action="append", default=[], metavar="NAME=MM")
    ap.add_argument("--gravity", type=float, nargs=3, default=(0.0, 0.0, -9810.0),
                    help="gravitational acceleration (mm/s^2)")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    pushes = {k: float(v) for k, v in (p.split("=", 1) for p in args.push)}
    case = load_case(CASE, size=args.size)
    case = dataclasses.replace(case, gravity=tuple(args.gravity)).with_pushes(pushes)
    dt, steps = args.dt, args.steps
    print(f"phantom size {args.size:g} mm: {case.mesh.n_vertices} vertices, {case.mesh.n_cells} "
          f"tets; gravity {tuple(args.gravity)} mm/s^2, density {case.material.density:g} "
          f"kg/mm^3, dt {dt:g} s, {steps} steps, pushes {pushes or 'none'}")
    print("load average {:.2f} {:.2f} {:.2f} on {} CPUs".format(*os.getloadavg(), os.cpu_count()))
    simulate(case, dt=dt, steps=1)  # warm-up: form compilation
    admm.solve(case, dynamics=admm.ImplicitEuler(dt=dt, steps=1), factorize=cholmod_factor)

    t_ref, med_ref, ref = best_time(lambda: simulate(case, dt=dt, steps=steps), args.repeats)
    t_admm, med_admm, whole = best_time(
        lambda: admm.solve(case, dynamics=admm.ImplicitEuler(dt=dt, steps=steps),
                           factorize=cholmod_factor), args.repeats)
    t_raw, med_raw, raw = best_time(
        lambda: admm.solve(case, dynamics=admm.ImplicitEuler(dt=dt, steps=steps), polish=False,
                           tol_mm=1e-5), args.repeats)
    stepped = admm_trajectory(case, dt=dt, steps=steps, factorize=cholmod_factor)
    stepped_raw = admm_trajectory(case, dt=dt, steps=steps, polish=False, tol_mm=1e-5)

    print(f"\n{'step':>4} {'t (s)':>7} {'max|u| ref':>11} {'KE (uJ)':>10} {'Newton':>6} "
          f"{'ADMM+polish':>12} {'its':>7} {'ADMM tol 1e-5':>14} {'its':>5}")
    for k in range(1, steps + 1):
        umax = np.sqrt((ref.u[k] ** 2).sum(axis=1)).max()
        d1 = np.abs(stepped.u[k] - ref.u[k]).max()
        d2 = np.abs(stepped_raw.u[k] - ref.u[k]).max()
        it = f"{stepped.iterations[k - 1]}"
        print(f"{k:4d} {ref.times[k]:7.3f} {umax:11.4f} {ref.kinetic_energy[k]:10.3e} "
              f"{ref.iterations[k - 1]:6d} {d1:12.2e} {it:>7} "
              f"{d2:14.2e} {stepped_raw.iterations[k - 1]:5d}")
    print(f"\nend state, one {steps}-step call: |ADMM+polish - ref| "
          f"{np.abs(whole.u - ref.u[-1]).max():.2e} mm, |ADMM tol 1e-5 - ref| "
          f"{np.abs(raw.u - ref.u[-1]).max():.2e} mm")
    print(f"wall time of the {steps} steps (min / median of {args.repeats}):")
    print(f"  reference (dolfinx Newton, {int(ref.iterations.sum())} iterations): "
          f"{t_ref:.3f} / {med_ref:.3f} s")
    print(f"  ADMM + Newton polish ({whole.extra['admm_iterations']} ADMM + "
          f"{whole.extra['newton_iterations']} Newton): {t_admm:.3f} / {med_admm:.3f} s  "
          f"-> reference / ADMM = {t_ref / t_admm:.1f}x")
    print(f"  ADMM without polish, tol 1e-5 mm ({raw.extra['admm_iterations']} iterations): "
          f"{t_raw:.3f} / {med_raw:.3f} s  -> reference / ADMM = {t_ref / t_raw:.1f}x")


if __name__ == "__main__":
    main()
