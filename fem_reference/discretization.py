"""The reference's discretization: which formulation a material gets (displacement, or mixed u-p
for nearly incompressible tissue), which displacement degree a solve that names none gets, the
quadrature degree per Lagrange degree, and ``Discretization``, a solve's options with every
default resolved against its Case (the kept solvers' key). Without dolfinx, so that what reads
or reports a discretization need not build one."""
from __future__ import annotations

from dataclasses import dataclass

from tissue_reference.errors import CaseError
from tissue_reference.model.case import UNCOUPLED_LAWS, Case, Material
from tissue_reference.model.tips import default_contact_rule, default_tip_start

__all__ = ["DEFAULT_QUADRATURE", "FORMULATIONS", "MIXED_FROM_NU", "SPLIT_LAWS", "Discretization",
           "checked_degree", "default_degree", "geometry_order", "resolve_formulation"]

# Quadrature degree per Lagrange degree. P1: F is constant per cell, degree 1 integrates the
# energy and the body-force term exactly. P2: F is linear; psi is not polynomial, degree 4 is
# checked against degree 6 in tests (UFL would estimate ~ 146 points per cell for J**(-2/3)).
# P3 (used to estimate the error of P2 answers): F is quadratic, degree 6.
DEFAULT_QUADRATURE = {1: 1, 2: 4, 3: 6}
FORMULATIONS = ("auto", "displacement", "mixed")
# "auto" picks the mixed u-p formulation from this Poisson ratio up: displacement elements lock
# (P1) or show pressure oscillations in their reactions (P2) as nu -> 0.5.
MIXED_FROM_NU = 0.49
SPLIT_LAWS = (*UNCOUPLED_LAWS, "linear-elastic")
"""The laws whose volumetric energy the mixed u-p formulation splits off: the only laws it
takes (the others couple it: compressible laws)."""


def resolve_formulation(formulation: str, material: Material) -> str:
    """"displacement" or "mixed" for a requested ``formulation`` in FORMULATIONS: "auto" is mixed
    for nu >= MIXED_FROM_NU, displacement below."""
    if formulation not in FORMULATIONS:
        raise CaseError(f"formulation must be one of {list(FORMULATIONS)}, got {formulation!r}")
    split = material.model in SPLIT_LAWS
    if formulation == "auto":
        return "mixed" if split and material.nu >= MIXED_FROM_NU else "displacement"
    if formulation == "mixed" and not split:
        raise CaseError(f"the mixed u-p formulation splits off the volumetric energy of the laws "
                        f"{list(UNCOUPLED_LAWS)} and linear elasticity; {material.model!r} "
                        f"couples it (a compressible law): use the displacement formulation")
    return formulation


def default_degree(case: Case, formulation: str) -> int:
    """The displacement degree of a solve that names none: the case's own (``[reference]
    degree``), else 2 for the mixed formulation (Taylor-Hood) and 1 for displacement."""
    if case.reference_degree is not None:
        return int(case.reference_degree)
    return 2 if formulation == "mixed" else 1


def checked_degree(case: Case, formulation: str, degree: int | None, *,
                   requested: str = "auto") -> int:
    """The displacement degree of a solve, checked against its formulation.

    Parameters
    ----------
    case : Case
        The Case (its material's nu; its ``reference_degree`` when ``degree`` is None).
    formulation : str
        The resolved formulation, "displacement" or "mixed" (``resolve_formulation``).
    degree : int or None
        The degree asked for; None: ``default_degree``.
    requested : str
        The formulation asked for ("auto", "displacement" or "mixed"): with "auto" the error
        for a mixed formulation at degree 1 says why it was picked.

    Returns
    -------
    int
        The Lagrange degree of the displacement, 1, 2 or 3.

    Raises
    ------
    CaseError
        For a degree other than 1, 2 or 3, degree 1 with the mixed formulation (Taylor-Hood),
        or nu = 0.5 with the displacement formulation.
    """
    if degree is None:
        degree = default_degree(case, formulation)
    if degree not in (1, 2, 3):
        raise CaseError(f"degree must be 1, 2 or 3, got {degree!r}")
    if formulation == "mixed" and degree < 2:
        why = "" if requested == "mixed" else \
            f" (picked for nu = {case.material.nu} >= {MIXED_FROM_NU}: P1 displacement " \
            f"elements lock there; formulation='displacement' accepts that)"
        raise CaseError(f"the mixed u-p formulation is Taylor-Hood (P2/P1, P3/P2) and needs "
                        f"degree=2 or 3, got degree={degree}{why}")
    if formulation == "displacement" and case.material.nu >= 0.5:
        raise CaseError("an incompressible material (nu = 0.5) needs the mixed formulation")
    return degree


def geometry_order(mesh, curved: bool | None, degree: int) -> int:
    """The order of the cells' geometry: 2 (isoparametric, from the mesh's curved edges) or 1.

    Parameters
    ----------
    mesh : Mesh
        The Case's mesh (``geometry_order`` 2 when it carries curved edges).
    curved : bool or None
        True: curved cells (the mesh must have curved edges); None: curved at degree >= 2
        when the mesh has them; False: straight.
    degree : int
        The displacement's Lagrange degree.

    Returns
    -------
    int
        2 for curved (second-order) cells, 1 for straight ones.

    Raises
    ------
    CaseError
        For ``curved=True`` on a mesh with no curved edges.
    """
    if curved and mesh.geometry_order == 1:
        raise CaseError("curved=True: this mesh has no curved (second-order) edges")
    return 2 if mesh.geometry_order == 2 and (curved or (curved is None and degree >= 2)) else 1


@dataclass(frozen=True)
class Discretization:
    """What a reference solve is discretized with, each default resolved against its Case: the
    displacement degree, the formulation ("displacement" or "mixed"), the quadrature degree,
    curved cells (None: the solver decides from the mesh's geometry), the linear solver, the
    contact rule and where indenters start, and the solver's other options as sorted (name,
    value) pairs. Two solves with equal Discretizations of one Case are the same problem: the
    kept solvers are keyed on it (``kept.solver_for``)."""

    degree: int
    formulation: str
    quadrature_degree: int
    curved: bool | None = None
    linear_solver: str = "auto"
    contact_rule: str | int = "nodal"
    tip_start: str = "nodes"
    options: tuple = ()

    @classmethod
    def of(cls, case: Case, degree: int | None = None, **options) -> Discretization:
        """The discretization of a ``ReferenceSolver(case, degree=degree, **options)``."""
        formulation = resolve_formulation(options.pop("formulation", "auto"), case.material)
        if degree is None:
            degree = default_degree(case, formulation)
        rule = options.pop("contact_quadrature", None)
        rule = default_contact_rule(case) if rule is None else rule
        start = options.pop("tip_start", None) or default_tip_start(case, rule)
        quadrature = options.pop("quadrature_degree", None) or DEFAULT_QUADRATURE.get(int(degree))
        return cls(int(degree), formulation, quadrature, options.pop("curved", None),
                   options.pop("linear_solver", "auto"), rule, start,
                   tuple(sorted(options.items())))

    def solver_options(self) -> dict:
        """The ReferenceSolver keywords that build this discretization."""
        return {"degree": self.degree, "formulation": self.formulation,
                "quadrature_degree": self.quadrature_degree, "curved": self.curved,
                "linear_solver": self.linear_solver, "contact_quadrature": self.contact_rule,
                "tip_start": self.tip_start, **dict(self.options)}
