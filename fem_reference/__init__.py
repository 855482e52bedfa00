"""FEniCSx (dolfinx 0.5) reference: Neo-Hookean and linear elasticity as UFL weak forms, PETSc
Newton with MUMPS, load stepping with cut-backs, exact tangent stiffness. Units mm, kPa, mN."""
from .solver import (
                     DEFAULT_QUADRATURE,
                     NewtonSettings,
                     ReferenceSolver,
                     Tangent,
                     solve,
                     tangent_stiffness,
)

__all__ = [
                     "DEFAULT_QUADRATURE",
                     "NewtonSettings",
                     "ReferenceSolver",
                     "Tangent",
                     "solve",
                     "tangent_stiffness",
]
