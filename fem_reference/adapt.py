"""Goal-oriented adaptivity: solve a Case until every probe's estimated discretization error is
within a requested accuracy of its value.

Strategy (degree first, then mesh refinement, local by default):

    level 0, degree 1  (estimated by degree 2 on the same mesh)
    level 0, degree 2  (the degree-2 solve of the previous estimate is this answer, no new
                        solve, unless the mesh has curved edges: degree 2 then solves on the
                        curved cells; estimated by degree 3)
    level 1, degree 2  (the mesh refined, see below; estimated by degree 3)
    level 2, degree 2  ...

(the mixed formulation starts at degree 2). Each step is one answer and its error estimate
(``fem_reference.estimate``: one more solve at degree + 1), so the estimate of the answer handed
back is the last solve. A probe q passes when |e_q| <= accuracy * max(|q|, floor * max_k |q_k|):
relative to its own displacement, with a floor (a fraction of the largest probe displacement) so
that a probe that barely moves does not demand an absolute accuracy nobody asked for. The
estimates are those of ``fem_reference.estimate``, with the same scope (the discretization error
on the geometry the solves use; see there).

Refinement, ``refine=``:

- "local" (default): per-cell indicators from the estimate just made (``fem_reference.indicators``:
  the energy of the estimated error field u_{p+1} - u_p in each cell, an energy-norm indicator,
  not a dual-weighted one), Doerfler marking of the fewest cells holding ``theta`` (0.5) of their
  squared sum, and conforming longest-edge bisection of those cells
  (``meshes.refine_local.refine_local``: each marked cell into 8 or more, a few neighbours
  bisected to close the mesh). Where the error concentrates (the clamped corners of Cook's
  membrane, the rim of a pushed patch) the levels add a few hundred cells each instead of
  multiplying them by 8: Cook's membrane reaches 0.05 % with 4k unknowns in the last estimate,
  where uniform refinement would need 600k (tests/test_refine_local.py).
- "uniform": every tetrahedron into 8, every triangle into 4 (``meshes.refine.refine_uniform``).

Each refined level's degree-2 answer starts from the coarser level's degree-3 solution carried to
the new mesh (``fem_reference.transfer``), and its estimate from the answer; both with a damped
Newton (``transfer.warm_settings``). When they do not converge ``solve_to_accuracy`` raises
AccuracyNotReached carrying the last level's answer with its estimate, as at ``max_dofs``; past
the first level the estimate is then tried from rest only with indenters (whose contact set the
enriched surface nodes change): near a glued patch's rim that solve crawls through cut-backs for
many minutes and, where the refined problem has lost its solution, still fails.
A degree-2 Neo-Hookean answer that is not valid (inverted cells: the refinement has gone where
the model has no regular solution, such as the rim of a glued patch, and P2 fields fold its
smallest cells) is not estimated or refined further: AccuracyNotReached names it and carries the
last valid level. A linear-elastic answer is refined on: its energy is quadratic, so J <= 0 at
a singular corner (Cook's membrane under its unit load) says the load is past small strain, not
that the discrete problem has no solution.

Cost: every degree-2 level solves the answer and the degree-3 estimate. A uniform refinement
multiplies the dofs by about 8 in 3D (4 in 2D), so each level costs roughly 8-10x the previous
one and the last level dominates; a local one adds what the marked cells need, so the levels
are many and cheap, and the Newton iterations of the warm starts dominate. ``max_dofs`` bounds
the largest system solved (the degree-3 estimate of the last level): before a step whose
estimate would exceed it, ``solve_to_accuracy`` raises AccuracyNotReached (the command line
exits 1), carrying the last answer with its estimate.

A curved boundary needs ``project`` (``meshes.refine.projector_for(builder)``, or pass the Case
file's path, which finds it), else the refined meshes keep the coarse facets and the answers
converge to the faceted body. Uniformly refined meshes have straight cells (their new boundary
vertices on the true surface); locally refined ones keep the curved (second-order) edges of the
cells left alone and give the new boundary edges projected mid-edge nodes, so the boundary away
from the refined cells keeps its second-order geometry. The estimates exclude the faceting that
remains (``fem_reference.estimate`` states the scope). Units: mm, kPa, mN.
"""
from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tissue_reference.errors import AccuracyNotReached, CaseError, ConvergenceError
from tissue_reference.meshes.refine import refine_uniform
from tissue_reference.meshes.refine_local import dorfler_mark, refine_local
from tissue_reference.model.case import Case
from tissue_reference.model.converged_range import unconverged_load
from tissue_reference.model.results import SolveResult

from .answer import solve
from .convergence import load_study_case
from .discretization import default_degree, resolve_formulation
from .dof_counts import entity_counts, predicted_dofs, refined_counts
from .estimate import ESTIMATE_RTOL, MAX_DEGREE, error_estimate
from .indicators import energy_indicators
from .kept import forget_solvers, solver_for
from .transfer import prolong, warm_settings

__all__ = [
    "DORFLER_THETA",
    "REFINEMENTS",
    "AccuracyNotReached",
    "AdaptiveResult",
    "AdaptiveStep",
    "predicted_dofs",
    "solve_to_accuracy",
]

REFINEMENTS = ("local", "uniform")
WARM_ANSWER_ITERATIONS = 16
"""Newton iterations of an answer warm-started from the coarser level before it is solved from
rest instead."""
DORFLER_THETA = 0.5
"""Local refinement marks the fewest cells holding this share of the squared indicators."""


@dataclass(frozen=True)
class AdaptiveStep:
    """One answer and its estimate.

    level: refinements of the Case mesh; degree: the answer's; cells; dofs: the answer's;
    estimate_dofs: the degree-(p+1) estimate's; probes: name -> (gdim,) answer (mm); estimates:
    name -> |estimated error| (mm); targets: name -> the accuracy asked of it (mm); wall_time_s:
    the step's solves.
    """

    level: int
    degree: int
    cells: int
    dofs: int
    estimate_dofs: int
    probes: dict
    estimates: dict
    targets: dict
    wall_time_s: float

    @property
    def passed(self) -> bool:
        return all(self.estimates[k] <= self.targets[k] for k in self.targets)

    @property
    def worst(self) -> tuple:
        """(probe name, estimate / target) of the probe farthest from its target."""
        k = max(self.targets, key=lambda n: self.estimates[n] / self.targets[n])
        return k, self.estimates[k] / self.targets[k]


@dataclass(frozen=True)
class AdaptiveResult:
    """The accepted answer (``result``: a SolveResult with the estimate's entries in ``extra``,
    see ``fem_reference.estimate``), the Case on its mesh, every step, and whether the accuracy
    was reached."""

    result: SolveResult
    case: Case
    steps: tuple
    accuracy: float
    reached: bool
    wall_time_s: float


def _targets(probes: dict, accuracy: float, floor: float) -> dict:
    mags = {k: float(np.linalg.norm(v)) for k, v in probes.items()}
    top = max(mags.values(), default=0.0)
    return {k: accuracy * max(m, floor * top) for k, m in mags.items()}


def solve_to_accuracy(case, pushes=None, *, accuracy: float = 0.01, max_dofs: int = 500_000,
                      degree: int | None = None, project=None, floor: float = 0.1,
                      refine: str = "local", theta: float = DORFLER_THETA,
                      progress: bool = True, **solver_options) -> AdaptiveResult:
    """Refine until every probe's estimated error is within ``accuracy`` (relative) of its value.

    case: a Case, or the path of a Case file (its builtin's boundary projection is then used
        unless ``project`` is given).
    pushes: actuator name -> push (mm). accuracy: relative, e.g. 0.01 for 1 %.
    max_dofs: bound on the largest system solved (the degree-3 estimate of the last level).
    degree: the first answer's degree (default 1; 2 for the mixed formulation).
    project: boundary projection for the refinements (``meshes.refine.projector_for``).
    floor: a probe's target is accuracy * max(|q|, floor * the largest probe |q|) (mm).
    refine: "local" (Doerfler marking of the energy indicators, longest-edge bisection) or
        "uniform" (every cell into 8, or 4 in 2D); theta: the marked share of the squared
        indicators ("local").
    progress: print each step (cells, dofs, worst probe) to stderr.
    solver_options: ReferenceSolver options (formulation, curved, settings, ...).
    Returns AdaptiveResult; raises AccuracyNotReached at max_dofs or at a degree-2 answer that is
    not valid (carrying the last answer before it), CaseError for a case without probes, a bad
    accuracy or a glued patch pushed past the range where its answers converge
    (``Case.glued_unconverged``), ConvergenceError when a solve fails.
    """
    t0 = time.perf_counter()
    if isinstance(case, (str, Path)):
        case, found = load_study_case(case)
        project = project if project is not None else found
    if not case.probes:
        raise CaseError(f"{case.source or case.name}: solve_to_accuracy needs probes: the "
                        f"accuracy is asked of their displacements")
    if refine not in REFINEMENTS:
        raise CaseError(f"refine must be one of {list(REFINEMENTS)}, got {refine!r}")
    if not (isinstance(theta, (int, float)) and 0 < theta <= 1):
        raise CaseError(f"theta must be in (0, 1], got {theta!r}")
    if not (isinstance(accuracy, (int, float)) and 0 < accuracy < 1):
        raise CaseError(f"accuracy must be a relative error in (0, 1), e.g. 0.01, got "
                        f"{accuracy!r}")
    _refuse_unconverged(case, pushes)
    formulation = resolve_formulation(solver_options.pop("formulation", "auto"), case.material)
    p = degree if degree is not None else default_degree(case, formulation)
    if p not in (1, 2) or (formulation == "mixed" and p != 2):
        raise CaseError(f"solve_to_accuracy starts at degree 1 or 2 (2 for the mixed "
                        f"formulation): the estimate needs degree + 1 <= {MAX_DEGREE}, got "
                        f"degree={p}")
    gdim = case.mesh.gdim
    counts = entity_counts(case.mesh)
    level, answer, steps, last, start = 0, None, [], None, None
    finite_strain = case.material.model != "linear-elastic"   # a folded linear answer still solves
    last_case = case  # the mesh of the last answer (set again with every step)
    while True:
        n_est = predicted_dofs(counts, gdim, p + 1, formulation)
        if n_est > max_dofs:
            done = None if last is None else AdaptiveResult(
                last[0], case, tuple(steps), accuracy, False, time.perf_counter() - t0)
            if last is None:
                msg = (f"{case.source or case.name}: the first estimate (degree {p + 1}, "
                       f"{counts[3]:,} cells) needs {n_est:,} dofs, more than "
                       f"max_dofs = {max_dofs:,}")
            else:
                msg = (f"{case.source or case.name}: accuracy {accuracy:.3g} not reached within "
                       f"max_dofs = {max_dofs:,}: the next step (level {level}, degree {p}, "
                       f"estimated at degree {p + 1}) needs {n_est:,} dofs; "
                       f"{_last_answer(steps[-1], accuracy)}")
            raise AccuracyNotReached(msg, result=done)
        ts = time.perf_counter()
        # degree-2 answers of a mesh with curved edges use them, degree-1 answers do not
        curved = getattr(case.mesh, "geometry_order", 1) == 2 and \
            solver_options.get("curved") is not False
        try:
            if answer is None:
                answer = level_answer(case, p, pushes, formulation, solver_options, start)
            if p >= 2 and finite_strain and answer.valid is False:
                kept, kept_case = (last[0], last_case) if last is not None else (answer, case)
                raise AccuracyNotReached(
                    _invalid_level(case, answer, level, p, accuracy, steps),
                    result=AdaptiveResult(kept, kept_case, tuple(steps), accuracy, False,
                                          time.perf_counter() - t0))
            # a degree-2 estimate that will be the next answer is converged fully
            est = error_estimate(case, answer, pushes=pushes, formulation=formulation,
                                 rtol=None if p == 1 and not curved else ESTIMATE_RTOL,
                                 progress=progress, from_rest=estimate_from_rest(case, level),
                                 **solver_options)
        except ConvergenceError as exc:
            if last is None:
                raise
            src = f"{case.source or case.name}: "
            why = str(exc).removeprefix(src)
            raise AccuracyNotReached(
                f"{src}accuracy {accuracy:.3g} not reached: the solves of level {level} "
                f"({case.mesh.n_cells:,} cells, degree {p}) did not converge ({why}); "
                f"{_last_answer(steps[-1], accuracy)}",
                result=AdaptiveResult(last[0], last_case, tuple(steps), accuracy, False,
                                      time.perf_counter() - t0)) from exc
        finally:
            if start is not None:
                forget_solvers(start[0].case.mesh)   # a mesh the loop has left: large factors
                start = None
        targets = _targets(answer.probes, accuracy, floor)
        step = AdaptiveStep(level, p, case.mesh.n_cells, _dofs(answer), _dofs(est.enriched),
                            {k: np.asarray(v, float) for k, v in answer.probes.items()},
                            est.probe_norms, targets, time.perf_counter() - ts)
        steps.append(step)
        last = (est.attach(answer), est)
        last_case = case
        if progress:
            name, ratio = step.worst
            print(f"tissue adapt: level {level}, degree {p}: {step.cells:,} cells, "
                  f"{step.dofs:,} dofs (estimate {step.estimate_dofs:,}): worst probe {name} "
                  f"{step.estimates[name]:.3g} mm = {ratio * accuracy:.3g} relative (target "
                  f"{accuracy:.3g}); {step.wall_time_s:.1f} s", file=sys.stderr, flush=True)
        if step.passed:
            return AdaptiveResult(last[0], case, tuple(steps), accuracy, True,
                                  time.perf_counter() - t0)
        if p == 1:   # degree 2 on the same mesh: the estimate's solve, unless on curved cells
            p, answer = 2, (None if curved else est.enriched)
            continue
        if project is None and getattr(case.mesh, "geometry_order", 1) == 2:
            raise AccuracyNotReached(
                f"{case.source or case.name}: accuracy {accuracy:.3g} not reached on the given "
                f"mesh, and its curved edges would be lost by a uniform refinement without the "
                f"boundary projection: pass project= (meshes.refine.projector_for) or the Case "
                f"file's path", result=AdaptiveResult(last[0], case, tuple(steps), accuracy,
                                                      False, time.perf_counter() - t0))
        if refine == "uniform":
            n_next = predicted_dofs(refined_counts(counts, gdim), gdim, p + 1, formulation)
            if n_next > max_dofs:   # report before refining a mesh that would not be solved
                counts = refined_counts(counts, gdim)
                level += 1
                continue
            mesh = refine_uniform(case.mesh, project=project)
            parents = np.repeat(np.arange(case.mesh.n_cells), 8 if gdim == 3 else 4)
        else:
            ts = time.perf_counter()
            eta = energy_indicators(case, answer, est)
            marked = dorfler_mark(eta, theta)
            mesh, parents = refine_local(case.mesh, marked, project=project,
                                         return_parents=True)
            if progress:
                print(f"tissue adapt: refine local: {len(marked):,} of {case.mesh.n_cells:,} "
                      f"cells marked (theta {theta:g}, energy indicators) -> {mesh.n_cells:,} "
                      f"cells; {time.perf_counter() - ts:.1f} s", file=sys.stderr, flush=True)
        counts = entity_counts(mesh)
        level += 1
        if predicted_dofs(counts, gdim, p + 1, formulation) > max_dofs:
            continue                # the loop's budget check reports it
        case = case.with_mesh(mesh)
        answer = None
        start = (est.solver, est.enriched, parents)    # the next answer's warm start


def estimate_from_rest(case, level: int) -> bool:
    """Whether the estimate of ``level`` is solved along the load path from rest when Newton
    from the interpolated answer does not converge: on the first level, and with indenters (the
    enriched surface nodes change the contact set). On a refined level of glued patches the
    loop stops instead: there the refined rim is what fails, and the solve from rest crawls
    through cut-backs (the phantom at A1 = 5 mm: 79 % of the load after 25 minutes)."""
    return level == 0 or bool(case.indenters())


def _last_answer(step: AdaptiveStep, accuracy: float) -> str:
    """What an AccuracyNotReached message says of the last answer: its size and worst probe."""
    name, ratio = step.worst
    return (f"the last answer ({step.dofs:,} dofs, degree {step.degree}, {step.cells:,} cells) "
            f"has probe {name!r} at {ratio * accuracy:.3g} relative (estimate "
            f"{step.estimates[name]:.3g} mm)")


def _refuse_unconverged(case, pushes) -> None:
    """CaseError where the load is past the range in which answers are known to converge under
    refinement (``model.converged_range.unconverged_load``): refining there would chase a
    limit that is not known to exist, and no estimate bounds an error."""

    if why := unconverged_load(case, pushes):
        raise CaseError(f"{case.source or case.name}: no accuracy can be certified at this load: "
                        f"{'; '.join(why)}")


def _invalid_level(case, answer, level: int, degree: int, accuracy: float,
                   steps: list) -> str:
    """What AccuracyNotReached says of a level whose answer is not valid (inverted cells): the
    refinement went where the model has no regular solution (the rim of a glued patch pushed
    deep), and refining further would only chase it; the last valid answer is handed back."""
    rims = [w for w in answer.warnings if w.startswith("glued patch")]
    last = (f"{_last_answer(steps[-1], accuracy)}, handed back" if steps else
            "there is no earlier answer: this one is handed back, flagged invalid")
    return (f"{case.source or case.name}: accuracy {accuracy:.3g} not reached: the answer of "
            f"level {level} ({answer.n_cells:,} cells, degree {degree}) is not valid "
            f"({answer.invalid_reason})" + "".join(f"; {w}" for w in rims)
            + f"; refining further would chase that point; {last}")


def level_answer(case, degree, pushes, formulation, options, start):
    """The degree-``degree`` answer of ``case``: warm-started from ``start`` = (solver, answer,
    parents) of the coarser level (its enriched answer, carried to the refined mesh by
    ``transfer.prolong``), or from rest when there is none, when the warm start does not converge
    within WARM_ANSWER_ITERATIONS, or for the mixed formulation (its pressure is not carried)."""
    if start is not None and formulation == "displacement" and degree >= 2:
        ref = solver_for(case, degree, formulation=formulation, **options)
        try:
            init = prolong(start[0], start[1], ref, start[2])
            return ref.solve(pushes, case=case, initial=init,
                             settings=warm_settings(ref.settings, WARM_ANSWER_ITERATIONS),
                             residual_line_search=True)
        except (CaseError, ConvergenceError):
            pass
    return solve(case, degree=degree, pushes=pushes, formulation=formulation, **options)


def _dofs(result: SolveResult) -> int:
    """The unknowns of the reference answer ``result`` (0 when it does not say)."""
    return int((result.discretization or {}).get("dofs", 0))
