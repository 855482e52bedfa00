"""Verification run: fast solvers, anyone's solver or a displacement field against the FEniCSx
reference on the same Case.

Three kinds of candidate, each scored against the reference it should match:

- the built-in fast solvers (``FAST_SOLVERS``) are P1 displacement solvers: each is scored
  against the degree-1 displacement reference on the same mesh, like with like (the solver's
  error, not the discretization's; ``estimate=True`` adds that discretization's own error
  beside it). ADMM is scored twice: ``admm`` (ADMM brought into Newton's basin, then the Newton
  polish) and ``admm-plain`` (ADMM alone, to its own stopping rule: what the ADMM iteration
  itself achieves); ``admm-anderson`` (ADMM alone with Anderson acceleration) and
  ``admm-chord`` (ADMM finished by chord steps on its kept tangent at rest, with rigid tips
  plus their contact stiffness) on
  request. The Mass Tensor Method is a linear model: on a Neo-Hookean case it is scored
  against the linear-elastic reference of the same E and nu and labelled ``model:
  linear-elastic`` (its distance to the Neo-Hookean truth is not what it claims to solve);
- solvers that are not ours (``verification.plugins``: a callable, ``"module:function"`` or an entry
  point of group ``tissue.solvers``), returning the displacement at every vertex;
- a displacement field (``field=``: a file or a ``verification.scoring.Field``), on the Case's mesh
  in any vertex order or on another mesh of the same body (``verification.scoring``).

Plugins and fields are scored against the reference of the Case's own material (a plugin that
declares another law of ``model.case.MATERIAL_MODELS`` in its ``extra["model"]``, against that
law's reference of the same E and nu: ``declared_law_case``, with the two references' distance,
the law difference, reported beside its score as ``law_difference_mm`` and a note) with the
discretization options of ``tissue solve`` (``degree``, ``formulation``; default the same as
there), so a field written by ``tissue solve --out`` scores ~0. Per candidate: the error at every
probe and over all vertices (max and RMS of |u - u_ref|, mm) and the volume norms of
``verification.scoring`` (L2, H1 seminorm, energy norm: for a solver, of the P1 interpolant of the
difference at the Case mesh's vertices, ``scoring.vertex_norms``, built-in or not); iterations,
wall time (s) and the speed ratio to the matching reference solve (built-ins: both timed on a
second, warm call, the reference's first call reported as ``first_call_wall_time_s``); for a
plugin also its ``history`` and ``extra`` (less ``model``, reported as the model it solves),
NumPy arrays and scalars as lists and numbers; an ``extra`` value JSON cannot hold is a
PluginError naming it. ``report`` (the command line's ``tissue.verify_report.write_report``,
bound to its folder) gets the result and each candidate's convergence trace to write a report.

Python:  ``verify(case, {"A1": 15.0}, solvers=["admm", my_solver], field="u.vtu")``.
"""
from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np

from tissue_reference.errors import CaseError, NotModeledError
from tissue_reference.meshes.mesh import deformation_state
from tissue_reference.model.case import COEFFICIENT_LAWS, MATERIAL_MODELS, UNCOUPLED_LAWS
from tissue_reference.model.converged_range import unconverged_load
from tissue_reference.model.results import material_json, write_json
from tissue_reference.solvers import SOLVERS, get_solver
from tissue_reference.solvers.registry import solver as registry_solver

from .plugins import json_safe, resolve_solver, run_plugin
from .scoring import Field, field_from_array, load_field, score_field, vertex_norms

__all__ = ["DEFAULT_SOLVERS", "FAST_SOLVERS", "VALIDITY_KEYS", "builtin_solver",
           "declared_law_case", "invalid_runs", "reference_material_for", "resolve_candidates",
           "tolerance_failures", "verify"]

VALIDITY_KEYS = ("valid", "invalid_reason", "inverted_cells", "min_J", "max_displacement_mm")

log = logging.getLogger("tissue.verify")

# name -> (solver in the solvers registry, keyword options, reference material model or None =
# the Case's own)
FAST_SOLVERS = {
    "admm": ("admm", {}, None),
    "admm-plain": ("admm", {"polish": False}, None),
    "admm-anderson": ("admm", {"polish": False, "anderson": 5}, None),
    "admm-chord": ("admm", {"polish": "chord"}, None),
    "mass-tensor": ("mass-tensor", {"method": "direct"}, "linear-elastic"),
    "mass-tensor-amg": ("mass-tensor", {"method": "amg", "stop_mm": 0.01}, "linear-elastic"),
    "mass-tensor-pcg": ("mass-tensor", {"method": "pcg", "stop_mm": 0.01}, "linear-elastic"),
    "mass-tensor-descent": ("mass-tensor", {"method": "descent", "stop_mm": 0.01},
                            "linear-elastic"),
}
DEFAULT_SOLVERS = ("admm", "admm-plain", "mass-tensor")

# the arguments of a built-in fast solver's ``solve`` that verify itself sets
_SET_BY_VERIFY = {"case", "pushes", "initial", "callback", "progress", "dynamics"}


def _accepted(key: str) -> set:
    """The keyword options the built-in fast solver ``key`` accepts from a caller."""
    import inspect

    try:
        params = inspect.signature(get_solver(key)).parameters
    except ImportError:
        return set()
    return set(params) - _SET_BY_VERIFY


def reference_material_for(case, solver: str):
    """The Case the reference runs for ``solver``: its own material, or linear-elastic (same E,
    nu) for the Mass Tensor solvers."""
    model = FAST_SOLVERS[solver][2]
    return case if model is None or case.material.model == model else case.with_material(model=model)


def _errors(case, u, u_ref, probes, probes_ref):
    """The scores of a solver's vertex displacements ``u`` against the reference's ``u_ref`` on
    ``case`` (the Case the reference solved: its E and nu weigh the energy norm): probe, max and
    RMS vertex errors, and the volume norms of the P1 interpolant of the difference
    (``scoring.vertex_norms``, as for a field on the Case's mesh)."""
    e = np.linalg.norm(np.asarray(u) - np.asarray(u_ref), axis=1)
    return {
        "probe_error_mm": {k: float(np.linalg.norm(np.asarray(probes[k]) - np.asarray(probes_ref[k])))
                           for k in probes_ref},
        "max_vertex_error_mm": float(e.max(initial=0.0)),
        "rms_vertex_error_mm": float(np.sqrt(np.mean(e ** 2))) if e.size else 0.0,
        **vertex_norms(case, u, u_ref),
    }


class _References:
    """The reference runs of one verification, by (material model, degree, formulation)."""

    def __init__(self, case, pushes, reference_solve, progress, estimate):
        self.case, self.pushes, self.progress, self.estimate = case, pushes, progress, estimate
        self.user = reference_solve
        self.runs = {}        # key -> (case, SolveResult)
        self.json = {}

    def _solve(self, c, degree, formulation, estimate=False):
        """The reference answer of ``c`` under the pushes, with its estimated error when
        ``estimate``: the caller's reference_solve, or the reference's answer composed by
        ``fem_reference.solve``."""
        # lazy: fem_reference loads dolfinx and PETSc (0.7 s of start-up)
        import tissue_reference.fem_reference as fr
        from tissue_reference.fem_reference.estimate import estimate as with_estimate

        if self.user is not None:
            res = self.user(c.with_pushes(self.pushes))
            return with_estimate(c.with_pushes(self.pushes), res) if estimate else res
        return fr.solve(c, degree=degree, formulation=formulation, pushes=self.pushes,
                        progress=self.progress, estimate=estimate)

    def _settings(self, degree, formulation):
        """The reference's settings for the JSON: the options asked of it and its Newton
        controls (left at their defaults); None for a caller's own reference_solve."""
        if self.user is not None:
            return None
        # lazy: fem_reference loads dolfinx and PETSc (0.7 s of start-up)
        from tissue_reference.fem_reference.newton_settings import settings_json

        return {"degree": degree, "formulation": formulation, **settings_json()}

    def get(self, rcase, degree, formulation, *, warm: bool = True):
        """(case, SolveResult) of the reference; ``warm``: timed on a second call (the first,
        with form compilation, is reported as first_call_wall_time_s)."""
        model = rcase.material.model
        key = (model, degree, formulation)
        if key not in self.runs:
            first = self._solve(rcase, degree, formulation, estimate=self.estimate and not warm)
            res = self._solve(rcase, degree, formulation, estimate=self.estimate) if warm \
                else first
            self.runs[key] = (rcase, res)
            name = model if (degree, formulation) == (1, "displacement") else \
                f"{model} ({formulation}, degree {degree or 'default'})"
            self.json[name] = {
                **res.to_json_dict(rcase.with_pushes(self.pushes)),
                "solver_settings": self._settings(degree, formulation),
                "E_kPa": rcase.material.E, "nu": rcase.material.nu,
                "newton_iterations": int(res.iterations),
                "first_call_wall_time_s": float(first.wall_time_s),
                "timed_call": "second (warm)" if warm else "first (includes form compilation)"}
        return self.runs[key]


def _check_options(options, builtins, plugins):
    known = set(FAST_SOLVERS) | {p.name for p in plugins}
    bad = [s for s in options if s not in known]
    if bad:
        raise CaseError(f"options for unknown solver(s) {bad}; solvers: {sorted(known)}")
    for name in builtins:
        key = FAST_SOLVERS[name][0]
        accepted = _accepted(key)
        wrong = sorted(set(options.get(name, {})) - accepted) if accepted else []
        if wrong:
            raise CaseError(f"solver {name!r} does not take option(s) {wrong}; it takes "
                            f"{sorted(accepted)}")


def resolve_candidates(solvers, options) -> tuple[list, list]:
    """(built-in fast solvers' names, ``plugins.SolverPlugin`` s) of ``solvers`` (built-in names
    of FAST_SOLVERS, callables, ``"module:function"``, ``"file.py:function"`` or entry-point
    names), with ``options`` (solver name -> keyword arguments) checked against them: CaseError
    for an unknown solver or option, a solver given twice or two that share a name."""
    builtins, plugins = [], []
    for s in solvers:
        if isinstance(s, str) and s in FAST_SOLVERS:
            builtins.append(s)
        elif isinstance(s, str) and ":" not in s and s in SOLVERS:
            raise CaseError(f"unknown fast solver {s!r}; solvers: {sorted(FAST_SOLVERS)}")
        else:
            try:
                plugins.append(resolve_solver(s))
            except CaseError:
                raise
            except Exception as exc:  # noqa: BLE001 - PluginError: name the choices too
                raise CaseError(f"{exc}; built-in solvers: {sorted(FAST_SOLVERS)}") from None
    names = [*builtins, *(p.name for p in plugins)]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise CaseError(f"solver(s) {twice} given twice (or two solvers share that name): each "
                        f"candidate is scored and reported under its name, so names must differ")
    _check_options(dict(options or {}), builtins, plugins)
    return builtins, plugins


def builtin_solver(name: str, case, opts: dict | None = None):
    """(solve, keyword arguments) of the built-in fast solver ``name`` (FAST_SOLVERS) on
    ``case`` with the caller's ``opts``, as ``verify`` runs it: ``solve(case, pushes=...,
    **kwargs)``; (None, why) when it cannot solve the case (not importable, or the case has
    what it does not model)."""
    key, defaults, _ = FAST_SOLVERS[name]
    opts = {**defaults, **(opts or {})}
    try:
        solve = get_solver(key)
        registry_solver(key).require_modeled(case, opts)
    except (ImportError, NotModeledError) as exc:   # no score, and the reason said
        why = f"{SOLVERS[key]} not importable ({exc})" if isinstance(exc, ImportError) else exc
        return None, f"{name}: {why}; skipped"
    return solve, registry_solver(key).with_factorization(opts)


def verify(case, pushes=None, solvers=DEFAULT_SOLVERS, *, report=None, json_file=None,
           options=None, reference_solve=None, progress: bool = False,
           estimate: bool = False, field=None, degree: int | None = None,
           formulation: str = "auto", field_name: str | None = None,
           outside: str = "error") -> dict:
    """Score ``solvers`` (built-in names, callables, ``"module:function"``, entry-point names)
    and ``field`` (a path, a Field or an (n, gdim) array in the Case's vertex order) on ``case``
    with ``pushes`` (name -> mm) against the reference.

    options: solver name -> extra keyword arguments (a built-in refuses options it does not
    take). degree, formulation: the reference's discretization for plugins and fields (as in
    ``tissue solve``); the built-in fast solvers are always scored against the P1 displacement
    reference on the same mesh. reference_solve(case) -> SolveResult replaces the reference
    solve (tests). estimate: also estimate each reference's own discretization error
    (``fem_reference.estimate``), reported beside each candidate's error as
    ``discretization_error_estimate_mm``. field_name: the field file's point field to take;
    outside: "error" or "skip" for field points outside the body (``verification.scoring``).
    Returns {"reference": {...}, "solvers": {name: {...}}, "skipped": {...}}; writes
    ``json_file`` and calls ``report`` when given.

    Parameters
    ----------
    case : Case
        The problem; every solver and the reference solve it on its mesh.
    pushes : dict or None
        Actuator name -> push (mm); None: the case as loaded.
    solvers : sequence
        Built-in fast solvers' names, callables, ``"module:function"``, ``"file.py:function"`` or
        entry-point names (default ``DEFAULT_SOLVERS``).
    report : callable or None
        report(case, result, traces) -> path of the report it wrote, called with the result
        (before ``json_file`` is written) and each candidate's convergence trace (name -> lists
        "iteration" or "entry", "max_error_mm", "max_step_mm"); the path is the result's
        "report". The command line passes ``tissue.verify_report.write_report`` bound to its
        folder (report.html and its PNGs). None: no report.
    json_file : str or Path or None
        Where to write the result as JSON; None: nowhere.
    options : dict or None
        Solver name -> extra keyword arguments.
    reference_solve : callable or None
        reference_solve(case) -> SolveResult in place of the reference solve; None: the reference.
    progress : bool
        Print a line per solve.
    estimate : bool
        Also estimate each reference's discretization error (mm).
    field : str or Path or Field or array_like or None
        A field to score: a file, a Field or an (n, gdim) array (mm) in the Case's vertex order.
    degree : int or None
        The reference's Lagrange degree for plugins and fields; None: the case's default.
    formulation : str
        The reference's "displacement", "mixed" or "auto" for plugins and fields.
    field_name : str or None
        The field file's point field to take; None: its displacement.
    outside : str
        "error" or "skip" for field points outside the body.

    Returns
    -------
    dict
        {"reference": {...}, "solvers": {name: {...}}, "skipped": {...}}: per candidate its errors
        against the reference (mm), reactions (mN), validity and timings (s).

    Raises
    ------
    CaseError
        For unknown solvers or options, a solver given twice, or a degree or formulation with no
        plugin or field to apply to.
    PluginError
        For a plugin that cannot be found or returns something unusable.
    """
    pushes = dict(pushes or {})
    options = dict(options or {})
    builtins, plugins = resolve_candidates(solvers, options)
    if (degree is not None or formulation != "auto") and not (plugins or field is not None):
        raise CaseError("degree and formulation choose the reference for plugin solvers and "
                        "fields; the built-in fast solvers are P1 displacement solvers, scored "
                        "against the P1 displacement reference on the same mesh (use estimate "
                        "for that discretization's own error)")
    case.with_pushes(pushes)  # unknown actuator names fail here, before any solve
    if isinstance(field, (str, Path)):
        field = load_field(field, case.mesh.points.shape[1], name=field_name)
    elif field is not None and not isinstance(field, Field):
        field = field_from_array(field)
    refs = _References(case, pushes, reference_solve, progress, estimate)
    out = {"reference": {"case": case.name, "source": case.source, "degree": 1,
                         "n_vertices": case.mesh.n_vertices,
                         "n_cells": case.mesh.n_cells, "pushes_mm": pushes,
                         "material": material_json(case.material),
                         "runs": refs.json},
           "solvers": {}, "skipped": {}}

    if why := unconverged_load(case, pushes):   # the scores then compare with no ground truth
        out["reference"]["no_converged_value"] = why
    traces = {}
    for name in builtins:
        entry, trace = _score_builtin(name, case, pushes, options.get(name, {}), refs, out)
        if entry is not None:
            out["solvers"][name] = entry
            traces[name] = trace
    for plugin in plugins:
        entry, trace = _score_plugin(plugin, case, pushes, options.get(plugin.name, {}), refs,
                                     degree, formulation)
        out["solvers"][plugin.name] = entry
        if trace:
            traces[plugin.name] = trace
    if field is not None:
        out["solvers"]["field"] = _score_field(field, case, refs, degree, formulation, outside)
    if report is not None:
        out["report"] = str(report(case, out, traces))
    if json_file is not None:
        write_json(out, json_file)
    return out


def _with_estimate(entry, res_ref):
    if res_ref.probe_error_estimates:
        entry["discretization_error_estimate_mm"] = {
            k: float(v) for k, v in res_ref.probe_error_estimates.items()}
        if res_ref.no_converged_value:   # then the estimate is no error bar
            entry["no_converged_value"] = list(res_ref.no_converged_value)
    return entry


def _disc(res_ref) -> dict:
    d = res_ref.discretization or {}
    return {k: d.get(k) for k in ("formulation", "degree", "pressure_degree", "geometry_order",
                                  "dofs")}


def _score_builtin(name, case, pushes, opts, refs, out):
    key = FAST_SOLVERS[name][0]
    solve, kw = builtin_solver(name, case, opts)
    if solve is None:
        print(f"tissue verify: {kw}")
        out["skipped"][name] = kw
        return None, None
    rcase, res_ref = refs.get(reference_material_for(case, name), 1, "displacement")
    model = rcase.material.model
    # run 1 (traced): error to the reference and largest displacement at every iteration
    trace = {"iteration": [], "max_error_mm": [], "max_step_mm": []}
    state = {"prev": None}
    u_ref = np.asarray(res_ref.u)

    def cb(it, u):
        u = np.asarray(u)
        trace["iteration"].append(int(it))
        trace["max_error_mm"].append(float(np.linalg.norm(u - u_ref, axis=1).max()))
        prev = state["prev"]
        trace["max_step_mm"].append(float("nan") if prev is None else
                                    float(np.linalg.norm(u - prev, axis=1).max()))
        state["prev"] = u.copy()

    traced = solve(rcase, pushes=pushes, callback=cb, **kw)
    own = traced.history.get("max_step_mm") if isinstance(traced.history, dict) else None
    if own is not None and len(own) == len(trace["iteration"]):
        trace["max_step_mm"] = [float(s) for s in own]     # the solver's own step record
    # run 2 (timed, no callback): the figures reported; the Mass Tensor's direct solve
    # factorizes again, as a first solve does (the tensors stay, as the reference's forms do)
    registry_solver(key).forget_kept()
    res = solve(rcase, pushes=pushes, **kw)
    entry = _errors(rcase, res.u, u_ref, res.probes, res_ref.probes)
    entry.update({
        "iterations": int(res.iterations),
        # the solver's own counts (ADMM: admm_iterations + newton_iterations of its polish)
        **{k: int(v) for k, v in res.extra.items()
           if k.endswith("_iterations") and isinstance(v, (int, np.integer))},
        "wall_time_s": float(res.wall_time_s),
        "speedup_vs_reference": float(res_ref.wall_time_s / res.wall_time_s)
        if res.wall_time_s > 0 else float("inf"),
        "converged": bool(res.converged),
        "model": model,
        "reference_model": model,
        "reference_discretization": _disc(res_ref),
        "reference_wall_time_s": float(res_ref.wall_time_s),
        "reference_newton_iterations": int(res_ref.iterations),
        "load_steps": int(res.load_steps),
        "options": {k: v for k, v in kw.items() if isinstance(v, (int, float, str, bool))},
        **{k: v for k, v in res.entries().items() if k in VALIDITY_KEYS},
    })
    if model != case.material.model:
        entry["note"] = (f"a {model} model: scored against the {model} reference of the same E "
                         f"and nu, not the case's {case.material.model} material")
    if "polish_restarts" in res.extra:
        entry["polish_restarts"] = [str(r) for r in res.extra["polish_restarts"]]
    return _with_estimate(entry, res_ref), trace


def declared_law_case(case, declared):
    """(the Case to score a plugin's answer against, why not its declared law): ``case`` with
    the law ``declared`` (its ``extra["model"]``) and the case's E, nu, density (and
    ``volumetric`` where that law takes one), or ``case`` itself with the reason when the
    declared law is the case's, is not a law of MATERIAL_MODELS, needs coefficients the case
    does not give (mooney-rivlin, yeoh) or refuses the case's E and nu."""
    m = case.material
    if not isinstance(declared, str) or declared == m.model:
        return case, None
    if declared not in MATERIAL_MODELS:
        return case, (f"it declares the law {declared!r}, which the reference does not know "
                      f"(laws: {list(MATERIAL_MODELS)})")
    if declared in COEFFICIENT_LAWS:
        return case, (f"it declares the {declared} law, whose coefficients "
                      f"({', '.join(COEFFICIENT_LAWS[declared])}) the case does not give: name "
                      f"them in its [material] to score it on its own law")
    try:
        return case.with_material(model=declared, E=m.E, nu=m.nu, c1=None, c2=None, c3=None,
                                  k=None, volumetric=m.volumetric if declared in UNCOUPLED_LAWS
                                  else "quadratic"), None
    except CaseError as exc:
        return case, f"its declared law cannot take the case's material: {exc}"


def _score_plugin(plugin, case, pushes, opts, refs, degree, formulation):
    _, res_case = refs.get(case, degree, formulation, warm=False)
    run = run_plugin(plugin, case, pushes, opts)
    declared = run.extra.get("model")
    lcase, why_not = declared_law_case(case, declared)
    res_ref = res_case if lcase is case else refs.get(lcase, degree, formulation, warm=False)[1]
    entry = _errors(lcase, run.u, res_ref.u, case.probe_values(run.u), res_ref.probes)
    entry.update({
        "iterations": run.iterations, "converged": run.converged,
        "wall_time_s": run.wall_time_s,
        "speedup_vs_reference": float(res_ref.wall_time_s / run.wall_time_s)
        if run.wall_time_s > 0 else float("inf"),
        # the model a plugin solves is what its answer says (extra["model"]), not the case's
        "model": str(declared or "not stated (its extra['model'])"),
        "reference_model": lcase.material.model,
        "reference_discretization": _disc(res_ref),
        "reference_wall_time_s": float(res_ref.wall_time_s),
        "reference_newton_iterations": int(res_ref.iterations),
        "plugin": True,
        "options": {k: v for k, v in opts.items() if isinstance(v, (int, float, str, bool))},
        # the same validity check as a built-in solver's final state (inverted cells, runaway)
        **{k: v for k, v in deformation_state(case.mesh, run.u).items() if k in VALIDITY_KEYS},
        # what the solver reported beside its figures, kept whole (its "model" is above)
        "history": {k: list(v) for k, v in run.history.items()},
        "extra": json_safe(plugin, "extra",
                           {k: v for k, v in run.extra.items() if k != "model"}),
    })
    if lcase is not case:
        gap = np.linalg.norm(np.asarray(res_ref.u) - np.asarray(res_case.u), axis=1)
        entry["law_difference_mm"] = float(gap.max(initial=0.0))
        entry["note"] = (f"a {declared} solver: scored against the {declared} reference of the "
                         f"case's E and nu, not the case's {case.material.model} material; the "
                         f"two laws' references differ by up to {entry['law_difference_mm']:.3g} "
                         f"mm (the law difference, not solver error)")
    elif why_not:
        entry["note"] = (f"scored against the case's {case.material.model} reference: {why_not}; "
                         f"its score then holds the law difference too")
    if entry.get("note"):
        print(f"tissue verify: warning: {plugin.name}: {entry['note']}")
    return _with_estimate(entry, res_ref), _plugin_trace(run.history)


def _plugin_trace(history: dict) -> dict | None:
    """The convergence plot's data of a plugin: its ``history["max_step_mm"]`` against its
    ``history["iteration"]`` (the iteration numbers, as the built-in solvers' traces record
    them) when it gives one per step, else against the entry's place in the history
    (``"entry"``); None without steps. Its distance to the reference per iteration is unknown."""
    steps = history.get("max_step_mm")
    if not steps:
        return None
    trace = {"max_error_mm": [float("nan")] * len(steps),
             "max_step_mm": [float(s) for s in steps]}
    its = history.get("iteration")
    if its is not None and len(its) == len(steps):
        trace["iteration"] = [int(i) if float(i).is_integer() else float(i) for i in its]
    else:
        trace["entry"] = list(range(1, len(steps) + 1))
    return trace


def _score_field(field, case, refs, degree, formulation, outside):
    _, res_ref = refs.get(case, degree, formulation, warm=False)
    t0 = time.perf_counter()
    entry = score_field(case, res_ref, field, outside=outside)
    entry.update({"scoring_wall_time_s": time.perf_counter() - t0,
                  "model": case.material.model, "reference_model": case.material.model,
                  "reference_discretization": _disc(res_ref),
                  "reference_wall_time_s": float(res_ref.wall_time_s)})
    return _with_estimate(entry, res_ref)


def tolerance_failures(out: dict, tol: float | None) -> list[tuple[str, str]]:
    """(solver, why) for each candidate of a ``verify`` result ``out`` that fails the tolerance
    ``tol`` (mm; ``tissue verify --tol``): its max vertex error above ``tol``, then each one
    that reported converged = false (an answer its own solver does not stand behind fails a
    tolerance, whatever its error). [] when ``tol`` is None.

    Parameters
    ----------
    out : dict
        A ``verify`` result.
    tol : float or None
        Largest vertex error allowed (mm); None: no tolerance.

    Returns
    -------
    list of tuple of str
        (solver, why) per failing candidate; [] when all pass or ``tol`` is None.
    """
    if tol is None:
        return []
    runs = out["solvers"]
    over = [(n, f"max vertex error {e['max_vertex_error_mm']:.4g} mm exceeds --tol {tol:g} mm")
            for n, e in runs.items() if e["max_vertex_error_mm"] > tol]
    unstood = ("reported converged = false; an answer its own solver does not stand behind "
               "fails --tol")
    return over + [(n, unstood) for n, e in runs.items() if e.get("converged") is False]


def invalid_runs(out: dict) -> dict:
    """Run name -> reason, for the reference runs and fast solvers of a ``verify`` result whose
    final state is not valid (inverted cells, runaway growth).

    Parameters
    ----------
    out : dict
        A ``verify`` result.

    Returns
    -------
    dict
        Run name -> reason ({} when every run is valid).
    """
    bad = {f"reference {m}": r.get("invalid_reason") for m, r in out["reference"]["runs"].items()
           if r.get("valid") is False}
    bad.update({n: e.get("invalid_reason") for n, e in out["solvers"].items()
                if e.get("valid") is False})
    return bad
