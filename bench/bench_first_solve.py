"""A newcomer's first solve, as they run it: ``tissue solve phantom --push A1=2`` from a folder of
their own, each run a fresh process (imports, meshing or the mesh cache, forms, solve, estimate,
outputs). Wall time of the command with an empty mesh cache, then with the cache filled; without
the estimate and report (``--no-estimate``), with the estimate (the default), and with the
report (``--out``); the solve's own wall time from its JSON. Then the report's two 3D views drawn
the way the report drew them before (one pyvista child process per view) and as it draws them
now (``tissue.views.start_views``: one child process for both, while the history is plotted),
with their ratio, measured in this run.

    .venv/bin/python bench/bench_first_solve.py [--push 2] [--rounds 3]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

TISSUE = Path(sys.executable).with_name("tissue")


def _run(args, cwd, env) -> tuple[float, dict]:
    t0 = time.perf_counter()
    p = subprocess.run([str(TISSUE), *args, "--json", "a.json", "-q"], cwd=cwd, env=env,
                       capture_output=True, text=True, check=False)
    wall = time.perf_counter() - t0
    if p.returncode not in (0, 1):
        raise SystemExit(f"tissue {' '.join(args)} failed: {p.stderr[-2000:]}")
    return wall, json.loads((Path(cwd) / "a.json").read_text())


def first_solves(push: float, rounds: int) -> None:
    base = ["solve", "phantom", "--push", f"A1={push:g}"]
    variants = [("solve only (--no-estimate)", ["--no-estimate"]),
                ("with the estimate (default)", []),
                ("with the estimate and the report (--out)", ["--out", "out"])]
    with tempfile.TemporaryDirectory() as home:
        env = {**os.environ, "TISSUE_MESH_CACHE": str(Path(home) / "meshes")}
        cold, _ = _run(base + ["--no-estimate"], home, env)
        print(f"first run, empty mesh cache, --no-estimate: {cold:6.2f} s wall")
        for label, extra in variants:
            walls, solves = [], []
            for _ in range(rounds):
                w, d = _run(base + extra, home, env)
                walls.append(w)
                solves.append(d["wall_time_s"])
            print(f"  {label:42s} {statistics.median(walls):6.2f} s wall (median of {rounds}); "
                  f"the solve itself {statistics.median(solves):5.2f} s")


def views(rounds: int) -> None:
    from tissue_reference.model.case import load_case
    from tissue_reference.tissue.views import render, start_views

    case = load_case("phantom")
    u = np.zeros((case.mesh.n_vertices, 3))
    u[:, 0] = -0.02 * np.clip(case.mesh.points[:, 0], 0, None)
    scalars = [np.linalg.norm(u, axis=1), case.mesh.points[:, 2]]
    before, now = [], []
    with tempfile.TemporaryDirectory() as d:
        for _ in range(rounds):
            t0 = time.perf_counter()
            for k, s in enumerate(scalars):
                render(case.mesh, u, s, Path(d) / f"a{k}.png", label=f"v{k}")
            before.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            start_views(case.mesh, u, [{"scalar": s, "path": Path(d) / f"b{k}.png",
                                        "label": f"v{k}"} for k, s in enumerate(scalars)]).wait()
            now.append(time.perf_counter() - t0)
    b, n = statistics.median(before), statistics.median(now)
    print(f"report's two 3D views: one child process per view {b:5.2f} s, one for both "
          f"{n:5.2f} s (x{b / n:.2f}), medians of {rounds}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--push", type=float, default=2.0)
    ap.add_argument("--rounds", type=int, default=3)
    a = ap.parse_args()
    first_solves(a.push, a.rounds)
    views(a.rounds)


if __name__ == "__main__":
    main()
