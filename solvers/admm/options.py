"""``SolveOptions``: the keyword options of one ADMM ``solve`` (``driver``), checked and with
their defaults resolved (the iteration budget, the polish's tolerance and hand-over residual,
which depend on the polish chosen)."""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from tissue_reference.errors import CaseError

from .dynamics import ImplicitEuler


@dataclass(frozen=True)
class SolveOptions:
    """The options of one ADMM solve: each attribute is the keyword parameter of ``solve`` of
    the same name, with its default, meaning and unit (mm, kPa, s) as ``solve``'s Parameters
    section gives them (tol_mm, max_iter, rho, polish, polish_tol_mm, polish_max_iter,
    dynamics, callback, load_steps, step_mm, intermediate_tol_mm, lift, handoff_mm, tip_step,
    progress, factorize, device, contact_quadrature, contact_penalty, tip_start, anderson).
    ``resolved`` checks them and fills in the defaults that depend on the polish."""

    tol_mm: float = 1e-4
    max_iter: int | None = None
    rho: float | None = None
    polish: bool | str = True
    polish_tol_mm: float | None = None
    polish_max_iter: int = 25
    dynamics: ImplicitEuler | None = None
    callback: object = None
    load_steps: int | None = None
    step_mm: float = 3.0
    intermediate_tol_mm: float = 1e-2
    lift: bool | str = "auto"
    handoff_mm: float | None = None
    tip_step: float = 0.5
    progress: bool = False
    factorize: object = None
    device: str = "cpu"
    contact_quadrature: str | int | None = None
    contact_penalty: float | None = None
    tip_start: str | None = None
    anderson: int = 0

    def resolved(self, case) -> SolveOptions:
        """These options checked, with the defaults that depend on the polish filled in.

        Parameters
        ----------
        case : Case
            The Case solved (named in the errors).

        Returns
        -------
        SolveOptions
            ``max_iter`` an int (20 with a polish, else 20000, when None), ``polish_tol_mm``
            (mm; tol_mm / 100 for Newton, tol_mm for the chord polish, when None) and
            ``handoff_mm`` (mm; 0.01 for Newton, 0.1 for the chord polish, when None) set.

        Raises
        ------
        CaseError
            For a ``tol_mm`` or ``max_iter`` out of range, a ``polish`` other than True, False
            or "chord", or a chord polish in dynamics.
        """
        if not (np.isfinite(self.tol_mm) and self.tol_mm > 0):
            raise CaseError(f"tol_mm must be > 0 mm, got {self.tol_mm!r}")
        max_iter = self.max_iter
        if max_iter is None:
            max_iter = 20 if self.polish else 20000
        if int(max_iter) < 1:
            raise CaseError(f"max_iter must be >= 1, got {max_iter!r}")
        if self.polish not in (True, False, "chord"):
            raise CaseError(f"polish must be True, False or 'chord', got {self.polish!r}")
        chord = self.polish == "chord"
        polish_tol_mm = self.polish_tol_mm
        if polish_tol_mm is None:
            polish_tol_mm = self.tol_mm if chord else self.tol_mm / 100.0
        handoff_mm = self.handoff_mm
        if handoff_mm is None:
            handoff_mm = 0.1 if chord else 1e-2
        if chord and self.dynamics is not None:
            raise CaseError(f"{case.source or case.name}: polish='chord' is for quasi-static "
                            f"solves (its tangent at rest has no inertia): use polish=True")
        return replace(self, max_iter=int(max_iter), polish_tol_mm=polish_tol_mm,
                       handoff_mm=handoff_mm)

    @property
    def use_chord(self) -> bool:
        """Whether the polish is the chord polish."""
        return self.polish == "chord"

    @property
    def dt(self) -> float | None:
        """The time step (s) of the dynamics; None for quasi-static equilibrium."""
        return self.dynamics.dt if self.dynamics is not None else None

    @property
    def contact(self) -> dict:
        """The contact settings given ("rule", "penalty", "tip_start"), for ``prepare``."""
        return {k: v for k, v in (("rule", self.contact_quadrature),
                                  ("penalty", self.contact_penalty),
                                  ("tip_start", self.tip_start)) if v is not None}

    def admm_tol(self, tol: float) -> float:
        """Where ADMM stops (mm) for a step of tolerance ``tol`` (mm): at the polish's hand-over
        residual with a polish (the larger of the two), else at ``tol``.

        Parameters
        ----------
        tol : float
            The step's tolerance (mm).

        Returns
        -------
        float
            ADMM's stopping tolerance (mm) on the primal and dual residuals.
        """
        return max(tol, self.handoff_mm) if self.polish else tol
