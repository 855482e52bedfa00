"""FEniCSx (dolfinx 0.5) reference: Neo-Hookean and linear elasticity as UFL weak forms, PETSc
Newton (lagged CHOLMOD/MUMPS factorization + GMRES), load stepping with cut-backs, exact tangent
stiffness. Units mm, kPa, mN. The public names: ``solve`` (an answer with its stated accuracy,
``answer``), ``tangent_stiffness`` (``kept``), the solver class and its settings (``solver``),
and ``cholmod_factor`` (CHOLMOD through PETSc for callers that import no PETSc, e.g. the ADMM
polish)."""
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

__all__ = ["DEFAULT_QUADRATURE", "FORMULATIONS", "MIXED_FROM_NU", "NewtonSettings",
           "ReferenceSolver", "Tangent", "cholmod_factor", "resolve_formulation", "solve",
           "tangent_stiffness"]
