"""Scoring a displacement field that is not ours against the reference.

A field comes from a file (``load_field``) or from a solver's return value (``field_from_array``):
its points, its displacement at those points (mm) and, when it has them, its cells (a mesh of
its own). ``score_field`` compares it with a reference SolveResult of the Case:

- points that coincide with the Case mesh's vertices (to 1e-6 of the body's size) are matched by
  coordinates, so a field in any vertex order scores the same; a field without coordinates (NPY,
  CSV) is in the Case mesh's vertex order by definition;
- on another mesh of the same body the reference is interpolated to the field's points: exactly
  for a degree-1 reference, with the degree-2 shape functions on straight cells for a degree-2
  one, and linearly in the reference's vertex values otherwise (the score then includes an
  O(h^2) interpolation error; ``reference_interpolation`` says which). A point within a small
  distance of the discretized surface (a curved body's facets) is snapped to it; a point farther
  out is outside the body: named in the error (or, with ``outside="skip"``, left out and listed).

Scores (mm unless stated): ``max_vertex_error_mm`` and ``rms_vertex_error_mm`` over the field's
points; on a mesh (the Case's, or the field's own cells) the volume L2 error of the linear
interpolant of the difference ``l2_error_mm`` (= sqrt(int |e|^2 dV / V), an RMS over the volume),
``h1_seminorm_error`` (sqrt(int |grad e|^2 dV / V), dimensionless), and the small-strain energy
norm of the difference with the Case's E and nu, ``energy_norm_error_sqrt_uJ`` (sqrt(int sigma(e) :
eps(e) dV), sqrt(uJ); none at nu = 0.5); ``probe_error_mm`` per probe (the field interpolated
at the probe, minus the reference's probe value); relative figures divide by the reference's own
norm. Units: mm, kPa, uJ. ``vertex_norms`` gives the volume norms of two fields at the Case mesh's
vertices: ``tissue verify`` scores every solver's vertex displacements with it, built-in or not.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tissue_reference.errors import CaseError

log = logging.getLogger("tissue.scoring")

__all__ = ["FIELD_NAMES", "Field", "field_from_array", "load_field", "score_field",
           "vertex_norms"]

# point-data names taken as the displacement, in order of preference
FIELD_NAMES = ("displacement", "u", "Displacement", "U", "disp", "DISPLACEMENT")
MATCH_RTOL = 1e-6   # coordinates within this fraction of the body's size are the same point
SNAP_RTOL = 0.05    # a point this close to the body (fraction of the local cell size) is inside
SAG_FACTOR = 1.5    # a curved facet's interior bulges up to about 4/3 of its edges' sag (sphere)


@dataclass(frozen=True)
class Field:
    """A displacement field: ``u`` (m, gdim) mm at ``points`` (m, gdim) mm, or at the Case mesh's
    vertices in their order when ``points`` is None; ``cells`` (k, gdim + 1) when the field has a
    mesh of its own. ``source`` names it in messages."""

    u: np.ndarray
    points: np.ndarray | None = None
    cells: np.ndarray | None = None
    source: str = "field"


def field_from_array(u, source: str = "field") -> Field:
    """A field at the Case mesh's vertices, in their order (n, gdim)."""
    return Field(u=np.asarray(u, float), source=source)


def _pick_vector(point_data: dict, gdim: int, source: str, name: str | None) -> np.ndarray:
    if name is not None:
        if name not in point_data:
            raise CaseError(f"{source}: no point field {name!r}; fields: {sorted(point_data)}")
        return np.asarray(point_data[name], float)
    for k in FIELD_NAMES:
        if k in point_data:
            return np.asarray(point_data[k], float)
    vec = [k for k, v in point_data.items() if np.ndim(v) == 2 and np.shape(v)[1] in (gdim, 3)]
    if len(vec) == 1:
        return np.asarray(point_data[vec[0]], float)
    raise CaseError(f"{source}: cannot tell which point field is the displacement (looked for "
                    f"{list(FIELD_NAMES[:2])} or a single vector field); fields: "
                    f"{sorted(point_data)}")


def _read_mesh_file(path: Path):
    import meshio

    if path.suffix.lower() == ".xdmf":
        try:  # a time series: its last step
            with meshio.xdmf.TimeSeriesReader(str(path)) as r:
                points, cells = r.read_points_cells()
                pd = {}
                for k in range(r.num_steps):
                    _, pd, _ = r.read_data(k)
                return points, cells, pd
        except Exception as exc:  # noqa: BLE001 - not a time series: a plain XDMF with fields
            log.debug("%s: not read as an XDMF time series (%s); reading it as one mesh",
                      path, exc)
    m = meshio.read(str(path))
    return m.points, m.cells, m.point_data


def load_field(path, gdim: int, *, name: str | None = None) -> Field:
    """Read a displacement field: VTU / VTK / XDMF (meshio; an XDMF time series gives its last
    step) with its points and cells, or NPY / CSV ((n, gdim) rows, the Case mesh's vertex order;
    a CSV header line is skipped). ``name``: the point field to take (default: ``displacement``,
    ``u``, ... or the only vector field). Errors name the file and what is wrong with it."""
    path = Path(path)
    src = str(path)
    if not path.is_file():
        raise CaseError(f"{src}: no such field file")
    suffix = path.suffix.lower()
    if suffix in (".npy", ".csv", ".txt"):
        try:
            if suffix == ".npy":
                u = np.load(path, allow_pickle=False)
            else:
                try:
                    u = np.loadtxt(path, delimiter=",", ndmin=2)
                except ValueError:
                    u = np.loadtxt(path, delimiter=",", ndmin=2, skiprows=1)
        except (OSError, ValueError) as exc:
            raise CaseError(f"{src}: not a readable {suffix[1:].upper()} array: {exc}") from None
        u = np.asarray(u, float)
        if u.ndim != 2 or u.shape[1] not in (gdim, 3):
            raise CaseError(f"{src}: expected an (n, {gdim}) displacement array, got shape "
                            f"{u.shape}")
        return Field(u=u[:, :gdim], source=src)
    if suffix not in (".vtu", ".vtk", ".xdmf"):
        raise CaseError(f"{src}: unsupported field format {suffix!r}; supported: .vtu .vtk "
                        f".xdmf .npy .csv")
    try:
        points, cell_blocks, pd = _read_mesh_file(path)
    except Exception as exc:  # noqa: BLE001 - meshio raises many kinds
        raise CaseError(f"{src}: cannot read the field: {exc}") from None
    u = _pick_vector(pd, gdim, src, name)
    points = np.asarray(points, float)
    if u.ndim != 2 or len(u) != len(points):
        raise CaseError(f"{src}: the displacement has shape {u.shape} for {len(points)} points")
    kind = "tetra" if gdim == 3 else "triangle"
    cells = [np.asarray(b.data) for b in cell_blocks if b.type == kind]
    cells = np.concatenate(cells).astype(np.int64) if cells else None
    return Field(u=u[:, :gdim], points=points[:, :gdim], cells=cells, source=src)


# --------------------------------------------------------------------------- geometry
def _locate(X, cells, pts, snap_rtol=SNAP_RTOL, sag=None):
    """Containing cell and barycentric weights of each point, searched among the cells with the
    nearest centroids (16, then 64, then 256 for the points not found yet); a point outside all
    of them within ``snap_rtol`` of the local cell size, or within ``sag`` (mm per cell: how
    far the true curved surface bulges beyond the cell's flat facets), is snapped to the
    closest of them. Returns (cell (m,), weights (m, d+1), inside (m,))."""
    from scipy.spatial import cKDTree

    d = X.shape[1]
    m = len(pts)
    tree = cKDTree(X[cells].mean(axis=1))
    T = X[cells[:, 1:]] - X[cells[:, :1]]                     # (c, d, d) rows = edges
    Tinv = _inverse_transposed(T)                             # maps x - x0 to lambda_1..d
    cell = np.zeros(m, np.int64)
    w = np.zeros((m, d + 1))
    score = np.full(m, -np.inf)
    todo = np.arange(m)
    for k in (16, 64, 256):
        k = min(k, len(cells))
        _, cand = tree.query(pts[todo], k=k)
        cand = cand.reshape(len(todo), k)
        rel = pts[todo, None, :] - X[cells[cand, 0]]           # (t, k, d)
        lam = np.einsum("tkij,tkj->tki", Tinv[cand], rel)
        wk = np.concatenate([1 - lam.sum(axis=2, keepdims=True), lam], axis=2)
        sk = wk.min(axis=2)
        best = sk.argmax(axis=1)
        rows = np.arange(len(todo))
        better = sk[rows, best] > score[todo]
        sel = todo[better]
        cell[sel] = cand[rows, best][better]
        w[sel] = wk[rows, best][better]
        score[sel] = sk[rows, best][better]
        todo = todo[score[todo] < -1e-10]
        if not len(todo) or k == len(cells):
            break
    # distance outside: clamp the weights, renormalize, compare the point with its image
    wc = np.clip(w, 0.0, None)
    wc /= wc.sum(axis=1, keepdims=True)
    proj = np.einsum("mi,mij->mj", wc, X[cells[cell]])
    dist = np.linalg.norm(proj - pts, axis=1)
    size = np.abs(np.linalg.det(T[cell])) ** (1.0 / d)
    found = score >= -1e-10
    reach = snap_rtol * size + (0.0 if sag is None else sag[cell])
    inside = found | (dist <= reach)
    return cell, np.where(found[:, None], w, wc), inside


def boundary_sag(mesh) -> np.ndarray | None:
    """Per cell (mm): SAG_FACTOR times the largest distance between the true curved boundary
    and the cell's straight edges (the mesh's second-order edge nodes against the chords'
    midpoints), 0 for cells away from a curved boundary; None for a mesh without curved
    geometry. A point of a finer mesh of the same body may lie that far outside the flat
    facets and still be inside the body."""
    if mesh.geometry_order < 2:
        return None
    X, cells = mesh.points, mesh.cells
    e = np.sort(np.asarray(mesh.curved_edges, np.int64), axis=1)
    sag_e = np.linalg.norm(np.asarray(mesh.curved_points, float)
                           - 0.5 * (X[e[:, 0]] + X[e[:, 1]]), axis=1)
    n = len(X)
    keys = e[:, 0] * n + e[:, 1]
    order = np.argsort(keys)
    keys, sag_e = keys[order], sag_e[order]
    k = cells.shape[1]
    out = np.zeros(len(cells))
    for i in range(k):
        for j in range(i + 1, k):
            a, b = np.minimum(cells[:, i], cells[:, j]), np.maximum(cells[:, i], cells[:, j])
            q = a * n + b
            pos = np.minimum(np.searchsorted(keys, q), len(keys) - 1)
            hit = keys[pos] == q
            out = np.maximum(out, np.where(hit, sag_e[pos], 0.0))
    return SAG_FACTOR * out


def _inverse_transposed(T):
    """inv(T^T) for a stack of (d, d) matrices whose rows are a simplex's edges, in closed form
    (cross products in 3D), much faster than a batched LAPACK inverse."""
    if T.shape[1] == 2:
        det = T[:, 0, 0] * T[:, 1, 1] - T[:, 0, 1] * T[:, 1, 0]
        inv = np.stack([np.stack([T[:, 1, 1], -T[:, 1, 0]], axis=1),
                        np.stack([-T[:, 0, 1], T[:, 0, 0]], axis=1)], axis=1)
        return inv / det[:, None, None]
    e1, e2, e3 = T[:, 0], T[:, 1], T[:, 2]
    rows = np.stack([np.cross(e2, e3), np.cross(e3, e1), np.cross(e1, e2)], axis=1)
    return rows / np.einsum("ci,ci->c", e1, rows[:, 0])[:, None, None]


def _p2_weights(w):
    """Degree-2 Lagrange shape functions from barycentric weights (m, d+1): vertices first, then
    the edges (i, j), i < j, in lexicographic order."""
    d1 = w.shape[1]
    pairs = [(i, j) for i in range(d1) for j in range(i + 1, d1)]
    return np.concatenate([w * (2 * w - 1)] + [4 * w[:, [i]] * w[:, [j]] for i, j in pairs],
                          axis=1), pairs


def _reference_at(case, ref, pts):
    """The reference displacement at ``pts``; returns (values, inside, method)."""
    X, cells = case.mesh.points, case.mesh.cells
    cell, w, inside = _locate(X, cells, pts, sag=boundary_sag(case.mesh))
    uv = np.asarray(ref.u, float)
    node_u, node_pts = ref.node_u, ref.node_points
    straight = case.mesh.curved_edges is None or len(case.mesh.curved_edges) == 0
    if ref.degree == 1:
        return np.einsum("mi,mij->mj", w, uv[cells[cell]]), inside, "P1 (exact)"
    if ref.degree == 2 and straight and node_u is not None:
        from scipy.spatial import cKDTree

        N, pairs = _p2_weights(w)
        mids = np.stack([(X[cells[cell, i]] + X[cells[cell, j]]) / 2 for i, j in pairs], axis=1)
        dist, idx = cKDTree(np.asarray(node_pts)).query(mids.reshape(-1, X.shape[1]))
        if dist.max(initial=0.0) <= MATCH_RTOL * _diameter(X):
            vals = np.concatenate([uv[cells[cell]],
                                   np.asarray(node_u)[idx].reshape(len(pts), len(pairs), -1)],
                                  axis=1)
            return np.einsum("mi,mij->mj", N, vals), inside, "P2 on straight cells (exact)"
    return (np.einsum("mi,mij->mj", w, uv[cells[cell]]), inside,
            f"linear in the P{ref.degree} vertex values (adds an O(h^2) interpolation error)")


def _diameter(X):
    return float(np.linalg.norm(X.max(axis=0) - X.min(axis=0))) or 1.0


def _match(case_pts, pts):
    """Index into the Case's vertices of each field point, or None unless every point matches
    a distinct vertex."""
    from scipy.spatial import cKDTree

    if len(pts) != len(case_pts):
        return None
    dist, idx = cKDTree(case_pts).query(pts)
    if dist.max(initial=0.0) > MATCH_RTOL * _diameter(case_pts):
        return None
    if len(np.unique(idx)) != len(idx):
        return None
    return idx


def _mesh_norms(X, cells, e, u_ref, material):
    """Volume-averaged L2 and H1-seminorm of the P1 interpolant of ``e`` on (X, cells), the
    small-strain energy norm, and the same norms of ``u_ref`` for relative figures."""
    d = X.shape[1]
    T = X[cells[:, 1:]] - X[cells[:, :1]]
    det = np.linalg.det(T)
    vol = np.abs(det) / (2 if d == 2 else 6)
    V = vol.sum()
    Ginv = np.linalg.inv(T)                       # grad of lambda_1..d: columns of T^{-1}
    grads = np.concatenate([-Ginv.sum(axis=2, keepdims=True), Ginv], axis=2)  # (c, d, d+1)

    def norms(f):
        fc = f[cells]                              # (c, d+1, d)
        # P1 mass on a simplex: int phi_i phi_j = V (1 + delta_ij) / ((d+1)(d+2))
        s = fc.sum(axis=1)
        l2 = vol / ((d + 1) * (d + 2)) * ((fc ** 2).sum(axis=(1, 2)) + (s ** 2).sum(axis=1))
        G = np.einsum("cin,cnj->cji", grads, fc)   # (c, d, d): G[c, j, i] = d f_j / d x_i
        h1 = vol * (G ** 2).sum(axis=(1, 2))
        eps = 0.5 * (G + np.transpose(G, (0, 2, 1)))
        out = {"l2": float(np.sqrt(l2.sum() / V)), "h1": float(np.sqrt(h1.sum() / V))}
        if material is not None and material.nu < 0.5:
            E, nu = material.E, material.nu
            mu, lam = E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))
            en = vol * (2 * mu * (eps ** 2).sum(axis=(1, 2)) + lam * np.trace(eps, axis1=1,
                                                                               axis2=2) ** 2)
            out["energy"] = float(np.sqrt(en.sum()))
        return out

    ne, nr = norms(e), norms(u_ref)
    res = {"l2_error_mm": ne["l2"], "h1_seminorm_error": ne["h1"],
           "l2_relative_error": ne["l2"] / nr["l2"] if nr["l2"] > 0 else None,
           "h1_relative_error": ne["h1"] / nr["h1"] if nr["h1"] > 0 else None,
           "energy_norm_error_sqrt_uJ": ne.get("energy"),
           "energy_relative_error": (ne["energy"] / nr["energy"]
                                     if ne.get("energy") is not None and nr["energy"] > 0
                                     else None)}
    return res


def vertex_norms(case, u, u_ref, material=None) -> dict:
    """The volume norms of ``u - u_ref`` for two fields at the Case mesh's vertices (its order,
    (n, gdim) mm): the P1 interpolant of the difference on the Case's cells, as for a field on
    the Case's mesh (module docstring: ``l2_error_mm``, ``h1_seminorm_error``,
    ``energy_norm_error_sqrt_uJ`` and their relative values). material: the E and nu of the
    energy norm (default the Case's)."""
    u_ref = np.asarray(u_ref, float)
    return _mesh_norms(case.mesh.points, case.mesh.cells, np.asarray(u, float) - u_ref, u_ref,
                       case.material if material is None else material)


def score_field(case, ref, field: Field, *, outside: str = "error") -> dict:
    """Scores of ``field`` against the reference SolveResult ``ref`` of ``case`` (see the module
    docstring). outside: "error" (default) raises CaseError naming the points outside the body;
    "skip" leaves them out of the scores and lists them under ``outside_points``."""
    gdim = case.mesh.points.shape[1]
    u = np.asarray(field.u, float)
    X = case.mesh.points
    ref_u = np.asarray(ref.u, float)
    out = {"field": field.source, "n_points": len(u)}
    if u.ndim == 2 and not np.all(np.isfinite(u)):
        bad = np.flatnonzero(~np.all(np.isfinite(u), axis=1))
        raise CaseError(f"{field.source}: the displacement is not finite at {len(bad)} "
                        f"point(s), first at row {int(bad[0])}")
    if field.points is None:
        if u.shape != ref_u.shape:
            raise CaseError(f"{field.source}: a field without coordinates must have one row per "
                            f"vertex of the case mesh ({ref_u.shape}), got {u.shape}")
        idx = np.arange(len(u))
    else:
        idx = _match(X, field.points)
    if idx is not None:                       # on the Case's mesh (any vertex order)
        uu = np.empty_like(ref_u)
        uu[idx] = u
        out["matched"] = "case mesh vertices" + (" by coordinates" if field.points is not None
                                                  else " in their order")
        e = uu - ref_u
        out.update(vertex_norms(case, uu, ref_u))
        probes = case.probe_values(uu)
    else:                                     # another mesh: the reference at its points
        pts = field.points
        vals, inside, how = _reference_at(case, ref, pts)
        if not inside.all():
            bad = np.flatnonzero(~inside)
            listed = "; ".join(f"point {int(i)} at {np.round(pts[i], 3).tolist()}"
                               for i in bad[:5])
            if outside != "skip":
                raise CaseError(f"{field.source}: {len(bad)} point(s) lie outside the body of "
                                f"case {case.name!r} (beyond the snap distance, "
                                f"{SNAP_RTOL:g} of the local cell size plus the curved "
                                f"surface's sag beyond the flat facets): {listed}"
                                f"{' ...' if len(bad) > 5 else ''}. A field on a finer mesh of "
                                f"a curved body has boundary points outside a coarser mesh's "
                                f"flat facets: score it against a reference on a finer mesh "
                                f"(--size) or at degree 2 (curved cells), or leave those points "
                                f"out (--skip-outside; the volume norms then need every point "
                                f"and are not computed)")
            out["outside_points"] = bad.tolist()
            out["note"] = (f"{len(bad)} point(s) outside the body were left out of the scores; "
                           f"the volume norms (l2, h1, energy) need every point of the field's "
                           f"mesh and are not computed")
        out["matched"] = "interpolated reference"
        out["reference_interpolation"] = how
        e = np.where(inside[:, None], u - vals, 0.0)
        if field.cells is not None and inside.all():
            out.update(_mesh_norms(pts, field.cells, e, vals, case.material))
        probes = {}
        if field.cells is not None and case.probes:
            at = np.array([np.asarray(p.point, float)[:gdim] for p in case.probes])
            c, w, ins = _locate(pts, field.cells, at)
            probes = {p.name: w[i] @ u[field.cells[c[i]]] for i, p in enumerate(case.probes)
                      if ins[i]}
        e_norm = np.linalg.norm(e[inside], axis=1)
        out["max_vertex_error_mm"] = float(e_norm.max(initial=0.0))
        out["rms_vertex_error_mm"] = float(np.sqrt(np.mean(e_norm ** 2))) if e_norm.size else 0.0
    if idx is not None:
        e_norm = np.linalg.norm(e, axis=1)
        out["max_vertex_error_mm"] = float(e_norm.max(initial=0.0))
        out["rms_vertex_error_mm"] = float(np.sqrt(np.mean(e_norm ** 2)))
    out["probe_error_mm"] = {k: float(np.linalg.norm(np.asarray(probes[k]) - np.asarray(v)))
                             for k, v in ref.probes.items() if k in probes}
    return out
