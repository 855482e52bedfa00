"""Mesh-convergence study of the reference on nested uniform refinements or remeshed levels.

Uniform (the default): the Case mesh (the coarsest) is refined uniformly ``levels - 1`` times
(``meshes.refine``: every tetrahedron into 8, every triangle into 4, so h halves exactly:
refinement ratio r = 2; the midpoints of boundary edges on a curved builtin surface are projected
onto it). Remeshed (``levels_by="remesh"``, a builtin mesh only): level k is the builtin built
again with every cell size of the case's ``[mesh]`` table (size, site_size, path_size, rim_size,
base_rim_size) divided by ratio^k (default sqrt 2, about 2.8 times the cells per level in 3D);
path_reach, the extent of the refined paths, stays. These are the levels of the indenter
phantom's studies (bench/bench_indenter_convergence.py). The reference is solved on every level
and each scalar quantity q is studied on its own:

- probe displacements (mm), one quantity per component; the *dominant* component (largest |u| on
  the finest mesh) is the probe's headline value, and every component with at least
  ``component_floor`` (1 %) of the dominant one's magnitude is reported too;
- reactions (mN) of every Dirichlet region, per component in the same way;
- the force (mN) of every rigid tip along its push, as the case solves it (a tip cut by a
  mirror plane: the cut tip's).

The orders, the asymptotic-range check, Richardson and the GCI live in ``richardson``.
"""
from __future__ import annotations

import math
import sys
import time
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from tissue_reference.errors import CaseError, ConvergenceError
from tissue_reference.meshes.builders import build, estimate_cells
from tissue_reference.meshes.builders_curved import LOCAL_SIZES
from tissue_reference.meshes.io import save_figure
from tissue_reference.meshes.mesh import MeshData
from tissue_reference.meshes.refine import mesh_hierarchy, projector_for
from tissue_reference.model.case import Case, load_case
from tissue_reference.model.case_file import case_path
from tissue_reference.model.case_schema import case_schema
from tissue_reference.model.converged_range import unconverged_load

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
    "LEVELS_BY",
    "MAX_CELLS",
    "MIN_LEVELS",
    "REMESH_RATIO",
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
    "remesh_hierarchy",
    "remesh_lengths",
    "richardson",
    "run_study",
    "study_to_json",
]

MAX_CELLS = 400_000     # default limit on the finest mesh
LEVELS_BY = ("uniform", "remesh")
REMESH_RATIO = math.sqrt(2.0)   # remeshed levels: every cell size / sqrt 2 per level
REMESHED = ("size", "site_size", "path_size", "rim_size", "base_rim_size")
"""The ``[mesh]`` lengths that are cell sizes: divided by the ratio per remeshed level (the
other, path_reach, is the extent of the refined paths and stays)."""

# --------------------------------------------------------------------------- the study
@dataclass(frozen=True)
class ConvergenceStudy:
    """A refinement study at one Lagrange degree.

    h: mean edge length of each level (mm; that of the coarsest mesh, divided by ``ratio`` per
    level). probes / reactions: name -> VectorConvergence (mm / mN). forces: rigid tip ->
    QuantityConvergence of its force along its push (mN). ratio: h of a level / h of the next
    (2: uniform refinement; remeshed: the ratio the cell sizes were divided by). mean_edge: the
    measured mean edge length of each level (mm). lengths: per level the builtin's cell sizes
    (mm; remeshed levels only).
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
    (``model.converged_range.unconverged_load``); then no quantity is extrapolated or given a
    GCI band."""
    forces: dict = field(default_factory=dict)
    ratio: float = RATIO
    levels_by: str = "uniform"
    mean_edge: tuple = ()
    lengths: tuple = ()
    geometry_order: int = 1

    def quantities(self):
        """(kind, VectorConvergence) of every probe, then every reaction."""
        return [("probe", v) for v in self.probes.values()] + \
            [("reaction", v) for v in self.reactions.values()]


def _check_levels(levels: int) -> None:
    if levels < MIN_LEVELS:
        raise CaseError(f"a convergence study needs at least {MIN_LEVELS} meshes (levels >= "
                        f"{MIN_LEVELS}: an observed order takes three), got levels = {levels}")


def check_budget(n_cells: int, gdim: int, levels: int, max_cells: int | None) -> int:
    """Cells of the finest of ``levels`` meshes (each refinement multiplies them by 2^gdim);
    CaseError naming the estimate when it exceeds ``max_cells`` or levels < 3."""
    _check_levels(levels)
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
                     progress: bool = False, ratio: float = RATIO, levels_by: str = "uniform",
                     lengths=(), **solver_options) -> ConvergenceStudy:
    """Solve ``case`` on its own mesh and ``levels - 1`` nested uniform refinements of it.

    pushes: actuator name -> push (mm). project: boundary projection for ``refine_uniform``
    (``meshes.refine.projector_for``), None for a flat or polyhedral boundary. meshes: a ready
    hierarchy (coarse first, each the uniform refinement of the previous; the first is
    ``case.mesh``) instead of ``levels`` / ``project``; with ``levels_by="remesh"`` the levels of
    ``remesh_hierarchy``, whose h shrinks by ``ratio`` per level (``lengths``: their cell
    sizes). max_cells: refuse (CaseError) a study whose finest mesh would exceed it.
    solver_options: passed on as ``ReferenceSolver(case, degree=degree, **solver_options)``.
    """
    if levels_by not in LEVELS_BY:
        raise CaseError(f"levels_by must be one of {LEVELS_BY}, got {levels_by!r}")
    if levels_by == "uniform" and ratio != RATIO:
        raise CaseError(f"uniform refinement halves h: refinement ratio {RATIO:g}, got {ratio!r}")
    if meshes is None:
        if levels_by == "remesh":
            raise CaseError("remeshed levels: pass the meshes of remesh_hierarchy")
        check_budget(case.mesh.n_cells, case.mesh.gdim, levels, max_cells)
        meshes = mesh_hierarchy(case.mesh, levels, project=project)
    else:
        meshes = list(meshes)
        if levels_by == "uniform":
            check_budget(meshes[0].n_cells, meshes[0].gdim, len(meshes), max_cells)
        else:
            _check_levels(len(meshes))
            if max_cells is not None and meshes[-1].n_cells > max_cells:
                raise CaseError(f"the finest of {len(meshes)} remeshed levels has "
                                f"{meshes[-1].n_cells:,} cells, more than the limit of "
                                f"{max_cells:,} (max_cells, --max-cells)")
        if meshes[0] is not case.mesh:
            case = case.with_mesh(meshes[0])
    curved = None if all(m.geometry_order == 2 for m in meshes) else False
    edges = tuple(_mean_edge(m) for m in meshes) if levels_by == "remesh" else \
        (_mean_edge(meshes[0]),)
    h = tuple(edges[0] / ratio ** k for k in range(len(meshes)))
    probes: dict = {p.name: [] for p in case.probes}
    reactions: dict = {}
    forces: dict = {}
    cells, dofs, its, walls = [], [], [], []
    geometry_order = 1
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
        for name, ind in (res.indenters or {}).items():
            forces.setdefault(name, []).append(float(ind["force"]))
        geometry_order = int((res.discretization or {}).get("geometry_order", 1))
        cells.append(mesh.n_cells)
        dofs.append(int((res.discretization or {}).get("dofs", mesh.n_vertices * mesh.gdim)))
        its.append(int(res.iterations))
        walls.append(wall)
        if progress:
            tips = "".join(f", {n} force {v[-1]:.10g} mN" for n, v in forces.items())
            print(f"tissue converge: degree {degree}, level {k}: h {h[k]:.3g} mm, "
                  f"{mesh.n_cells:,} cells, {dofs[-1]:,} dofs, {res.iterations} Newton "
                  f"iterations{tips}, {wall:.1f} s", file=sys.stderr, flush=True)
    reactions = {n: v for n, v in reactions.items() if len(v) == len(meshes)}
    forces = {n: v for n, v in forces.items() if len(v) == len(meshes)}
    r_scale = max((float(np.abs(v).max()) for v in reactions.values()), default=0.0)
    u_noise = max(NOISE_REL * u_scale, NOISE_ABS["mm"])
    r_noise = max(NOISE_REL * r_scale, NOISE_ABS["mN"])
    f_noise = max(NOISE_REL * max((abs(x) for v in forces.values() for x in v), default=0.0),
                  NOISE_ABS["mN"])
    pv = {n: vector_convergence(n, "mm", v, h, degree + 1, order_tol, component_floor, u_noise,
                                ratio=ratio)
          for n, v in probes.items()}
    rv = {n: vector_convergence(n, "mN", v, h, 2 * degree, order_tol, component_floor, r_noise,
                                ratio=ratio)
          for n, v in reactions.items()}
    fv = {n: assess(v, h, expected_order=2 * degree, order_tol=order_tol, ratio=ratio,
                    noise=f_noise, name=f"{n} force", unit="mN")
          for n, v in forces.items()}

    why = tuple(unconverged_load(case, pushes))
    if why:   # the levels are data; an extrapolated value or a band would claim a limit
        pv, rv = ({n: _no_limit(v) for n, v in g.items()} for g in (pv, rv))
        fv = {n: _no_limit_q(q) for n, q in fv.items()}
    return ConvergenceStudy(degree, h, tuple(cells), tuple(dofs), pv, rv, tuple(its),
                            tuple(walls), dict(pushes or {}), case.name, why, forces=fv,
                            ratio=float(ratio), levels_by=levels_by,
                            mean_edge=edges if levels_by == "remesh" else (),
                            lengths=tuple(dict(lv) for lv in lengths),
                            geometry_order=geometry_order)


def _no_limit(vec: VectorConvergence) -> VectorConvergence:
    """``vec`` with every component's extrapolation and GCI band removed: at a load where no
    mesh-converged answer is known the study reports its levels and orders only."""
    return replace(vec, components={k: _no_limit_q(q) for k, q in vec.components.items()})


def _no_limit_q(q: QuantityConvergence) -> QuantityConvergence:
    return replace(q, asymptotic=False, extrapolated=None, gci=None, gci_rel=None,
                   reason="no mesh-converged answer is known at this load")


def load_study_case(path, *, size: float | None = None):
    """(Case, projection) of a Case file, or of a shipped case by its name (``thick-sphere``): its
    mesh built at ``size`` (mm; a builtin mesh only, default the file's own) and the boundary
    projection of its builtin (None for a mesh file, whose boundary is taken as it is)."""
    path = case_path(path)
    case = load_case(path, size=size)
    builder = tomllib.loads(path.read_text()).get("mesh", {}).get("builtin")
    return case, (projector_for(builder) if builder is not None else None)


def remesh_lengths(path, *, levels: int, ratio: float = REMESH_RATIO,
                   size: float | None = None) -> tuple[str, list[dict]]:
    """(builtin name, per level its lengths in mm) of the remeshed levels of a Case file with a
    builtin mesh: level k has every cell size of the ``[mesh]`` table (``REMESHED``; ``size``
    overrides the characteristic one) divided by ratio^k, path_reach as the table gives it.
    CaseError for a case without a builtin mesh."""
    path = case_path(path)
    try:
        table = tomllib.loads(Path(path).read_text(encoding="utf-8")).get("mesh", {})
    except (OSError, ValueError) as exc:
        raise CaseError(f"{path}: {exc}") from None
    name = table.get("builtin") if isinstance(table, dict) else None
    if not isinstance(name, str):
        what = f"the file {table['file']!r}" if isinstance(table, dict) and "file" in table \
            else "no builtin mesh"
        raise CaseError(f"{path}: remeshed levels (levels_by 'remesh', --levels-by remesh) "
                        f"rebuild a builtin mesh with smaller cells, and this case's [mesh] is "
                        f"{what}: use uniform refinement (--levels-by uniform)")
    if isinstance(ratio, bool) or not isinstance(ratio, (int, float)) or \
            not math.isfinite(ratio) or ratio <= 1.0:
        raise CaseError(f"the refinement ratio of remeshed levels must be a number > 1, got "
                        f"{ratio!r}")
    default = case_schema()["properties"]["mesh"]["properties"]["size"]["default"]
    base = {"size": size if size is not None else table.get("size", default)}
    base.update({k: table[k] for k in LOCAL_SIZES if k in table})
    for k, v in base.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
                or v <= 0:
            raise CaseError(f"{path}: [mesh].{k}: expected a length > 0 (mm), found {v!r}")
    return name, [{k: float(v) / ratio ** lv if k in REMESHED else float(v)
                   for k, v in base.items()} for lv in range(levels)]


def _level_text(lv: dict) -> str:
    return ", ".join(f"{k} {v:.4g}" for k, v in lv.items()) + " mm"


def remesh_hierarchy(path, *, levels: int, ratio: float = REMESH_RATIO,
                     size: float | None = None, max_cells: int | None = MAX_CELLS,
                     progress: bool = False) -> tuple[list, list]:
    """(meshes, lengths) of the remeshed levels of a Case file (``remesh_lengths``). Each level's
    cells are estimated (``meshes.builders.estimate_cells``) before any is built: a finest level
    estimated above ``max_cells`` is refused (CaseError naming the estimate), as is a built level
    that exceeds it."""
    _check_levels(levels)
    name, lengths = remesh_lengths(path, levels=levels, ratio=ratio, size=size)
    estimates = [estimate_cells(name, lv["size"], **{k: v for k, v in lv.items() if k != "size"})
                 for lv in lengths]
    finest = estimates[-1]
    if max_cells is not None and finest is not None and finest > max_cells:
        grow = f" (x {finest / estimates[0]:.2f} per level)" if estimates[0] else ""
        raise CaseError(
            f"the finest of {levels} remeshed levels would have about {finest:,} cells "
            f"(builtin {name!r} with {_level_text(lengths[-1])}: every cell size divided by "
            f"{ratio:.4g}^{levels - 1}; level 0 about {estimates[0]:,} cells{grow}), more "
            f"than the limit of {max_cells:,} (max_cells, --max-cells): use a larger --size, "
            f"fewer --levels or raise the limit")
    meshes = []
    for k, lv in enumerate(lengths):
        t0 = time.perf_counter()
        try:
            mesh = build(name, lv["size"], max_cells=max_cells,
                         **{key: v for key, v in lv.items() if key != "size"})
        except CaseError as exc:
            raise CaseError(f"{path}: remeshed level {k} ({_level_text(lv)}): {exc}") from None
        if max_cells is not None and mesh.n_cells > max_cells:
            raise CaseError(f"remeshed level {k} of {levels} ({_level_text(lv)}) has "
                            f"{mesh.n_cells:,} cells, more than the limit of {max_cells:,} "
                            f"(max_cells, --max-cells)")
        meshes.append(mesh)
        if progress:
            print(f"tissue converge: remeshed level {k}: {_level_text(lv)}, {mesh.n_cells:,} "
                  f"cells ({time.perf_counter() - t0:.1f} s)", file=sys.stderr, flush=True)
    return meshes, lengths


def run_study(path, *, size: float | None = None, degrees=(1,), levels: int = MIN_LEVELS,
              pushes=None, max_cells: int | None = MAX_CELLS, order_tol: float = ORDER_TOL,
              progress: bool = False, levels_by: str = "uniform", ratio: float | None = None,
              **options) -> list:
    """The study of a Case file at each degree in ``degrees``, on one mesh hierarchy: the case's
    mesh at ``size`` (mm) refined ``levels - 1`` times (``levels_by="uniform"``), or the case's
    builtin remeshed ``levels`` times with every cell size divided by ``ratio`` (default sqrt 2)
    per level (``levels_by="remesh"``; ``remesh_hierarchy``). Returns a list of
    ConvergenceStudy. ``options`` go to ``refinement_study`` (and from there to
    ``ReferenceSolver``).

    Parameters
    ----------
    path : str or Path
        A Case TOML file or a shipped case's name.
    size : float or None
        Cell size (mm) of the coarsest (builtin) mesh; None: the file's.
    degrees : sequence of int
        Lagrange degrees, one study each.
    levels : int
        Meshes in the hierarchy (h halved per level when uniform).
    pushes : dict or None
        Actuator name -> push (mm); None: the case as loaded.
    max_cells : int or None
        Cells of the finest level above which the study is refused; None: no limit.
    levels_by : str
        "uniform" (each level the previous one refined uniformly) or "remesh" (the case's
        builtin remeshed with its cell sizes divided by ``ratio`` per level).
    ratio : float or None
        Refinement ratio of remeshed levels; None: sqrt 2.
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
    if levels_by not in LEVELS_BY:
        raise CaseError(f"levels_by must be one of {LEVELS_BY}, got {levels_by!r}")
    if levels_by == "remesh":
        r = REMESH_RATIO if ratio is None else ratio
        meshes, lengths = remesh_hierarchy(path, levels=levels, ratio=r, size=size,
                                           max_cells=max_cells, progress=progress)
        case = load_case(case_path(path), mesh=meshes[0])
        return [refinement_study(case, degree=d, pushes=pushes, meshes=meshes,
                                 max_cells=max_cells, order_tol=order_tol, progress=progress,
                                 ratio=r, levels_by="remesh", lengths=lengths, **options)
                for d in degrees]
    if ratio is not None and ratio != RATIO:
        raise CaseError(f"uniform refinement halves h (ratio {RATIO:g}): a refinement ratio "
                        f"({ratio!r}) applies to remeshed levels (--levels-by remesh)")
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
            **({"indenter_forces": {k: q.to_json_dict() for k, q in study.forces.items()}}
               if study.forces else {}),
            **({"mean_edge_mm": list(study.mean_edge)} if study.mean_edge else {}),
            **({"mesh_lengths_mm": [dict(lv) for lv in study.lengths]}
               if study.lengths else {}),
            **({"no_converged_value": list(study.no_converged_value)}
               if study.no_converged_value else {})}


def _fmt(x, width=10):
    return f"{x:>{width}.6g}" if x is not None else f"{'-':>{width}}"


def format_study(study: ConvergenceStudy) -> str:
    """The study as a plain-text table; each value outside the asymptotic range says so."""
    push = ", ".join(f"{k}={v:g} mm" for k, v in study.pushes.items()) or "none"
    how = (f"remeshed levels, every cell size divided by {study.ratio:.4g} per level"
           if study.levels_by == "remesh" else "nested meshes (uniform refinement, h halved)")
    lines = [(f"degree {study.degree}: {len(study.h)} {how}, pushes {push}"),
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
    forces = {n: VectorConvergence(n, "mN", np.asarray(q.values)[:, None], "push",
                                   {"push": q}) for n, q in study.forces.items()}
    for title, group in (("probe displacements (mm)", study.probes),
                         ("reactions of the Dirichlet regions (mN)", study.reactions),
                         ("forces of the rigid tips along their pushes (mN)", forces)):
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

