"""Mixed u-p (Taylor-Hood P2/P1) reference against a textbook dolfinx solve of the same
discretization: the same mesh (curved cells too), energy, boundary conditions and load steps,
solved with
dolfinx.fem.petsc.NonlinearProblem + dolfinx.nls.petsc.NewtonSolver + MUMPS LU (every Newton
iteration factorized), as the dolfinx demos do.

Prints, per mesh size: tets, dofs, both wall times (solve only; forms compiled beforehand), the
speed ratio, Newton iterations, peak memory and the largest probe difference (mm) between the two.

    .venv/bin/python bench/bench_mixed.py [--sizes 6 4] [--nu 0.49] [--push 10] [--np 2]

--np N runs each size under ``mpirun -n N`` (both solvers distributed; peak memory summed over
the ranks).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def textbook(case, push_mm: float, steps: int, qdeg: int, geometry_order: int):
    """The dolfinx-demo way: NonlinearProblem + NewtonSolver, MUMPS LU, equal load steps (as many
    as the reference took, doubled until Newton converges: only the converging run is timed)."""
    import dolfinx
    import dolfinx.fem.petsc
    import dolfinx.nls.petsc
    import ufl
    from mpi4py import MPI

    from tissue_reference.fem_reference.dolfinx_mesh import to_dolfinx

    dm = to_dolfinx(case.mesh, MPI.COMM_WORLD, geometry_order=geometry_order)
    mesh = dm.mesh
    cell = mesh.ufl_cell()
    W = dolfinx.fem.FunctionSpace(mesh, ufl.MixedElement([ufl.VectorElement("Lagrange", cell, 2),
                                                          ufl.FiniteElement("Lagrange", cell, 1)]))
    w = dolfinx.fem.Function(W)
    u, p = ufl.split(w)
    E, nu = case.material.E, case.material.nu
    mu, kappa = E / (2 * (1 + nu)), E / (3 * (1 - 2 * nu))
    F = ufl.Identity(3) + ufl.grad(u)
    J = ufl.det(F)
    psi = mu / 2 * (J ** (-2 / 3) * ufl.tr(F.T * F) - 3) - p * (J - 1) - p ** 2 / (2 * kappa)
    dx = ufl.dx(metadata={"quadrature_degree": qdeg})
    Pi = psi * dx
    R = ufl.derivative(Pi, w, ufl.TestFunction(W))
    K = ufl.derivative(R, w, ufl.TrialFunction(W))
    V, _ = W.sub(0).collapse()
    tdim = mesh.topology.dim
    ft = dm.facet_tags
    bcs, moving = [], []
    for region, value in [("base", (0.0, 0.0, 0.0)),
                          (case.actuator("A1").region, tuple(case.actuator("A1").direction))]:
        facets = ft.indices[ft.values == dm.region_tags[region]]
        dofs = dolfinx.fem.locate_dofs_topological((W.sub(0), V), tdim - 1, facets)
        g = dolfinx.fem.Function(V)
        bcs.append(dolfinx.fem.dirichletbc(g, dofs, W.sub(0)))
        moving.append((g, np.asarray(value, float)))
    while True:  # equal load steps; twice as many when Newton fails (timed: the last run only)
        its = 0
        w.x.array[:] = 0.0
        problem = dolfinx.fem.petsc.NonlinearProblem(R, w, bcs=bcs, J=K)
        solver = dolfinx.nls.petsc.NewtonSolver(MPI.COMM_WORLD, problem)
        solver.rtol, solver.atol, solver.max_it = 1e-10, 1e-10, 50
        ksp = solver.krylov_solver
        ksp.setType("preonly")
        ksp.getPC().setType("lu")
        ksp.getPC().setFactorSolverType("mumps")
        t0 = time.perf_counter()
        try:
            for k in range(1, steps + 1):
                for g, direction in moving:
                    val = push_mm * k / steps * direction
                    g.interpolate(lambda x, val=val: np.tile(val[:, None], (1, x.shape[1])))
                n, _ = solver.solve(w)
                its += n
            wall = time.perf_counter() - t0
            break
        except RuntimeError:
            if steps >= 64:
                raise
            steps *= 2
    uh = w.sub(0).collapse()
    probes = {}
    tree = dolfinx.geometry.BoundingBoxTree(mesh, tdim)
    for pr in case.probes:
        x = np.asarray(pr.point, float)[None, :]
        cells = dolfinx.geometry.compute_colliding_cells(
            mesh, dolfinx.geometry.compute_collisions(tree, x), x).links(0)
        probes[pr.name] = uh.eval(x, cells[:1]).tolist()
    return wall, its, steps, probes


def rebuilt_every_iteration(case, push: float) -> float:
    """Wall time (s) of the same fieldsplit solve with the preconditioner rebuilt at every
    Newton iteration (``saddle.LAG`` off)."""
    import tissue_reference.fem_reference as fr
    from tissue_reference.fem_reference import saddle

    saddle.LAG = False
    try:
        s = fr.ReferenceSolver(case, formulation="mixed", linear_solver="fieldsplit")
        return s.solve({"A1": push}).wall_time_s
    finally:
        saddle.LAG = True


def one(size: float, nu: float, push: float, peer: bool = True, lag: bool = False) -> dict:
    sys.path.insert(0, str(ROOT))
    import tissue_reference.fem_reference as fr
    from tissue_reference.model.case import load_case

    t0 = time.perf_counter()
    case = load_case(ROOT / "meshes/cases/phantom.toml", size=size).with_material(nu=nu)
    t_mesh = time.perf_counter() - t0
    t0 = time.perf_counter()
    solver = fr.ReferenceSolver(case, formulation="mixed",
                                **({"linear_solver": "fieldsplit"} if lag else {}))
    t_setup = time.perf_counter() - t0
    res = solver.solve({"A1": push})
    from mpi4py import MPI

    peak_ours = MPI.COMM_WORLD.allreduce(
        resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024 ** 2, op=MPI.SUM)
    steps = max(res.load_steps, math.ceil(push / solver.settings.max_step_mm))
    if peer:
        wall_tb, its_tb, steps, probes_tb = textbook(case.with_pushes({"A1": push}), push, steps,
                                                     solver.qdeg, solver.geometry_order)
        diff = max(float(np.abs(np.asarray(res.probes[k]) - v).max())
                   for k, v in probes_tb.items())
    else:
        wall_tb, its_tb, steps, diff = float("nan"), 0, 0, float("nan")
    return {"size": size, "tets": case.mesh.n_cells, "dofs": res.extra["n_dofs"],
            "ours_s": res.wall_time_s, "ours_newton": res.iterations,
            "ours_steps": res.load_steps, "factorizations": res.extra["factorizations"],
            "textbook_s": wall_tb, "textbook_newton": its_tb, "textbook_steps": steps,
            "ratio": wall_tb / res.wall_time_s, "probe_diff_mm": diff, "peak_gib": peak_ours,
            "mesh_s": t_mesh, "setup_s": t_setup, "ranks": MPI.COMM_WORLD.size,
            "preconditioner_builds": res.extra.get("preconditioner_builds", 0),
            "linear_solver": res.extra.get("linear_solver"),
            "T1_mm": np.asarray(res.probes["T1"]).tolist(),
            "rebuilt_s": rebuilt_every_iteration(case, push) if lag else None}


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--sizes", type=float, nargs="+", default=[6.0, 4.0])
    ap.add_argument("--nu", type=float, default=0.49)
    ap.add_argument("--push", type=float, default=10.0, help="A1 push, mm")
    ap.add_argument("--no-peer", action="store_true",
                    help="skip the textbook solve (large meshes: time and memory of ours only)")
    ap.add_argument("--np", type=int, default=1, help="MPI ranks per solve (mpirun -n NP)")
    ap.add_argument("--lag", action="store_true",
                    help="fieldsplit solver at every size, and the same solve with its "
                         "preconditioner rebuilt at every Newton iteration (the ratio)")
    ap.add_argument("--one", type=float, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one is not None:
        from mpi4py import MPI

        out = one(args.one, args.nu, args.push, not args.no_peer, args.lag)
        if MPI.COMM_WORLD.rank == 0:
            print(json.dumps(out))
        return
    launch = []
    if args.np > 1:
        launch = ["mpirun", "-n", str(args.np)] + \
            (["--allow-run-as-root"] if os.geteuid() == 0 else [])
    print(f"phantom, A1 = {args.push} mm, nu = {args.nu}, mixed P2/P1 (ours vs textbook dolfinx), "
          f"{args.np} MPI rank(s)")
    print(f"{'size':>5} {'tets':>7} {'dofs':>8} {'ours_s':>7} {'newton':>6} {'factor':>6} "
          f"{'textbook_s':>10} {'steps':>5} {'newton':>6} {'ratio':>6} {'probe_diff_mm':>13} {'peak_GiB':>8}")
    for size in args.sizes:
        argv = [sys.executable, __file__, "--one", str(size), "--nu", str(args.nu),
                "--push", str(args.push)] + (["--no-peer"] if args.no_peer else []) \
            + (["--lag"] if args.lag else [])
        out = subprocess.run(launch + argv, capture_output=True, text=True, check=False)
        if out.returncode:
            print(f"{size:5g} failed: {out.stderr.strip().splitlines()[-1:]}")
            continue
        r = json.loads(out.stdout.strip().splitlines()[-1])
        print(f"{r['size']:5g} {r['tets']:7d} {r['dofs']:8d} {r['ours_s']:7.2f} "
              f"{r['ours_newton']:6d} {r['factorizations']:6d} {r['textbook_s']:10.2f} "
              f"{r['textbook_steps']:5d} "
              f"{r['textbook_newton']:6d} {r['ratio']:6.2f} {r['probe_diff_mm']:13.2e} "
              f"{r['peak_gib']:8.2f}  ({r['linear_solver']}, preconditioner builds "
              f"{r['preconditioner_builds']})", flush=True)
        if r.get("rebuilt_s"):
            print(f"      rebuilt at every Newton iteration: {r['rebuilt_s']:.2f} s; lagged "
                  f"{r['ours_s']:.2f} s: {r['rebuilt_s'] / r['ours_s']:.2f}x faster", flush=True)


if __name__ == "__main__":
    main()
