"""The reference's discretization defaults: which formulation a material gets (displacement, or
mixed u-p for nearly incompressible tissue), which displacement degree a solve that names none
gets, and the quadrature degree per Lagrange degree. Plain functions of the Case, without
dolfinx, so that what reads or reports a discretization need not build one."""
from __future__ import annotations

from tissue_reference.meshes.case import Case, Material
from tissue_reference.meshes.errors import CaseError

__all__ = ["DEFAULT_QUADRATURE", "FORMULATIONS", "MIXED_FROM_NU", "default_degree",
           "resolve_formulation"]

# Quadrature degree per Lagrange degree. P1: F is constant per cell, degree 1 integrates the
# energy and the body-force term exactly. P2: F is linear; psi is not polynomial, degree 4 is
# checked against degree 6 in tests (UFL would estimate ~ 146 points per cell for J**(-2/3)).
# P3 (used to estimate the error of P2 answers): F is quadratic, degree 6.
DEFAULT_QUADRATURE = {1: 1, 2: 4, 3: 6}
FORMULATIONS = ("auto", "displacement", "mixed")
# "auto" picks the mixed u-p formulation from this Poisson ratio up: displacement elements lock
# (P1) or show pressure oscillations in their reactions (P2) as nu -> 0.5.
MIXED_FROM_NU = 0.49


def resolve_formulation(formulation: str, material: Material) -> str:
    """"displacement" or "mixed" for a requested ``formulation`` in FORMULATIONS: "auto" is mixed
    for nu >= MIXED_FROM_NU, displacement below."""
    if formulation not in FORMULATIONS:
        raise CaseError(f"formulation must be one of {list(FORMULATIONS)}, got {formulation!r}")
    if formulation == "auto":
        return "mixed" if material.nu >= MIXED_FROM_NU else "displacement"
    return formulation


def default_degree(case: Case, formulation: str) -> int:
    """The displacement degree of a solve that names none: the case's own (``[reference]
    degree``), else 2 for the mixed formulation (Taylor-Hood) and 1 for displacement."""
    if case.reference_degree is not None:
        return int(case.reference_degree)
    return 2 if formulation == "mixed" else 1
