"""Mesh-convergence study of the reference on nested uniform refinements.

The Case mesh (the coarsest) is refined uniformly ``levels - 1`` times (``meshes.refine``: every
tetrahedron into 8, every triangle into 4, so h halves exactly: refinement ratio r = 2; the
midpoints of boundary edges on a curved builtin surface are projected onto it). The reference is
solved on every level and each scalar quantity q is studied on its own:

- probe displacements (mm), one quantity per component; the *dominant* component (largest |u| on
  the finest mesh) is the probe's headline value, and every component with at least
  ``component_floor`` (1 %) of the dominant one's magnitude is reported too;
- reactions (mN) of every Dirichlet region, per component in the same way.

The orders, the asymptotic-range check, Richardson and the GCI live in ``richardson``.
"""
from __future__ import annotations

import sys
import time
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from tissue_reference.meshes.case import Case, load_case
from tissue_reference.meshes.case_file import case_path
from tissue_reference.meshes.converged_range import unconverged_load
from tissue_reference.meshes.errors import CaseError, ConvergenceError
from tissue_reference.meshes.io import save_figure
from tissue_reference.meshes.mesh import MeshData
from tissue_reference.meshes.refine import mesh_hierarchy, projector_for

from .richardson import (
    MIN_LEVELS,
    NOISE_ABS,
    NOISE_REL,
    ORDER_TOL,
    RATIO,
    QuantityConvergence,
    VectorConvergence,
    assess,
    gci,
    observed_order,
    richardson,
    vector_convergence,
)
from .solver import ReferenceSolver

__all__ = [
    "MAX_CELLS",
    "MIN_LEVELS",
    "ConvergenceStudy",
    "QuantityConvergence",
    "VectorConvergence",
    "assess",
    "check_budget",
    "format_study",
    "gci",
    "load_study_case",
    "observed_order",
    "plot_studies",
    "refinement_study",
    "richardson",
    "run_study",
    "study_to_json",
]

MAX_CELLS = 400_000     # default limit on the finest mesh

# --------------------------------------------------------------------------- the study
@dataclass(frozen=True)
class ConvergenceStudy:
    """A refinement study at one Lagrange degree.

    h: mean edge length of each level (mm; that of the coarsest mesh, halved per level).
    probes / reactions: name -> VectorConvergence (mm / mN).
    """

    degree: int
    h: tuple
    n_cells: tuple
    n_dofs: tuple
    probes: dict
    reactions: dict
    newton_iterations: tuple = ()
    wall_time_s: tuple = ()
    pushes: dict = field(default_factory=dict)
    case_name: str = "case"
    no_converged_value: tuple = ()
    """Why no mesh-converged answer is known at the study's load
    (``meshes.converged_range.unconverged_load``); then no quantity is extrapolated or given a
    GCI band."""

    def quantities(self):
        """(kind, VectorConvergence) of every probe, then every reaction."""
        return [("probe", v) for v in self.probes.values()] + \
            [("reaction", v) for v in self.reactions.values()]


def check_budget(n_cells: int, gdim: int, levels: int, max_cells: int | None) -> int:
    """Cells of the finest of ``levels`` meshes (each refinement multiplies them by 2^gdim);
    CaseError naming the estimate when it exceeds ``max_cells`` or levels < 3."""
    if levels < MIN_LEVELS:
        raise CaseError(f"a convergence study needs at least {MIN_LEVELS} meshes (levels >= "
                        f"{MIN_LEVELS}: an observed order takes three), got levels = {levels}")
    finest = n_cells * (2 ** gdim) ** (levels - 1)
    if max_cells is not None and finest > max_cells:
        raise CaseError(
            f"the finest of {levels} meshes would have about {finest:,} cells ({n_cells:,} x "
            f"{2 ** gdim}^{levels - 1}), more than the limit of {max_cells:,} (max_cells, "
            f"--max-cells): start from a coarser mesh (--size), use fewer levels or raise the "
            f"limit")
    return finest


def _mean_edge(mesh: MeshData) -> float:
    k = mesh.cells.shape[1]
    e = np.sort(np.concatenate([mesh.cells[:, [a, b]] for a in range(k)
                                for b in range(a + 1, k)]), axis=1)
    e = np.unique(e, axis=0)
    return float(np.linalg.norm(mesh.points[e[:, 0]] - mesh.points[e[:, 1]], axis=1).mean())


def refinement_study(case: Case, *, levels: int = MIN_LEVELS, degree: int = 1, pushes=None,
                     project=None, meshes=None, max_cells: int | None = MAX_CELLS,
                     order_tol: float = ORDER_TOL, component_floor: float = 0.01,
                     progress: bool = False,
                     **solver_options) -> ConvergenceStudy:
    """Solve ``case`` on its own mesh and ``levels - 1`` nested uniform refinements of it.

    pushes: actuator name -> push (mm). project: boundary projection for ``refine_uniform``
    (``meshes.refine.projector_for``), None for a flat or polyhedral boundary. meshes: a ready
    hierarchy (coarse first, each the uniform refinement of the previous; the first is
    ``case.mesh``) instead of ``levels`` / ``project``. max_cells: refuse (CaseError) a study whose
    finest mesh would exceed it. solver_options: passed on as
    ``ReferenceSolver(case, degree=degree, **solver_options)``.
    """
    if meshes is None:
        check_budget(case.mesh.n_cells, case.mesh.gdim, levels, max_cells)
        meshes = mesh_hierarchy(case.mesh, levels, project=project)
    else:
        meshes = list(meshes)
        check_budget(meshes[0].n_cells, meshes[0].gdim, len(meshes), max_cells)
        if meshes[0] is not case.mesh:
            case = case.with_mesh(meshes[0])
    curved = None if all(m.geometry_order == 2 for m in meshes) else False
    h0 = _mean_edge(meshes[0])
    h = tuple(h0 / RATIO ** k for k in range(len(meshes)))
    probes: dict = {p.name: [] for p in case.probes}
    reactions: dict = {}
    cells, dofs, its, walls = [], [], [], []
    u_scale = 0.0
    for k, mesh in enumerate(meshes):
        c = case if mesh is case.mesh else case.with_mesh(mesh)
        t0 = time.perf_counter()
        # every level curved where the hierarchy carries curved edges on all of them
        # (``mesh_hierarchy`` of a curved builtin), else every level straight-sided
        solver = ReferenceSolver(c, degree=degree, **{"curved": curved, **solver_options})
        try:
            res = solver.solve(pushes)
        except ConvergenceError as exc:
            raise ConvergenceError(
                f"level {k} of the study ({mesh.n_cells:,} cells, h {h[k]:.3g} mm): {exc}",
                load_fraction=exc.load_fraction, last_converged=exc.last_converged) from exc
        finally:
            solver.close()   # the level's matrices and factor now, not at the process's end
        if res.valid is False:  # a folded state is no point of a study
            raise ConvergenceError(
                f"level {k} of the study ({mesh.n_cells:,} cells, h {h[k]:.3g} mm): the answer is "
                f"not valid: {res.invalid_reason}", last_converged=res)
        wall = time.perf_counter() - t0
        u_scale = max(u_scale, float(np.abs(np.asarray(res.u)).max(initial=0.0)))
        for name, series in probes.items():
            series.append(np.asarray(res.probes[name], dtype=np.float64))
        for name, r in res.reactions.items():
            reactions.setdefault(name, []).append(np.asarray(r, dtype=np.float64))
        cells.append(mesh.n_cells)
        dofs.append(int((res.discretization or {}).get("dofs", mesh.n_vertices * mesh.gdim)))
        its.append(int(res.iterations))
        walls.append(wall)
        if progress:
            print(f"tissue converge: degree {degree}, level {k}: h {h[k]:.3g} mm, "
                  f"{mesh.n_cells:,} cells, {dofs[-1]:,} dofs, {res.iterations} Newton "
                  f"iterations, {wall:.1f} s", file=sys.stderr, flush=True)
    reactions = {n: v for n, v in reactions.items() if len(v) == len(meshes)}
    r_scale = max((float(np.abs(v).max()) for v in reactions.values()), default=0.0)
    u_noise = max(NOISE_REL * u_scale, NOISE_ABS["mm"])
    r_noise = max(NOISE_REL * r_scale, NOISE_ABS["mN"])
    pv = {n: vector_convergence(n, "mm", v, h, degree + 1, order_tol, component_floor, u_noise)
          for n, v in probes.items()}
    rv = {n: vector_convergence(n, "mN", v, h, 2 * degree, order_tol, component_floor, r_noise)
          for n, v in reactions.items()}

    why = tuple(unconverged_load(case, pushes))
    if why:   # the levels are data; an extrapolated value or a band would claim a limit
        pv, rv = ({n: _no_limit(v) for n, v in g.items()} for g in (pv, rv))
    return ConvergenceStudy(degree, h, tuple(cells), tuple(dofs), pv, rv, tuple(its),
                            tuple(walls), dict(pushes or {}), case.name, why)


def _no_limit(vec: VectorConvergence) -> VectorConvergence:
    """``vec`` with every component's extrapolation and GCI band removed: at a load where no
    mesh-converged answer is known the study reports its levels and orders only."""
    return replace(vec, components={
        k: replace(q, asymptotic=False, extrapolated=None, gci=None, gci_rel=None,
                   reason="no mesh-converged answer is known at this load")
        for k, q in vec.components.items()})


def load_study_case(path, *, size: float | None = None):
    """(Case, projection) of a Case file, or of a shipped case by its name (``thick-sphere``): its
    mesh built at ``size`` (mm; a builtin mesh only, default the file's own) and the boundary
    projection of its builtin (None for a mesh file, whose boundary is taken as it is)."""
    path = case_path(path)
    case = load_case(path, size=size)
    builder = tomllib.loads(path.read_text()).get("mesh", {}).get("builtin")
    return case, (projector_for(builder) if builder is not None else None)


def run_study(path, *, size: float | None = None, degrees=(1,), levels: int = MIN_LEVELS,
              pushes=None, max_cells: int | None = MAX_CELLS, order_tol: float = ORDER_TOL,
              progress: bool = False, **options) -> list:
    """The study of a Case file at each degree in ``degrees``, on one mesh hierarchy: the case's
    mesh at ``size`` (mm) refined ``levels - 1`` times. Returns a list of ConvergenceStudy.
    ``options`` go to ``refinement_study`` (and from there to ``ReferenceSolver``).

    Parameters
    ----------
    path : str or Path
        A Case TOML file or a shipped case's name.
    size : float or None
        Cell size (mm) of the coarsest (builtin) mesh; None: the file's.
    degrees : sequence of int
        Lagrange degrees, one study each.
    levels : int
        Meshes in the hierarchy (h halved per level).
    pushes : dict or None
        Actuator name -> push (mm); None: the case as loaded.
    max_cells : int or None
        Cells of the finest level above which the study is refused; None: no limit.
    order_tol : float
        Tolerance of the asymptotic-range test on the observed order.
    progress : bool
        Print a line per solve.
    **options
        Options of ``refinement_study`` and ``ReferenceSolver``.

    Returns
    -------
    list of ConvergenceStudy
        One per degree: per level h (mm), cells and unknowns; per probe (mm) and reaction (mN)
        its QuantityConvergence.

    Raises
    ------
    CaseError
        For a bad case, fewer than 3 levels, or a finest mesh past ``max_cells``.
    ConvergenceError
        When a solve of the study does not converge.
    """
    case, project = load_study_case(path, size=size)
    check_budget(case.mesh.n_cells, case.mesh.gdim, levels, max_cells)
    t0 = time.perf_counter()
    meshes = mesh_hierarchy(case.mesh, levels, project=project)
    if progress:
        print(f"tissue converge: {levels} nested meshes, {meshes[0].n_cells:,} to "
              f"{meshes[-1].n_cells:,} cells ({time.perf_counter() - t0:.1f} s)",
              file=sys.stderr, flush=True)
    return [refinement_study(case, degree=d, pushes=pushes, meshes=meshes, max_cells=max_cells,
                             order_tol=order_tol, progress=progress, **options)
            for d in degrees]


# --------------------------------------------------------------------------- output
def study_to_json(study: ConvergenceStudy) -> dict:
    """JSON form: degree, h_mm, n_cells, n_dofs, probes / reactions: name -> the dominant
    component's fields (values_mm / values_mN, observed_order, asymptotic, extrapolated_*, gci_*,
    gci_rel, ...) with ``components`` holding every reported component."""
    return {"degree": study.degree, "h_mm": list(study.h), "n_cells": list(study.n_cells),
            "n_dofs": list(study.n_dofs), "newton_iterations": list(study.newton_iterations),
            "wall_time_s": list(study.wall_time_s),
            "probes": {k: v.to_json_dict() for k, v in study.probes.items()},
            "reactions": {k: v.to_json_dict() for k, v in study.reactions.items()},
            **({"no_converged_value": list(study.no_converged_value)}
               if study.no_converged_value else {})}


def _fmt(x, width=10):
    return f"{x:>{width}.6g}" if x is not None else f"{'-':>{width}}"


def format_study(study: ConvergenceStudy) -> str:
    """The study as a plain-text table; each value outside the asymptotic range says so."""
    push = ", ".join(f"{k}={v:g} mm" for k, v in study.pushes.items()) or "none"
    lines = [(f"degree {study.degree}: {len(study.h)} nested meshes (uniform refinement, "
              f"h halved), pushes {push}"),
             (f"  {'level':>5} {'h (mm)':>8} {'cells':>10} {'dofs':>10} {'Newton':>6} "
              f"{'time (s)':>8}")]
    for k in range(len(study.h)):
        it = study.newton_iterations[k] if study.newton_iterations else 0
        wt = study.wall_time_s[k] if study.wall_time_s else float("nan")
        lines.append(f"  {k:>5} {study.h[k]:>8.3g} {study.n_cells[k]:>10,} "
                     f"{study.n_dofs[k]:>10,} {it:>6} {wt:>8.1f}")
    lines += [f"  NO CONVERGED VALUE: {w}; the levels and orders below are data, nothing is "
              f"extrapolated or given a band" for w in study.no_converged_value]
    head = (f"  {'quantity':<16} {'values, coarse -> fine':<{11 * len(study.h)}} "
            f"{'orders':<{7 * max(len(study.h) - 2, 1)}} {'extrapolated':>12} {'GCI':>8}")
    for title, group in (("probe displacements (mm)", study.probes),
                         ("reactions of the Dirichlet regions (mN)", study.reactions)):
        if not group:
            continue
        lines += ["", f"  {title}; first the dominant component, then any of >= 1 % of it:", head]
        for vec in group.values():
            for lab in [vec.dominant] + [c for c in vec.components if c != vec.dominant]:
                q = vec.components[lab]
                vals = "".join(_fmt(v) + " " for v in q.values)
                ords = "".join(f"{o:>6.2f} " if o is not None else f"{'-':>6} " for o in q.orders)
                g = f"{100 * q.gci_rel:>7.3g}%" if q.gci_rel is not None else f"{'-':>8}"
                lines.append(f"  {vec.name + ' ' + lab:<16} {vals} {ords}"
                             f"{_fmt(q.extrapolated, 12)} {g}")
                if q.gci is None:
                    lines.append(f"  {'':<16} {q.reason}: nothing to extrapolate")
                elif q.asymptotic:
                    lines.append(f"  {'':<16} asymptotic: {q.reason}; GCI with Fs = "
                                 f"{q.safety_factor:g}")
                else:
                    lines.append(f"  {'':<16} NOT in the asymptotic range ({q.reason}): no "
                                 f"extrapolated value; GCI is a band with Fs = "
                                 f"{q.safety_factor:g}")
    return "\n".join(lines)


def plot_studies(studies, path) -> Path:
    """Log-log plot (PNG) of |q(h) - q(h/2)|, the difference between successive levels, against
    h (mm) for the dominant component of every probe (mm) and reaction (mN), with reference
    slopes of order 1 and 2. The difference estimates the error of the coarser level when
    convergence is monotone; it is not the error itself."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5))
    for ax, kind, unit in ((axes[0], "probes", "mm"), (axes[1], "reactions", "mN")):
        anchor = None
        for st in studies:
            for vec in getattr(st, kind).values():
                q = np.asarray(vec.headline.values)
                d = np.abs(np.diff(q))
                hh = np.asarray(st.h[:-1])
                ok = d > 0
                if not np.any(ok):
                    continue
                ax.loglog(hh[ok], d[ok], "o-", label=f"P{st.degree} {vec.name} {vec.dominant}")
                if anchor is None:
                    anchor = (hh[ok][0], d[ok][0], hh[ok][-1])
        if anchor is not None:
            h0, d0, h1 = anchor
            hs = np.array([h0, h1 if h1 < h0 else h0 / 4])
            for p, style in ((1, "k--"), (2, "k:")):
                ax.loglog(hs, d0 * (hs / h0) ** p, style, lw=1, label=f"slope {p}")
        ax.set_xlabel("h (mm)")
        ax.set_ylabel(f"|q(h) - q(h/2)| ({unit})")
        ax.set_title(f"{kind}: difference between successive levels")
        ax.grid(True, which="both", alpha=0.3)
        if ax.has_data():
            ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
    return path

