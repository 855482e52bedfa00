"""``tissue jacobian CASE [--state-push A1=5.0 ...] [--solver fem|admm] [--degree 1|2] --json FILE``

The Dirichlet sensitivity of the targets to rigid actuator pushes (control/jacobian.py) at the state
``--state-push`` (every actuator held; unnamed ones at 0 mm), from the solver's exact tangent, checked
against central finite differences of the same solver's nonlinear solve (``--fd-h`` mm; 0 skips).
"""
from __future__ import annotations

import numpy as np

from meshes.errors import CaseError
from meshes.results import write_json

from .common import add_case_args, case_from_args, parse_pushes


def plant_for(name: str, *, degree: int = 1, tight: bool = True):
    """plant(case, pushes, initial_u) -> SolveResult for solver ``name`` (fem | admm)."""
    if name == "fem":
        from fem_reference import solve

        return lambda case, pushes, initial: solve(case, degree=degree, pushes=pushes,
                                                   initial=initial)
    if name == "admm":
        from solvers.admm import solve

        kw = {"tol_mm": 1e-6} if tight else {}
        return lambda case, pushes, initial: solve(case, pushes=pushes, initial=initial, **kw)
    raise CaseError(f"unknown plant/model solver {name!r}; choose fem or admm")


def tangent_for(name: str):
    """tangent(case, u) -> CSR K (P1, node-major, Case numbering) for solver ``name``."""
    if name == "fem":
        from fem_reference import tangent_stiffness

        return lambda case, u: tangent_stiffness(case, u).K
    if name == "admm":
        from solvers.admm import tangent_stiffness

        return lambda case, u: tangent_stiffness(case, u)
    raise CaseError(f"unknown plant/model solver {name!r}; choose fem or admm")


def compute(case, state_pushes, *, solver="fem", degree=1, fd_h=0.02):
    from control.jacobian import (dirichlet_jacobian, fd_jacobian, full_pushes, max_rel_error,
                                  p2_interpolation, p2_region_nodes)

    if degree not in (1, 2):
        raise CaseError(f"--degree must be 1 or 2, got {degree}")
    if degree == 2 and solver != "fem":
        raise CaseError("--degree 2 needs --solver fem")
    plant = plant_for(solver, degree=degree)
    st = full_pushes(case, state_pushes)
    res = plant(case, st, None)
    if not res.converged:
        raise CaseError(f"the state solve at pushes {st} did not converge")
    pushed = case.with_pushes(st)
    if solver == "fem":
        from fem_reference import tangent_stiffness

        T = tangent_stiffness(pushed, res.u, degree=degree, pushes=st)
        K = T.K
        if degree == 2:
            P = p2_interpolation(case, T.node_points)
            jac = dirichlet_jacobian(pushed, K, P=P, region_nodes=p2_region_nodes(case,
                                                                                T.node_points))
        else:
            jac = dirichlet_jacobian(pushed, K)
    else:
        jac = dirichlet_jacobian(pushed, tangent_for(solver)(pushed, res.u))
    out = {"actuators": list(jac.actuators), "targets": list(jac.targets),
           "rows": jac.rows, "J": jac.J.tolist(), "state_pushes": st, "solver": solver,
           "degree": degree}
    if fd_h and fd_h > 0:
        fd = fd_jacobian(plant, case, st, h=fd_h, initial=res.u)
        out["fd_max_rel_error"] = max_rel_error(jac.J, fd.J)
        out["fd_h_mm"] = fd_h
    else:
        out["fd_max_rel_error"] = None
    return out


def run(args) -> int:
    case = case_from_args(args)
    out = compute(case, parse_pushes(args.state_push), solver=args.solver, degree=args.degree,
                  fd_h=args.fd_h)
    if args.json:
        write_json(out, args.json)
    J = np.asarray(out["J"])
    print(f"{case.name}: J_s ({args.solver}, degree {args.degree}) rows T.x/T.y/T.z, columns "
          f"{out['actuators']} (mm/mm); fd_max_rel_error = {out['fd_max_rel_error']}")
    for name, row in zip(out["rows"], J):
        print(f"  {name:6s} " + " ".join(f"{v:+.5f}" for v in row))
    return 0


def add_parser(sub):
    p = sub.add_parser("jacobian", help="control Jacobian of targets w.r.t. actuator pushes",
                       description=__doc__)
    add_case_args(p)
    p.add_argument("--state-push", action="append", default=[], metavar="NAME=MM",
                   help="state at which to linearize (repeatable); other actuators held at 0")
    p.add_argument("--solver", choices=("fem", "admm"), default="fem")
    p.add_argument("--degree", type=int, default=1, choices=(1, 2))
    p.add_argument("--fd-h", type=float, default=0.02, help="central FD step (mm); 0 skips")
    p.add_argument("--json", help="write the result here")
    p.set_defaults(func=run)
