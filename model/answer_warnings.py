"""What a caller of the Python API must not miss about an answer, said as Python warnings
(``errors.TissueWarning``): an answer that is not valid, one past the loads where answers
converge (its estimate is then no error bar), a warning the solve recorded, an estimated error
above ESTIMATE_WARN of a probe's displacement (``estimate_warning``). The command line prints the
same lines, as its own warnings instead of Python's.
"""
from __future__ import annotations

import warnings

import numpy as np

from tissue_reference.errors import TissueWarning

__all__ = ["ESTIMATE_WARN", "FOLDED_ADVICE", "advice_for", "answer_concerns",
           "estimate_warning", "probes_above_estimate_warn", "relative_estimates", "warn_about"]

ESTIMATE_WARN = 0.02
"""An estimated error above this fraction of a probe's displacement is worth a warning."""

FOLDED_ADVICE = ("cells fold where the mesh is too coarse for the strain there (or too thin: "
                 "a sliver): refine it (a smaller size, or [mesh] site_size / path_size near "
                 "the actuators), raise the degree, or for a nearly incompressible material "
                 "(nu >= 0.49) use the mixed formulation")
"""What to try when an answer is invalid for inverted cells."""


def advice_for(reason) -> str:
    """What to try for an answer not valid for ``reason`` (``invalid_reason``): FOLDED_ADVICE
    when cells inverted, else ""."""
    return FOLDED_ADVICE if "inverted cell" in str(reason) else ""


def relative_estimates(res) -> dict:
    """Probe -> its estimated error relative to its displacement; only the probes with an
    estimate (``probe_error_estimates``). A probe that did not move has 0 when its
    estimate is 0 too (nothing moved: nothing is wrong), else inf."""
    pe = res.probe_error_estimates
    out = {}
    for k, v in res.probes.items():
        if k in pe:
            size = float(np.linalg.norm(v))
            out[k] = pe[k] / size if size > 0 else (0.0 if pe[k] == 0 else float("inf"))
    return out


def probes_above_estimate_warn(res) -> list[str]:
    """The probes whose estimated error is an error bar above ESTIMATE_WARN of their
    displacement.

    Parameters
    ----------
    res : SolveResult
        An answer, with or without error estimates (``probe_error_estimates``, mm).

    Returns
    -------
    list of str
        Probe names, in the answer's order; none at a load with no mesh-converged answer
        (``no_converged_value``: the estimate is no error bar there) or without estimates.
    """
    if getattr(res, "no_converged_value", ()):
        return []
    return [k for k, rel in relative_estimates(res).items() if rel > ESTIMATE_WARN]


def estimate_warning(res) -> str | None:
    """What the SolveResult ``res``'s estimated discretization errors say, where they say
    something: at a load with no mesh-converged answer (``no_converged_value``) the largest
    difference to degree + 1, relative to its probe's displacement, which is no error bar (the
    lines on why follow it); else the largest estimated error where it is above ESTIMATE_WARN of
    its probe's displacement. None without an estimate or below ESTIMATE_WARN."""
    rel = relative_estimates(res) if hasattr(res, "probes") else {}
    worst = max(rel.values(), default=None)
    if worst is None:
        return None
    if getattr(res, "no_converged_value", ()):
        return (f"the degree-{int(res.degree) + 1} answer differs from this one by up to "
                f"{worst:.1%} of a probe's displacement, but at this load no mesh-converged "
                f"answer is known (below): neither is an error bar, and refining will not "
                f"settle it")
    if worst > ESTIMATE_WARN:
        return (f"estimated discretization error up to {worst:.1%} of a probe's displacement "
                f"(above {ESTIMATE_WARN:.0%}): raise --degree, or refine until it is within a "
                f"tolerance (--accuracy 0.01)")
    return None


def answer_concerns(res) -> list[str]:
    """One line per fact about the SolveResult ``res`` that a caller must not miss: whether it
    is valid, what its estimates say (``estimate_warning``), its warnings, and why no
    mesh-converged answer is known at its load."""
    out = []
    if getattr(res, "valid", None) is False:
        why = res.invalid_reason
        advice = advice_for(why)
        out.append(f"the answer is not valid: {why}" + (f"; {advice}" if advice else ""))
    if line := estimate_warning(res):
        out.append(line)
    out += [str(w) for w in getattr(res, "warnings", ()) or ()]
    why = getattr(res, "no_converged_value", ())
    if why:
        out += [f"no mesh-converged answer is known at this load: {w}" for w in
                ([why] if isinstance(why, str) else why) if str(w) not in out]
    return out


def warn_about(res, stacklevel: int = 3):
    """Warn (TissueWarning) once per line of ``answer_concerns(res)``; returns ``res``."""
    for line in answer_concerns(res):
        warnings.warn(line, TissueWarning, stacklevel=stacklevel)
    return res
