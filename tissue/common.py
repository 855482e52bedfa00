"""Helpers shared by the command modules: push parsing, case loading, solver dispatch."""
from __future__ import annotations

import argparse
from pathlib import Path

from meshes.case import Case, load_case
from meshes.errors import CaseError

__all__ = ["SOLVER_NAMES", "add_case_args", "case_from_args", "parse_pushes", "run_solver"]

SOLVER_NAMES = ("fem", "admm", "mass-tensor")


def parse_pushes(items) -> dict:
    """["A1=15", "A2=5.5"] -> {"A1": 15.0, "A2": 5.5} (mm)."""
    out = {}
    for item in items or []:
        name, sep, val = item.partition("=")
        try:
            if not sep:
                raise ValueError
            out[name.strip()] = float(val)
        except ValueError:
            raise CaseError(f"--push expects NAME=MM (e.g. A1=15), got {item!r}") from None
    return out


def add_case_args(p: argparse.ArgumentParser):
    p.add_argument("case", help="case TOML file (e.g. meshes/cases/phantom.toml)")
    p.add_argument("--size", type=float, default=None,
                   help="override the builtin mesh's characteristic length (mm)")


def case_from_args(args) -> Case:
    return load_case(Path(args.case), size=args.size)


def run_solver(name: str, case: Case, *, degree: int = 1, pushes=None, initial=None,
               progress: bool = False, **kw):
    """Solve ``case`` with the named solver; every solver returns a SolveResult."""
    if name == "fem":
        from fem_reference import solve

        return solve(case, degree=degree, pushes=pushes, initial=initial, progress=progress, **kw)
    if name == "admm":
        from solvers.admm import solve
        if "factorize" not in kw:
            from fem_reference import cholmod_factor

            kw["factorize"] = cholmod_factor  # the polish's tangents by CHOLMOD (PETSc)
    elif name == "mass-tensor":
        from solvers.mass_tensor import solve
    else:
        raise CaseError(f"unknown solver {name!r}; solvers: {list(SOLVER_NAMES)}")
    return solve(case, pushes=pushes, initial=initial, progress=progress, **kw)
