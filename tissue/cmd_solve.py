"""``tissue solve CASE --solver fem|admm|mass-tensor [--degree 1|2] [--push A1=15 ...]``."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from meshes.errors import ConvergenceError
from meshes.io import check_output_file, write_point_data
from meshes.mesh import cell_jacobians
from meshes.results import write_json

from .common import (
    SOLVER_NAMES,
    add_case_args,
    add_discretization_args,
    case_from_args,
    check_outputs,
    check_prescribed,
    check_pushes,
    parse_pushes,
    report_validity,
    run_solver,
)

STEMS = ("displacement", "last_converged")


def _rank():
    try:
        from mpi4py import MPI

        return MPI.COMM_WORLD.rank
    except ImportError:  # pragma: no cover
        return 0


def write_outputs(case, res, out_dir=None, json_file=None, stem="displacement"):
    """Fields (XDMF + VTU: displacement, its magnitude, pressure for the mixed formulation, and
    per cell J = det F and ``inverted`` = 1 where J <= 0) and the JSON summary (with ``valid``
    and ``invalid_reason``); rank 0 writes, each file whole or not at all."""
    if _rank() != 0:
        return
    if out_dir:
        u = res.u
        fields = {"displacement": u, "displacement_magnitude": np.linalg.norm(u, axis=1)}
        if res.extra.get("pressure") is not None:  # mixed formulation, kPa
            fields["pressure"] = np.asarray(res.extra["pressure"], float)
        J = cell_jacobians(case.mesh.points, case.mesh.cells, u)
        write_point_data(case.mesh, out_dir, stem, fields,
                         cell_data={"J": J, "inverted": (~(J > 0)).astype(float)})
    if json_file:
        write_json(res.to_json_dict(case), json_file)


def run(args) -> int:
    check_outputs(args, files=("json",), dirs=("out",))
    if args.out and Path(args.out).is_dir():
        for stem in STEMS:
            for suffix in (".xdmf", ".h5", ".vtu"):
                check_output_file(Path(args.out) / f"{stem}{suffix}", "--out")
    pushes = parse_pushes(args.push)
    case = case_from_args(args)
    check_pushes(case, pushes)
    check_prescribed(case, pushes)
    try:
        res = run_solver(args.solver, case, degree=args.degree, formulation=args.formulation,
                         pushes=pushes, progress=not args.quiet)
    except ConvergenceError as exc:
        if exc.last_converged is not None:
            write_outputs(case.with_pushes(pushes), exc.last_converged, args.out, args.json,
                          stem="last_converged")
            if _rank() == 0 and args.out:
                print(f"tissue solve: last converged state (load fraction {exc.load_fraction:.4f})"
                      f" written to {Path(args.out) / 'last_converged.xdmf'}", file=sys.stderr)
        raise
    write_outputs(case, res, args.out, args.json)
    if _rank() == 0:
        print(f"{case.name}: {args.solver} converged={res.converged} "
              f"iterations={res.iterations} load_steps={res.load_steps} "
              f"time={res.wall_time_s:.2f}s vertices={res.n_vertices} cells={res.n_cells}")
        disc = res.extra.get("discretization")
        if disc:
            p = f"/P{disc['pressure_degree']}" if disc.get("pressure_degree") is not None else ""
            print(f"  discretization: {disc['formulation']} P{disc['degree']}{p}, "
                  f"{disc['dofs']} dofs")
        for k, v in res.probes.items():
            print(f"  probe {k}: u = [{', '.join(f'{x:+.4f}' for x in v)}] mm")
        for k, v in res.reactions.items():
            print(f"  reaction {k}: [{', '.join(f'{x:+.2f}' for x in v)}] mN")
        return report_validity("solve", res)
    return 0 if res.extra.get("valid", True) else 1


def add_parser(sub):
    p = sub.add_parser("solve", help="solve a case with the reference or a fast solver")
    add_case_args(p)
    p.add_argument("--solver", choices=SOLVER_NAMES, default="fem")
    add_discretization_args(p)
    p.add_argument("--push", action="append", metavar="NAME=MM",
                   help="push an actuator's region rigidly along its direction (repeatable)")
    p.add_argument("--out", help="folder for the displacement field (XDMF + VTU)")
    p.add_argument("--json", help="JSON summary file")
    p.add_argument("-q", "--quiet", action="store_true", help="no per-step progress")
    p.set_defaults(func=run)
