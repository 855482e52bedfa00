"""Plain ADMM (the seed's), ADMM with Anderson acceleration, ADMM + Newton polish and ADMM + chord
polish (``polish="chord"``: Anderson-mixed chord steps on the tangent at rest, factorized once),
both polishes factorizing by CHOLMOD as the command line does, against the P1
reference's Newton, per mesh size, in one run: iterations, time (best of ``--repeat``), the
largest vertex difference from the reference (mm) and the time ratio reference / solver
(> 1: faster).

    python bench/bench_admm_accel.py                      # phantom sizes 10 and 5 (1.8k, 9.5k tets)
    python bench/bench_admm_accel.py --sizes 10 5 3 --push 5 --anderson 5
    python bench/bench_admm_accel.py --sizes 1.8 --only chord   # 185k tets: the chord row only
    python bench/bench_admm_accel.py --rest-tangent     # cold solves with and without the kept
                                                        # factorization of the tangent at rest
                                                        # (with the chord polish: its memory)

Cold: every solve from rest (the reference's forms compiled beforehand, its solver kept);
warm: a re-solve after +0.5 mm on every actuator, from the previous answer (the reference from
its own). Plain and accelerated ADMM stop at ``--tol`` (mm) on the primal and dual residuals.
One thread (OPENBLAS_NUM_THREADS=1 unless set), as bench/bench_admm.py.
"""
import argparse
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
import time

import numpy as np

import tissue_reference.fem_reference as fr
from tissue_reference.model.case import load_case
from tissue_reference.solvers import admm

ACTS = ("A1", "A2", "A3", "A4")


def timed(fun):
    t = time.perf_counter()
    res = fun()
    return res, time.perf_counter() - t


def best(fun, repeat):
    """(result, the shortest time) of ``repeat`` calls."""
    runs = [timed(fun) for _ in range(max(1, repeat))]
    return runs[0][0], min(t for _, t in runs)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", default="phantom", help="a shipped case (default phantom)")
    ap.add_argument("--sizes", type=float, nargs="+", default=[10.0, 5.0], help="mesh sizes (mm)")
    ap.add_argument("--push", type=float, default=4.0,
                    help="every actuator's push (mm; default 4, +0.5 stays within the glued "
                         "patches' radius)")
    ap.add_argument("--tol", type=float, default=1e-5, help="ADMM stopping tolerance (mm)")
    ap.add_argument("--anderson", type=int, default=5, help="Anderson history (default 5)")
    ap.add_argument("--repeat", type=int, default=3, help="timings are the best of this many")
    ap.add_argument("--only", nargs="+", choices=("admm", "anderson(5)", "polish", "chord"),
                    help="only these rows (by the label's last word; default all)")
    ap.add_argument("--rest-tangent", action="store_true",
                    help="only the cold solves, best of 5, with the tangent at rest factorized "
                         "once and kept (the default) and factorized at every lift")
    args = ap.parse_args()
    if args.rest_tangent:
        return rest_tangent(args)
    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs")
    for size in args.sizes:
        case = load_case(args.case, size=size)
        acts = [a.name for a in case.actuators if a.name in ACTS]
        p0 = dict.fromkeys(acts, args.push)
        p1 = dict.fromkeys(acts, args.push + 0.5)
        fr.solve(case, degree=1, pushes=dict.fromkeys(acts, 0.1))   # compile the forms
        print(f"\n{args.case} size {size:g}: {case.mesh.n_cells} tets; pushes {args.push:g} mm "
              f"({', '.join(acts)}), then +0.5 mm")
        ref0, t_ref0 = best(lambda c=case, p=p0: fr.solve(c, degree=1, pushes=p), args.repeat)
        ref1, t_ref1 = best(lambda c=case, p=p1, r=ref0: fr.solve(c, degree=1, pushes=p,
                                                                  initial=r), args.repeat)
        print(f"  reference P1 Newton: cold {t_ref0:.3f} s ({ref0.iterations} its), "
              f"warm {t_ref1:.3f} s ({ref1.iterations} its)")
        runs = (("plain ADMM", {"polish": False, "tol_mm": args.tol, "max_iter": 50000}),
                (f"Anderson({args.anderson})", {"polish": False, "tol_mm": args.tol,
                                                "max_iter": 50000,
                                                "anderson": args.anderson}),
                ("ADMM + polish", {"factorize": fr.cholmod_factor}),
                ("ADMM + chord", {"polish": "chord", "factorize": fr.cholmod_factor}))
        for label, kw in runs:
            if args.only and label.split()[-1].lower() not in args.only:
                continue
            admm.solve(case, pushes=dict.fromkeys(acts, 0.1), **kw)   # operators, kernel built
            r0, t0 = best(lambda kw=kw, c=case, p=p0: admm.solve(c, pushes=p, **kw), args.repeat)
            r1, t1 = best(lambda kw=kw, c=case, p=p1, r=r0: admm.solve(c, pushes=p, initial=r.u,
                                                                       **kw), args.repeat)
            for tag, r, t, ref, tr in (("cold", r0, t0, ref0, t_ref0),
                                       ("warm", r1, t1, ref1, t_ref1)):
                print(f"  {label:14s} {tag}: {r.extra['admm_iterations']:6d} ADMM + "
                      f"{r.extra['newton_iterations'] + r.extra.get('chord_iterations', 0):2d} polish its, {t:7.3f} s, converged "
                      f"{r.converged}, max |u - u_ref| {np.abs(r.u - ref.u).max():.1e} mm, "
                      f"reference / solver x{tr / t:.2f}")


def rest_tangent(args):
    """Cold solves (best of 5) with the rest tangent's factorization kept and without."""
    from tissue_reference.solvers.admm import polish

    kept = polish.REST_TANGENT_KEPT_DOFS
    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs; cold solves, best of 5")
    for size in args.sizes:
        case = load_case(args.case, size=size)
        acts = [a.name for a in case.actuators if a.name in ACTS]
        p0 = dict.fromkeys(acts, args.push)
        fr.solve(case, degree=1, pushes=dict.fromkeys(acts, 0.1))
        t_ref = min(timed(lambda c=case, p=p0: fr.solve(c, degree=1, pushes=p))[1] for _ in range(5))
        print(f"\n{args.case} size {size:g}: {case.mesh.n_cells} tets; reference P1 Newton "
              f"{t_ref * 1e3:.1f} ms")
        runs = (("plain ADMM", {"polish": False, "tol_mm": args.tol, "max_iter": 50000}),
                (f"Anderson({args.anderson})", {"polish": False, "tol_mm": args.tol,
                                                "max_iter": 50000, "anderson": args.anderson}),
                ("ADMM + polish", {}),
                ("ADMM + chord", {"polish": "chord", "factorize": fr.cholmod_factor}))
        for label, kw in runs:
            if args.only and label.split()[-1].lower() not in args.only:
                continue
            out = []
            for limit in (0, kept):
                polish.REST_TANGENT_KEPT_DOFS = limit
                admm.solve(case, pushes=dict.fromkeys(acts, 0.1), **kw)
                out.append(min(timed(lambda kw=kw, c=case, p=p0: admm.solve(c, pushes=p, **kw))[1]
                               for _ in range(5)))
            polish.REST_TANGENT_KEPT_DOFS = kept
            held = _kept_memory(case, acts) if "chord" in label else ""
            print(f"  {label:14s} factorized at every lift {out[0] * 1e3:7.1f} ms "
                  f"(x{t_ref / out[0]:.2f}), kept {out[1] * 1e3:7.1f} ms (x{t_ref / out[1]:.2f}): "
                  f"{out[0] / out[1]:.2f}x faster{held}")


def _rss_mib() -> float:
    """This process's resident memory (MiB) after returning freed memory to the system."""
    import ctypes
    import gc

    gc.collect()
    ctypes.CDLL("libc.so.6").malloc_trim(0)
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("VmRSS")) / 1024


def _kept_memory(case, acts) -> str:
    """The resident memory (MiB) the kept rest tangent holds: the operators' kept factorization
    and element matrices dropped and rebuilt."""
    from tissue_reference.solvers.admm import operators, polish

    ops = operators.prepare(case.with_pushes(dict.fromkeys(acts, 0.1)))
    if ops.rest_tangent is None:
        return "; not kept"
    ops.rest_tangent = None
    without = _rss_mib()
    _, factor = polish.rest_factor(ops, fr.cholmod_factor)
    held = _rss_mib() - without
    ksp = getattr(factor, "ksp", None)     # CHOLMOD through PETSc: the factor's size
    nz = "" if ksp is None else \
        f", factor {ksp.getPC().getFactorMatrix().getInfo()['nz_used'] / 1e6:.1f}M nonzeros"
    return f"; the kept rest tangent holds {held:.0f} MiB ({ops.nq} unknowns{nz})"


if __name__ == "__main__":
    main()
