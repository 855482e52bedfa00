"""The Table I plant on phantom-seed's two ground-truth meshes, measured in one run (prints;
asserts nothing): meshes/cases/phantom-seed.toml (P2, 64,329 unknowns) against
meshes/cases/phantom-seed-coarse.toml (the same case on its refinement study's level -1, P2,
27,393 unknowns), each solving what a control loop's plant step solves: every head preloaded
(not timed), then warm-started steps of the pushes (timed, each from the last answer).

Per case and step: Newton iterations, factorizations, wall time; then the coarse case's ratio
against phantom-seed, and how far its targets and forces are from phantom-seed's (relative to
phantom-seed's: the two meshes' discretization difference, which each case's measured rows
bound from the study's finest level).

    .venv/bin/python bench/bench_seed_plant.py [--preload 3]
        [--step A1=3.5,A2=3.25 --step A1=4,A2=3.5 ...]
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CASES = ("phantom-seed", "phantom-seed-coarse")
STEPS = ("A1=3.5,A2=3.25", "A1=4,A2=3.5", "A1=4.5,A2=3.5,A3=3.2")


def pushes_of(text: str, names, preload: float) -> dict:
    """NAME=MM,NAME=MM over every actuator at ``preload``."""
    out = {n: preload for n in names}
    for part in text.split(","):
        name, mm = part.split("=")
        out[name.strip()] = float(mm)
    return out


def run(name: str, steps, preload: float) -> list[dict]:
    import tissue_reference.fem_reference as fr
    from tissue_reference.model.case import load_case

    case = load_case(ROOT / "meshes" / "cases" / f"{name}.toml")
    names = [a.name for a in case.actuators]
    solver = fr.ReferenceSolver(case)
    prev = solver.solve({n: preload for n in names})
    rows = []
    for text in steps:
        pushes = pushes_of(text, names, preload)
        t0 = time.perf_counter()
        res = solver.solve(pushes, initial=prev)
        rows.append({"step": text, "newton": res.iterations, "wall": time.perf_counter() - t0,
                     "factor": solver.timings.factorizations,
                     "dofs": res.discretization["dofs"],
                     "forces": {a: res.indenters[a]["force"] for a in names},
                     "probes": {n: np.asarray(u, float) for n, u in res.probes.items()}})
        print(f"  [{name}: {text}: {res.iterations} Newton iterations, "
              f"{rows[-1]['wall']:.1f} s]", flush=True)
        prev = res
    solver.close()
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--preload", type=float, default=3.0, help="every head's push first (mm)")
    ap.add_argument("--step", action="append", default=None,
                    help="NAME=MM,NAME=MM: one warm step's pushes (repeatable; the others at "
                         "the preload)")
    args = ap.parse_args()
    steps = args.step or list(STEPS)
    rows = {name: run(name, steps, args.preload) for name in CASES}
    fine, coarse = (rows[n] for n in CASES)
    print(f"{'case':>20} {'unknowns':>8} {'step':>22} {'newton':>6} {'factor':>6} {'wall_s':>7}")
    for name in CASES:
        for r in rows[name]:
            print(f"{name:>20} {r['dofs']:>8} {r['step']:>22} {r['newton']:>6} {r['factor']:>6} "
                  f"{r['wall']:>7.1f}")
    for f, c in zip(fine, coarse):
        dp = max(np.linalg.norm(c["probes"][n] - u) / np.linalg.norm(u)
                 for n, u in f["probes"].items())
        df = max(abs(c["forces"][a] / v - 1.0) for a, v in f["forces"].items() if v > 1.0)
        print(f"{f['step']}: coarse x{f['wall'] / c['wall']:.2f} wall time; worst target "
              f"{100 * dp:.2f} %, force {100 * df:.2f} % from phantom-seed's (heads > 1 mN)")
    total = sum(r["wall"] for r in fine), sum(r["wall"] for r in coarse)
    print(f"all steps: {total[0]:.1f} s against {total[1]:.1f} s: x{total[0] / total[1]:.2f}")


if __name__ == "__main__":
    main()
