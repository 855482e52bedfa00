"""Reference solver scaling on the phantom, all four actuators pushed 15 mm (speed and memory figures).

Each size runs in its own process so that peak memory (ru_maxrss) is that size's own.
Prints tets, dofs, load steps, Newton iterations, the linear solver chosen ("auto": MUMPS every
iteration below 20k dofs, lagged MUMPS + GMRES above), its factorizations and Krylov iterations,
solve seconds, peak memory, and the growth exponent of time against dofs (log-log fit). Usage:

    .venv/bin/python bench/bench_reference.py [--sizes 5 3.5 2.75 2.2] [--degree 1]
"""
from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PUSH = {"A1": 15.0, "A2": 15.0, "A3": 15.0, "A4": 15.0}


def one(size: float, degree: int) -> dict:
    sys.path.insert(0, str(ROOT))
    import tissue_reference.fem_reference as fr
    from tissue_reference.model.case import load_case

    t0 = time.perf_counter()
    case = load_case(ROOT / "meshes/cases/phantom.toml", size=size)
    t_mesh = time.perf_counter() - t0
    t0 = time.perf_counter()
    solver = fr.ReferenceSolver(case, degree=degree)
    t_setup = time.perf_counter() - t0
    res = solver.solve(PUSH)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024 ** 2  # GiB (ru_maxrss in KiB)
    return {"size": size, "tets": case.mesh.n_cells, "dofs": res.extra["n_dofs"],
            "converged": res.converged, "load_steps": res.load_steps, "newton": res.iterations,
            "solve_s": res.wall_time_s, "setup_s": t_setup, "mesh_s": t_mesh, "peak_gib": peak,
            "T1_mm": np.asarray(res.probes["T1"]).tolist(), "linear": res.extra["linear_solver"],
            "factorizations": res.extra["factorizations"],
            "krylov": res.extra["krylov_iterations"], "assemble_s": res.extra["assemble_s"],
            "linear_s": res.extra["linear_solve_s"]}


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--sizes", type=float, nargs="+", default=[5.0, 3.5, 2.75, 2.2])
    ap.add_argument("--degree", type=int, default=1)
    ap.add_argument("--one", type=float, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one is not None:
        print(json.dumps(one(args.one, args.degree)))
        return
    rows = []
    print(f"{'size':>6} {'tets':>8} {'dofs':>8} {'conv':>5} {'steps':>5} {'newton':>6} "
          f"{'linear':>7} {'factor':>6} {'krylov':>6} {'solve_s':>8} {'(asm':>6} {'lin)':>6} "
          f"{'setup_s':>8} {'mesh_s':>7} {'peak_GiB':>8}", flush=True)
    for s in args.sizes:
        out = subprocess.run([sys.executable, __file__, "--one", str(s), "--degree",
                              str(args.degree)], capture_output=True, text=True, check=True)
        r = json.loads(out.stdout.strip().splitlines()[-1])
        rows.append(r)
        print(f"{r['size']:6.2f} {r['tets']:8d} {r['dofs']:8d} {r['converged']!s:>5} "
              f"{r['load_steps']:5d} {r['newton']:6d} {r['linear']:>7} {r['factorizations']:6d} "
              f"{r['krylov']:6d} {r['solve_s']:8.2f} {r['assemble_s']:6.1f} {r['linear_s']:6.1f} "
              f"{r['setup_s']:8.2f} "
              f"{r['mesh_s']:7.2f} {r['peak_gib']:8.2f}", flush=True)
    dofs = np.array([r["dofs"] for r in rows], float)
    t = np.array([r["solve_s"] for r in rows])
    if len(rows) >= 2:
        k = np.polyfit(np.log(dofs), np.log(t), 1)[0]
        print(f"growth exponent of solve time against dofs: {k:.2f}")
    big = max(rows, key=lambda r: r["tets"])
    print(f"largest: {big['tets']} tets, solve {big['solve_s']:.1f} s (target <= 60 s: "
          f"{'met' if big['solve_s'] <= 60 else 'NOT met'}), peak {big['peak_gib']:.2f} GiB "
          f"(target < 8 GiB: {'met' if big['peak_gib'] < 8 else 'NOT met'})")


if __name__ == "__main__":
    main()
