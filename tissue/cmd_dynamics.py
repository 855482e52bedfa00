"""``tissue dynamics CASE --dt S --steps N [--solver fem|admm] [--push A1=15 ...]``:
implicit-Euler dynamics (seed 000 eq. 5) with the reference (``fem_reference.dynamics``) or the
ADMM's dynamic mode (``solvers.admm.ImplicitEuler``), same lumped mass and time step."""
from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np

from tissue_reference.errors import CaseError, ConvergenceError
from tissue_reference.meshes.io import atomic_path, check_output_file, write_mesh
from tissue_reference.model.results import material_json, write_json
from tissue_reference.solvers.registry import dynamics_names, reference, solver

from .common import (
    add_case_args,
    add_discretization_args,
    case_from_args,
    check_outputs,
    check_prescribed,
    check_pushes,
    integer,
    parse_pushes,
    real,
    report_validity,
)
from .dynamics_report import write_dynamics_report
from .solve_outputs import solver_settings, write_outputs

STEMS = ("displacement", "last_converged", "trajectory")
# the page and its pictures (tissue.dynamics_report)
PAGE_FILES = ("report.html", "dynamics_history.png", "final_view_u.png")
MAX_STEPS = 100_000


def _write_trajectory(case, traj, out_dir):
    """DIR/trajectory_NNNNN.vtu per step (displacement, velocity) and DIR/trajectory.pvd, the
    ParaView collection with their times (s); each file whole or not at all."""
    out_dir = Path(out_dir)
    entries = []
    for k, t in enumerate(traj.times):
        name = f"trajectory_{k:05d}.vtu"
        write_mesh(case.mesh, out_dir / name,
                   point_data={"displacement": traj.u[k], "velocity": traj.velocity[k]})
        entries.append(f'    <DataSet timestep="{t:.9g}" part="0" file="{name}"/>')
    text = ('<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1">\n  <Collection>\n'
            + "\n".join(entries) + "\n  </Collection>\n</VTKFile>\n")
    with atomic_path(out_dir / "trajectory.pvd") as tmp:
        tmp.write_text(text)


def trajectory_json(case, traj, args) -> dict:
    """The JSON summary: the trajectory (``DynamicsResult.to_json_dict``) with what was solved:
    the pushes (mm), the material, gravity (mm/s^2), the discretization (reference) and the
    solver settings; ``final`` is the last step's summary with the Case's material and pushes."""

    d = traj.to_json_dict()
    if traj.final is not None:
        d["final"] = traj.final.to_json_dict(case)
    d.update({"source": case.source,
              "pushes_mm": {a.name: float(a.push) for a in case.actuators},
              "material": material_json(case.material),
              "gravity_mm_s2": list(map(float, case.gravity)) if case.gravity is not None
              else None})
    if solver(args.solver).reference:
        disc = (traj.final.discretization if traj.final is not None else None)
        if disc is not None:
            d["discretization"] = disc
        d["solver_settings"] = solver_settings(args.solver, mass=args.mass,
                                               ramp_steps=args.ramp_steps)
    else:
        d["solver_settings"] = solver_settings(args.solver)
    return d


def run(args) -> int:
    check_outputs(args, files=("json",), dirs=("out",))
    if args.out and Path(args.out).is_dir():
        for stem in STEMS:
            for suffix in (".xdmf", ".h5", ".vtu", ".pvd"):
                check_output_file(Path(args.out) / f"{stem}{suffix}", "--out")
        for name in PAGE_FILES:
            check_output_file(Path(args.out) / name, "--out")
    entry = solver(args.solver)
    entry.check_dynamics(args.degree, args.formulation, args.mass, args.ramp_steps)
    pushes = parse_pushes(args.push)
    case = case_from_args(args)
    if args.gravity is not None:
        if len(args.gravity) != case.mesh.gdim:
            raise CaseError(f"--gravity expects {case.mesh.gdim} components (mm/s^2) for this "
                            f"{case.mesh.gdim}D mesh, got {len(args.gravity)}")
        case = dataclasses.replace(case, gravity=tuple(args.gravity))
    check_pushes(case, pushes)
    check_prescribed(case, pushes)
    progress = not args.quiet
    try:
        traj = entry.simulate(case, dt=args.dt, steps=args.steps, pushes=pushes,
                              degree=args.degree, formulation=args.formulation, mass=args.mass,
                              ramp_steps=args.ramp_steps, progress=progress)
    except ConvergenceError as exc:
        if exc.last_converged is not None:
            write_outputs(case.with_pushes(pushes), exc.last_converged, args.out, None,
                          stem="last_converged")
            if args.out:
                print(f"tissue dynamics: last converged state written to "
                      f"{Path(args.out) / 'last_converged.xdmf'}", file=sys.stderr)
        raise
    pushed = case.with_pushes(pushes)
    data = trajectory_json(pushed, traj, args)
    if args.out:
        write_outputs(pushed, traj.final, args.out, None)
        _write_trajectory(pushed, traj, args.out)
        write_dynamics_report(pushed, data, traj.u[-1], args.out)
    if args.json:
        write_json(data, args.json)
    print(f"{case.name}: {args.solver} dynamics dt={traj.dt:g}s steps={traj.steps} "
          f"converged={bool(traj.converged.all())} time={traj.wall_time_s:.2f}s "
          f"vertices={case.mesh.n_vertices} mass={traj.total_mass_kg:.4g}kg")
    umax = np.sqrt((traj.u ** 2).sum(axis=2).max(axis=1))
    k = int(np.argmax(umax))
    print(f"  max |u| {umax[k]:.4f} mm at t = {traj.times[k]:.4g} s; final kinetic energy "
          f"{traj.kinetic_energy[-1]:.4e} uJ, strain energy {traj.strain_energy[-1]:.4e} uJ")
    for name, p in traj.probes.items():
        print(f"  probe {name} at t = {traj.times[-1]:.4g} s: u = "
              f"[{', '.join(f'{x:+.4f}' for x in p[-1])}] mm")
    return report_validity("dynamics", traj.final, "the final state")


def add_parser(sub):
    p = sub.add_parser("dynamics", help="implicit-Euler dynamics (reference or ADMM)")
    add_case_args(p)
    p.add_argument("--dt", type=real("positive", "s"), required=True, help="time step (s)")
    p.add_argument("--steps", type=integer(1, MAX_STEPS), required=True,
                   help="number of time steps")
    p.add_argument("--solver", choices=dynamics_names(), default=reference().name,
                   help="the reference or ADMM (same lumped mass)")
    add_discretization_args(p)
    p.add_argument("--mass", choices=("lumped", "consistent"), default="lumped",
                   help="reference mass: lumped (P1 vertex mass, the ADMM's) or consistent")
    p.add_argument("--ramp-steps", type=integer(0, MAX_STEPS), default=0, metavar="K",
                   help="reference: move the Dirichlet values linearly over the first K steps "
                        "(default 0: in full from the first step)")
    p.add_argument("--gravity", type=real("finite", "mm/s^2", magnitude=1e9), nargs="+",
                   metavar="G", help="override the case's gravity (mm/s^2), e.g. 0 0 -9810")
    p.add_argument("--push", action="append", metavar="NAME=MM",
                   help="push an actuator's region rigidly along its direction (repeatable)")
    p.add_argument("--out", help="folder: final state (XDMF + VTU), the trajectory "
                                 "(trajectory.pvd + one VTU per step) and report.html (settings, "
                                 "probes against time, the final state in 3D)")
    p.add_argument("--json", help="JSON summary: times, probes, energies per step")
    p.add_argument("-q", "--quiet", action="store_true", help="no per-step progress")
    p.set_defaults(func=run)
