"""ADMM benchmarks (issue 3): time per ADMM iteration at ~1.7k tets, warm-started re-solve after a
0.5 mm actuator increment against the FEniCSx reference Newton from the same warm start, and
scaling of time per iteration and peak memory with mesh size (log-log growth exponent).

    .venv/bin/python bench/bench_admm.py [--sizes 10 5 2.8 1.8] [--iters 50]

Units: mm, ms, MiB. Prints measured figures and ratios from this one run.
"""
from __future__ import annotations

import argparse
import time
import tracemalloc

import numpy as np

from meshes.builders import phantom
from meshes.case import load_case
from solvers import admm

CASE = "meshes/cases/phantom.toml"
TOL = 0.01  # mm, ADMM stopping tolerance of the warm re-solve; its error to the reference printed


def time_per_iteration(case, iters, pushes):
    """ms per steady ADMM iteration (x-step + z-step + residuals): timed between the callbacks
    of iterations 10 and iters, warm-started from the ADMM state after 30 iterations."""
    u = admm.solve(case, pushes=pushes, polish=False, lift=False, max_iter=30).u
    stamps = {}

    def cb(it, _u):
        stamps[it] = time.perf_counter()

    admm.solve(case, pushes=pushes, initial=u, polish=False, lift=False, load_steps=1,
               max_iter=iters, tol_mm=1e-30, callback=cb)
    k = sorted(stamps)
    return 1e3 * (stamps[k[-1]] - stamps[k[9]]) / (k[-1] - k[9])


def peak_memory_mib(case, pushes):
    tracemalloc.start()
    admm.solve(case, pushes=pushes, polish=False, lift=False, load_steps=1, max_iter=5,
               tol_mm=1e-30)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return peak / 2 ** 20


def accuracy():
    """Issue target: every probe within 0.05 mm, every vertex within 0.1 mm of the reference."""
    from fem_reference import solve as fem_solve
    case = load_case(CASE)
    pushes = {"A1": 15.0, "A2": 15.0, "A3": 15.0, "A4": 15.0}
    t = time.perf_counter()
    rf = fem_solve(case, degree=1, pushes=pushes)
    tf = time.perf_counter() - t
    t = time.perf_counter()
    try:
        rp = admm.solve(case, pushes=pushes, polish=False, tol_mm=1e-3, max_iter=5000)
    except admm.SolverDivergedError as exc:
        print(f"[accuracy] plain ADMM (no Newton polish, tol_mm 1e-3, 5000 it per load step) "
              f"FAILED: {exc}", flush=True)
        rp = None
    tp = time.perf_counter() - t
    if rp is not None:
        _print_plain(rp, rf, tp)
    t = time.perf_counter()
    ra = admm.solve(case, pushes=pushes, max_iter=200)
    ta = time.perf_counter() - t
    _print_polished(case, ra, rf, ta, tf)


def _print_plain(rp, rf, tp):
    perr_p = {k: f"{np.linalg.norm(rp.probes[k] - rf.probes[k]):.1e}" for k in rf.probes}
    print(f"[accuracy] plain ADMM (no Newton polish, tol_mm 1e-3): {rp.extra['admm_iterations']} "
          f"it in {rp.load_steps} load steps, "
          f"converged {rp.converged}, {tp:.1f} s, max vertex error {np.abs(rp.u - rf.u).max():.3f}"
          f" mm, probe errors {perr_p} mm, rho doublings "
          f"{len(rp.history.get('rho_changes', []))}", flush=True)


def _print_polished(case, ra, rf, ta, tf):
    perr = {k: float(np.linalg.norm(ra.probes[k] - rf.probes[k])) for k in rf.probes}
    print(f"[accuracy] phantom.toml {case.mesh.n_cells} tets, 15 mm x 4: max vertex error "
          f"{np.abs(ra.u - rf.u).max():.2e} mm (target 0.1), probe errors "
          f"{ {k: f'{v:.1e}' for k, v in perr.items()} } mm (target 0.05); ADMM "
          f"{ra.extra['admm_iterations']} it (max 200 per load step) + Newton polish "
          f"{ra.extra['newton_iterations']} it, polish restarts "
          f"{len(ra.extra['polish_restarts'])}, {ta:.1f} s; reference {rf.iterations} Newton it, "
          f"{rf.load_steps} load steps, {tf:.1f} s", flush=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", type=float, nargs="*", default=[10.0, 5.0, 2.8, 1.8])
    ap.add_argument("--iters", type=int, default=50)
    ap.add_argument("--skip-fem", action="store_true")
    ap.add_argument("--skip-iteration", action="store_true")
    ap.add_argument("--accuracy", action="store_true",
                    help="phantom.toml (size 6), all four actuators 15 mm: ADMM vs reference")
    a = ap.parse_args()
    pushes = {"A1": 2.0, "A2": 2.0, "A3": 2.0, "A4": 2.0}

    # 1. one ADMM iteration at ~1.7k tets (phantom size 10)
    case10 = load_case(CASE, size=10.0)
    for iters in (() if a.skip_iteration else (50, 200)):
        ms = time_per_iteration(case10, iters, pushes)
        print(f"[iteration] phantom size 10: {case10.mesh.n_cells} tets, {ms:.3f} ms per ADMM "
              f"iteration, mean over iterations 10..{iters} (target <= 0.5 ms; seed: 18.75 ms)",
              flush=True)

    # 2. warm re-solve after a 0.5 mm increment, to 0.05 mm, vs reference Newton
    if not a.skip_fem:
        from fem_reference import solve as fem_solve
        base = {"A1": 5.0, "A2": 5.0, "A3": 5.0, "A4": 5.0}
        inc = dict(base, A1=5.5)
        u0 = admm.solve(case10, pushes=base, max_iter=300).u
        admm.solve(case10, pushes=inc, initial=u0, tol_mm=TOL, polish=False, max_iter=2000)
        fem_solve(case10, degree=1, pushes=inc, initial=u0)  # warm the reference's caches too
        t = time.perf_counter()
        ra = admm.solve(case10, pushes=inc, initial=u0, tol_mm=TOL, polish=False,
                        max_iter=2000)  # harmonic lift of the 0.5 mm boundary change + ADMM
        ta = time.perf_counter() - t
        t = time.perf_counter()
        rf = fem_solve(case10, degree=1, pushes=inc, initial=u0)
        tf = time.perf_counter() - t
        err = np.abs(ra.u - rf.u).max()
        print(f"[warm re-solve] +0.5 mm on A1 (5 mm base), {case10.mesh.n_cells} tets: ADMM "
              f"{ra.extra['admm_iterations']} it (tol_mm {TOL}), {1e3 * ta:.1f} ms (max vertex diff to "
              f"reference {err:.3f} mm); reference Newton {rf.iterations} it, {1e3 * tf:.1f} ms; "
              f"speed-up {tf / ta:.2f}x (target >= 5x)", flush=True)

    if a.accuracy:
        accuracy()

    # 3. scaling
    rows = []
    for s in a.sizes:
        t = time.perf_counter()
        mesh = phantom(s)
        case = load_case(CASE, mesh=mesh)
        tm = time.perf_counter() - t
        ms = time_per_iteration(case, a.iters, pushes)
        mem = peak_memory_mib(case, pushes)
        lu = admm.prepare(case.with_pushes(pushes)).lu
        nnz = lu.nnz if hasattr(lu, "nnz") else lu.L.nnz + lu.U.nnz
        lu_mib = nnz * 12 / 2 ** 20  # SuperLU factors (not seen by tracemalloc)
        rows.append((case.mesh.n_cells, ms, mem + lu_mib))
        print(f"[scaling] size {s}: {case.mesh.n_cells} tets, {ms:.3f} ms/iteration, peak "
              f"{mem:.1f} MiB numpy (tracemalloc) + {lu_mib:.1f} MiB x-step LU factors "
              f"(mesh {tm:.1f} s)", flush=True)
    if len(rows) >= 2:
        n, t, m = map(np.array, zip(*rows))
        kt = np.polyfit(np.log(n), np.log(t), 1)[0]
        km = np.polyfit(np.log(n), np.log(m), 1)[0]
        print(f"[scaling] growth exponent: time per iteration ~ n^{kt:.2f} (target <= 1.1), "
              f"peak memory (numpy + LU) ~ n^{km:.2f}")


if __name__ == "__main__":
    main()
