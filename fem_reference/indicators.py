"""Per-cell error indicators from the p-enrichment estimate (``fem_reference.estimate``), to
steer local refinement (``meshes.refine_local``, ``fem_reference.adapt``).

The estimate solves the Case again at degree p + 1 on the same mesh; the difference of the two
answers, e = u_{p+1} - u_p (u_p is a polynomial of degree p, so it is exactly a function of the
degree-(p+1) space), is the estimated error FIELD, of which the probe estimates are point values.
The indicator of cell K is its linearized elastic energy there,

    eta_K^2 = int_K ( 2 mu eps(e) : eps(e) + lambda (div e)^2 ) dx        (mN mm)

with the Case's Lame constants (mu = E / (2 (1 + nu)), lambda = E nu / ((1 + nu)(1 - 2 nu)); for
an incompressible material, nu = 0.5, lambda is replaced by the shear modulus, the mixed
formulation's pressure carrying the volume change). Their sum is the estimated energy norm of
the error of u_p (the hierarchical estimate of the energy error: the degree-(p+1) answer stands
for the exact one), so Doerfler marking on eta_K refines where the ENERGY error is: the rim of a
pushed patch, a clamped edge, a reentrant corner.

It is an energy-norm indicator, not a goal-oriented (dual-weighted) one: it does not weigh a cell
by its influence on the probes. Where the probes' error is the pollution of a singularity (the
patch rims and the clamped base edge pollute the whole phantom) the energy error drives the
probe error and refining where it is large reduces both; a probe's own neighbourhood is refined
only as far as the energy error there asks. The probe estimates decide when ``solve_to_accuracy``
stops; the indicators decide only where it refines.

Units: mm, kPa, mN. Serial (the nodal states of degree >= 2 are handed on in serial runs).
"""
from __future__ import annotations

import numpy as np

from tissue_reference.errors import CaseError
from tissue_reference.model.case import Case
from tissue_reference.model.results import SolveResult

from .jit import compile_form
from .transfer import dolfinx_cells, field

__all__ = ["INDICATOR", "energy_indicators"]

INDICATOR = "energy"
"""What ``energy_indicators`` measures: the linearized elastic energy of u_{p+1} - u_p per cell."""


def energy_indicators(case: Case, answer: SolveResult, estimate) -> np.ndarray:
    """eta_K (sqrt(mN mm)) of every cell of ``case.mesh`` in its own order: the energy of the
    estimated error field u_{p+1} - u_p in that cell (module docstring).

    answer: the degree-p reference SolveResult of ``case``; estimate: its ErrorEstimate
    (``fem_reference.estimate.error_estimate``), whose enriched solver and answer are used.
    """
    import dolfinx.fem
    import dolfinx.fem.petsc
    import ufl

    solver = getattr(estimate, "solver", None)
    if solver is None:
        raise CaseError("energy_indicators: the estimate does not carry its enriched solver")
    if answer.n_vertices != case.mesh.n_vertices or solver.case.mesh is not case.mesh:
        raise CaseError(f"energy_indicators: the answer ({answer.n_vertices} vertices) and the "
                        f"estimate must be of this case's mesh ({case.mesh.n_vertices})")
    mesh = solver.dm.mesh
    e = field(solver, estimate.enriched) - field(solver, answer)
    mat = case.material
    mu = mat.E / (2.0 * (1.0 + mat.nu))
    lmbda = mat.E * mat.nu / ((1.0 + mat.nu) * (1.0 - 2.0 * mat.nu)) if mat.nu < 0.5 else mu
    eps = ufl.sym(ufl.grad(e))
    W0 = dolfinx.fem.FunctionSpace(mesh, ("DG", 0))
    v = ufl.TestFunction(W0)
    dx = ufl.Measure("dx", domain=mesh,
                     metadata={"quadrature_degree": max(2 * (solver.degree - 1), 2)})
    form = compile_form((2 * mu * ufl.inner(eps, eps) + lmbda * ufl.tr(eps) ** 2) * v * dx)
    vec = dolfinx.fem.petsc.assemble_vector(form)
    eta2 = vec.array[W0.dofmap.list.array.reshape(-1)]          # per dolfinx cell
    vec.destroy()
    return np.sqrt(np.maximum(eta2[dolfinx_cells(solver)], 0.0))
