"""A-posteriori estimate of the discretization error of a reference answer, by p-enrichment.

The answer u_p of degree p (P1 or P2 displacement, Taylor-Hood P2/P1 mixed) is compared with the
answer u_{p+1} of the same Case on the *same mesh* at degree p + 1 (P2, P3, P3/P2 mixed). For
every probe and every Dirichlet region's reaction the estimated error of the degree-p value q_p is

    e_q = q_{p+1} - q_p                 (probes: mm, reactions: mN)

and ``probe_error_estimates`` / ``reaction_error_estimates`` hold its norm |e_q|. Since
q - q_p = e_q + (q - q_{p+1}), the effectivity |e_q| / |q - q_p| tends to 1 when the
degree-(p+1) answer converges faster than the degree-p one. Where both are limited by the same
singularity (a clamped corner, the rim of a rigidly pushed patch) the degree-(p+1) error is a
fraction of the degree-p one and the estimate is low by about that fraction. Measured
(bench/bench_estimate.py, probes): 1.0-1.3 (once 1.8) where the answer is smooth (thick
sphere), 0.8-1.0 for P1 answers, 0.6-0.7 for P2 answers limited by a clamped corner or a patch
rim (Cook's membrane, the phantom), 0.4-0.6 at a point where the P2 error is nearly zero (a
few 1e-5 mm).

The degree-3 solve that estimates a degree-2 answer starts from that answer interpolated (the
mixed pressure too); its first Newton step is then the dual-weighted-residual estimate with the
exact tangent's adjoint in the enriched space (J'(u_p) K_{p+1}^{-1} R_{p+1}(u_p) for every linear
goal J at once), and the further iterations add the nonlinear terms. The degree-2 solve that
estimates a degree-1 answer starts from rest: a coarse P1 answer is a worse start than that.

What it measures: the discretization error of the degree-p answer on the geometry it was
solved on: the enriched solve uses the same cells (straight, or the curved second-order cells of
a degree >= 2 answer on a mesh that carries curved edges). The estimate therefore EXCLUDES the
geometric error of that geometry: the faceting of a curved boundary by straight cells (a
degree-1 answer of a curved body, or ``curved=False``), or the much smaller one of the
quadratic surface of curved cells. A refinement study with the boundary projected onto the true
surface (``fem_reference.convergence``) includes it. Passing ``curved=True`` for a degree-1
answer on a curved mesh enriches onto the curved cells, and the estimate then includes the
faceting (``estimate_includes_geometry`` is True).
The model error (material law, boundary conditions) and the solver error (Newton stops far below
any discretization error) are not part of it.

Reactions are sums of nodal residuals over a region's dofs. A region whose border nodes are also
prescribed by another region (an inner surface meeting symmetry planes) shares those nodes'
forces with it: that share shrinks only as the cells do, at any degree, so such a reaction
converges slowly and its estimate is low (0.36 on the thick sphere's inner surface). Probe
estimates are not affected.

Cost: one solve at degree p + 1 on the same mesh, stopped at a residual reduction of
ESTIMATE_RTOL; for a degree-2 answer warm-started (one load step, a few Newton iterations, a
correction taken only when it lowers the residual norm: ``transfer.warm_settings``), or, when
Newton does not converge from there within WARM_ITERATIONS (large strains on a coarse mesh),
solved along the load path from rest (``estimate_warm_start`` False; ``from_rest=False`` raises
ConvergenceError instead).
``estimate_cost_ratio`` is the estimate's wall time (the enriched solver's set-up included when it
was built for this call) over the degree-p solve's wall time. The enriched problem has 3-7x the
dofs in 3D and a denser, costlier tangent: measured 2-7 for degree-2 answers (0.4-0.9 of a
separate degree-3 solve) and 10-40 for degree-1 answers (about one separate degree-2 solve) on
meshes of 1-3k tetrahedra (bench/bench_estimate.py).

    res = fr.solve(case, pushes={"A1": 5.0}, estimate=True)
    res.probe_error_estimates       # {"T1": 0.012, ...} mm
    res.reaction_error_estimates    # {"act_px": 0.8, ...} mN

Units: mm, kPa, mN. Serial (a degree-2 answer hands its nodal state on in serial runs only).
"""
from __future__ import annotations

import dataclasses
import sys
import time

import numpy as np

from tissue_reference.errors import CaseError, ConvergenceError
from tissue_reference.model.case import Case
from tissue_reference.model.results import SolveResult

from .dof_counts import entity_counts, predicted_dofs
from .kept import solver_for
from .newton_settings import NewtonSettings
from .transfer import match_points, warm_settings

__all__ = ["AUTO_MAX_DOFS", "ESTIMATE_METHOD", "ESTIMATE_RTOL", "MAX_DEGREE", "ErrorEstimate",
           "auto_estimate", "auto_estimate_note", "error_estimate", "estimate"]

ESTIMATE_METHOD = "p-enrichment"
MAX_DEGREE = 3
"""The richest reference degree: answers of degree 1 and 2 can be estimated."""
ESTIMATE_RTOL = 1e-6
"""Newton of the enriched solve stops once its residual has fallen by this factor within the
final load step (from the warm start's, for a degree-2 answer): the Newton error left is then
about this fraction of the estimate itself."""
WARM_ITERATIONS = 24
"""Newton iterations allowed from the interpolated answer before the enriched problem is solved
from rest instead (2-5 on smooth problems; 8-11 on the phantom at A1 = 2 mm once its patch rims
are refined: a damped start, then quadratic convergence; at A1 = 5 mm on the second refined
level 12 damped iterations, then full ones from |R| 7.2 to 0.046 by the 16th)."""


@dataclasses.dataclass(frozen=True)
class ErrorEstimate:
    """The estimated discretization error of one reference answer (see the module docstring).

    probes: probe name -> (gdim,) estimated error vector q_{p+1} - q_p (mm).
    reactions: Dirichlet region -> (gdim,) estimated error vector (mN).
    enriched: the degree-(p+1) SolveResult the estimate comes from.
    includes_geometry: the enriched solve used a curved geometry the answer did not.
    warm_start: the enriched solve started from the answer (degree 2; False for degree 1, or when
        Newton did not converge from there and the solve went along the load path from rest).
    wall_time_s: the estimate's wall time (s), set-up included; setup_s: the part spent building
        the enriched solver (about 0 when it was cached).
    cost_ratio: wall_time_s over the degree-p solve's wall time.
    solver: the enriched ReferenceSolver (its spaces and mesh; per-cell indicators use them,
        ``fem_reference.indicators``).
    """

    method: str
    degree: int
    enriched_degree: int
    probes: dict
    reactions: dict
    enriched: SolveResult
    includes_geometry: bool
    warm_start: bool
    wall_time_s: float
    setup_s: float
    cost_ratio: float
    solver: object = dataclasses.field(default=None, repr=False, compare=False)

    @property
    def probe_norms(self) -> dict:
        """Probe name -> |estimated error| (mm)."""
        return {k: float(np.linalg.norm(v)) for k, v in self.probes.items()}

    @property
    def reaction_norms(self) -> dict:
        """Dirichlet region -> |estimated error| (mN)."""
        return {k: float(np.linalg.norm(v)) for k, v in self.reactions.items()}

    def extras(self) -> dict:
        """The entries ``estimate`` adds to a SolveResult's ``extra`` (all JSON-serializable;
        the probe and reaction norms are its fields, ``attach``)."""
        return {
            "probe_error_vectors": {k: np.asarray(v, float).tolist()
                                    for k, v in self.probes.items()},
            "reaction_error_vectors": {k: np.asarray(v, float).tolist()
                                       for k, v in self.reactions.items()},
            "estimate_method": self.method,
            "estimate_discretization": self.enriched.discretization,
            "estimate_includes_geometry": self.includes_geometry,
            "estimate_warm_start": self.warm_start,
            "estimate_wall_time_s": self.wall_time_s,
            "estimate_setup_s": self.setup_s,
            "estimate_cost_ratio": self.cost_ratio,
        }

    def attach(self, result: SolveResult) -> SolveResult:
        """``result`` with this estimate: its fields ``probe_error_estimates`` (mm) and
        ``reaction_error_estimates`` (mN), and ``extras`` added to its ``extra``."""
        return dataclasses.replace(result, probe_error_estimates=self.probe_norms,
                                   reaction_error_estimates=self.reaction_norms,
                                   extra={**result.extra, **self.extras()})


def error_estimate(case: Case, result: SolveResult, *, pushes=None, progress: bool = False,
                   rtol: float | None = ESTIMATE_RTOL, from_rest: bool = True,
                   **solver_options) -> ErrorEstimate:
    """Estimate the discretization error of ``result``, a reference solve of ``case`` with
    ``pushes`` (actuator name -> mm), by one solve at degree ``result.degree + 1`` on the same
    mesh (module docstring).

    rtol: residual reduction at which the enriched Newton stops (None: the solver settings' own,
        1e-10: a fully converged degree-(p+1) answer, e.g. to be used as an answer itself).
    from_rest: when Newton from the interpolated degree-2 answer does not converge, solve along
        the load path from rest (True), or raise ConvergenceError (False: for a caller with a
        cheaper way out than the from-rest solve).
    solver_options: the ReferenceSolver options of the degree-p solve (formulation, curved,
        settings, sliding_penalty, body_force, linear_solver); the formulation defaults to the
        one recorded in ``result.discretization``; a quadrature_degree is not passed
        on (the enriched degree has its own).
    Raises CaseError when the answer cannot be enriched (degree 3, not a reference answer of this
    mesh, a degree-2 answer without its nodal state) and ConvergenceError when the enriched
    solve fails.
    """
    t0 = time.perf_counter()
    if not result.reference:
        raise CaseError(f"error estimates are for reference (fem) answers, got a "
                        f"{result.solver!r} result")
    if result.n_vertices != case.mesh.n_vertices:
        raise CaseError(f"the answer has {result.n_vertices} vertices, the case mesh "
                        f"{case.mesh.n_vertices}: estimate an answer of this case")
    p = int(result.degree)
    if p + 1 > MAX_DEGREE:
        raise CaseError(f"a degree-{p} answer cannot be estimated by p-enrichment: the richest "
                        f"reference degree is {MAX_DEGREE}; estimate a degree-{MAX_DEGREE - 1} "
                        f"answer (or refine the mesh)")
    disc = result.discretization or {}
    options = dict(solver_options)
    options.pop("degree", None)
    options.pop("quadrature_degree", None)
    options.setdefault("formulation", disc.get("formulation", "auto"))
    if "geometry_order" in disc and hasattr(case.mesh, "geometry_order"):
        options.setdefault("curved", disc["geometry_order"] == 2)   # the answer's geometry
    if rtol is not None:
        settings = options.get("settings") or NewtonSettings()
        options["settings"] = dataclasses.replace(settings, rtol=max(settings.rtol, rtol))
    ts = time.perf_counter()
    enriched = solver_for(case, p + 1, **options)   # cached per mesh, degree and options
    setup = time.perf_counter() - ts
    if progress:
        print(f"tissue fem: error estimate ({ESTIMATE_METHOD}): degree {p + 1} on the same "
              f"{case.mesh.n_cells:,} cells", file=sys.stderr, flush=True)
    # A degree-2 answer starts the degree-3 solve (Newton converges from it in a few
    # iterations). A degree-1 answer is a poor start for degree 2 (on a coarse mesh it is off by
    # tens of percent, and Newton from rest along the load path needs fewer iterations).
    warm = p >= 2
    if warm:
        # one try (with nothing to ramp, cut-backs would repeat it) of WARM_ITERATIONS, with a
        # line search on the residual norm (``transfer.warm_settings``)
        try:
            res = enriched.solve(pushes, case=case, initial=_lift(enriched, result),
                                 progress=progress,
                                 settings=warm_settings(enriched.settings, WARM_ITERATIONS),
                                 residual_line_search=True)
        except ConvergenceError as exc:
            warm = False
            if not from_rest:
                raise ConvergenceError(
                    f"{case.source or case.name}: the degree-{p + 1} estimate did not converge "
                    f"within {WARM_ITERATIONS} Newton iterations from the degree-{p} answer "
                    f"({case.mesh.n_cells:,} cells)", load_fraction=exc.load_fraction,
                    last_converged=exc.last_converged) from exc
            if progress:
                print("tissue fem: error estimate: Newton from the interpolated answer did not "
                      "converge, solving from rest", file=sys.stderr, flush=True)
    if not warm:
        res = enriched.solve(pushes, case=case, progress=progress)
    probes = {k: np.asarray(res.probes[k], float) - np.asarray(v, float)
              for k, v in result.probes.items() if k in res.probes}
    reactions = {k: np.asarray(res.reactions[k], float) - np.asarray(v, float)
                 for k, v in result.reactions.items() if k in res.reactions}
    geo = (res.discretization or {}).get("geometry_order", 1)
    wall = time.perf_counter() - t0
    ratio = wall / result.wall_time_s if result.wall_time_s > 0 else float("inf")
    return ErrorEstimate(ESTIMATE_METHOD, p, p + 1, probes, reactions, res,
                         geo > disc.get("geometry_order", 1), warm, wall, setup, ratio, enriched)


def estimate(case: Case, result: SolveResult, *, pushes=None, progress: bool = False,
             **solver_options) -> SolveResult:
    """The reference answer ``result`` with its estimated discretization error.

    result: a reference SolveResult of ``case`` with ``pushes`` (actuator name -> mm)
        (``fem_reference.solve(..., estimate=True)`` solves and estimates in one call).
    Returns ``result`` with the fields ``probe_error_estimates`` (probe -> mm, the norm of the
    estimated error vector) and ``reaction_error_estimates`` (region -> mN), and ``extra``
    holding ``estimate_method`` ("p-enrichment"), ``estimate_cost_ratio`` (estimate wall time /
    solve wall time), the error vectors and the enriched discretization
    (``ErrorEstimate.extras``).
    """
    est = error_estimate(case, result, pushes=pushes, progress=progress, **solver_options)
    return est.attach(result)


AUTO_MAX_DOFS = 60_000
"""``auto_estimate`` runs the enriched solve when it has at most this many unknowns: a few
seconds (the P2 estimate of the default P1 phantom, 28.5k unknowns, takes about 4 s on a
2-core machine; the P3 estimate of its P2 answer, 91k unknowns, about 25 s)."""


def auto_estimate(case: Case, result: SolveResult, *, pushes=None, progress: bool = False,
                  max_dofs: int | None = None, **solver_options) -> SolveResult:
    """``result`` with its estimated discretization error (``estimate``) where that is cheap,
    else with ``estimate_note`` saying why it has none: not a valid converged reference
    answer, a degree-3 answer (nothing richer to compare with), a run under MPI, or an enriched
    solve of more than ``max_dofs`` (default AUTO_MAX_DOFS) unknowns. An enriched solve that
    does not converge leaves the answer as it is, with that note. ``estimate`` itself runs
    whatever the cost."""
    max_dofs = AUTO_MAX_DOFS if max_dofs is None else max_dofs
    note = _no_auto_estimate(case, result, max_dofs, solver_options)
    if note is None:
        try:
            return estimate(case, result, pushes=pushes, progress=progress, **solver_options)
        except ConvergenceError as exc:
            note = f"the degree-{int(result.degree) + 1} solve of the estimate did not converge " \
                   f"({exc})"
    return dataclasses.replace(result, estimate_note=note)


def auto_estimate_note(case: Case, result: SolveResult, *, max_dofs: int | None = None,
                       **solver_options) -> str | None:
    """Why ``auto_estimate`` would not estimate ``result`` (None: it would)."""
    return _no_auto_estimate(case, result, AUTO_MAX_DOFS if max_dofs is None else max_dofs,
                             solver_options)


def _no_auto_estimate(case: Case, result: SolveResult, max_dofs: int, options: dict):
    """Why ``auto_estimate`` does not estimate ``result`` (None: it does)."""
    from mpi4py import MPI

    if not result.reference:
        return f"a {result.solver!r} answer: estimates are for reference answers"
    if not result.converged or result.valid is False:
        return "the answer is not a valid converged state"
    p = int(result.degree)
    if p + 1 > MAX_DEGREE:
        return f"degree {p} is the richest reference degree: refine the mesh (--accuracy) " \
               f"or estimate a degree-{MAX_DEGREE - 1} answer"
    comm = options.get("comm", MPI.COMM_WORLD)
    if comm.size > 1:
        return "not estimated automatically under MPI (--estimate runs it)"
    disc = result.discretization or {}
    n = predicted_dofs(entity_counts(case.mesh), case.mesh.gdim, p + 1,
                       disc.get("formulation", "displacement"))
    if n > max_dofs:
        return f"the degree-{p + 1} solve would have {n:,} unknowns, more than the " \
               f"{max_dofs:,} of an automatic estimate (--estimate runs it)"
    return None


def _lift(enriched, result: SolveResult) -> SolveResult:
    """The degree-p state of ``result`` interpolated into the enriched solver's spaces, as a
    SolveResult its ``solve(initial=...)`` takes: the nodal displacement (mm) in its Tangent node
    order and, for the mixed formulation, the P1 pressure field (kPa) as a Function (a pressure
    recovered from the interpolated displacement alone is far off for nearly incompressible
    tissue: kappa times the interpolation error of J)."""
    import dolfinx.fem

    node_u = result.node_u
    node_points = result.node_points
    if node_u is None or node_points is None:
        raise CaseError(f"a degree-{result.degree} answer without its nodal state "
                        f"(node_u, serial solves only) cannot be estimated")
    gdim = enriched.gdim
    mesh = enriched.dm.mesh
    Vp = dolfinx.fem.VectorFunctionSpace(mesh, ("Lagrange", int(result.degree)))
    up = dolfinx.fem.Function(Vp)
    up.x.array.reshape(-1, gdim)[:] = np.asarray(node_u, float)[
        match_points(np.asarray(node_points, float), Vp.tabulate_dof_coordinates()[:, :gdim],
               f"the degree-{result.degree} answer's nodes")]
    uq = dolfinx.fem.Function(enriched.V)
    uq.interpolate(up)
    points = enriched.node_points()
    own = enriched.V.tabulate_dof_coordinates()[:, :gdim]
    state = {"node_u": uq.x.array.reshape(-1, gdim)[match_points(own, points, "the enriched nodes")],
             "node_points": points}
    pressure = result.pressure
    if enriched.Q is not None and pressure is not None:
        Q1 = dolfinx.fem.FunctionSpace(mesh, ("Lagrange", 1))
        p1 = dolfinx.fem.Function(Q1)
        p1.x.array[:] = np.asarray(pressure, float)[
            match_points(enriched.case.mesh.points, Q1.tabulate_dof_coordinates()[:, :gdim],
                   "the pressure's vertices")]
        state["pressure"] = p1
    return dataclasses.replace(result, degree=enriched.degree, extra={},
                               pressure=state.pop("pressure", None), **state)
