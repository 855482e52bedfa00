"""The HTML report of a verification run: the reference runs, a table per solver (errors,
iterations, time, speed-up), the probe errors and, per solver with a trace, the seed 001 Fig. 7
analog (largest distance to the reference and largest per-iteration displacement against the
iteration number; for a plugin whose history gives no iteration numbers, against the entry's
place in its history, and the axis says so). Each plot is ``plot_file(solver)`` beside the
page."""
from __future__ import annotations

import hashlib
import html
import re
import textwrap
from pathlib import Path

import numpy as np

from tissue_reference.meshes.io import atomic_path, save_figure

__all__ = ["plot_file", "write_report"]

_SAFE = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]*")
_SLUG_CHARS = 40


def plot_file(solver: str) -> str:
    """The file name of ``solver``'s convergence plot: ``convergence_NAME.png`` for a name of
    letters, digits, '.', '_' and '-' (the built-in solvers); for any other name (a plugin's
    ``path/to/plugin.py:solve``, a callable's ``module:<lambda>``) its last path part with
    every other character replaced by '_', cut to 40 characters, and 10 hex digits of the whole
    name's SHA-1, so that distinct solvers get distinct files: no folders, colons, spaces or
    characters a URL would have to escape."""
    if _SAFE.fullmatch(solver) and len(solver) <= _SLUG_CHARS:
        return f"convergence_{solver}.png"
    tail = re.split(r"[/\\]", solver)[-1]
    slug = re.sub(r"[^A-Za-z0-9._-]+", "_", tail).strip("._-")[:_SLUG_CHARS] or "solver"
    digest = hashlib.sha1(solver.encode("utf-8", "surrogatepass")).hexdigest()[:10]
    return f"convergence_{slug}_{digest}.png"


def _plot(path: Path, name: str, trace: dict, entry: dict):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    if "iteration" in trace:
        x, xlabel = np.asarray(trace["iteration"], float), "iteration number"
    else:   # a plugin's history without iteration numbers
        x = np.asarray(trace["entry"], float)
        xlabel = "entry of the solver's history (it gives no iteration numbers)"
    err = np.asarray(trace["max_error_mm"], float)
    step = np.asarray(trace["max_step_mm"], float)
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    pos = lambda a: np.where(a > 0, a, np.nan)
    if np.isfinite(err).any():    # a plugin's distance to the reference per iteration is unknown
        ax.semilogy(x, pos(err), "-", color="C0",
                    label="max distance to reference over all vertices")
    ax.semilogy(x, pos(step), "--", color="C1", label="max displacement in one iteration")
    stop = entry.get("options", {}).get("stop_mm")
    if stop:
        ax.axhline(stop, color="0.5", lw=0.8, ls=":", label=f"stopping rule {stop:g} mm")
    ax.set_xlabel(xlabel)
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_ylabel("distance (mm)")
    # a plugin's name may be a long path: wrapped to the figure's width
    ax.set_title("\n".join(textwrap.wrap(f"{name}: convergence (seed 001 Fig. 7 analog)", 64)))
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, path, dpi=110)


def _table(headers, rows):
    th = "".join(f"<th>{html.escape(str(h))}</th>" for h in headers)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in r) + "</tr>"
                   for r in rows)
    return f"<table><tr>{th}</tr>{body}</table>"


def _fmt(x, nd=4):
    if x is None:
        return ""
    return f"{x:.{nd}g}" if isinstance(x, float) else str(x)


def write_report(out_dir: Path, case, out: dict, traces: dict) -> Path:
    out_dir.mkdir(parents=True, exist_ok=True)
    imgs = {}
    for name, trace in traces.items():
        imgs[name] = plot_file(name)       # the file written and the page's link alike
        _plot(out_dir / imgs[name], name, trace, out["solvers"][name])
    ref = out["reference"]
    ref_rows = [(m, r.get("E_kPa"), r.get("nu"), r.get("newton_iterations", r.get("iterations")),
                 r.get("load_steps"), _fmt(r.get("wall_time_s")),
                 _fmt(r.get("first_call_wall_time_s")), r.get("converged"))
                for m, r in ref["runs"].items()]
    def disc(e):
        d = e.get("reference_discretization") or {}
        p = f"/P{d['pressure_degree']}" if d.get("pressure_degree") is not None else ""
        return f"{e['reference_model']}, {d.get('formulation', '')} P{d.get('degree', '')}{p}"

    sol_rows = [(n, e.get("model", ""), disc(e), _fmt(e["max_vertex_error_mm"]),
                 _fmt(e["rms_vertex_error_mm"]), _fmt(e.get("l2_error_mm")),
                 _fmt(e.get("h1_seminorm_error")), _fmt(e.get("energy_norm_error_sqrt_uJ")),
                 _fmt(e.get("iterations", "")),
                 e.get("admm_iterations", ""), e.get("newton_iterations", ""),
                 _fmt(e.get("wall_time_s", "")), _fmt(e.get("speedup_vs_reference", ""), 3),
                 e.get("converged", ""))
                for n, e in out["solvers"].items()]
    notes = [f"<li>{html.escape(n)}: {html.escape(e['note'])}</li>"
             for n, e in out["solvers"].items() if e.get("note")]
    probes = sorted({p for e in out["solvers"].values() for p in e["probe_error_mm"]})
    probe_rows = [(n, *[_fmt(e["probe_error_mm"].get(p, float("nan"))) for p in probes])
                  for n, e in out["solvers"].items()]
    # the reference's own discretization error at the probes (--estimate), one row per
    # reference the solvers were scored against: how far the ground truth itself may be off
    own = {}
    for e in out["solvers"].values():
        est = e.get("discretization_error_estimate_mm")
        if est:
            label = ("reference's own error (estimate, no error bar: no converged value)"
                     if e.get("no_converged_value") else "reference's own error (estimate)")
            own[f"{label}: {e.get('reference_model', '')} {disc(e)}"] = est
    probe_rows += [(label, *[_fmt(est.get(p, float("nan"))) for p in probes])
                   for label, est in own.items()]
    parts = [
        "<!DOCTYPE html><html><head><meta charset='utf-8'>",
        f"<title>tissue verify: {html.escape(case.name)}</title>",
        ("<style>body{font-family:sans-serif;margin:2em}table{border-collapse:collapse;margin:1em 0}"
        "td,th{border:1px solid #999;padding:3px 8px;text-align:right}th{background:#eee}</style>"),
        "</head><body>",
        f"<h1>Verification: {html.escape(case.name)}</h1>",
        (f"<p>{ref['n_vertices']} vertices, {ref['n_cells']} cells; pushes (mm): "
        f"{html.escape(str(ref['pushes_mm']))}. Errors are |u - u_ref| at vertices / probes (mm) "
        "and the volume norms of the difference (L2, H1 seminorm, energy norm with the "
        "reference's E and nu) of its P1 interpolant on the case mesh (a field on another mesh: "
        "on its own cells), for every solver alike; "
        "the built-in fast solvers are scored against the FEniCSx P1 displacement solution on the "
        "same mesh (Neo-Hookean for ADMM, linear-elastic with the same E, nu for the Mass Tensor "
        "Method, a linear model); solvers that are not ours and fields against the reference "
        "named in their row. <i>admm</i> is ADMM finished by Newton steps, <i>admm-plain</i> ADMM "
        "alone.</p>"),
        "<h2>Reference</h2>",
        _table(["material", "E (kPa)", "nu", "Newton its", "load steps", "wall time (s)",
                "first call (s)", "converged"], ref_rows),
        "<h2>Solvers and fields</h2>",
        _table(["solver", "model", "reference", "max vertex error (mm)", "RMS vertex error (mm)",
                "volume L2 error (mm)", "H1 seminorm error (mm/mm)",
                "energy-norm error (sqrt uJ)", "iterations", "ADMM its",
                "Newton its (polish)", "wall time (s)", "speed-up vs reference", "converged"],
               sol_rows),
        "<ul>" + "".join(notes) + "</ul>" if notes else "",
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
