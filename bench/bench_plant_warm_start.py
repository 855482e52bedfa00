"""A control loop's reference plant warm-started from its previous answer's full state (edge
nodes, pressure) against the vertex values alone, measured in one run (prints; asserts nothing).

The loop: the Table I analog's ``nu`` scenario on the phantom (size 10): the plant is the
reference's mixed P2/P1 formulation at nu = 0.495, the model ADMM at the case's nu; T1, task 1
moved by --task-mm (0.3 mm keeps the glued patches' pushes below 5 mm), --steps closed-loop
steps (no open-loop baseline). Per variant: Newton iterations over the plant solves, the plant's
wall time, the final target error; the two loops must end at the same pushes.

    .venv/bin/python bench/bench_plant_warm_start.py [--steps 30] [--task-mm 0.3]
"""
from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def run(full: bool, steps: int, task_mm: float):
    import tissue_reference.fem_reference as fr
    from tissue_reference.control.loop import LoopSettings
    from tissue_reference.control.plants import full_warm_start
    from tissue_reference.control.scenarios import scenario_loop
    from tissue_reference.fem_reference.kept import forget_solvers
    from tissue_reference.meshes.builders import build
    from tissue_reference.model.case import load_case

    case = load_case(ROOT / "meshes" / "cases" / "phantom.toml")
    case = dataclasses.replace(case, mesh=build("phantom", 10.0))
    loop = scenario_loop(case, "nu")
    forget_solvers()          # each variant compiles and factorizes for itself
    tally = {"newton": 0, "solves": 0, "wall_s": 0.0}

    def vertex_plant(c, pushes, initial):   # what a loop got before: the vertex field
        return fr.solve(c, pushes=pushes, initial=initial)

    inner = full_warm_start(vertex_plant) if full else vertex_plant

    def plant(c, pushes, initial):
        t0 = time.perf_counter()
        r = inner(c, pushes, initial)
        tally["wall_s"] += time.perf_counter() - t0
        tally["newton"] += r.iterations
        tally["solves"] += 1
        return r

    loop.plant = plant
    res = loop.run("T1", 1, LoopSettings(steps=steps, task_mm=task_mm, open_loop=False))
    return tally, res


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=30)
    ap.add_argument("--task-mm", type=float, default=0.3)
    args = ap.parse_args()
    out = {}
    for name, full in (("vertex values", False), ("full state", True)):
        tally, res = run(full, args.steps, args.task_mm)
        out[name] = (tally, res)
        print(f"{name:>13}: {tally['solves']} plant solves, {tally['newton']} Newton iterations, "
              f"plant {tally['wall_s']:.1f} s, final error {res.error_mm[-1]:.4g} mm, "
              f"pushes {np.round(res.pushes[-1], 4).tolist()} mm", flush=True)
    (tv, rv), (tf, rf) = out["vertex values"], out["full state"]
    print(f"full state vs vertex values: {tv['newton'] / tf['newton']:.2f}x fewer Newton "
          f"iterations, {tv['wall_s'] / tf['wall_s']:.2f}x less plant time; final pushes differ "
          f"by {np.abs(rv.pushes[-1] - rf.pushes[-1]).max():.2e} mm")


if __name__ == "__main__":
    main()
