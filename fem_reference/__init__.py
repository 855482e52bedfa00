"""FEniCSx (dolfinx 0.5) reference: the strain-energy laws as UFL weak forms, PETSc Newton
(lagged CHOLMOD/MUMPS factorization + GMRES), load stepping with cut-backs, exact tangent
stiffness. Units mm, kPa, mN. The public names: ``solve`` (an answer with its stated accuracy,
``answer``), ``tangent_stiffness`` (``kept``), the solver class and its settings (``solver``),
and ``cholmod_factor`` (CHOLMOD through PETSc for callers that import no PETSc, e.g. the ADMM
polish).

Each name is imported on first use (PEP 562), so that a module of this package that needs no
dolfinx (``factor``, ``measured``, ``discretization``, ``newton_settings``, ``richardson``) can
be imported without loading dolfinx, UFL and the form compiler (about 0.6 s and their memory):
``tissue solve --solver admm`` loads none of them."""
from __future__ import annotations

import importlib
import warnings
from typing import TYPE_CHECKING

if TYPE_CHECKING:   # what static tools and editors resolve
    from .answer import solve
    from .factor import cholmod_factor
    from .kept import tangent_stiffness
    from .solver import (
        DEFAULT_QUADRATURE,
        FORMULATIONS,
        MIXED_FROM_NU,
        NewtonSettings,
        ReferenceSolver,
        Tangent,
        resolve_formulation,
    )

_HOME = {"solve": "answer", "cholmod_factor": "factor", "tangent_stiffness": "kept",
         "DEFAULT_QUADRATURE": "solver", "FORMULATIONS": "solver", "MIXED_FROM_NU": "solver",
         "NewtonSettings": "solver", "ReferenceSolver": "solver", "Tangent": "solver",
         "resolve_formulation": "solver"}

__all__ = ["DEFAULT_QUADRATURE", "FORMULATIONS", "MIXED_FROM_NU", "NewtonSettings",
           "ReferenceSolver", "Tangent", "cholmod_factor", "resolve_formulation", "solve",
           "tangent_stiffness"]


def __getattr__(name: str):
    home = _HOME.get(name)
    if home is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(_import_keeping_warnings(f".{home}"), name)
    globals()[name] = value
    return value


def _import_keeping_warnings(module: str):
    """Import a submodule with Python's warnings shown as they were before: the form compiler
    (FFCx), which importing dolfinx imports, routes every warning to the logging module when it
    is first imported (``logging.captureWarnings``), so that an answer's TissueWarning would
    become a log record that ``warnings.catch_warnings`` and ``pytest.warns`` never see."""
    shown = warnings.showwarning
    try:
        return importlib.import_module(module, __name__)
    finally:
        warnings.showwarning = shown


def __dir__():
    return sorted({*globals(), *__all__})
