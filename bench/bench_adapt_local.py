"""Local against uniform refinement in ``solve_to_accuracy`` (fem_reference.adapt), in one run.

The phantom case (meshes/cases/phantom.toml, glued actuator patches, curved dome) is solved to a
requested relative accuracy of every probe (default 1 %) with ``refine="local"`` (energy
indicators, Doerfler marking, longest-edge bisection) and ``refine="uniform"`` under the same
``max_dofs``, for each push set. For each run: the levels (cells, answer and estimate dofs,
worst probe's estimated relative error, seconds), whether the accuracy was reached, and why not;
then the ratios local / uniform of the largest system solved, of the wall time and of the worst
estimate reached, measured in this run.

    .venv/bin/python bench/bench_adapt_local.py                       # A1 = 5 mm and A1 = 3 mm
    .venv/bin/python bench/bench_adapt_local.py --pushes A1=5 --pushes A1=5,A2=5,A3=5,A4=5
    .venv/bin/python bench/bench_adapt_local.py --accuracy 0.02 --max-dofs 300000 --only local

Units: mm. Serial; a few minutes per run on two cores (the degree-3 estimates dominate).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tissue_reference.errors import ConvergenceError
from tissue_reference.fem_reference.adapt import AccuracyNotReached, solve_to_accuracy
from tissue_reference.fem_reference.dof_counts import entity_counts, predicted_dofs, refined_counts

CASE = ROOT / "meshes/cases/phantom.toml"


def parse(text: str) -> dict:
    return {k: float(v) for k, v in (kv.split("=") for kv in text.split(","))}


def run(pushes: dict, refine: str, accuracy: float, max_dofs: int) -> dict:
    t0 = time.perf_counter()
    why, done = "", None
    try:
        done = solve_to_accuracy(str(CASE), pushes, accuracy=accuracy, max_dofs=max_dofs,
                                 refine=refine, progress=True)
    except AccuracyNotReached as exc:
        done, why = exc.result, str(exc)
    except ConvergenceError as exc:
        why = f"ConvergenceError: {exc}"
    wall = time.perf_counter() - t0
    steps = done.steps if done is not None else ()
    out = {"refine": refine, "reached": bool(done is not None and done.reached), "wall_s": wall,
           "why": why, "steps": steps}
    if refine == "uniform" and done is not None and not out["reached"]:
        mesh = done.case.mesh       # what the next uniform level's estimate would need
        out["next_uniform"] = predicted_dofs(refined_counts(entity_counts(mesh), mesh.gdim),
                                             mesh.gdim, 3, "displacement")
    if steps:
        last = steps[-1]
        name, ratio = last.worst
        out.update(levels=last.level, dofs=last.dofs, estimate_dofs=last.estimate_dofs,
                   largest=max(s.estimate_dofs for s in steps), worst=(name, ratio * accuracy),
                   probes={k: v for k, v in done.result.probes.items()})
    return out


def report(label: str, r: dict, accuracy: float) -> None:
    print(f"\n{label}, refine={r['refine']}: {'REACHED' if r['reached'] else 'not reached'} "
          f"in {r['wall_s']:.0f} s")
    print(f"  {'level':>5} {'deg':>3} {'cells':>8} {'dofs':>8} {'est.dofs':>9} "
          f"{'worst %':>8} {'s':>6}")
    for s in r["steps"]:
        name, ratio = s.worst
        print(f"  {s.level:5d} {s.degree:3d} {s.cells:8,d} {s.dofs:8,d} {s.estimate_dofs:9,d} "
              f"{100 * ratio * accuracy:8.2f} {s.wall_time_s:6.0f}   ({name})")
    if r.get("probes"):
        print("  answer: " + ", ".join(f"{k} |u| {np.linalg.norm(v):.4f} mm"
                                       for k, v in r["probes"].items()))
    if r["why"]:
        print(f"  stopped: {r['why']}")
    if r.get("next_uniform"):
        print(f"  the next uniform level's degree-3 estimate would have {r['next_uniform']:,} "
              f"dofs")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pushes", action="append", metavar="A1=5,...",
                    help="push set (repeatable); default A1=5 and A1=3")
    ap.add_argument("--accuracy", type=float, default=0.01)
    ap.add_argument("--max-dofs", type=int, default=500_000)
    ap.add_argument("--only", choices=("local", "uniform"), default=None)
    args = ap.parse_args(argv)
    sets = args.pushes or ["A1=5", "A1=3"]
    modes = [args.only] if args.only else ["local", "uniform"]
    results = {}
    for text in sets:
        for mode in modes:
            print(f"\n=== {text}, refine={mode}, accuracy {args.accuracy:g}, max_dofs "
                  f"{args.max_dofs:,}", file=sys.stderr, flush=True)
            results[(text, mode)] = run(parse(text), mode, args.accuracy, args.max_dofs)
            report(text, results[(text, mode)], args.accuracy)
    if len(modes) == 2:
        print("\nratios local / uniform (this run):")
        for text in sets:
            loc, uni = results[(text, "local")], results[(text, "uniform")]
            if "largest" not in loc or "largest" not in uni:
                print(f"  {text}: a run has no step")
                continue
            print(f"  {text}: largest system {loc['largest'] / uni['largest']:.2f} "
                  f"({loc['largest']:,} / {uni['largest']:,}), wall time "
                  f"{loc['wall_s'] / uni['wall_s']:.2f} ({loc['wall_s']:.0f} s / "
                  f"{uni['wall_s']:.0f} s), worst estimate {loc['worst'][1] / uni['worst'][1]:.2f} "
                  f"({100 * loc['worst'][1]:.2f} % / {100 * uni['worst'][1]:.2f} %), reached "
                  f"{loc['reached']} / {uni['reached']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
