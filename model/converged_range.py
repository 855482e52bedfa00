"""The range of pushes where a model's answers converge under refinement, decided from the
pushes alone, before any solve: a glued patch up to GLUED_CONVERGED_RADII of its radius (its
rim is singular beyond: ``Case.glued_unconverged``), a rounded rigid tip up to
UNCONVERGED_RADII of its radius. A solve, a study or a control loop that goes past it says so.
Units: mm.
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING

from .case_variants import GLUED_CONVERGED_RADII, patch_radius

if TYPE_CHECKING:
    from .case_model import Case

__all__ = ["UNCONVERGED_RADII", "converged_push_limit", "converged_travel", "past_converged_depth",
           "unconverged_load"]


UNCONVERGED_RADII = 2.5
"""Depth (in tip radii) past which no mesh-converged answer is known for a rounded tip: on the
indenter phantom the 5 mm tips converge at 2.5 radii (12.5 mm; GCI bands 1.5-4 %) and part by
2-5 % per level at 3 radii (15 mm), where the skin has slid over the buried ball onto its rod;
8 mm tips converge at 1.9 radii (15 mm). A solve with a tip deeper than this warns."""


def past_converged_depth(depth: float, radius: float) -> bool:
    """Whether a tip ``depth`` mm in (its push; negative: retracted) is deeper than
    UNCONVERGED_RADII of its ``radius`` (mm), where no mesh-converged answer is known."""
    return depth > UNCONVERGED_RADII * radius * (1.0 + 1e-9)


def unconverged_load(case: Case, pushes) -> list[str]:
    """Why no mesh-converged answer is known for ``case`` under ``pushes`` (actuator name ->
    mm), one line per actuator: a glued patch pushed past ``GLUED_CONVERGED_RADII`` of its
    radius (``Case.glued_unconverged``), an indenter deeper than UNCONVERGED_RADII of its tip's;
    [] within the range where answers converge. Decided from the pushes, before any solve."""
    pushes = dict(pushes or {})
    why = list(case.with_pushes(pushes).glued_unconverged().values())
    why += [f"indenter {a.name!r} pushed {float(pushes[a.name]):g} mm, more than "
            f"{UNCONVERGED_RADII:g} of its tip's {a.radius:g} mm radius: no mesh-converged answer "
            f"is known that deep" for a in case.actuators
            if a.type == "indenter" and past_converged_depth(float(pushes.get(a.name, 0.0)),
                                                             a.radius)]
    return why


def converged_travel(case: Case) -> dict[str, float]:
    """Actuator name -> the deepest push (mm) within the range where answers converge: a glued
    patch's GLUED_CONVERGED_RADII radii (``patch_radius``), an indenter's UNCONVERGED_RADII tip
    radii; math.inf for every actuator of a linear-elastic material, whose answer scales with
    the push."""
    if case.material.model == "linear-elastic":
        return {a.name: math.inf for a in case.actuators}
    return {a.name: (UNCONVERGED_RADII * a.radius if a.type == "indenter"
                     else GLUED_CONVERGED_RADII * patch_radius(case.mesh, a.region))
            for a in case.actuators}


def converged_push_limit(*cases: Case) -> float | None:
    """One push limit (mm) that keeps every actuator of every Case in ``cases`` (a loop's plant
    and model) within the range where its answers converge: the smallest of their
    ``converged_travel``; None when nothing limits it (linear-elastic materials)."""
    limit = min((v for c in cases for v in converged_travel(c).values()), default=math.inf)
    return None if math.isinf(limit) else float(limit)
