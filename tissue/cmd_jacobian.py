"""``tissue jacobian CASE [--state-push A1=5.0 ...] [--solver fem|admm] [--degree 1|2] [--json FILE]
[--out DIR]``

The sensitivity of the targets to the actuators' pushes at the state ``--state-push`` (every
actuator held; unnamed ones at 0 mm), from the solver's exact tangent: for glued patches the
Dirichlet sensitivity (control/jacobian.py), for rigid indenters the sensitivity to the tip's
travel with the contact of that state (fem_reference/contact_jacobian.py); checked against central
finite differences of the same solver's nonlinear solve (``--fd-h`` mm; 0 skips). ``--out DIR``
writes ``jacobian.json`` (what ``--json`` writes), ``jacobian.png`` (|J_s|) and ``report.html``.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from tissue_reference.control.plants import FD_FLOOR, jacobian_at
from tissue_reference.errors import CaseError
from tissue_reference.meshes.io import check_output_file
from tissue_reference.model.results import write_json
from tissue_reference.solvers.registry import control_names

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
from .jacobian_report import write_jacobian_report

OUT_FILES = ("jacobian.json", "jacobian.png", "report.html")
"""What ``--out`` holds."""


def run(args) -> int:
    check_outputs(args, files=("json",), dirs=("out",))
    if args.out and Path(args.out).is_dir():
        for name in OUT_FILES:
            check_output_file(Path(args.out) / name, "--out")
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
    out = jacobian_at(case, state, solver=args.solver, degree=args.degree,
                  formulation=args.formulation, fd_h=args.fd_h)
    if args.json:
        write_json(out, args.json)
    if args.out:
        write_json(out, Path(args.out) / "jacobian.json")
        write_jacobian_report(out, args.out)
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
    p.add_argument("--solver", choices=control_names(), default="fem",
                   help="whose tangent and solves: the reference or ADMM")
    add_discretization_args(p)
    p.add_argument("--fd-h", type=real("nonneg", "mm"), default=0.02,
                   help="central FD step (mm); 0 skips")
    p.add_argument("--json", help="write the result here")
    p.add_argument("--out", help="folder for jacobian.json (as --json), jacobian.png (a heat map "
                                 "of |J_s|) and report.html")
    p.set_defaults(func=run)
