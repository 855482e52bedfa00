"""Mesh-convergence study of the reference on nested uniform refinements.

The Case mesh (the coarsest) is refined uniformly ``levels - 1`` times (``meshes.refine``: every
tetrahedron into 8, every triangle into 4, so h halves exactly: refinement ratio r = 2; the
midpoints of boundary edges on a curved builtin surface are projected onto it). The reference is
solved on every level and each scalar quantity q is studied on its own:

- probe displacements (mm), one quantity per component; the *dominant* component (largest |u| on
  the finest mesh) is the probe's headline value, and every component with at least
  ``component_floor`` (1 %) of the dominant one's magnitude is reported too;
- reactions (mN) of every Dirichlet region, per component in the same way.

For three successive levels q1 (coarse), q2, q3 (fine) the observed order is
p = ln((q1 - q2) / (q2 - q3)) / ln r, defined only when the ratio is positive (monotone
convergence) and both differences exceed round-off (``NOISE_REL`` = 1e-9 of the study's largest
displacement or reaction, at least 1e-10 mm / 1e-8 mN: below the Newton tolerances). A quantity
that is round-off on every level is reported as zero.

A quantity is in the *asymptotic range* when
- with 4 or more meshes: the observed orders of the two finest triples are both defined, agree
  within ``order_tol`` (0.25) and the finest is at least ``MIN_ORDER`` (0.5);
- with exactly 3 meshes (one observed order, nothing to compare it with): that order lies within
  ``order_tol`` of the smooth-solution order (``expected_order``: degree + 1 for a point
  displacement, 2 degree for a reaction); a singular problem (e.g. the rim of a pushed patch)
  converges more slowly and is reported as not asymptotic until a fourth mesh confirms its order.

Only then is the Richardson value q3 + (q3 - q2) / (r^p - 1) given, with Roache's grid convergence
index GCI = Fs |q3 - q2| / (r^p - 1), Fs = 1.25. Otherwise ``extrapolated`` is None and the GCI
is a conservative band: Fs = 3 with p clamped to [0.5, expected order] (p = 0.5 and the larger of
the two finest differences when the differences change sign).
"""
from __future__ import annotations

import gc
import math
import sys
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from meshes.case import Case, load_case
from meshes.errors import CaseError, ConvergenceError
from meshes.mesh import MeshData
from meshes.refine import mesh_hierarchy, projector_for

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

RATIO = 2.0             # uniform refinement halves h
MIN_LEVELS = 3          # meshes needed for one observed order
MIN_ORDER = 0.5         # below this an "order" is stagnation, not convergence
ORDER_TOL = 0.25        # agreement of observed orders (and with the expected one, 3 meshes)
FS_ASYMPTOTIC = 1.25    # Roache's safety factor with a confirmed observed order
FS_OTHERWISE = 3.0      # Roache's safety factor when the order is not confirmed
MAX_CELLS = 400_000     # default limit on the finest mesh
NOISE_REL = 1e-9        # round-off, relative to the largest displacement / reaction of a study
NOISE_ABS = {"mm": 1e-10, "mN": 1e-8}   # below the Newton tolerances
COMPONENTS = "xyz"


# --------------------------------------------------------------------------- scalar helpers
def observed_order(q_coarse: float, q_mid: float, q_fine: float, *, ratio: float = RATIO,
                   noise: float = 0.0) -> float | None:
    """p = ln((q1 - q2) / (q2 - q3)) / ln(ratio) for three successive levels of a scalar.

    None when the ratio is not positive (the differences change sign: oscillating) or either
    difference is at most ``noise`` (same unit as q)."""
    d1 = float(q_coarse) - float(q_mid)
    d2 = float(q_mid) - float(q_fine)
    if abs(d1) <= noise or abs(d2) <= noise:
        return None
    r = d1 / d2
    if r <= 0:
        return None
    return math.log(r) / math.log(ratio)


def richardson(q_mid: float, q_fine: float, order: float, *, ratio: float = RATIO) -> float:
    """Richardson value q_fine + (q_fine - q_mid) / (ratio^order - 1)."""
    return float(q_fine) + (float(q_fine) - float(q_mid)) / (ratio ** order - 1.0)


def gci(q_mid: float, q_fine: float, order: float, *, ratio: float = RATIO,
        safety: float = FS_ASYMPTOTIC) -> tuple[float, float | None]:
    """Roache's fine-grid convergence index: (absolute Fs |q_fine - q_mid| / (ratio^order - 1),
    relative to |q_fine|, None when q_fine is 0)."""
    a = safety * abs(float(q_fine) - float(q_mid)) / (ratio ** order - 1.0)
    return a, (a / abs(float(q_fine)) if q_fine != 0 else None)


@dataclass(frozen=True)
class QuantityConvergence:
    """One scalar quantity (unit ``unit``: mm or mN) on the levels of a study, coarse to fine.

    orders: observed order of each triple of successive levels (None where undefined).
    asymptotic: the module docstring's test passed; ``reason`` says why or why not.
    extrapolated: Richardson value (None unless asymptotic). gci / gci_rel: uncertainty of the
    finest value (absolute, unit; relative), with safety factor ``safety_factor``.
    """

    name: str
    unit: str
    values: tuple
    h: tuple
    orders: tuple
    expected_order: float
    asymptotic: bool
    reason: str
    extrapolated: float | None
    gci: float | None
    gci_rel: float | None
    safety_factor: float

    @property
    def observed_order(self) -> float | None:
        """The order from the three finest levels (None where undefined)."""
        return self.orders[-1] if self.orders else None

    def to_json_dict(self) -> dict:
        u = self.unit
        return {"values_" + u: list(self.values), "h_mm": list(self.h),
                "observed_order": self.observed_order, "observed_orders": list(self.orders),
                "expected_order": self.expected_order, "asymptotic": self.asymptotic,
                "reason": self.reason, "extrapolated_" + u: self.extrapolated,
                "gci_" + u: self.gci, "gci_rel": self.gci_rel,
                "safety_factor": self.safety_factor}


def assess(values, h, *, expected_order: float, order_tol: float = ORDER_TOL,
           ratio: float = RATIO, noise: float | None = None, name: str = "q",
           unit: str = "mm") -> QuantityConvergence:
    """Observed orders, asymptotic-range test, Richardson value and GCI of a scalar sequence
    ``values`` (coarse to fine, unit ``unit``) on meshes of size ``h`` (mm) refined by ``ratio``.
    noise: differences at most this large (unit) are round-off (default NOISE_REL max |q|).
    See the module docstring for the rules. Needs at least 3 values."""
    q = [float(v) for v in values]
    if len(q) < MIN_LEVELS:
        raise CaseError(f"{name}: an observed order needs at least {MIN_LEVELS} levels, "
                        f"got {len(q)}")
    if noise is None:
        noise = NOISE_REL * max(abs(v) for v in q)
    if max(abs(v) for v in q) <= noise:
        return QuantityConvergence(
            name, unit, tuple(q), tuple(float(x) for x in h), (None,) * (len(q) - 2),
            float(expected_order), False, f"zero: |q| <= {noise:.3g} {unit} (round-off) on "
            f"every level", None, None, None, FS_OTHERWISE)
    orders = tuple(observed_order(q[k], q[k + 1], q[k + 2], ratio=ratio, noise=noise)
                   for k in range(len(q) - 2))
    p = orders[-1]
    d_fine, d_prev = q[-2] - q[-1], q[-3] - q[-2]
    if abs(d_fine) <= noise and abs(d_prev) <= noise:
        ok, why = False, "the values do not change between levels (differences at round-off)"
    elif p is None:
        why = "the differences between levels change sign (oscillating)" \
            if d_fine * d_prev < 0 else "a difference between levels is at round-off"
        ok, why = False, f"{why}: {d_prev:+.3g}, {d_fine:+.3g} {unit}"
    elif len(orders) >= 2:
        prev = orders[-2]
        if prev is None:
            ok, why = False, f"order {p:.2f} from the finest levels, none from the coarser triple"
        elif abs(p - prev) > order_tol:
            ok, why = False, (f"observed orders {prev:.2f} then {p:.2f} differ by more than "
                              f"{order_tol:g}")
        elif p < MIN_ORDER:
            ok, why = False, f"observed order {p:.2f} < {MIN_ORDER:g} (stagnating)"
        else:
            ok, why = True, f"observed orders {prev:.2f} and {p:.2f} agree within {order_tol:g}"
    elif abs(p - expected_order) > order_tol:
        ok, why = False, (f"one observed order ({len(q)} meshes): {p:.2f}, not within "
                          f"{order_tol:g} of the smooth-solution order {expected_order:g}")
    else:
        ok, why = True, (f"observed order {p:.2f} within {order_tol:g} of the smooth-solution "
                         f"order {expected_order:g}")
    if ok:
        extra = richardson(q[-2], q[-1], p, ratio=ratio)
        g, g_rel = gci(q[-2], q[-1], p, ratio=ratio, safety=FS_ASYMPTOTIC)
        fs = FS_ASYMPTOTIC
    else:
        extra = None
        fs = FS_OTHERWISE
        if p is None:
            p_used, diff = MIN_ORDER, max(abs(d_fine), abs(d_prev))
        else:
            p_used, diff = min(max(p, MIN_ORDER), max(expected_order, MIN_ORDER)), abs(d_fine)
        g = fs * diff / (ratio ** p_used - 1.0)
        g_rel = g / abs(q[-1]) if q[-1] != 0 else None
    return QuantityConvergence(name, unit, tuple(q), tuple(float(x) for x in h), orders,
                               float(expected_order), ok, why, extra, g, g_rel, fs)


@dataclass(frozen=True)
class VectorConvergence:
    """A probe displacement (mm) or a region's reaction (mN) on every level.

    values: (levels, gdim). dominant: the component with the largest |value| on the finest mesh.
    components: label ("x", "y", "z") -> QuantityConvergence for the components of at least
    ``component_floor`` times the dominant magnitude (the dominant one always among them).
    """

    name: str
    unit: str
    values: np.ndarray
    dominant: str
    components: dict

    @property
    def headline(self) -> QuantityConvergence:
        return self.components[self.dominant]

    def to_json_dict(self) -> dict:
        d = {"component": self.dominant, **self.headline.to_json_dict(),
             "vector_" + self.unit: self.values.tolist(),
             "components": {k: v.to_json_dict() for k, v in self.components.items()}}
        return d


def _vector(name, unit, values, h, expected, order_tol, floor, noise) -> VectorConvergence:
    v = np.asarray(values, dtype=np.float64)
    fine = np.abs(v[-1])
    k = int(np.argmax(fine))
    comps = {}
    for c in range(v.shape[1]):
        if c == k or (fine[c] >= floor * fine[k] and fine[k] > noise):
            comps[COMPONENTS[c]] = assess(v[:, c], h, expected_order=expected, order_tol=order_tol,
                                          noise=noise, name=f"{name} {COMPONENTS[c]}", unit=unit)
    return VectorConvergence(name, unit, v, COMPONENTS[k], comps)


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
    from .solver import ReferenceSolver

    if meshes is None:
        check_budget(case.mesh.n_cells, case.mesh.gdim, levels, max_cells)
        meshes = mesh_hierarchy(case.mesh, levels, project=project)
    else:
        meshes = list(meshes)
        check_budget(meshes[0].n_cells, meshes[0].gdim, len(meshes), max_cells)
        if meshes[0] is not case.mesh:
            case = case.with_mesh(meshes[0])
    h0 = _mean_edge(meshes[0])
    h = tuple(h0 / RATIO ** k for k in range(len(meshes)))
    probes: dict = {p.name: [] for p in case.probes}
    reactions: dict = {}
    cells, dofs, its, walls = [], [], [], []
    u_scale = 0.0
    for k, mesh in enumerate(meshes):
        c = case if mesh is case.mesh else case.with_mesh(mesh)
        t0 = time.perf_counter()
        # every level straight-sided (its boundary vertices on the true geometry): the curved
        # edges of the coarsest mesh have no counterpart on the refined ones
        solver = ReferenceSolver(c, degree=degree, **{"curved": False, **solver_options})
        try:
            res = solver.solve(pushes)
        except ConvergenceError as exc:
            raise ConvergenceError(
                f"level {k} of the study ({mesh.n_cells:,} cells, h {h[k]:.3g} mm): {exc}",
                load_fraction=exc.load_fraction, last_converged=exc.last_converged) from exc
        wall = time.perf_counter() - t0
        u_scale = max(u_scale, float(np.abs(np.asarray(res.u)).max(initial=0.0)))
        for name, series in probes.items():
            series.append(np.asarray(res.probes[name], dtype=np.float64))
        for name, r in res.reactions.items():
            reactions.setdefault(name, []).append(np.asarray(r, dtype=np.float64))
        cells.append(mesh.n_cells)
        dofs.append(int(res.extra.get("n_dofs", mesh.n_vertices * mesh.gdim)))
        its.append(int(res.iterations))
        walls.append(wall)
        if progress:
            print(f"tissue converge: degree {degree}, level {k}: h {h[k]:.3g} mm, "
                  f"{mesh.n_cells:,} cells, {dofs[-1]:,} dofs, {res.iterations} Newton "
                  f"iterations, {wall:.1f} s", file=sys.stderr, flush=True)
        del solver, res
        gc.collect()
    reactions = {n: v for n, v in reactions.items() if len(v) == len(meshes)}
    r_scale = max((float(np.abs(v).max()) for v in reactions.values()), default=0.0)
    u_noise = max(NOISE_REL * u_scale, NOISE_ABS["mm"])
    r_noise = max(NOISE_REL * r_scale, NOISE_ABS["mN"])
    pv = {n: _vector(n, "mm", v, h, degree + 1, order_tol, component_floor, u_noise)
          for n, v in probes.items()}
    rv = {n: _vector(n, "mN", v, h, 2 * degree, order_tol, component_floor, r_noise)
          for n, v in reactions.items()}
    return ConvergenceStudy(degree, h, tuple(cells), tuple(dofs), pv, rv, tuple(its),
                            tuple(walls), dict(pushes or {}), case.name)


def load_study_case(path, *, size: float | None = None):
    """(Case, projection) of a Case file: its mesh built at ``size`` (mm; a builtin mesh only,
    default the file's own) and the boundary projection of its builtin (None for a mesh file,
    whose boundary is taken as it is)."""
    case = load_case(Path(path), size=size)
    builder = tomllib.loads(Path(path).read_text()).get("mesh", {}).get("builtin")
    return case, (projector_for(builder) if builder is not None else None)


def run_study(path, *, size: float | None = None, degrees=(1,), levels: int = MIN_LEVELS,
              pushes=None, max_cells: int | None = MAX_CELLS, order_tol: float = ORDER_TOL,
              progress: bool = False, **options) -> list:
    """The study of a Case file at each degree in ``degrees``, on one mesh hierarchy: the case's
    mesh at ``size`` (mm) refined ``levels - 1`` times. Returns a list of ConvergenceStudy.
    ``options`` go to ``refinement_study`` (and from there to ``ReferenceSolver``)."""
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
            "reactions": {k: v.to_json_dict() for k, v in study.reactions.items()}}


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

    from meshes.io import atomic_path

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
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
    return path
