"""Warm re-solves after +0.5 mm on every actuator, per mesh size, in one run: the P1 reference's
Newton from its own previous answer; ADMM + chord polish from the previous answer (chord steps
on the kept tangent at rest); and the control model's state update (``control.fast_model``:
the first-order predictor from the sensitivities at the previous state, then chord steps on the
tangent factorized at that state, kept from the step before, as a control loop holds it for its
Jacobian), its tangents factorized by SuperLU (its default) and by CHOLMOD (the ``factorize``
hook). Each: time (best of ``--repeat``), iterations, the largest vertex distance from the
reference's answer (mm) and the ratio reference time / its time; the control model's update to
its default tolerance (1e-6 mm, what its Jacobian needs) and to 1e-3 mm (the accuracy the fast
solvers are held to against the reference; ``--state-tols``). The control model's update
holds a factorization it did not pay for in the call: its cost (the tangent at the previous
state, assembled and factorized) is printed beside it, and the ratio with that cost counted.

    .venv/bin/python bench/bench_warm_update.py                 # sizes 10 6 5 2.8
    .venv/bin/python bench/bench_warm_update.py --sizes 10 --push 4
    .venv/bin/python bench/bench_warm_update.py --sizes 1.8 --factorizations cholmod --repeat 2
    .venv/bin/python bench/bench_warm_update.py --case phantom-indenter-control --push 4

The glued phantom (pushes within the patches' radius), or with ``--case`` a shipped case as it
is meshed (e.g. the rigid-tip phantom meshed for control: frictionless tips, P1); one BLAS
thread (OPENBLAS_NUM_THREADS=1 unless set), as bench/bench_admm_accel.py.
"""
import argparse
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
import numpy as np
from bench_admm_accel import best  # (result, shortest time) of repeated calls (this folder)

import tissue_reference.fem_reference as fr
from tissue_reference.control.fast_model import STATE_TOL_MM, FastModel
from tissue_reference.model.case import load_case
from tissue_reference.solvers import admm


def fast_update(case, target, p0, p1, factorize, state_tol_mm):
    """(model after the update, the update's timings (ms: "state", "jacobian", "factor"), the
    factorization ms it holds from the step before, its refactorizations, its chord iterations)
    for one control model started at p0."""
    model = FastModel(case, target, factorize=factorize, state_tol_mm=state_tol_mm)
    model.jacobian(p0)                 # full ADMM solve, tangent factorized, sensitivities
    held_ms = model.timings[-1]["factor"]
    n0 = model.refactorizations
    model.jacobian(p1)                 # the update: predictor + chord on the kept factorization
    return (model, model.timings[-1], held_ms, model.refactorizations - n0,
            model.chord_iterations)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=float, nargs="+", default=[10.0, 6.0, 5.0, 2.8],
                    help="phantom mesh sizes (mm)")
    ap.add_argument("--push", type=float, default=4.0,
                    help="every actuator's push before the +0.5 mm (default 4)")
    ap.add_argument("--repeat", type=int, default=3, help="timings are the best of this many")
    ap.add_argument("--target", default="T1", help="the control model's target probe")
    ap.add_argument("--factorizations", nargs="+", choices=("superlu", "cholmod"),
                    default=["superlu", "cholmod"],
                    help="the control model's factorizations to time (SuperLU takes minutes "
                         "and gigabytes from 50k tets on)")
    ap.add_argument("--state-tols", type=float, nargs="+", default=[STATE_TOL_MM, 1e-3],
                    help="the control model's chord tolerances (mm) to time: its default, "
                         "and the 1e-3 mm the fast solvers are held to against the reference")
    ap.add_argument("--case", help="a shipped case (meshes/cases/CASE.toml) instead of the "
                    "glued phantom at --sizes")
    args = ap.parse_args()
    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs; warm re-solves "
          f"{args.push:g} -> {args.push + 0.5:g} mm on every actuator, best of {args.repeat}")
    if args.case:
        rows(load_case(args.case), args.case, args)
        return
    for size in args.sizes:
        rows(load_case("phantom", size=size), f"phantom size {size:g}", args)


def rows(case, label, args):
    """The rows of one case (``label`` names it)."""
    acts = [a.name for a in case.actuators]
    p0 = dict.fromkeys(acts, args.push)
    p1 = dict.fromkeys(acts, args.push + 0.5)
    fr.solve(case, degree=1, pushes=dict.fromkeys(acts, 0.1))   # compile the forms
    ref0 = fr.solve(case, degree=1, pushes=p0)
    ref1, t_ref = best(lambda: fr.solve(case, degree=1, pushes=p1, initial=ref0), args.repeat)
    print(f"\n{label}: {case.mesh.n_cells} tets; reference P1 Newton warm "
          f"{t_ref * 1e3:8.1f} ms ({ref1.iterations} its)")

    def err(u):
        return float(np.abs(np.asarray(u).reshape(ref1.u.shape) - ref1.u).max())

    kw = {"polish": "chord", "factorize": fr.cholmod_factor}
    a0 = admm.solve(case, pushes=p0, **kw)
    a1, t_ch = best(lambda: admm.solve(case, pushes=p1, initial=a0.u, **kw), args.repeat)
    print(f"  ADMM + chord (rest tangent)    {t_ch * 1e3:8.1f} ms "
          f"({a1.extra['admm_iterations']} ADMM + {a1.extra['chord_iterations']} chord its), "
          f"{err(a1.u):.1e} mm, x{t_ref / t_ch:.1f}")
    for name, factorize in (("SuperLU", None), ("CHOLMOD", fr.cholmod_factor)):
        if name.lower() not in args.factorizations:
            continue
        for tol in args.state_tols:
            runs = [fast_update(case, args.target, p0, p1, factorize, tol)
                    for _ in range(max(1, args.repeat))]
            model, tm, _, refac, chords = min(runs, key=lambda r: r[1]["state"])
            t_fm = tm["state"] / 1e3
            held_s = min(r[2] for r in runs) / 1e3
            print(f"  control model update, {name:7s} {t_fm * 1e3:8.1f} ms (predictor + "
                  f"{chords} chord its to {tol:g} mm), {err(model.u):.1e} mm, "
                  f"x{t_ref / t_fm:.1f}; the tangent it holds {held_s * 1e3:.1f} ms: with it "
                  f"x{t_ref / (t_fm + held_s):.1f}; then its Jacobian {tm['jacobian']:.1f} ms "
                  f"({refac} refactorizations in the call, {tm['factor']:.1f} ms)")


if __name__ == "__main__":
    main()
