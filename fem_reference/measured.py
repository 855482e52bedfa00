"""What a case file says its own discretization's answers are worth (``[reference.measured]``).

A default discretization fine enough to be accurate is often too large for the automatic error
estimate (one solve at degree + 1): the indenter phantom's P3 estimate would have 303k unknowns.
Its error is measured instead, once, against the converged answers of refinement studies
(docs/verification.md), for the loads the case is meant for. The case file keeps each
measurement as a row: the load (actuator -> push, mm), the discretization measured (its unknowns,
degree, contact rule and tip start) and the largest relative differences of the indenters'
forces and of the probes' displacement vectors from the values they are measured against, with
what those values are and, as ``band``, how far those are themselves from the converged value
(the GCI bands of the study's finest level): the answer's error bar is the sum (``error_bar``).
A load at which no converged value is known is a row with ``converged = false`` and why.

``measured_accuracy`` hands back the row that describes a given answer: the same unknowns,
degree, contact rule, tip start and pushes (to PUSH_TOL mm). Another mesh, degree, rule, start
or load matches no row, so a measurement is never stretched to an answer it was not made for.
Dimensionless fractions (0.01 = 1 %); pushes in mm.
"""
from __future__ import annotations

import dataclasses

from tissue_reference.model.case import Case
from tissue_reference.model.results import SolveResult
from tissue_reference.model.tips import default_contact_rule, default_tip_start

from .discretization import default_degree

__all__ = ["PUSH_TOL", "accuracy_line", "describe", "error_bar", "measured_accuracy",
           "unmatched_note", "with_measured_accuracy"]

PUSH_TOL = 1e-9
"""A measured load matches an answer's when every push agrees to this (mm)."""


def _start(case: Case, result: SolveResult) -> str:
    """Where ``result``'s indenters started ("nodes" or "surface"); the case's without
    indenters."""
    for report in result.indenters.values():
        return report.get("started_on", "nodes")
    return default_tip_start(case)


def _rule(case: Case, result: SolveResult):
    """The contact rule of ``result`` ("nodal" or a Gauss degree); the case's without
    indenters."""
    for report in result.indenters.values():
        return report.get("quadrature", "nodal")
    return default_contact_rule(case)


def measured_accuracy(case: Case, result: SolveResult, pushes=None) -> dict | None:
    """The ``[reference.measured]`` row of ``case`` that describes ``result`` (a reference answer
    of ``case`` under ``pushes``, actuator name -> mm; the others at 0), with ``converged``
    filled in; None when no row has its unknowns, degree, contact rule and pushes."""
    if not case.reference_measured or not result.reference:
        return None
    load = {a.name: float((pushes or {}).get(a.name, 0.0)) for a in case.actuators}
    for row in case.reference_measured:
        if _same_discretization(case, result, row) and all(
                abs(float(row["pushes"].get(name, 0.0)) - push) <= PUSH_TOL
                for name, push in load.items()):
            return {"converged": True, **row}
    return None


def _same_discretization(case: Case, result: SolveResult, row: dict) -> bool:
    """Whether ``row`` was measured on ``result``'s discretization: its unknowns, degree and
    contact rule and where its indenters started (a row's degree and rule default to the case's,
    its start to the case's or, where the case names none, to the one of the row's rule)."""
    disc = result.discretization or {}
    degree = row.get("degree", default_degree(case, disc.get("formulation", "displacement")))
    rule = row.get("contact_quadrature", default_contact_rule(case))
    start = row.get("tip_start", default_tip_start(case, rule))
    return row["dofs"] == disc.get("dofs") and degree == result.degree and \
        rule == _rule(case, result) and start == _start(case, result)


def with_measured_accuracy(case: Case, result: SolveResult, pushes=None) -> SolveResult:
    """``result`` with ``extra["measured_accuracy"]`` (``measured_accuracy``) where a row of the
    case describes it; where the case has rows and none does, ``extra["measured_note"]`` names
    the loads it measured (``unmatched_note``); unchanged for a case without rows."""
    if not case.reference_measured or not result.reference:
        return result
    row = measured_accuracy(case, result, pushes)
    if row is None:
        return dataclasses.replace(result, extra={**result.extra,
                                                  "measured_note": unmatched_note(case, result)})
    warnings = result.warnings
    if not row["converged"]:   # a warning like the solve's own: the CLI, the report, the JSON
        warnings += ((f"no converged value is known at this load ({row['why']}): this answer "
                      f"has no error bar"),)
    return dataclasses.replace(result, extra={**result.extra, "measured_accuracy": row},
                               warnings=warnings)


def unmatched_note(case: Case, result: SolveResult) -> str:
    """Why no row describes ``result``: the loads measured on its discretization, or that its
    discretization (unknowns, degree, contact rule) is not the one measured."""
    same = [r for r in case.reference_measured if _same_discretization(case, result, r)]
    rule = _rule(case, result)
    disc = result.discretization or {}
    if not same:
        dofs = sorted({r["dofs"] for r in case.reference_measured})
        return f"not measured: the case's measurements are of {', '.join(map(str, dofs))} " \
               f"unknowns, this answer has {disc.get('dofs')} (contact rule {rule})"
    loads = "; ".join(", ".join(f"{k} = {v:g}" for k, v in r["pushes"].items()) for r in same)
    return f"not measured for this load: on this discretization (contact rule {rule}) the " \
           f"case measured {loads} mm"


def accuracy_line(extra: dict) -> str | None:
    """The accuracy an answer's entries (``SolveResult.entries()`` or its JSON form) state from
    the case's measurements: its row
    (``describe``), or, where it carries no error estimate of its own, why no row describes it;
    None when neither applies."""
    if extra.get("measured_accuracy"):
        return describe(extra["measured_accuracy"])
    if extra.get("measured_note") and not extra.get("probe_error_estimates"):
        return extra["measured_note"]
    return None


def error_bar(row: dict) -> dict | None:
    """{"force": ..., "probes": ...}: how far an answer that ``row`` describes is from the
    converged value, as fractions: the row's difference from the value it was measured against
    plus that value's own band (``band``; the force only where the row has one); None for a row
    without a band or without a converged value."""
    band = row.get("band")
    if not row.get("converged", True) or band is None:
        return None
    out = {"probes": row["probes"] + band["probes"]}
    if "force" in row:
        out["force"] = row["force"] + band["force"]
    return out


def describe(row: dict) -> str:
    """One line for a measured row: the error bar (the difference from the study's finest level
    plus that level's band), the parts and the reference, or why there is none."""
    if not row.get("converged", True):
        return f"none: no converged value is known at this load ({row['why']})"
    bar = error_bar(row)
    if bar is None:
        force = f"indenter force within {row['force']:.2%}, " if "force" in row else ""
        return f"measured for this discretization and load: {force}probes within " \
               f"{row['probes']:.2%} of the converged value: {row['against']}"
    band = row["band"]
    force = f"indenter force within {bar['force']:.2%}, " if "force" in bar else ""
    parts = (f"{row['force']:.2%} / {row['probes']:.2%} from the study's finest level, which is "
             f"within {band['force']:.2%} / {band['probes']:.2%} of it by its GCI band" if "force"
             in row else f"{row['probes']:.2%} from the study's finest level, which is within "
             f"{band['probes']:.2%} of it by its GCI band")
    return f"measured for this discretization and load: {force}probes within " \
           f"{bar['probes']:.2%} of the converged value ({parts}): {row['against']}"
