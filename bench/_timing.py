"""Timing helpers shared by the bench scripts (imported from this folder, which ``python
bench/<script>.py`` puts first on the path)."""
from __future__ import annotations

import time

import numpy as np


def best(f, repeat, before=None):
    """(result, best time of ``repeat`` calls of f); ``before()`` runs untimed before each.

    Parameters
    ----------
    f : callable
        What is timed, called without arguments.
    repeat : int
        How many calls of f; the time is the shortest.
    before : callable, optional
        Called without arguments, untimed, before each call of f.

    Returns
    -------
    tuple
        (the last call's result, the best wall time in s).
    """
    out, t_best = None, np.inf
    for _ in range(repeat):
        if before is not None:
            before()
        t0 = time.perf_counter()
        out = f()
        t_best = min(t_best, time.perf_counter() - t0)
    return out, t_best
