"""MUMPS factorizations that recover: a factorization that runs out of the workspace MUMPS sized
at its analysis is repeated on a new factor with a larger ICNTL(14), the percentage MUMPS adds
to its estimate. Numerical pivoting of an indefinite matrix (the mixed formulation's saddle
point, a contact tangent) delays pivots beyond the estimate; in parallel the delays depend on
the order in which messages arrive, so the same matrix can factorize in one run and not in the
next. Used by the reference's Newton (``linalg``, ``saddle``) and its one-off solves."""
from __future__ import annotations

import logging

from petsc4py import PETSc

log = logging.getLogger("tissue.fem")

__all__ = ["MUMPS_WORKSPACE_ERRORS", "MUMPS_WORKSPACE_MAX", "grown_mumps_workspace",
           "mumps_failure", "set_mumps_workspace", "solve_mumps"]

# MUMPS's INFOG(1) values that say a workspace sized at the analysis was too small
MUMPS_WORKSPACE_ERRORS = frozenset({-8, -9, -11, -12, -14, -15, -17, -20})
# the largest ICNTL(14) (percent) the workspace is grown to, doubling from MUMPS's default
MUMPS_WORKSPACE_MAX = 1000


def mumps_failure(ksp) -> int:
    """MUMPS's INFOG(1) when ``ksp``'s last solve failed in a MUMPS factorization, else 0.

    PETSc 3.18 never factorizes such a factor again (MatFactorNumeric_MUMPS returns at once
    while INFOG(1) < 0): every later solve of ``ksp`` fails too, and a new KSP is needed."""
    if ksp.getConvergedReason() != PETSc.KSP.ConvergedReason.DIVERGED_PCSETUP_FAILED:
        return 0
    try:
        pc = ksp.getPC()
        if pc.getFactorSolverType() != "mumps":
            return 0
        return min(int(pc.getFactorMatrix().getMumpsInfog(1)), 0)
    except PETSc.Error:
        return 0


def grown_mumps_workspace(ksp, current: int | None = None) -> int | None:
    """The ICNTL(14) (percent) to factorize ``ksp``'s matrix again with, on a new KSP, when its
    last MUMPS factorization ran out of workspace: twice ``current`` (None: the factor's own
    setting), at most MUMPS_WORKSPACE_MAX. None when the solve did not fail that way or the
    workspace is at its limit (logged)."""
    info = mumps_failure(ksp)
    if not info:
        return None
    if info not in MUMPS_WORKSPACE_ERRORS:
        log.debug("MUMPS factorization failed (INFOG(1) = %d)", info)
        return None
    if current is None:
        current = int(ksp.getPC().getFactorMatrix().getMumpsIcntl(14))
    if current >= MUMPS_WORKSPACE_MAX:
        log.info("MUMPS factorization failed for want of workspace (INFOG(1) = %d) with "
                 "ICNTL(14) = %d %%", info, current)
        return None
    grown = min(2 * max(current, 10), MUMPS_WORKSPACE_MAX)
    log.info("MUMPS needed more workspace than its analysis estimated (INFOG(1) = %d): "
             "factorizing again with ICNTL(14) = %d %%", info, grown)
    return grown


def set_mumps_workspace(ksp, percent: int | None):
    """ICNTL(14) of ``ksp``'s MUMPS factor (its operators set); None leaves MUMPS's default."""
    if percent is None:
        return
    pc = ksp.getPC()
    pc.setFactorSetUpSolverType()
    pc.getFactorMatrix().setMumpsIcntl(14, int(percent))


def solve_mumps(ksp, b, x, rebuild):
    """``ksp.solve(b, x)`` with ``ksp`` a MUMPS factorization; returns the KSP to use from now
    on. That is ``ksp`` unless its factorization failed; then it is a new one from
    ``rebuild(percent)`` (a KSP on the same operators, its ICNTL(14) set to ``percent``). After
    a failure for want of workspace the new KSP, its workspace grown, has solved again (and
    maybe failed again, up to the limit); after any other failure it is unsolved, so its
    converged reason (0) still says that the solve failed."""
    ksp.solve(b, x)
    while mumps_failure(ksp):
        grown = grown_mumps_workspace(ksp)
        percent = grown if grown is not None else \
            int(ksp.getPC().getFactorMatrix().getMumpsIcntl(14))
        ksp.destroy()
        ksp = rebuild(percent)
        if grown is None:
            return ksp
        ksp.solve(b, x)
    return ksp
