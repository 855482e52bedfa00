"""A standard verification suite: small problems with answers known without finite elements,
each with its source and a tolerance, run by any solver (the reference, the built-in fast
solvers, solvers that are not ours) and scored on one scorecard.

Problems (``PROBLEMS``; units mm, kPa):

- ``uniaxial-stretch``: a Neo-Hookean block stretched 20 % between sliding faces, lateral faces
  free; the lateral contraction at a corner against the closed form (a scalar root of
  P_22 = 0, ``verification.closed_forms``). Any P1 solver is exact here (homogeneous deformation).
- ``shear-patch``: the patch test: affine simple shear (gamma = 0.3) prescribed on every face;
  the displacement at an interior point is exactly gamma y for any homogeneous material, linear
  or not.
- ``thick-sphere``: a thick Neo-Hookean shell (radii 10 and 20 mm, nu = 0.45) whose inner surface
  is pushed out 2 mm, octant with symmetry planes; the outer radial displacement against the
  radial equilibrium ODE solved as a boundary-value problem.
- ``thick-sphere-nearly-incompressible``: the same at nu = 0.4999 (kappa / mu = 5e3), where
  displacement elements lock; against the same ODE (within 2e-4 of the incompressible closed
  form).
- ``cook-membrane``: Cook's tapered panel under a unit shear load (linear elasticity, plane
  stress E = 1, nu = 1/3 as the equivalent plane strain); the tip's vertical displacement against
  the published converged value 23.96 (Cook 1974; Simo & Rifai 1990).

On another law (``run_suite(law=...)``, ``tissue suite --law``) every problem's material becomes
that law with the same small-strain E and nu (``law_material``) and its answer that law's
(``verification.closed_forms``: the uniaxial root and the shell's ODE from the law's energy in
principal stretches); the shear patch is exact for every law. A problem with no answer for the
law is left out with the reason (``not_applicable`` in the scorecard): Cook's panel (a published
linear-elastic value), the nearly incompressible shell for the laws without the mixed
formulation, and the shell where the law's radial stress has no root on the physical branch
(St Venant-Kirchhoff: the inner surface needs more radial compression than the law carries).

Every solver runs on the problem's mesh (P1 solvers there have their own discretization error,
which is part of their score: the question is how far from the true answer each solver is). The
reference runs with the discretization listed per problem. A solver that refuses a problem (a
2D case, an incompressible material) gets ``refused`` with its message; one that takes it and
fails (diverges, raises, returns a wrong shape) gets ``error`` and counts as failed. The phantom
is not in the suite: its glued actuator patches have no mesh-independent answer at the seed's
pushes (see the case file).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np

from tissue_reference.errors import CaseError, TissueError
from tissue_reference.fem_reference.discretization import SPLIT_LAWS
from tissue_reference.meshes.builders import box, cook_membrane, shell_octant
from tissue_reference.model.case import (
    MATERIAL_MODELS,
    Boundary,
    Case,
    Material,
    Probe,
)
from tissue_reference.model.results import material_json, write_json
from tissue_reference.solvers.registry import is_reference
from tissue_reference.solvers.registry import solver as registry_solver

from . import closed_forms as cf
from .plugins import resolve_solver, run_plugin
from .verify import FAST_SOLVERS

__all__ = ["PROBLEMS", "Problem", "law_material", "run_suite"]

E_TISSUE = 6.0   # kPa


def law_material(model: str, E: float, nu: float) -> Material:
    """The law ``model`` with the small-strain moduli E (kPa) and nu: Mooney-Rivlin splits
    mu0 = E / (2 (1 + nu)) as c1 = 0.35 mu0, c2 = 0.15 mu0; Yeoh has c1 = mu0 / 2,
    c2 = -0.05 mu0, c3 = 0.01 mu0 (inside its stable range); Ogden mu = [0.7 mu0, 0.3 mu0],
    alpha = [4, -2] (sum mu_i = mu0); all k = E / (3 (1 - 2 nu))."""
    mu0, k = E / (2 * (1 + nu)), E / (3 * (1 - 2 * nu))
    if model == "mooney-rivlin":
        return Material(model, c1=0.35 * mu0, c2=0.15 * mu0, k=k)
    if model == "yeoh":
        return Material(model, c1=0.5 * mu0, c2=-0.05 * mu0, c3=0.01 * mu0, k=k)
    if model == "ogden":
        return Material(model, ogden_mu=(0.7 * mu0, 0.3 * mu0), ogden_alpha=(4.0, -2.0), k=k)
    return Material(model, E=E, nu=nu)


@dataclass
class Problem:
    """One problem: ``build()`` -> Case; ``quantity`` (probe name, component 0..d-1 or
    "radial"); ``expected`` (mm) from ``source``; pass when |value - expected| <= tol *
    |expected|; ``reference`` = keyword options of ``fem_reference.solve``."""

    name: str
    description: str
    build: object
    quantity: tuple
    expected_fn: object
    source: str
    tol: float
    reference: dict = field(default_factory=dict)

    @cached_property
    def case(self):
        return self.build()

    law_answer: object = None
    """Callable(Material) -> the expected value (mm) on that law, or a str: why this problem has
    no answer on another law (``on_law``)."""

    @cached_property
    def expected(self) -> float:
        return float(self.expected_fn())

    def on_law(self, model: str):
        """This problem with its material made the law ``model`` (``law_material``, same E and
        nu) and the expected value that law's; a str (why not) where it has no answer there."""
        if model == self.case.material.model:
            return self
        if not callable(self.law_answer):
            return self.law_answer or f"{self.name} has no answer on other laws"
        m = self.case.material
        # nu = 0.5 has no compressible or linear-elastic material; a mixed reference needs a
        # law that the mixed formulation splits (the rule of ``resolve_formulation``)
        if ((m.nu >= 0.5 and (model == "linear-elastic" or model not in SPLIT_LAWS))
                or (self.reference.get("formulation") == "mixed" and model not in SPLIT_LAWS)):
            return (f"{self.name} needs the mixed u-p formulation, which the {model} law does "
                    f"not split (a compressible law)")
        material = law_material(model, m.E, m.nu)
        try:
            expected = float(self.law_answer(material))
        except (RuntimeError, ValueError) as exc:
            return f"{self.name} has no answer on the {model} law here: {exc}"
        case = replace(self.case, material=material)
        return replace(self, build=lambda: case, expected_fn=lambda: expected, law_answer=None)


def _material(nu, model="neo-hookean", E=E_TISSUE):
    return Material(model, E=E, nu=nu)


def _uniaxial():

    return Case(mesh=box(5.0), material=_material(0.45), name="uniaxial-stretch",
                boundaries=(Boundary("xmin", "sliding", normal=[1, 0, 0]),
                            Boundary("ymin", "sliding", normal=[0, 1, 0]),
                            Boundary("zmin", "sliding", normal=[0, 0, 1]),
                            Boundary("xmax", "displacement", value=[2.0, 0, 0], components=(0,))),
                probes=(Probe("corner", (10.0, 10.0, 10.0)),))


def _uniaxial_expected():
    m = _material(0.45)
    return (cf.uniaxial_lateral_stretch(1.2, m.mu, m.kappa) - 1.0) * 10.0


def _shear():

    G = [[0.0, 0.3, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]
    return Case(mesh=box(5.0), material=_material(0.45), name="shear-patch",
                boundaries=tuple(Boundary(f, "affine", gradient=G, offset=[0, 0, 0])
                                 for f in ("xmin", "xmax", "ymin", "ymax", "zmin", "zmax")),
                probes=(Probe("interior", (3.0, 4.0, 5.0)),))


def _sphere(nu):
    def build():

        return Case(mesh=shell_octant(2.5), material=_material(nu), name=f"thick-sphere-{nu}",
                    boundaries=(Boundary("xsym", "sliding", normal=[1, 0, 0]),
                                Boundary("ysym", "sliding", normal=[0, 1, 0]),
                                Boundary("zsym", "sliding", normal=[0, 0, 1]),
                                Boundary("inner", "affine", gradient=(0.2 * np.eye(3)).tolist(),
                                         offset=[0, 0, 0])),
                    probes=(Probe("outer", (20.0, 0.0, 0.0)),))
    return build


def _sphere_expected(nu):
    m = _material(nu)
    return lambda: cf.thick_sphere(10.0, 20.0, 2.0, m.mu, m.kappa)["u_outer"]


def _cook():

    return Case(mesh=cook_membrane(2.0), material=_material(0.25, "linear-elastic", 15.0 / 16.0),
                name="cook-membrane",
                boundaries=(Boundary("left", "fixed"),
                            Boundary("right", "traction", value=[0.0, 1.0 / 16.0])),
                probes=(Probe("tip", (48.0, 52.0)),))


def _sphere_law(material) -> float:
    return cf.law_thick_sphere(10.0, 20.0, 2.0, material)["u_outer"]


PROBLEMS = [
    Problem("uniaxial-stretch", "Neo-Hookean block stretched 20 %, lateral faces free",
            _uniaxial, ("corner", 1), _uniaxial_expected,
            "closed form (root of P_22 = 0)", 1e-6, {"degree": 1},
            lambda m: (cf.law_uniaxial_lateral_stretch(1.2, m) - 1.0) * 10.0),
    Problem("shear-patch", "affine simple shear gamma = 0.3 on every face (patch test)",
            _shear, ("interior", 0), lambda: 0.3 * 4.0, "exact: u_x = gamma y", 1e-6,
            {"degree": 1}, lambda m: 0.3 * 4.0),
    Problem("thick-sphere", "thick shell 10/20 mm, inner surface pushed 2 mm, nu = 0.45",
            _sphere(0.45), ("outer", "radial"), _sphere_expected(0.45),
            "radial equilibrium ODE (boundary-value problem)", 0.01, {"degree": 2},
            _sphere_law),
    Problem("thick-sphere-nearly-incompressible", "the same shell at nu = 0.4999",
            _sphere(0.4999), ("outer", "radial"), _sphere_expected(0.4999),
            "radial equilibrium ODE (boundary-value problem)", 0.01, {"formulation": "mixed"},
            _sphere_law),
    Problem("cook-membrane", "Cook's panel, unit shear load, linear elastic (plane stress "
            "E = 1, nu = 1/3)", _cook, ("tip", 1), lambda: 23.96,
            "published converged value 23.96 (Cook 1974; Simo & Rifai 1990)", 0.01,
            {"degree": 3}, "cook-membrane's answer is a published linear-elastic value"),
]


def _value(problem, probes) -> float:
    name, comp = problem.quantity
    v = np.asarray(probes[name], float)
    if comp == "radial":
        x = np.asarray(problem.case.probe(name).point, float)
        return float(v @ x / np.linalg.norm(x))
    return float(v[comp])


def _options(solver, problem) -> dict:
    """The settings ``solver`` runs ``problem`` with (JSON-ready): the reference's options and
    Newton controls (left at their defaults), a built-in fast solver's options, {} for a
    plugin."""
    if is_reference(solver):
        return {**problem.reference, **registry_solver(solver).settings()}
    if isinstance(solver, str) and solver in FAST_SOLVERS:
        return dict(FAST_SOLVERS[solver][1])
    return {}


def _run_one(solver, problem):
    """(value, iterations, converged, wall s, discretization) of ``solver`` on ``problem``."""
    case = problem.case
    if is_reference(solver):
        res = registry_solver(solver).solve(case, **problem.reference)
        return _value(problem, res.probes), res.iterations, res.converged, res.wall_time_s, \
            res.discretization

    if isinstance(solver, str) and solver in FAST_SOLVERS:
        key, opts, _ = FAST_SOLVERS[solver]
        res = registry_solver(key).solve(case, **opts)
        return _value(problem, res.probes), res.iterations, res.converged, res.wall_time_s, \
            {"formulation": "displacement", "degree": 1}
    run = run_plugin(resolve_solver(solver), case, {})
    return _value(problem, case.probe_values(run.u)), run.iterations, run.converged, \
        run.wall_time_s, None


def _name(solver) -> str:
    if isinstance(solver, str):
        return solver

    return resolve_solver(solver).name


def run_suite(solvers=("fem",), problems=None, *, json_file=None, progress: bool = False,
              law: str | None = None) -> dict:
    """Run every problem (``problems``: names, default all) with every solver ("fem" for the
    reference, built-in fast-solver names, plugins) and score it. Returns {"problems": [...],
    "summary": {solver: {"passed", "failed", "refused"}}}; each problem lists its expected
    value, source, tolerance and per solver {value_mm, error_rel, passed, wall_time_s,
    iterations} or {refused: message}. ``law``: every problem on that strain-energy law
    (``Problem.on_law``); "law" and "not_applicable" (problem -> why it has no answer on it)
    are then in the result. ``json_file``: where to write the result as JSON; the scorecard
    page of a result is the command line's (``tissue.suite_report.write_scorecard``)."""
    chosen = PROBLEMS if problems is None else [_problem(n) for n in problems]
    skipped = {}
    if law is not None:
        if law not in MATERIAL_MODELS:
            raise CaseError(f"unknown law {law!r}; laws: {list(MATERIAL_MODELS)}")
        on = [(p.name, p.on_law(law)) for p in chosen]
        skipped = {n: q for n, q in on if isinstance(q, str)}
        chosen = [q for _, q in on if not isinstance(q, str)]
    names = [_name(s) for s in solvers]
    out = {"problems": [], "summary": {n: {"passed": 0, "failed": 0, "refused": 0}
                                       for n in names}}
    if law is not None:
        out.update(law=law, not_applicable=skipped)
    for p in chosen:
        row = {"name": p.name, "description": p.description, "expected_mm": p.expected,
               "source": p.source, "tolerance_rel": p.tol, "reference_options": p.reference,
               **_what(p), "results": {}}
        for s, n in zip(solvers, names):
            if progress:
                print(f"  {p.name}: {n} ...", flush=True)
            t0 = time.perf_counter()
            try:
                val, its, conv, wall, disc = _run_one(s, p)
            except CaseError as exc:      # the solver does not take this problem
                row["results"][n] = {"refused": str(exc),
                                     "wall_time_s": time.perf_counter() - t0}
                out["summary"][n]["refused"] += 1
                continue
            except TissueError as exc:    # it took it and failed (diverged, raised, bad output)
                row["results"][n] = {"error": str(exc), "passed": False,
                                     "wall_time_s": time.perf_counter() - t0}
                out["summary"][n]["failed"] += 1
                continue
            err = abs(val - p.expected) / abs(p.expected)
            ok = bool(err <= p.tol and conv is not False)
            row["results"][n] = {"value_mm": val, "error_rel": err, "passed": ok,
                                 "converged": conv, "iterations": its, "wall_time_s": wall,
                                 "discretization": disc, "options": _options(s, p)}
            out["summary"][n]["passed" if ok else "failed"] += 1
        out["problems"].append(row)
    if json_file is not None:
        write_json(out, json_file)
    return out


def _what(problem) -> dict:
    """The problem's case: its name, mesh size in cells and vertices, material, and the probe
    and component scored; the loads are its boundary values (no actuator is pushed)."""
    case = problem.case
    name, comp = problem.quantity
    return {"case": case.name, "n_cells": case.mesh.n_cells, "n_vertices": case.mesh.n_vertices,
            "material": material_json(case.material),
            "quantity": {"probe": name,
                         "component": comp if comp == "radial" else "xyz"[comp]}}


def _problem(name):
    for p in PROBLEMS:
        if p.name == name:
            return p
    raise CaseError(f"unknown suite problem {name!r}; problems: {[p.name for p in PROBLEMS]}")
