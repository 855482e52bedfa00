"""Newton's and the load stepping's settings (``NewtonSettings``), their JSON record and the
per-solve counters of the reference's assembly and linear solves. Units: mm, mN."""
from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class NewtonSettings:
    """Newton and load-stepping controls.

    Attributes
    ----------
    rtol, atol : float
        residual reduction within the final load step / absolute residual, the latter
        relative to the force scale E h_min^2 (mN; dimensionless: a displacement-controlled
        solve then stops at the same state whatever E's magnitude);
    atol_mm : float
        Newton correction (inf-norm, mm) under which the final step is converged;
    intermediate_rtol, intermediate_atol_mm : float
        the same, for load steps before the last (their states
        only start the next step, so they need not be converged to round-off). A solve that
        fails converges its last such state to the final step's tolerances before reporting it
        (``ConvergenceError.last_converged``). 1e-4 instead of 1e-6 took all four tips of the
        quarter indenter phantom to 5 mm in 33 Newton iterations instead of 47, to the same
        answer within 1e-9; 1e-3 took 56 instead of 33 from 10 to 12.5 mm
        (bench/bench_default_accuracy.py --case quarter --old newton: 1e-6 with the lagged
        factorization);
    max_iterations : int
        Newton iterations per load step before it counts as failed and is cut
        back; past them Newton goes on while each correction is taken whole and at least halves
        the residual (``newton.CONTRACTION``: converging), up to twice as many. A step one or
        two corrections from converging is not thrown away (a tip pushed from 10 to 12.5 mm
        took 25 iterations to a residual of 1.7e-4 mN, then 27 more after the cut-back);
    max_step_mm : float
        largest prescribed-displacement increment of the first try;
    min_fraction : float
        smallest load increment, as a fraction of the whole load, that a cut-back may
        reach before the solve fails (ConvergenceError);
    grow : float
        factor of the next load increment after a step that converged within 5 iterations
        (with indenters ``contact_grow``);
    line_search : int
        halvings of a Newton correction allowed when it inverts an element (non-finite
        residual: after the last one the step counts as failed) or, with indenters, raises the
        total energy (the last halving is taken regardless). 8: on the indenter half phantom
        (P2, 32k unknowns, A1 = 5 mm) 64 Newton iterations instead of 164 with 4, where each
        forced quarter-step that raised the energy set Newton wandering;
    lag_max_its : int
        "lagged" linear solver: GMRES iterations above which the tangent is refactorized.
    predictor : str
        start of each load step after the first: "none" (the last converged state;
        Newton's first step from it, with the new boundary values, is the exact tangent predictor)
        or "secant" (linear extrapolation of the last two converged states: on the phantom at
        degree 2 it overshoots into inverted cells near the actuator rims, 6 factorizations
        instead of 3, 1.5-1.8x slower);
    contact_curvature_after_halving : str
        with indenters, the correction after a halved one is
        computed with the tips' curvature terms dropped from the penalty's Hessian ("drop",
        fem_reference.contact) or with the exact tangent ("keep").
    contact_curvature_below : float
        with indenters, Newton's matrix leaves the tips' curvature terms
        out (a positive semi-definite contact term) while the residual is above this fraction of
        its value at the load step's start, and is the exact tangent below it, so the last
        iterations converge quadratically (math.inf: exact from the first iteration). Far from
        the answer the curvature of a tip that skin nodes sit deep in makes the corrections
        long and the line search cuts them to 1/16-1/128. Where the tips press hard their
        curvature carries the tangent and the matrix without it converges slowly: a whole step
        that leaves more than half the residual (``newton.CONTRACTION``) makes the rest of the
        load step exact (without that, all four tips stalled near 14 mm).
    tip_step : float
        with indenters, each load increment moves a tip by at most this fraction of its
        radius (failed ones are cut back);
    contact_intermediate_rtol : float
        with indenters, the residual reduction of the load steps before
        the last, instead of ``intermediate_rtol``. A step's first correction, the tangent's
        predictor of the tips' increment, takes the residual of their fresh penetration down
        200-fold (the quarter indenter phantom, all four tips: 1.1e4 to 35-70 mN); the
        corrections after it are mostly cut to 1/256-1/16 by the energy line search while the
        contact set moves, 6-9 Newton iterations a step at 1e-4. At 1e-2 a step before the last
        ends after its predictor and only the last converges, so the increments are kept small
        (``tip_step`` 0.1: the predictors' error accumulates) and do not grow (``contact_grow``
        1: every such step is quick; growing by 1.5 took 79 and 135 instead of 27 and 29
        iterations at 10 and 15 mm).
        The answer is the same: the last step converges to ``rtol`` (forces equal to 1e-9).
        That quarter phantom pushed along 5 / 10 / 12.5 / 15 mm: 19 / 27 / 27 / 29 Newton
        iterations against 33 / 49 / 33 / 37 with 1e-4 and ``tip_step`` 0.2
        (bench/bench_default_accuracy.py --case quarter --old stepping);
    contact_grow : float
        with indenters, the factor of the next load increment after a step that
        converged within 5 iterations (``grow`` without them);
    descent_shift : float
        with indenters, a Newton correction that is not a descent direction of the
        total energy, or whose tangent's factorization has negative pivots (tissue crushed
        against a tip: the corrections are huge), is solved again, first without the tips'
        curvature in the penalty's Hessian, then with mu |diag K| added to the tangent
        (Levenberg-Marquardt), mu starting at this value and growing tenfold until the tangent
        is positive definite and the correction descends (four times at most); the shift stays
        until a correction is taken whole. 0: never shift. On the whole indenter phantom (P2,
        59k unknowns, all four tips at 5 mm) it takes 392 Newton iterations down to 106
        (bench/bench_indenter_newton.py);
    interpolate : bool
        with indenters, the energy line search's next step length is the minimizer
        of the quadratic through the energy, its slope and the refused trial (kept within
        [0.1, 0.5] of the trial) instead of half the trial. Off by default: it took more Newton
        iterations than halving on the indenter phantoms (70 against 61 for A1 alone on the
        half phantom, 112 against 106 for all four on the whole one) and on the block.
    follow_tips : bool
        with indenters, each trial of the energy line search is also bent along the tips, and
        the one of lower energy is tried: in the bent one a node pressed into a tip keeps the
        gap its linearization predicts instead of leaving the curved tip along the straight
        correction (``Contact.follow_tips``; the discrete problem is unchanged). Off by default:
        on the quarter indenter phantom (P2, all four tips from rest) it takes 31 instead of 37
        Newton iterations at 10 mm and 47 instead of 52 at 12.5 mm, 19 either way at 5 mm, where
        its second energy per trial costs time (bench/bench_indenter_newton.py --settings default
        bent); a tip retracted from pressed skin takes 96 iterations either way. It has not yet
        run through the suite's other contact cases and control loops.
    """

    rtol: float = 1e-10
    atol: float = 1e-11
    atol_mm: float = 1e-10
    intermediate_rtol: float = 1e-4
    intermediate_atol_mm: float = 1e-6
    max_iterations: int = 25
    max_step_mm: float = 5.0
    min_fraction: float = 1.0 / 1024
    grow: float = 1.5
    line_search: int = 8
    lag_max_its: int = 12
    predictor: str = "none"
    contact_curvature_after_halving: str = "drop"
    contact_curvature_below: float = 1e-4
    tip_step: float = 0.1
    contact_intermediate_rtol: float = 1e-2
    contact_grow: float = 1.0
    descent_shift: float = 1e-2
    interpolate: bool = False
    follow_tips: bool = False

    def __post_init__(self):
        for name in ("rtol", "atol", "atol_mm", "intermediate_rtol", "intermediate_atol_mm",
                     "max_step_mm", "min_fraction", "tip_step", "contact_intermediate_rtol",
                     "grow", "contact_grow"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and v > 0 and math.isfinite(v)):
                raise ValueError(f"NewtonSettings.{name} must be a positive number, got {v!r}")
        if self.max_iterations < 1:
            raise ValueError(f"NewtonSettings.max_iterations must be >= 1, got "
                             f"{self.max_iterations}")
        if self.contact_curvature_after_halving not in ("drop", "keep"):
            raise ValueError("NewtonSettings.contact_curvature_after_halving must be 'drop' or "
                             "'keep'")
        if self.predictor not in ("secant", "none"):
            raise ValueError(f"NewtonSettings.predictor must be 'secant' or 'none', got "
                             f"{self.predictor!r}")
        if not (isinstance(self.contact_curvature_below, (int, float))
                and self.contact_curvature_below > 0):
            raise ValueError(f"NewtonSettings.contact_curvature_below must be a number > 0 "
                             f"(math.inf: the exact tangent throughout), got "
                             f"{self.contact_curvature_below!r}")
        if not (self.descent_shift >= 0 and math.isfinite(self.descent_shift)):
            raise ValueError("NewtonSettings.descent_shift must be a finite number >= 0")
        if self.line_search < 0 or self.lag_max_its < 1:
            raise ValueError("NewtonSettings.line_search must be >= 0 and lag_max_its >= 1")


def settings_json(settings: NewtonSettings | None = None) -> dict:
    """The reference's settings as the JSON outputs record them: ``{"newton": {...}}`` with every
    field of ``settings`` (default: the defaults, which the command line does not change)."""
    import dataclasses

    return {"newton": dataclasses.asdict(settings or NewtonSettings())}


@dataclass
class Timings:
    """Per-solve counters: seconds in assembly, linear solves and setup; factorizations, Krylov
    iterations, preconditioner builds, and Newton corrections solved with a shifted tangent."""

    assemble: float = 0.0
    solve: float = 0.0
    setup: float = 0.0
    factorizations: int = 0
    krylov_iterations: int = 0
    preconditioner_builds: int = 0
    shifts: int = 0

    def reset(self):
        """Zero the counters of a new solve; the setup time stays."""
        for name, value in vars(type(self)()).items():
            if name != "setup":
                setattr(self, name, value)
