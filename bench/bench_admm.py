"""ADMM benchmarks: time per ADMM iteration at ~1.7k tets, warm-started re-solve after a
0.5 mm actuator increment against the FEniCSx reference Newton from the same warm start, and
scaling of time per iteration and peak memory with mesh size (log-log growth exponent).

    .venv/bin/python bench/bench_admm.py [--sizes 10 5 2.8 1.8] [--skip-fem] [--accuracy]

Units: mm, ms, MiB. Prints measured figures and ratios from this one run, with the machine's
load average. Times are wall clock on one thread (OPENBLAS_NUM_THREADS=1 unless set); on a
shared machine they are noisy, so each is the minimum (and median) of repeats, and the scaling
study interleaves its sizes in rounds.
"""
from __future__ import annotations

import argparse
import os

# one thread: ADMM is single-threaded, and OpenBLAS's idle threads (woken by SuperLU, numpy.linalg)
# spin on the second core; the reference's MUMPS/CHOLMOD get the same setting (ratios are
# single-core against single-core). Override by setting the variable.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
import time
import tracemalloc

import numpy as np

from tissue_reference.errors import SolverDivergedError
from tissue_reference.meshes.builders import phantom
from tissue_reference.model.case import load_case
from tissue_reference.solvers import admm
from tissue_reference.solvers.admm import operators

CASE = "meshes/cases/phantom.toml"
TOL = 0.01  # mm, ADMM stopping tolerance of the warm re-solve; its error to the reference printed
SCALING_TOL = 1e-4  # mm, ADMM tolerance of the scaling solves (the solver's default)


def _load():
    return "load average {:.2f} {:.2f} {:.2f} on {} CPUs".format(*os.getloadavg(), os.cpu_count())


def time_per_iteration(case, pushes, n=200, repeats=5, skip=5):
    """ms per steady ADMM iteration (x-step + element work + residuals), wall clock: from the
    solver's own per-iteration clock (history["admm_clock_s"]) over iterations skip..n of
    solves warm-started from the ADMM state after 30 iterations (no setup, start-up or final
    checks in the interval). Returns (min, median) over ``repeats`` solves."""
    u = admm.solve(case, pushes=pushes, polish=False, lift=False, max_iter=30).u
    per = []
    for _ in range(repeats):
        r = admm.solve(case, pushes=pushes, initial=u, polish=False, lift=False, load_steps=1,
                       max_iter=n, tol_mm=1e-30)
        c = r.history["admm_clock_s"]
        per.append(1e3 * (c[-1] - c[skip]) / (len(c) - 1 - skip))
    return min(per), float(np.median(per))


def time_per_iteration_of_solve(case, pushes, tol=SCALING_TOL):
    """(ms per iteration wall, cpu, iterations) of a solve from rest to ``tol`` (no lift, no
    polish), timed between the callbacks of its second and last iterations: the x-step of
    large meshes is iterative, so its cost per ADMM iteration depends on the tolerance."""
    wall, cpu = {}, {}

    def cb(it, _u):
        wall[it], cpu[it] = time.perf_counter(), time.process_time()

    r = admm.solve(case, pushes=pushes, polish=False, lift=False, tol_mm=tol, max_iter=5000,
                   callback=cb)
    k = sorted(wall)
    n = k[-1] - k[1]
    return (1e3 * (wall[k[-1]] - wall[k[1]]) / n, 1e3 * (cpu[k[-1]] - cpu[k[1]]) / n,
            r.extra["admm_iterations"], r.converged)


def peak_memory_mib(case, pushes):
    """Peak memory (MiB) of building the operators (fresh) and 5 ADMM iterations: numpy/scipy
    arrays traced by tracemalloc plus SuperLU's own factor storage (not traced)."""
    operators.OPERATOR_CACHE.clear()
    tracemalloc.start()
    admm.solve(case, pushes=pushes, polish=False, lift=False, load_steps=1, max_iter=5,
               tol_mm=1e-30)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    ops = admm.prepare(case.with_pushes(pushes))
    return peak / 2 ** 20, ops.lu.untracked_bytes / 2 ** 20


def accuracy():
    """Issue target: every probe within 0.05 mm, every vertex within 0.1 mm of the reference."""
    from tissue_reference.fem_reference import solve as fem_solve
    case = load_case(CASE)
    fem_solve(case, degree=1, pushes={"A1": 1.0})  # form compilation outside the timing
    pushes = {"A1": 15.0, "A2": 15.0, "A3": 15.0, "A4": 15.0}
    t = time.perf_counter()
    rf = fem_solve(case, degree=1, pushes=pushes)
    tf = time.perf_counter() - t
    t = time.perf_counter()
    try:
        rp = admm.solve(case, pushes=pushes, polish=False, tol_mm=1e-3, max_iter=5000)
    except SolverDivergedError as exc:
        print(f"[accuracy] plain ADMM (no Newton polish, tol_mm 1e-3, 5000 it per load step) "
              f"FAILED: {exc}", flush=True)
        rp = None
    tp = time.perf_counter() - t
    if rp is not None:
        _print_plain(rp, rf, tp)
    from tissue_reference.fem_reference import cholmod_factor
    t = time.perf_counter()
    ra = admm.solve(case, pushes=pushes, max_iter=200, factorize=cholmod_factor)
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
    ap.add_argument("--skip-fem", action="store_true")
    ap.add_argument("--skip-iteration", action="store_true")
    ap.add_argument("--rounds", type=int, default=5,
                    help="interleaved timing rounds of the scaling study (minimum kept)")
    ap.add_argument("--accuracy", action="store_true",
                    help="phantom.toml (size 6), all four actuators 15 mm: ADMM vs reference")
    a = ap.parse_args()
    pushes = {"A1": 2.0, "A2": 2.0, "A3": 2.0, "A4": 2.0}
    print(f"[machine] {_load()}", flush=True)

    # 1. one ADMM iteration at ~1.7k tets (phantom size 10)
    case10 = load_case(CASE, size=10.0)
    if not a.skip_iteration:
        t = time_per_iteration(case10, pushes)
        print(f"[iteration] phantom size 10: {case10.mesh.n_cells} tets, {t[0]:.3f} ms per "
              f"ADMM iteration (median {t[1]:.3f}), wall clock, min/median of 5 solves of 200 "
              f"iterations (target <= 0.5 ms; seed: 18.75 ms); {_load()}", flush=True)

    # 2. warm re-solve after a 0.5 mm increment, to 0.05 mm, vs reference Newton
    if not a.skip_fem:
        from tissue_reference.fem_reference import solve as fem_solve
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

    # 3. scaling: per-iteration time and peak memory against mesh size
    if a.sizes:
        scaling(a.sizes, pushes, a.rounds)


def scaling(sizes, pushes, rounds):
    """Time per steady ADMM iteration at each size, measured in ``rounds`` interleaved rounds
    (every size once per round; the minimum per size is kept, so that a slow spell of the shared
    machine does not bias one size against another), iterations and time per iteration of a
    solve from rest to SCALING_TOL, and peak memory; then the log-log growth exponents."""
    cases = []
    for s in sizes:
        t = time.perf_counter()
        case = load_case(CASE, mesh=phantom(s))
        tm = time.perf_counter() - t
        operators.OPERATOR_CACHE.clear()
        t = time.process_time()
        ops = admm.prepare(case.with_pushes(pushes))
        ts = time.process_time() - t
        stats = getattr(ops.lu.groups[0][0], "count", None) if hasattr(ops.lu, "groups") else None
        if stats is not None:
            stats[:] = [0, 0]
        w, c, its, conv = time_per_iteration_of_solve(case, pushes)
        pcg = f", {stats[1] / max(stats[0], 1):.1f} CG iterations per x-step" if stats else ""
        mem, lu_mib = peak_memory_mib(case, pushes)
        print(f"[scaling] size {s}: {case.mesh.n_cells} tets, {case.mesh.n_vertices} vertices, "
              f"x-step {ops.lu.kind}{pcg}; solve from rest: {its} iterations to {SCALING_TOL} mm "
              f"(converged {conv}), {c:.3f} ms/iteration CPU ({w:.3f} wall) with its start-up; "
              f"peak {mem:.1f} MiB numpy (tracemalloc) + {lu_mib:.1f} MiB SuperLU factors; setup "
              f"{ts:.2f} s CPU (mesh {tm:.1f} s); {_load()}", flush=True)
        cases.append((case, mem + lu_mib))
    steady = [[] for _ in cases]
    for r in range(rounds):
        for k, (case, _) in enumerate(cases):
            big = case.mesh.n_cells > 20000
            steady[k].append(time_per_iteration(case, pushes, 30 if big else 200, 1)[0])
        print(f"[scaling] round {r + 1}/{rounds}: ms/iteration "
              f"{[round(st[-1], 3) for st in steady]}; {_load()}", flush=True)
    rows = [(case.mesh.n_cells, min(st), float(np.median(st)), m)
            for (case, m), st in zip(cases, steady)]
    for row in rows:
        print("[scaling] table: tets {:7d}  ms/iteration {:9.3f} (median {:9.3f})  peak "
              "MiB {:8.1f}".format(*row))
    if len(rows) >= 2:
        n, w, wm, m = map(np.array, zip(*rows))
        kw = np.polyfit(np.log(n), np.log(w), 1)[0]
        kwm = np.polyfit(np.log(n), np.log(wm), 1)[0]
        km = np.polyfit(np.log(n), np.log(m), 1)[0]
        print(f"[scaling] growth exponent (least squares on log-log, steady iterations, wall "
              f"clock, one thread): time per iteration ~ n^{kw:.2f} from the minima of {rounds} "
              f"interleaved rounds (n^{kwm:.2f} from the medians) (target <= 1.1), peak memory "
              f"~ n^{km:.2f}")


if __name__ == "__main__":
    main()
