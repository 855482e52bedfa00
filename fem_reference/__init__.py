"""FEniCSx (dolfinx 0.5) reference: Neo-Hookean and linear elasticity as UFL weak forms, PETSc
Newton (lagged CHOLMOD/MUMPS factorization + GMRES), load stepping with cut-backs, exact tangent
stiffness. Units mm, kPa, mN. The public names are those of ``solver.__all__`` and
``cholmod_factor`` (CHOLMOD through PETSc for callers that import no PETSc, e.g. the ADMM
polish)."""
from .factor import cholmod_factor  # noqa: F401
from .solver import *
from .solver import __all__  # noqa: F401
