"""A reference answer, composed: the solve (on a kept solver, ``kept.solver_for``), then the
measured accuracy a case file states for exactly that load and discretization (``measured``),
then, when asked, the estimated discretization error (``estimate``), then the warnings an answer
that is not valid or not converged deserves (``meshes.answer_warnings``). ``fem_reference.solve``
is this module's ``solve``."""
from __future__ import annotations

from tissue_reference.meshes.answer_warnings import warn_about
from tissue_reference.meshes.case import Case
from tissue_reference.meshes.errors import CaseError
from tissue_reference.meshes.results import SolveResult

from .estimate import auto_estimate
from .estimate import estimate as with_estimate
from .kept import solver_for
from .measured import with_measured_accuracy

__all__ = ["solve"]


def solve(case: Case, *, degree: int | None = None, pushes=None, initial=None,
          dirichlet_override=None, progress: bool = False, estimate: bool | str = False,
          **kw) -> SolveResult:
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
    error above 2 % also warns (``meshes.errors.TissueWarning``; ``meshes.answer_warnings``).
    """
    if estimate not in (False, True, "auto"):
        raise CaseError(f"estimate must be True, False or 'auto', got {estimate!r}")
    if estimate and dirichlet_override is not None:
        raise CaseError(f"estimate={estimate!r}: the error estimate does not take "
                        f"dirichlet_override")
    s = solver_for(case, degree, **kw)
    res = s.solve(pushes, case=case, initial=initial, dirichlet_override=dirichlet_override,
                  progress=progress)
    if dirichlet_override is None:   # another problem than the case's: no row describes it
        res = with_measured_accuracy(case, res, pushes)
    if estimate:   # the estimate's degree is the answer's + 1, whatever degree asked for
        add = auto_estimate if estimate == "auto" else with_estimate
        res = add(case, res, pushes=pushes, progress=progress, **kw)
    return warn_about(res)
