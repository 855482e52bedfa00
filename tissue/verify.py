"""Verification run: each fast solver against the FEniCSx reference on the same Case.

Same mesh, same boundary conditions, degree-1 reference. ADMM is compared with the reference for
the Case's own material (Neo-Hookean on the phantom); the Mass Tensor Method, a linear model, with
the linear-elastic reference of the same E and nu (kPa). Per solver: the error at every probe and
over all vertices (max and RMS of |u - u_ref|, mm), iterations, wall time (s) and the speed ratio
to the matching reference solve (both timed on a second, warm call: the reference's first call,
which includes form compilation, is reported as ``first_call_wall_time_s``; the fast solvers'
first call is the traced one). ADMM entries carry its ``admm_iterations`` and the
``newton_iterations`` of its polish, the reference runs their ``newton_iterations``. Solvers
come from the ``solvers`` registry (``solvers.get_solver``). ``out_dir`` gets report.html with
tables and, per fast solver, the seed 001 Fig. 7 analog: the largest distance to the reference
over all vertices and the largest per-iteration displacement, both against the iteration number
on a log scale.

Python:  ``verify(case, {"A1": 15.0}, out_dir="out/verify") -> dict`` (its JSON form).
"""
from __future__ import annotations

import html
import logging
from pathlib import Path

import numpy as np

from meshes.errors import CaseError
from meshes.io import atomic_path
from meshes.results import write_json
from solvers import SOLVERS, get_solver

__all__ = ["FAST_SOLVERS", "VALIDITY_KEYS", "invalid_runs", "reference_material_for", "verify"]

VALIDITY_KEYS = ("valid", "invalid_reason", "inverted_cells", "min_J", "max_displacement_mm")

log = logging.getLogger(__name__)

# name -> (solver in the solvers registry, keyword options, reference material model or None =
# the Case's own)
FAST_SOLVERS = {
    "admm": ("admm", {}, None),
    "mass-tensor": ("mass-tensor", {"method": "pcg", "stop_mm": 0.01}, "linear-elastic"),
    "mass-tensor-descent": ("mass-tensor", {"method": "descent", "stop_mm": 0.01},
                            "linear-elastic"),
}


def reference_material_for(case, solver: str):
    """The Case the reference runs for ``solver``: its own material, or linear-elastic (same E,
    nu) for the Mass Tensor solvers."""
    model = FAST_SOLVERS[solver][2]
    return case if model is None or case.material.model == model else case.with_material(model=model)


def _errors(case, u, u_ref, probes, probes_ref):
    e = np.linalg.norm(np.asarray(u) - np.asarray(u_ref), axis=1)
    return {
        "probe_error_mm": {k: float(np.linalg.norm(np.asarray(probes[k]) - np.asarray(probes_ref[k])))
                           for k in probes_ref},
        "max_vertex_error_mm": float(e.max(initial=0.0)),
        "rms_vertex_error_mm": float(np.sqrt(np.mean(e ** 2))) if e.size else 0.0,
    }


def verify(case, pushes=None, solvers=("admm", "mass-tensor"), out_dir=None, *, json_file=None,
           options=None, reference_solve=None, progress: bool = False,
           estimate: bool = False) -> dict:
    """Run the degree-1 reference and each fast solver on ``case`` with ``pushes`` (name -> mm).

    solvers: names from FAST_SOLVERS; a solver whose module is missing is skipped (listed under
    "skipped"). options: solver name -> extra keyword arguments for its ``solve``.
    reference_solve(case) -> SolveResult replaces ``fem_reference.solve(case, degree=1)`` (tests).
    estimate: also estimate the reference's own discretization error (one P2 solve on the same
    mesh, ``fem_reference.estimate``), reported beside each solver's error to the reference as
    ``discretization_error_estimate_mm``: the solver error (fast solver vs the same discretization)
    and the discretization error (that discretization vs the converged answer), never confused.
    Returns {"reference": {...}, "solvers": {name: {"probe_error_mm": {...}, "max_vertex_error_mm",
    "rms_vertex_error_mm", "iterations", "wall_time_s", "speedup_vs_reference", ...}},
    "skipped": {...}}; writes ``json_file`` and ``out_dir``/report.html + PNGs when given.
    """
    pushes = dict(pushes or {})
    options = dict(options or {})
    unknown = [s for s in solvers if s not in FAST_SOLVERS]
    if unknown:
        raise CaseError(f"unknown fast solver(s) {unknown}; solvers: {sorted(FAST_SOLVERS)}")
    bad_opts = [s for s in options if s not in FAST_SOLVERS]
    if bad_opts:
        raise CaseError(f"options for unknown solver(s) {bad_opts}; solvers: {sorted(FAST_SOLVERS)}")
    case.with_pushes(pushes)  # unknown actuator names fail here, before any solve
    if reference_solve is None:
        from fem_reference import solve as fem_solve

        def reference_solve(c):
            return fem_solve(c, degree=1, formulation="displacement", pushes=pushes,
                             progress=progress)
    else:
        _user_ref = reference_solve

        def reference_solve(c):
            return _user_ref(c.with_pushes(pushes))

    refs = {}          # material model -> (case, SolveResult)
    out = {"reference": {"case": case.name, "degree": 1, "n_vertices": case.mesh.n_vertices,
                         "n_cells": case.mesh.n_cells, "pushes_mm": pushes, "runs": {}},
           "solvers": {}, "skipped": {}}
    traces = {}
    for name in solvers:
        key, defaults, _ = FAST_SOLVERS[name]
        try:
            solve = get_solver(key)
        except ImportError as exc:
            msg = f"{name}: {SOLVERS[key]} not importable ({exc}); skipped"
            print(f"tissue verify: {msg}")
            out["skipped"][name] = msg
            continue
        rcase = reference_material_for(case, name)
        model = rcase.material.model
        if model not in refs:
            first = reference_solve(rcase)
            # timed like the fast solvers' timed run: a second, warm solve (form compilation,
            # caches of the first call excluded)
            res_ref = reference_solve(rcase)
            if estimate:
                from fem_reference.estimate import estimate as with_estimate

                res_ref = with_estimate(rcase.with_pushes(pushes), res_ref)
            refs[model] = (rcase, res_ref)
            out["reference"]["runs"][model] = {
                **res_ref.to_json_dict(rcase), "E_kPa": rcase.material.E, "nu": rcase.material.nu,
                "newton_iterations": int(res_ref.iterations),
                "first_call_wall_time_s": float(first.wall_time_s)}
        rcase, res_ref = refs[model]
        kw = {**defaults, **options.get(name, {})}
        if key == "admm" and "factorize" not in kw:
            from fem_reference import cholmod_factor

            kw["factorize"] = cholmod_factor  # the polish's tangents by CHOLMOD (PETSc)
        # run 1 (traced): error to the reference and largest displacement at every iteration
        trace = {"iteration": [], "max_error_mm": [], "max_step_mm": []}
        state = {"prev": None}
        u_ref = np.asarray(res_ref.u)

        def cb(it, u, trace=trace, state=state, u_ref=u_ref):
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
        # run 2 (timed, no callback): the figures reported
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
            "reference_model": model,
            "reference_wall_time_s": float(res_ref.wall_time_s),
            "reference_newton_iterations": int(res_ref.iterations),
            "load_steps": int(res.load_steps),
            "options": {k: v for k, v in kw.items() if isinstance(v, (int, float, str, bool))},
            **{k: res.extra[k] for k in VALIDITY_KEYS if k in res.extra},
        })
        if "probe_error_estimates" in res_ref.extra:
            entry["discretization_error_estimate_mm"] = {
                k: float(v) for k, v in res_ref.extra["probe_error_estimates"].items()}
        out["solvers"][name] = entry
        traces[name] = trace
    if out_dir is not None:
        out["report"] = str(_write_report(Path(out_dir), case, out, traces))
    if json_file is not None:
        write_json(out, json_file)
    return out


def invalid_runs(out: dict) -> dict:
    """Run name -> reason, for the reference runs and fast solvers of a ``verify`` result whose
    final state is not valid (inverted cells, runaway growth)."""
    bad = {f"reference {m}": r.get("invalid_reason") for m, r in out["reference"]["runs"].items()
           if r.get("valid") is False}
    bad.update({n: e.get("invalid_reason") for n, e in out["solvers"].items()
                if e.get("valid") is False})
    return bad


# --------------------------------------------------------------------------- report
def _plot(path: Path, name: str, trace: dict, entry: dict):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    it = np.asarray(trace["iteration"])
    err = np.asarray(trace["max_error_mm"])
    step = np.asarray(trace["max_step_mm"], float)
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    pos = lambda a: np.where(a > 0, a, np.nan)
    ax.semilogy(it, pos(err), "-", color="C0", label="max distance to reference over all vertices")
    ax.semilogy(it, pos(step), "--", color="C1", label="max displacement in one iteration")
    stop = entry.get("options", {}).get("stop_mm")
    if stop:
        ax.axhline(stop, color="0.5", lw=0.8, ls=":", label=f"stopping rule {stop:g} mm")
    ax.set_xlabel("iteration number")
    ax.set_ylabel("distance (mm)")
    ax.set_title(f"{name}: convergence (seed 001 Fig. 7 analog)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def _table(headers, rows):
    th = "".join(f"<th>{html.escape(str(h))}</th>" for h in headers)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in r) + "</tr>"
                   for r in rows)
    return f"<table><tr>{th}</tr>{body}</table>"


def _fmt(x, nd=4):
    return f"{x:.{nd}g}" if isinstance(x, float) else str(x)


def _write_report(out_dir: Path, case, out: dict, traces: dict) -> Path:
    out_dir.mkdir(parents=True, exist_ok=True)
    imgs = {}
    for name, trace in traces.items():
        png = out_dir / f"convergence_{name}.png"
        _plot(png, name, trace, out["solvers"][name])
        imgs[name] = png.name
    ref = out["reference"]
    ref_rows = [(m, r.get("E_kPa"), r.get("nu"), r.get("newton_iterations", r.get("iterations")),
                 r.get("load_steps"), _fmt(r.get("wall_time_s")),
                 _fmt(r.get("first_call_wall_time_s")), r.get("converged"))
                for m, r in ref["runs"].items()]
    sol_rows = [(n, e["reference_model"], _fmt(e["max_vertex_error_mm"]),
                 _fmt(e["rms_vertex_error_mm"]), e["iterations"],
                 e.get("admm_iterations", ""), e.get("newton_iterations", ""),
                 _fmt(e["wall_time_s"]), _fmt(e["speedup_vs_reference"], 3), e["converged"])
                for n, e in out["solvers"].items()]
    probes = sorted({p for e in out["solvers"].values() for p in e["probe_error_mm"]})
    probe_rows = [(n, *[_fmt(e["probe_error_mm"].get(p, float("nan"))) for p in probes])
                  for n, e in out["solvers"].items()]
    parts = [
        "<!DOCTYPE html><html><head><meta charset='utf-8'>",
        f"<title>tissue verify: {html.escape(case.name)}</title>",
        ("<style>body{font-family:sans-serif;margin:2em}table{border-collapse:collapse;margin:1em 0}"
        "td,th{border:1px solid #999;padding:3px 8px;text-align:right}th{background:#eee}</style>"),
        "</head><body>",
        f"<h1>Verification: {html.escape(case.name)}</h1>",
        (f"<p>{ref['n_vertices']} vertices, {ref['n_cells']} cells; pushes (mm): "
        f"{html.escape(str(ref['pushes_mm']))}. Errors are |u - u_ref| at vertices / probes (mm); "
        "the reference is the FEniCSx P1 solution on the same mesh (Neo-Hookean for ADMM, "
        "linear-elastic with the same E, nu for the Mass Tensor Method).</p>"),
        "<h2>Reference</h2>",
        _table(["material", "E (kPa)", "nu", "Newton its", "load steps", "wall time (s)",
                "first call (s)", "converged"], ref_rows),
        "<h2>Fast solvers</h2>",
        _table(["solver", "reference", "max vertex error (mm)", "RMS vertex error (mm)",
                "iterations", "ADMM its", "Newton its (polish)", "wall time (s)",
                "speed-up vs reference", "converged"], sol_rows),
        "<h2>Probe errors (mm)</h2>",
        _table(["solver", *probes], probe_rows),
    ]
    if out.get("skipped"):
        parts.append("<h2>Skipped</h2><ul>" + "".join(
            f"<li>{html.escape(m)}</li>" for m in out["skipped"].values()) + "</ul>")
    parts.append("<h2>Convergence (seed 001 Fig. 7 analog)</h2>")
    for name, img in imgs.items():
        parts.append(f"<h3>{html.escape(name)}</h3><img src='{html.escape(img)}' "
                     f"alt='convergence of {html.escape(name)}'>")
    parts.append("</body></html>")
    path = out_dir / "report.html"
    with atomic_path(path) as tmp:
        tmp.write_text("\n".join(parts) + "\n")
    return path
