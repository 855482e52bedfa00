"""Seed 000's model validation (its Fig. 7) on a case: each actuator pushed alone in steps (the
seed's 5, 10 and 15 mm: 12 experiments with four actuators), the reference standing in for the
seed's EM tracker and a fast solver for its model, and the localization error of every target
per axis (model minus reference, mm) summarized over the experiments as Fig. 7 does: mean,
median, 25th-75th percentile and min-max.

The reference ("tracker") is the case's own law at its default discretization
(``fem_reference.solve``), whatever the candidate solves: a Mass Tensor model (linear) or a plugin
of another law is scored against the case's law, so its errors hold the law difference, as the
seed's model errors hold every difference between its model and the phantom. A candidate is any
solver ``verify`` takes (built-in names of ``FAST_SOLVERS`` with their settings, plugins),
solved on ``model_case`` (another mesh of the same body, or the case with another E: a model
mismatch) or on the case itself. On the case itself the errors are the solver's error on the
same law and mesh, not a model error.

The reference's own error bar is reported where the case states one for that load and
discretization (``[[reference.measured]]``, ``fem_reference.measured.error_bar``: a fraction of
each target's displacement, here in mm); elsewhere the result says why there is none.

Python:  ``sweep(load_case("phantom-seed"), ["admm"])``.
"""
from __future__ import annotations

import time

import numpy as np

from tissue_reference.errors import CaseError
from tissue_reference.meshes.mesh import deformation_state
from tissue_reference.model.converged_range import unconverged_load
from tissue_reference.model.results import material_json, write_json

from .plugins import run_plugin
from .verify import (
    FAST_SOLVERS,
    VALIDITY_KEYS,
    builtin_solver,
    reference_material_for,
    resolve_candidates,
)

__all__ = ["AXES", "DEFAULT_PUSHES_MM", "SEED_FIG7", "error_statistics", "experiments", "sweep"]

DEFAULT_PUSHES_MM = (5.0, 10.0, 15.0)
"""The seed's steps: each actuator pushed alone 5, 10 and 15 mm (mm)."""

AXES = ("x", "y", "z")

SEED_FIG7 = {
    "max_abs_error_mm": 1.6,
    "experiments_per_target": 12,
    "targets": 5,
    "statistics": "per target and axis (X, Y, Z): mean, median, 25th-75th percentile and "
                  "min-max of the localization error over the 12 experiments",
    "per_target_values": None,
    "note": "the seed's text gives the largest error only ('on the order of 1.6 mm'); its "
            "per-target means and medians are in Fig. 7, which the text does not hold",
    "truth": "Aurora EM tracker (a sensor inside a plastisol phantom, E = 6 kPa)",
    "model": "minimum-energy ADMM, Neo-Hookean, 1706 tetrahedra, 800 iterations (15 s on 6 "
             "cores)",
}
"""What seed 000 states of its Fig. 7 (model against EM tracker, 5 targets x 12 experiments)."""


def experiments(case, pushes_mm=DEFAULT_PUSHES_MM, actuators=None) -> list[dict]:
    """The experiments of the sweep: each of ``actuators`` (None: every actuator of ``case``)
    alone at each push of ``pushes_mm`` (mm), actuator by actuator: [{"A1": 5.0}, {"A1": 10.0},
    ...]. CaseError for an unknown actuator, a push that is not positive, or none at all."""
    names = [a.name for a in case.actuators]
    acts = list(names if actuators is None else actuators)
    bad = [a for a in acts if a not in names]
    if bad:
        raise CaseError(f"unknown actuator(s) {bad}; the case has {names}")
    if len(set(acts)) != len(acts):
        raise CaseError(f"actuators given twice: {acts}")
    pushes = [float(p) for p in pushes_mm]
    if not acts or not pushes:
        raise CaseError("a sweep needs at least one actuator and one push")
    if any(not np.isfinite(p) or p <= 0 for p in pushes):
        raise CaseError(f"sweep pushes must be positive (mm), got {pushes}")
    return [{a: p} for a in acts for p in pushes]


def error_statistics(values) -> dict:
    """mean, median, std, min, max and the 25th / 75th percentiles of ``values`` (mm), with
    their count ``n``; every statistic None for no values."""
    v = np.asarray(values, float).ravel()
    if v.size == 0:
        return {k: None for k in ("mean", "median", "std", "min", "q25", "q75", "max")} | {"n": 0}
    q25, med, q75 = np.percentile(v, [25.0, 50.0, 75.0])
    return {"mean": float(v.mean()), "median": float(med), "std": float(v.std()),
            "min": float(v.min()), "q25": float(q25), "q75": float(q75), "max": float(v.max()),
            "n": int(v.size)}


def _reference(case, pushes, reference_solve, degree=None):
    # lazy: fem_reference loads dolfinx and PETSc (0.7 s of start-up)
    import tissue_reference.fem_reference as fr

    if reference_solve is not None:
        return reference_solve(case.with_pushes(pushes))
    return fr.solve(case, pushes=pushes, degree=degree)


def _error_bar(res, probes) -> tuple[dict | None, str | None]:
    """(target -> the reference's error bar in mm, None) where the case's measured accuracy
    describes the answer; (None, why not) elsewhere."""
    # lazy: fem_reference loads dolfinx and PETSc (0.7 s of start-up)
    from tissue_reference.fem_reference.measured import error_bar

    extra = res.extra or {}
    row = extra.get("measured_accuracy")
    if row:
        bar = error_bar(row)
        if bar is None:
            return None, (f"the case's measurement of this load gives no error bar: "
                          f"{row.get('why', 'no band of the converged value')}")
        return {k: float(bar["probes"] * np.linalg.norm(v)) for k, v in probes.items()}, None
    if extra.get("measured_note"):
        return None, str(extra["measured_note"])
    return None, ("the case states no measured accuracy of its default discretization (no "
                  "[[reference.measured]] rows): the reference's answers here carry no error "
                  "bar")


def _run_candidate(kind, cand, mcase, pushes, opts):
    """(model target positions name -> (gdim,) mm, the run's record) of one candidate."""
    if kind == "builtin":
        solve, kw = cand
        res = solve(mcase, pushes=pushes, **kw)
        rec = {"iterations": int(res.iterations),
               **{k: int(v) for k, v in res.extra.items()
                  if k.endswith("_iterations") and isinstance(v, (int, np.integer))},
               "wall_time_s": float(res.wall_time_s), "converged": bool(res.converged),
               **{k: v for k, v in res.entries().items() if k in VALIDITY_KEYS}}
        return {k: np.asarray(v, float) for k, v in res.probes.items()}, rec
    run = run_plugin(cand, mcase, pushes, opts)
    rec = {"iterations": run.iterations, "wall_time_s": float(run.wall_time_s),
           "converged": run.converged,
           **{k: v for k, v in deformation_state(mcase.mesh, run.u).items()
              if k in VALIDITY_KEYS}}
    return mcase.probe_values(run.u), rec


def sweep(case, solvers=("admm",), *, pushes_mm=DEFAULT_PUSHES_MM, actuators=None,
          options=None, model_case=None, model_E_factor: float = 1.0, reference_solve=None,
          progress: bool = False, json_file=None, report=None, degree: int | None = None) -> dict:
    """Seed 000's model validation on ``case``: every experiment of ``experiments(case,
    pushes_mm, actuators)`` solved by the reference and by each of ``solvers``, and each
    target's localization error per axis (solver minus reference, mm) summarized per solver,
    target and axis.

    Parameters
    ----------
    case : Case
        The body, its actuators and targets (probes); the reference solves it at its default
        discretization (``degree`` aside).
    solvers : sequence
        Built-in fast solvers' names (``verify.FAST_SOLVERS``, with their settings: ``admm`` is
        ADMM with the Newton polish), callables, ``"module:function"``, ``"file.py:function"``
        or entry-point names, as ``verify`` takes them.
    pushes_mm : sequence of float
        The pushes of each actuator (mm; default the seed's 5, 10, 15).
    actuators : sequence of str or None
        The actuators pushed, one at a time; None: all of the case's.
    options : dict or None
        Solver name -> extra keyword arguments (checked as ``verify`` checks them).
    model_case : Case or None
        The case the solvers solve (a model mismatch: another mesh of the same body, another
        E); None: ``case`` itself. It must have the case's actuators and targets.
    reference_solve : callable or None
        reference_solve(case with pushes) -> SolveResult in place of the reference (tests).
    progress : bool
        Print a line per experiment.
    json_file : str or Path or None
        Where to write the result as JSON; None: nowhere.
    report : callable or None
        report(result) -> path of what it wrote (the command line's plot), its path kept as
        the result's "report".
    degree : int or None
        The reference's Lagrange degree; None: the case's (``[reference] degree``, else 1 for
        the displacement formulation).

    Returns
    -------
    dict
        "experiments" (per experiment: the pushes, the reference's target displacements, its
        error bar or why none, and per solver its target displacements, errors and run record),
        "summary" (solver -> per target and axis the signed and absolute error statistics,
        ``error_statistics``; per target the 3D distance's; the largest absolute error and
        where), "seed_fig7" (what the seed states of its Fig. 7), "skipped" (solvers that
        could not run, and why) and what was run.

    Raises
    ------
    CaseError
        For an unknown actuator or solver, bad pushes or options, or a model case of another
        body.
    PluginError
        For a plugin that cannot be found or returns something unusable.
    """
    options = dict(options or {})
    runs = experiments(case, pushes_mm, actuators)
    builtins, plugins = resolve_candidates(solvers, options)
    mcase = case
    if model_case is not None or model_E_factor != 1.0:
        # lazy: the control layer's model case, checked as a loop's (casadi-free)
        from tissue_reference.control.plants import model_case_for

        mcase = model_case_for(case, model_case, model_E_factor)
    targets = [p.name for p in case.probes]
    if not targets:
        raise CaseError(f"case {case.name!r} has no probes: a sweep compares targets")
    cands, skipped, models = {}, {}, {}
    for name in builtins:
        solve, kw = builtin_solver(name, mcase, options.get(name))
        if solve is None:
            skipped[name] = kw
            continue
        cands[name] = ("builtin", (solve, kw), reference_material_for(mcase, name), {})
        models[name] = FAST_SOLVERS[name][2] or mcase.material.model
    for plugin in plugins:
        cands[plugin.name] = ("plugin", plugin, mcase, options.get(plugin.name, {}))
        models[plugin.name] = None     # what its answer declares (extra["model"]), if anything
    rows = []
    for pushes in runs:
        t0 = time.perf_counter()
        ref = _reference(case, pushes, reference_solve, degree)
        ref_wall = time.perf_counter() - t0
        rp = {k: np.asarray(ref.probes[k], float) for k in targets}
        bar, why = _error_bar(ref, rp)
        row = {"pushes_mm": dict(pushes),
               "reference": {"probes_mm": {k: v.tolist() for k, v in rp.items()},
                             "newton_iterations": int(ref.iterations),
                             "degree": int(ref.degree) if ref.degree is not None else None,
                             "wall_time_s": float(getattr(ref, "wall_time_s", ref_wall)),
                             "converged": bool(ref.converged), "valid": ref.valid,
                             "error_bar_mm": bar},
               "solvers": {}}
        if why is not None:
            row["reference"]["error_bar_note"] = why
        if unc := unconverged_load(case, pushes):
            row["reference"]["no_converged_value"] = unc
        for name, (kind, cand, scase, opts) in cands.items():
            pp, rec = _run_candidate(kind, cand, scase, pushes, opts)
            err = {k: np.asarray(pp[k], float) - rp[k] for k in targets}
            row["solvers"][name] = {
                "probes_mm": {k: np.asarray(pp[k], float).tolist() for k in targets},
                "error_mm": {k: e.tolist() for k, e in err.items()},
                "distance_mm": {k: float(np.linalg.norm(e)) for k, e in err.items()}, **rec}
        rows.append(row)
        if progress:
            ref_line = (f"reference {row['reference']['wall_time_s']:.1f} s "
                        f"({row['reference']['newton_iterations']} Newton its)")
            parts = [ref_line]
            parts += [f"{n} {e['wall_time_s']:.1f} s, largest target error "
                      f"{max(e['distance_mm'].values()):.3g} mm" for n, e in row["solvers"].items()]
            label = ", ".join(f"{a} = {p:g} mm" for a, p in pushes.items())
            print(f"sweep {len(rows)}/{len(runs)}: {label}: " + "; ".join(parts), flush=True)
    out = {"case": case.name, "source": case.source, "n_vertices": case.mesh.n_vertices,
           "n_cells": case.mesh.n_cells, "material": material_json(case.material),
           "model_case": None if mcase is case else {
               "case": mcase.name, "source": mcase.source, "n_vertices": mcase.mesh.n_vertices,
               "n_cells": mcase.mesh.n_cells, "material": material_json(mcase.material)},
           "pushes_mm": [float(p) for p in pushes_mm],
           "actuators": sorted({a for r in runs for a in r}, key=[a.name for a in
                                                                  case.actuators].index),
           "targets": targets, "experiments": rows,
           "summary": {n: _summary(n, rows, targets, models[n]) for n in cands},
           "reference_error_bar": _bar_summary(rows, targets),
           "seed_fig7": SEED_FIG7, "skipped": skipped}
    if report is not None:
        out["report"] = str(report(out))
    if json_file is not None:
        write_json(out, json_file)
    return out


def _summary(name, rows, targets, model) -> dict:
    """One solver's statistics over the experiments: per target and axis the signed and the
    absolute errors', per target the 3D distance's, and the largest absolute error with where
    it was."""
    per = {}
    worst = {"max_abs_error_mm": 0.0, "target": None, "axis": None, "pushes_mm": None}
    for t in targets:
        e = np.array([r["solvers"][name]["error_mm"][t] for r in rows], float)   # (n, gdim)
        entry = {}
        for j, ax in enumerate(AXES[:e.shape[1]]):
            entry[ax] = {"signed": error_statistics(e[:, j]),
                         "absolute": error_statistics(np.abs(e[:, j])),
                         "rms": float(np.sqrt(np.mean(e[:, j] ** 2)))}
            k = int(np.argmax(np.abs(e[:, j])))
            if abs(e[k, j]) > worst["max_abs_error_mm"] or worst["target"] is None:
                worst = {"max_abs_error_mm": float(abs(e[k, j])), "target": t, "axis": ax,
                         "pushes_mm": rows[k]["pushes_mm"]}
        entry["distance"] = error_statistics(np.linalg.norm(e, axis=1))
        per[t] = entry
    runs = [r["solvers"][name] for r in rows]
    out = {"targets": per, **worst,
           "experiments": len(rows),
           "iterations": int(sum(r["iterations"] or 0 for r in runs)),
           "wall_time_s": float(sum(r["wall_time_s"] for r in runs)),
           "not_converged": [r["pushes_mm"] for r in rows
                             if r["solvers"][name].get("converged") is False],
           "not_valid": [r["pushes_mm"] for r in rows
                         if r["solvers"][name].get("valid") is False]}
    if model is not None:
        out["model"] = model
    return out


def _bar_summary(rows, targets) -> dict:
    """The reference's largest error bar per target over the experiments (mm), or None with why
    for the targets of an experiment without one."""
    notes = sorted({r["reference"]["error_bar_note"] for r in rows
                    if r["reference"].get("error_bar_note")})
    if notes:
        return {"max_mm": None, "note": "; ".join(notes)}
    return {"max_mm": {t: max(r["reference"]["error_bar_mm"][t] for r in rows) for t in targets},
            "note": None}
