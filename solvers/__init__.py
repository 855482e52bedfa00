"""The fast solvers, by name: ``get_solver("admm")`` -> ``solvers.admm.solve``. Every built-in
solver, the reference included, with one face: ``solvers.registry``.

Every registered ``solve(case, *, pushes=None, initial=None, callback=None, progress=False, ...)``
returns a ``model.results.SolveResult``; every module also has ``require_modeled(case)``, which
raises ``errors.NotModeledError`` for a problem its solver does not model. Modules are imported on first use (importing this
package stays cheap); a module that cannot be imported raises ImportError from ``get_solver``.
"""
from __future__ import annotations

import importlib

from tissue_reference.errors import CaseError

from .registry import entries

__all__ = ["SOLVERS", "get_solver", "solver_module"]

# name -> module whose ``solve`` it is: the fast solvers of the registry (``solvers.registry``,
# which has the reference too)
SOLVERS = {e.name: e.module for e in entries() if not e.reference}


def solver_module(name: str):
    """The module of the fast solver ``name`` (ImportError if it cannot be imported)."""
    try:
        modname = SOLVERS[name]
    except KeyError:
        raise CaseError(f"unknown fast solver {name!r}; solvers: {sorted(SOLVERS)}") from None
    return importlib.import_module(modname)


def get_solver(name: str):
    """``solve`` function of the fast solver ``name`` ("admm", "mass-tensor")."""
    return solver_module(name).solve
