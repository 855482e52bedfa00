"""The reference solve of a symmetric load on a mirrored mesh, on the part it was mirrored from
(``model.symmetry``): the same discrete problem (the part with its plane sliding), solved at
about half the unknowns per mirror plane and mirrored back onto the whole mesh: the displacement
at every vertex (and the nodal state and pressure), every probe, reaction and tip report, the
strain energy, the unknowns the whole mesh has (``discretization["dofs"]``, which the case's
``[reference.measured]`` rows are keyed by). The part may itself be mirrored (the phantom's
whole is its half mirrored, the half its quarter): it is reduced again while the load stays
symmetric.

An error estimate of such an answer (``estimate_split``) is the part's, mirrored back: the
degree + 1 solve on the part too, where the automatic estimate decides by the whole mesh's
unknowns as it would for the whole.

The answer says so in ``SolveResult.symmetry``: ``solved_on`` "part" with the ``planes`` the
solve was cut by and the part's ``part_dofs``; on a mirrored mesh solved whole, "whole" and
``why`` (an asymmetric load, or ``symmetry=False``, a warm start, a ``dirichlet_override``).
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

from tissue_reference.errors import ConvergenceError
from tissue_reference.model.case import Case
from tissue_reference.model.results import SolveResult
from tissue_reference.model.symmetry import Reduction, reduction

from .discretization import resolve_formulation
from .dof_counts import entity_counts, predicted_dofs
from .estimate import auto_estimate_note, error_estimate
from .kept import solver_for

__all__ = ["Split", "estimate_split", "solve_reduced", "solve_split"]


@dataclass(frozen=True)
class Split:
    """How an answer was solved on a symmetric part: the ``plan`` (``model.symmetry``), the
    part's answer ``part`` (itself from its own part when ``inner`` is not None)."""

    plan: Reduction
    part: SolveResult
    inner: Split | None = None


def solve_reduced(case: Case, degree: int | None, *, pushes=None, initial=None,
                  dirichlet_override=None, progress: bool = False, symmetry: bool = True,
                  **kw) -> SolveResult:
    """The reference solve of ``case`` under ``pushes`` (``ReferenceSolver.solve`` on a kept
    solver), on the symmetric part where the mesh is mirrored, the load symmetric and
    ``symmetry`` is True, with neither a warm start nor a ``dirichlet_override`` (the part's
    answer mirrored back: the module docstring); else on the whole mesh. Options ``kw``: those
    of ``ReferenceSolver``."""
    return solve_split(case, degree, pushes=pushes, initial=initial,
                       dirichlet_override=dirichlet_override, progress=progress,
                       symmetry=symmetry, **kw)[0]


def solve_split(case: Case, degree: int | None, *, pushes=None, initial=None,
                dirichlet_override=None, progress: bool = False, symmetry: bool = True,
                **kw) -> tuple[SolveResult, Split | None]:
    """``solve_reduced``'s answer and how it was split (None: solved on the whole mesh)."""
    t0 = time.perf_counter()
    why = None
    if case.mesh.mirrored:
        why = ("symmetry=False" if not symmetry else
               "a warm start (initial)" if initial is not None else
               "a dirichlet_override" if dirichlet_override is not None else None)
        plan = reduction(case, pushes) if why is None else why
        if isinstance(plan, Reduction):
            part, inner = solve_split(plan.part, degree, progress=progress, **kw)
            res = mirrored_result(plan, part, kw.get("formulation", "auto"))
            res = dataclasses.replace(res, wall_time_s=time.perf_counter() - t0)
            return res, Split(plan, part, inner)
        why = plan
    s = solver_for(case, degree, **kw)
    res = s.solve(pushes, case=case, initial=initial, dirichlet_override=dirichlet_override,
                  progress=progress)
    if why is not None:
        res = dataclasses.replace(res, symmetry={"solved_on": "whole", "why": why})
    return res, None


def _split_estimate(split: Split, progress: bool, kw: dict):
    """The ``ErrorEstimate`` of the whole answer: the innermost part's, mirrored back."""
    if split.inner is None:
        est = error_estimate(split.plan.part, split.part, progress=progress, **kw)
    else:
        est = _split_estimate(split.inner, progress, kw)
    plan = split.plan
    return dataclasses.replace(est, probes=plan.probes(est.probes),
                               reactions=plan.reactions(est.reactions),
                               enriched=mirrored_result(plan, est.enriched))


def estimate_split(case: Case, result: SolveResult, split: Split, *, auto: bool,
                   progress: bool = False, **kw) -> SolveResult:
    """``result`` (the answer ``solve_split`` split as ``split``) with its estimated
    discretization error, by p-enrichment on the part (``fem_reference.estimate``); ``auto``:
    only where the automatic estimate would run on the whole mesh (``auto_estimate``), else
    with its ``estimate_note``."""
    if auto:
        note = auto_estimate_note(case, result, **kw)
        if note is not None:
            return dataclasses.replace(result, estimate_note=note)
    try:
        est = _split_estimate(split, progress, kw)
    except ConvergenceError as exc:
        if not auto:
            raise
        return dataclasses.replace(
            result, estimate_note=f"the degree-{int(result.degree) + 1} solve of the estimate "
                                  f"did not converge ({exc})")
    if result.wall_time_s > 0:
        est = dataclasses.replace(est, cost_ratio=est.wall_time_s / result.wall_time_s)
    return est.attach(result)


def mirrored_result(plan: Reduction, part: SolveResult, formulation: str = "auto") \
        -> SolveResult:
    """The whole mesh's answer from ``part``, the answer of ``plan.part``."""
    whole = plan.whole
    disc = dict(part.discretization or {})
    form = disc.get("formulation") or resolve_formulation(formulation, whole.material)
    dofs = predicted_dofs(entity_counts(whole.mesh), whole.mesh.gdim, int(part.degree), form)
    disc.update(cells=whole.mesh.n_cells, dofs=dofs)
    inner = part.symmetry or {}
    planes = [plan.plane, *(inner.get("planes") or [])] if inner.get("solved_on") == "part" \
        else [plan.plane]
    part_dofs = inner.get("part_dofs", (part.discretization or {}).get("dofs"))
    # the part's cells are the whole's first, each with its image: twice as many inverted
    extra, reason = dict(part.extra), part.invalid_reason
    k = extra.get("inverted_cells")
    if k and not isinstance(k, bool):
        k = int(k)
        extra["inverted_cells"] = 2 * k
        if reason:
            said = f"{k} inverted cell{'' if k == 1 else 's'} "
            reason = reason.replace(said, f"{2 * k} inverted cells ", 1)
    state = {}
    if part.node_u is not None and part.node_points is not None:
        state["node_u"], state["node_points"] = plan.nodes(part.node_u, part.node_points)
    if part.pressure is not None:
        state["pressure"] = plan.vertex_field(part.pressure, vector=False)
    return dataclasses.replace(
        part, u=plan.vertex_field(part.u), probes=plan.probes(part.probes),
        reactions=plan.reactions(part.reactions), indenters=plan.indenters(part.indenters),
        strain_energy=2.0 * part.strain_energy, warnings=plan.warnings(part.warnings),
        case_name=whole.name, n_vertices=whole.mesh.n_vertices, n_cells=whole.mesh.n_cells,
        discretization=disc, invalid_reason=reason,
        extra={**extra, "n_dofs": dofs},
        symmetry={"solved_on": "part", "planes": planes, "part_dofs": part_dofs,
                  "part_cells": inner.get("part_cells", part.n_cells)},
        **state)
