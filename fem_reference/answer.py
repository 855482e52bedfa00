"""A reference answer, composed: the solve (on a kept solver, ``kept.solver_for``; a symmetric
load on a mirrored mesh on its symmetric part, ``symmetric``), then the
measured accuracy a case file states for exactly that load and discretization (``measured``),
then, when asked, the estimated discretization error (``estimate``), then the warnings an answer
that is not valid or not converged deserves (``model.answer_warnings``). ``fem_reference.solve``
is this module's ``solve``."""
from __future__ import annotations

from tissue_reference.errors import CaseError
from tissue_reference.model.answer_warnings import warn_about
from tissue_reference.model.case import Case
from tissue_reference.model.results import SolveResult

from .estimate import auto_estimate
from .estimate import estimate as with_estimate
from .measured import with_measured_accuracy
from .symmetric import estimate_split, solve_split

__all__ = ["solve"]


def solve(case: Case, *, degree: int | None = None, pushes=None, initial=None,
          dirichlet_override=None, progress: bool = False, estimate: bool | str = False,
          symmetry: bool = True, **kw) -> SolveResult:
    """Solve a Case with the reference (compiled forms are cached per mesh and degree).

    degree, formulation (in ``kw``) and the other options: see ReferenceSolver; the default
    degree is the case's (``[reference] degree``), else mixed P2/P1 for nu >= 0.49 and P1
    displacement below.
    pushes: actuator name -> push (mm); initial: warm start (n_vertices, gdim) mm;
    dirichlet_override: (node-major Case dofs, values in mm) added to the Case's prescriptions.
    estimate: add the estimated discretization error (``fem_reference.estimate``: one more solve
    at degree + 1): the fields probe_error_estimates (mm) and reaction_error_estimates (mN),
    the method and its cost in ``extra``; "auto": only where that is cheap
    (``estimate.auto_estimate``; otherwise the field ``estimate_note`` says why there is none),
    as ``tissue solve`` does by default.
    A case file's measured accuracy for exactly this load and discretization
    (``[reference.measured]``, ``fem_reference.measured``) is in ``extra["measured_accuracy"]``.
    An answer that is not valid, past the loads where answers converge, or with an estimated
    error above 2 % also warns (``errors.TissueWarning``; ``model.answer_warnings``).
    symmetry: on a mesh joined from a symmetric part and its mirror images (``meshes.mirror``,
    e.g. the builtin ``phantom-symmetric``) under a load symmetric about the mirror planes,
    solve the part with its planes sliding (the same discrete problem) and mirror its answer
    back onto the whole mesh (``fem_reference.symmetric``; ``SolveResult.symmetry`` says which was
    solved; its error estimate is the part's too); False: solve the whole mesh.

    Parameters
    ----------
    case : Case
        The problem: mesh (mm), material (kPa), boundaries, probes and actuators.
    degree : int or None
        Lagrange degree of the displacement, 1, 2 or 3; None: the case's, else the default above.
    pushes : dict or None
        Actuator name -> push (mm) along its direction; None: every actuator at its case value.
    initial : array_like or SolveResult or None
        Warm start: (n_vertices, gdim) displacement (mm) or an earlier reference answer on this
        mesh (``ReferenceSolver.solve``); None: the rest state.
    dirichlet_override : tuple or None
        (node-major Case dofs, values in mm at full load) added to the Case's prescriptions;
        refused with ``estimate``.
    progress : bool
        Log each load step and Newton iteration.
    estimate : bool or str
        True, False or "auto": the estimated discretization error, as above.
    symmetry : bool
        Solve a symmetric load on a mirrored mesh's symmetric part (True, default), or the
        whole mesh (False).
    **kw
        The other options of ``ReferenceSolver`` (formulation, settings, linear_solver, ...).

    Returns
    -------
    SolveResult
        The answer: ``u`` (mm), ``probes`` (mm), ``reactions`` (mN), ``strain_energy`` (uJ), its
        validity, warnings and, when asked, its error estimates (mm, mN).

    Raises
    ------
    CaseError
        For an ``estimate`` that is not True, False or "auto", ``estimate`` with
        ``dirichlet_override``, or options the reference does not take.
    ConvergenceError
        When a load step still fails after the cut-backs.
    """
    if estimate not in (False, True, "auto"):
        raise CaseError(f"estimate must be True, False or 'auto', got {estimate!r}")
    if estimate and dirichlet_override is not None:
        raise CaseError(f"estimate={estimate!r}: the error estimate does not take "
                        f"dirichlet_override")
    res, split = solve_split(case, degree, pushes=pushes, initial=initial,
                             dirichlet_override=dirichlet_override, progress=progress,
                             symmetry=symmetry, **kw)
    if dirichlet_override is None:   # another problem than the case's: no row describes it
        res = with_measured_accuracy(case, res, pushes)
    if estimate and split is not None:   # on the part too (symmetric.estimate_split)
        res = estimate_split(case, res, split, auto=estimate == "auto", progress=progress, **kw)
    elif estimate:   # the estimate's degree is the answer's + 1, whatever degree asked for
        add = auto_estimate if estimate == "auto" else with_estimate
        res = add(case, res, pushes=pushes, progress=progress, **kw)
    return warn_about(res)
