"""``tissue jacobian CASE [--state-push A1=5.0 ...] [--solver fem|admm] [--degree 1|2] --json FILE``

The Dirichlet sensitivity of the targets to rigid actuator pushes (control/jacobian.py) at the
state ``--state-push`` (every actuator held; unnamed ones at 0 mm), from the solver's exact
tangent, checked against central finite differences of the same solver's nonlinear solve
(``--fd-h`` mm; 0 skips).
"""
from __future__ import annotations

import sys

import numpy as np

from meshes.errors import CaseError
from meshes.results import write_json

from .common import (
    add_case_args,
    add_discretization_args,
    body_diameter,
    case_from_args,
    check_outputs,
    check_prescribed,
    check_pushes,
    parse_pushes,
    real,
)

# ADMM as a control plant/model: the ADMM stage hands over to the Newton polish (part of
# solvers.admm.solve, iteration budget left to the solver: 20 per load step) which finishes to
# 1e-7 mm, the accuracy finite differences and J_s need; lift=True starts every load step from the
# tangent lift of the new boundary values. Measured on the phantom (size 12, model of the mismatch
# runs): a tight ADMM stage (tol 1e-6, or 1000 iterations per load step) cost up to 24 s per step
# above ~21 mm pushes, and at A1 = 25, A3 = 12.5 mm its polish settled on a stationary point with
# 17% more strain energy than the reference's solution on the same mesh; the default hand-over
# finds the reference's solution (tests/test_control_admm_model.py). With lift="auto" a sub-mm step
# whose polish restarted returned the previous step's boundary values flagged converged (caught by
# control.loop.check_prescribed).
FD_FLOOR = 1e-7
"""Smallest central-difference step, relative to the body's diameter: the solves agree to about
1e-10 mm, so a smaller step differences round-off."""
ADMM_CONTROL_OPTIONS = {"tol_mm": 1e-2, "polish": True, "polish_tol_mm": 1e-7, "lift": True}


def plant_for(name: str, *, degree: int = 1, tight: bool = True):
    """plant(case, pushes, initial_u) -> SolveResult for solver ``name`` (fem | admm).
    tight: ADMM with ``ADMM_CONTROL_OPTIONS`` (else the solver's defaults)."""
    if name == "fem":
        from fem_reference import solve

        return lambda case, pushes, initial: solve(case, degree=degree, pushes=pushes,
                                                   initial=initial)
    if name == "admm":
        from solvers.admm import solve

        kw = dict(ADMM_CONTROL_OPTIONS) if tight else {}
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


def reference_state(case, state_pushes, *, degree=None, formulation="auto"):
    """Reference solve at ``state_pushes`` and the exact tangent at *its own* state.

    Returns (SolveResult, Tangent, plant) where plant(case, pushes, initial) re-solves with the same
    solver instance. The tangent is taken from the solver's current dof vector right after the
    solve: for degree 2 that is the full P2 state (edge nodes included), the state the SolveResult
    carries too (``fem_reference.tangent_stiffness(case, res, degree=2)`` gives the same K). The
    vertex values ``res.u`` alone do not determine it (edge nodes = mean of their end vertices is
    *not* the solution away from rest: 17% off J_s on the phantom at A1 = 3 mm) and are refused.
    """
    from fem_reference import ReferenceSolver

    s = ReferenceSolver(case, degree=degree, formulation=formulation)
    res = s.solve(state_pushes)
    if not res.converged:
        raise CaseError(f"the state solve at pushes {state_pushes} did not converge")
    T = s.tangent(None, pushes=state_pushes)

    def plant(c, pushes, initial):
        return s.solve(pushes, case=c, initial=initial)
    return res, T, plant


def compute(case, state_pushes, *, solver="fem", degree=None, formulation="auto", fd_h=0.02,
            actuators=None):
    """J_s at ``state_pushes`` from the solver's exact tangent and, when fd_h > 0, its max relative
    error against central finite differences (step fd_h mm) of the same solver's nonlinear solve.
    actuators: the columns (default: every actuator of the Case; the others are held)."""
    from control.jacobian import (
        dirichlet_jacobian,
        fd_jacobian,
        full_pushes,
        max_rel_error,
        p2_interpolation,
        p2_region_nodes,
    )

    if degree not in (None, 1, 2):
        raise CaseError(f"--degree must be 1 or 2, got {degree}")
    if solver != "fem" and (degree == 2 or formulation == "mixed"):
        raise CaseError("--degree 2 and --formulation mixed need --solver fem")
    st = full_pushes(case, state_pushes)
    pushed = case.with_pushes(st)
    if solver == "fem":
        res, T, plant = reference_state(case, st, degree=degree, formulation=formulation)
        degree = T.degree
        if degree == 2:
            P = p2_interpolation(case, T.node_points)
            jac = dirichlet_jacobian(pushed, T.K, actuators=actuators, P=P,
                                     region_nodes=p2_region_nodes(case, T.node_points),
                                     internal_dofs=T.internal_dofs)
        else:
            jac = dirichlet_jacobian(pushed, T.K, actuators=actuators)
    else:
        plant = plant_for(solver, degree=degree)
        res = plant(case, st, None)
        if not res.converged:
            raise CaseError(f"the state solve at pushes {st} did not converge")
        jac = dirichlet_jacobian(pushed, tangent_for(solver)(pushed, res.u), actuators=actuators)
    out = {"actuators": list(jac.actuators), "targets": list(jac.targets),
           "rows": jac.rows, "J": jac.J.tolist(), "state_pushes": st, "solver": solver,
           "degree": degree or 1, "formulation": res.extra.get("discretization", {}).get(
               "formulation", "displacement"),
           "state_valid": bool(res.extra.get("valid", True)),
           "state_invalid_reason": res.extra.get("invalid_reason")}
    if fd_h and fd_h > 0:
        # degree 2 solves start cold: a warm start from vertex values (edge nodes interpolated)
        # is not the P2 state and can leave Newton's basin on coarse meshes
        fd = fd_jacobian(plant, case, st, h=fd_h, actuators=jac.actuators,
                         initial=res.u if degree == 1 else None)
        out["fd_max_rel_error"] = max_rel_error(jac.J, fd.J)
        out["fd_h_mm"] = fd_h
    else:
        out["fd_max_rel_error"] = None
    return out


def run(args) -> int:
    check_outputs(args, files=("json",))
    state = parse_pushes(args.state_push, "--state-push")
    case = case_from_args(args)
    check_pushes(case, state, "--state-push", margin=args.fd_h)
    check_prescribed(case, state)
    floor = FD_FLOOR * body_diameter(case)
    if 0 < args.fd_h < floor:
        raise CaseError(f"--fd-h {args.fd_h:g}: a step below {floor:.2g} mm ({FD_FLOOR:g} of the "
                        f"body's diameter) differences round-off; expected 0 (no check) or a "
                        f"larger step (mm)")
    if args.fd_h > 0:  # every actuator is stepped by fd_h, the held ones too
        check_pushes(case, {a.name: 0.0 for a in case.actuators if a.name not in state},
                     f"--fd-h {args.fd_h:g}: push", margin=args.fd_h)
    out = compute(case, state, solver=args.solver, degree=args.degree,
                  formulation=args.formulation, fd_h=args.fd_h)
    if args.json:
        write_json(out, args.json)
    J = np.asarray(out["J"])
    print(f"{case.name}: J_s ({args.solver}, {out['formulation']} degree {out['degree']}) rows T.x/T.y/T.z, columns "
          f"{out['actuators']} (mm/mm); fd_max_rel_error = {out['fd_max_rel_error']}")
    for name, row in zip(out["rows"], J):
        print(f"  {name:6s} " + " ".join(f"{v:+.5f}" for v in row))
    if not out["state_valid"]:
        print(f"tissue jacobian: error: the state at {out['state_pushes']} is not valid: "
              f"{out['state_invalid_reason']} (outputs written, marked state_valid = false)",
              file=sys.stderr)
        return 1
    return 0


def add_parser(sub):
    p = sub.add_parser("jacobian", help="control Jacobian of targets w.r.t. actuator pushes",
                       description=__doc__)
    add_case_args(p)
    p.add_argument("--state-push", action="append", default=[], metavar="NAME=MM",
                   help="state at which to linearize (repeatable); other actuators held at 0")
    p.add_argument("--solver", choices=("fem", "admm"), default="fem")
    add_discretization_args(p)
    p.add_argument("--fd-h", type=real("nonneg", "mm"), default=0.02,
                   help="central FD step (mm); 0 skips")
    p.add_argument("--json", help="write the result here")
    p.set_defaults(func=run)
