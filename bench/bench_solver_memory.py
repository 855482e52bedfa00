"""Memory of reference solvers built and dropped one after another in one process, as a
convergence study, the adaptive loop or a test suite does: the resident set after each solve
when every solver is closed (``ReferenceSolver.close``, ``with ... as s``) and when each is only
dropped (its Python objects gone, collected), in one run, closed first.

petsc4py queues a dropped PETSc object of a parallel communicator until
``PETSc.garbage_cleanup`` runs on that communicator (``fem_reference.petsc_memory``), so a dropped
solver's tangent and MUMPS factor stay resident until the process ends.

    .venv/bin/python bench/bench_solver_memory.py [--degree 3] [--solves 4] [--push 2]
"""
from __future__ import annotations

import argparse
import ctypes
import gc
import time
from pathlib import Path

import tissue_reference.fem_reference as fr
from tissue_reference.model.case import load_case

ROOT = Path(__file__).resolve().parents[1]
_LIBC = ctypes.CDLL("libc.so.6")


def resident_mib() -> float:
    """This process's resident set (MiB) after handing freed heap back to the system."""
    _LIBC.malloc_trim(0)
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS"):
                return int(line.split()[1]) / 1024
    raise RuntimeError("no VmRSS in /proc/self/status")


def series(case, degree: int, solves: int, push: float, close: bool) -> list:
    rows = []
    for _ in range(solves):
        t0 = time.perf_counter()
        s = fr.ReferenceSolver(case, degree=degree)
        res = s.solve({"A1": push})
        dofs = int(res.extra["n_dofs"])
        if close:
            s.close()
        del s, res
        gc.collect()
        rows.append((resident_mib(), dofs, time.perf_counter() - t0))
    return rows


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--degree", type=int, default=3)
    ap.add_argument("--solves", type=int, default=4)
    ap.add_argument("--push", type=float, default=2.0, help="A1's push (mm)")
    args = ap.parse_args(argv)
    case = load_case(ROOT / "meshes" / "cases" / "phantom.toml")
    base = resident_mib()
    growth = {}
    for close in (True, False):
        rows = series(case, args.degree, args.solves, args.push, close)
        name = "closed" if close else "dropped"
        print(f"{name}: P{args.degree}, {rows[0][1]:,} dofs, A1 = {args.push:g} mm")
        for k, (mib, _, wall) in enumerate(rows):
            print(f"  solve {k + 1}: resident {mib:7.0f} MiB  ({wall:.1f} s)")
        growth[name] = (rows[-1][0] - rows[0][0]) / max(len(rows) - 1, 1)
        print(f"  growth per solve after the first: {growth[name]:.0f} MiB")
    print(f"before the first solve: {base:.0f} MiB")
    print(f"dropped / closed growth per solve: {growth['dropped']:.0f} / "
          f"{growth['closed']:.0f} MiB")


if __name__ == "__main__":
    main()
