"""The backtracking line search on an energy that the fast solvers' Newton-like iterations share
(ADMM's Newton polish, ``solvers.admm.polish``; its chord polish where a correction moves points
into or out of contact, ``solvers.admm.chord``; the Mass Tensor Method's Newton on the condensed
contact, ``solvers.mass_tensor.contact``).

From a state with energy e0 along a direction with slope s0 (the energy's derivative there along
the direction, negative for a descent direction), the steps t = 1, 1/2, 1/4, ... are tried in
turn, ``tries`` of them at the most (the shortest 2^-(tries - 1)), and the first that the energy
accepts is taken (Armijo's sufficient decrease, up to round-off):

    e(t) <= e0 + ARMIJO t s0 + round_off scale,

scale = |e0|, or with ``round_off_of_both`` max(|e0|, |e(t)|, 1e-300). A trial point that is not
admissible (an inverted cell: its energy given as None) is halved without testing; one whose
energy is not finite is refused; one that fails the test may still be taken where the caller's
``fallback`` accepts it (the Newton polish: a decrease of the free residual where the tangent is
indefinite).

Units: the energy's (uJ with mm and mN); t is a fraction of the direction, without unit.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["ARMIJO", "Step", "backtrack", "sufficient_decrease"]

ARMIJO = 1e-4
"""The fraction of the linear decrease t s0 a step must achieve (Armijo's constant)."""


@dataclass(frozen=True)
class Step:
    """The step a line search took: its length t (a fraction of the direction), the energy there
    (uJ), whatever the trial returned with it (``state``) and the halvings it took (t =
    2^-halvings)."""

    t: float
    energy: float
    state: Any
    halvings: int


def sufficient_decrease(e1: float, e0: float, slope: float, t: float, *,
                        armijo: float = ARMIJO, round_off: float = 1e-12,
                        round_off_of_both: bool = False) -> bool:
    """Whether a step of length t lowers the energy enough (Armijo, up to round-off).

    Parameters
    ----------
    e1 : float
        The energy at the step (uJ).
    e0 : float
        The energy at the start (uJ).
    slope : float
        The energy's derivative along the direction at the start (uJ per unit step; negative
        for a descent direction).
    t : float
        The step's length, a fraction of the direction (no unit).
    armijo : float
        The fraction of the linear decrease ``t * slope`` required (no unit).
    round_off : float
        The energy's relative round-off allowed above the Armijo line (no unit).
    round_off_of_both : bool
        The round-off relative to the larger of |e0| and |e1| (at least 1e-300 uJ) instead of
        |e0|.

    Returns
    -------
    bool
        True where e1 is finite and e1 <= e0 + armijo t slope + round_off scale.
    """
    scale = max(abs(e0), abs(e1), 1e-300) if round_off_of_both else abs(e0)
    return bool(np.isfinite(e1)) and e1 <= e0 + armijo * t * slope + round_off * scale


def backtrack(trial: Callable[[float], tuple], e0: float, slope: float, *, tries: int,
              armijo: float = ARMIJO, round_off: float = 1e-12, round_off_of_both: bool = False,
              fallback: Callable[[float, Any], bool] | None = None) -> Step | None:
    """The first step t = 1, 1/2, 1/4, ... along a direction that the energy accepts (module
    docstring).

    Parameters
    ----------
    trial : callable
        ``trial(t) -> (e, state)``: the energy (uJ) at the step of length t along the direction,
        None where that point is not admissible (halved untested), and whatever the caller wants
        back with the step taken (``Step.state``).
    e0 : float
        The energy at the start (uJ).
    slope : float
        The energy's derivative along the direction at the start (uJ per unit step).
    tries : int
        The most steps tried: the shortest is 2^-(tries - 1).
    armijo, round_off, round_off_of_both
        The acceptance test's constants (``sufficient_decrease``).
    fallback : callable, optional
        ``fallback(t, state) -> bool``: whether an admissible step that fails the test is taken
        all the same.

    Returns
    -------
    Step or None
        The step taken (its length, energy, the trial's state and the halvings), or None where
        none of the ``tries`` steps was accepted.
    """
    t = 1.0
    for k in range(tries):
        e1, state = trial(t)
        if e1 is not None and (
                sufficient_decrease(e1, e0, slope, t, armijo=armijo, round_off=round_off,
                                    round_off_of_both=round_off_of_both)
                or (fallback is not None and fallback(t, state))):
            return Step(t, e1, state, k)
        t *= 0.5
    return None
