"""Helpers shared by the command modules: push parsing, case loading, solver dispatch."""
from __future__ import annotations

import argparse
from pathlib import Path

from meshes.case import Case, load_case
from meshes.errors import CaseError

__all__ = ["SOLVER_NAMES", "add_case_args", "add_discretization_args", "case_from_args",
           "parse_pushes", "run_solver"]

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


def add_discretization_args(p: argparse.ArgumentParser):
    """--degree and --formulation of the reference."""
    p.add_argument("--degree", type=int, choices=(1, 2), default=None,
                   help="Lagrange degree of the reference's displacement (default: 2 for the "
                        "mixed formulation, 1 otherwise)")
    p.add_argument("--formulation", choices=("auto", "displacement", "mixed"), default="auto",
                   help="reference formulation: mixed u-p (Taylor-Hood P2/P1, locking-free for "
                        "nearly incompressible tissue) or displacement; auto: mixed for "
                        "nu >= 0.49")


def case_from_args(args) -> Case:
    return load_case(Path(args.case), size=args.size)


def run_solver(name: str, case: Case, *, degree: int | None = None, formulation: str = "auto",
               pushes=None, initial=None, progress: bool = False, **kw):
    """Solve ``case`` with the named solver; every solver returns a SolveResult. ``degree`` and
    ``formulation`` are the reference's; the fast solvers are P1 displacement solvers and refuse
    anything else."""
    if name == "fem":
        from fem_reference import solve

        return solve(case, degree=degree, formulation=formulation, pushes=pushes,
                     initial=initial, progress=progress, **kw)
    if degree not in (None, 1) or formulation == "mixed":
        raise CaseError(f"solver {name!r} is a P1 displacement solver: --degree and "
                        f"--formulation mixed apply to the reference (--solver fem)")
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
