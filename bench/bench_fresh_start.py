"""What a reference solve's fresh start costs and what it buys, in one run: a kept solver's
solve now factorizes its own first tangent instead of starting Newton from the factorization
the previous solve left (``LinearSolver.fresh``).

1. Cost: a control plant's sequence of warm re-solves (A1 from 0.5 to ``--to`` mm in 0.5 mm
   steps, each warm-started from the last answer) on the phantom at ``--size``, timed with the
   fresh start and with the earlier carried-over factorization (the fresh start switched off
   here, for comparison only); their answers compared.
2. What it buys: the marginal load of tests/test_same_input_same_answer.py (A1 = 80 mm on the
   glued phantom at size 10), solved first and after unrelated solves, under each behaviour.

    .venv/bin/python bench/bench_fresh_start.py [--size 6] [--to 5] [--repeat 3]
"""
from __future__ import annotations

import argparse
import time
import warnings
from contextlib import contextmanager
from pathlib import Path

import numpy as np

import tissue_reference.fem_reference as fr
from tissue_reference.errors import ConvergenceError, TissueWarning
from tissue_reference.fem_reference.kept import forget_solvers
from tissue_reference.fem_reference.linalg import LinearSolver
from tissue_reference.fem_reference.solver import ReferenceSolver
from tissue_reference.model.case import load_case

ROOT = Path(__file__).resolve().parents[1]
CASE = ROOT / "meshes" / "cases" / "phantom.toml"


@contextmanager
def carried_over():
    """The behaviour before the fresh start: a solve starts from whatever factorization and
    factor package its kept solver holds."""
    saved = LinearSolver.fresh
    LinearSolver.fresh = lambda self: None
    try:
        yield
    finally:
        LinearSolver.fresh = saved


def warm_sequence(case, to_mm: float):
    """(wall s, factorizations, final answer) of the warm re-solves A1 = 0.5, 1, ..., to_mm."""
    s = ReferenceSolver(case)
    res, facts = None, 0
    t0 = time.perf_counter()
    for p in np.arange(0.5, to_mm + 1e-9, 0.5):
        res = s.solve({"A1": float(p)}, initial=res)
        facts += res.extra["factorizations"]
    wall = time.perf_counter() - t0
    s.close()
    return wall, facts, res.u


def verdict(case, pushes):
    try:
        fr.solve(case, pushes=pushes)
        return "converged"
    except ConvergenceError as exc:
        return f"gave up at load fraction {exc.load_fraction:.4f}"


def main():
    # part 2 solves far past the loads where answers converge, on purpose: no warning per solve
    warnings.simplefilter("ignore", TissueWarning)
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", type=float, default=6.0)
    ap.add_argument("--to", type=float, default=5.0)
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()

    case = load_case(CASE, size=a.size)
    print(f"1. warm re-solves A1 = 0.5..{a.to:g} mm, phantom size {a.size:g} "
          f"({case.mesh.n_cells} tets), best of {a.repeat}")
    runs = {}
    for name in ("fresh start", "carried over"):
        best = None
        for _ in range(a.repeat):
            if name == "fresh start":
                r = warm_sequence(case, a.to)
            else:
                with carried_over():
                    r = warm_sequence(case, a.to)
            best = r if best is None or r[0] < best[0] else best
        runs[name] = best
        print(f"   {name:13s} {best[0]:7.3f} s, {best[1]:3d} factorizations")
    gap = float(np.abs(runs["fresh start"][2] - runs["carried over"][2]).max())
    print(f"   time fresh / carried over: {runs['fresh start'][0] / runs['carried over'][0]:.2f}; "
          f"answers {gap:.2e} mm apart")

    print("2. A1 = 80 mm on the glued phantom at size 10, first and after unrelated solves")
    small = load_case(CASE, size=10.0)
    for name in ("fresh start", "carried over"):
        ctx = carried_over() if name == "carried over" else contextmanager(lambda: (yield))()
        with ctx:
            forget_solvers()
            first = verdict(small, {"A1": 80.0})
            forget_solvers()
            for p in ({"A2": 10.0}, {"A3": 30.0}, {"A1": 60.0, "A3": 60.0}):
                verdict(small, p)
            after = verdict(small, {"A1": 80.0})
        same = "same" if first == after else "DIFFERENT"
        print(f"   {name:13s} first: {first}; after: {after} ({same})")


if __name__ == "__main__":
    main()
