"""Triangulated surfaces (skin, muscle, implant shell): reading, sheet checks, normals, rays,
closest points. Lengths in mm.

Body frame used throughout ``implant``: x toward the patient's left, y superior (up), z anterior
(out of the chest, toward the camera). A skin surface is a sheet seen from the front.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from tissue_reference.errors import CaseError, ReadError

__all__ = [
    "SURFACE_SUFFIXES",
    "TriSurface",
    "boundary_edges",
    "check_single_sheet",
    "closest_points",
    "ray_hits",
    "read_surface",
    "triangle_normals",
    "vertex_normals",
]

SURFACE_SUFFIXES = (".stl", ".ply", ".obj", ".vtk", ".vtu", ".off")


@dataclass(frozen=True)
class TriSurface:
    """A triangle surface: points (n, 3) in mm, triangles (m, 3) vertex ids."""

    points: np.ndarray
    triangles: np.ndarray

    def __post_init__(self):
        p = np.ascontiguousarray(self.points, dtype=np.float64)
        t = np.ascontiguousarray(self.triangles, dtype=np.int64)
        if p.ndim != 2 or p.shape[1] != 3:
            raise CaseError(f"surface points must be (n, 3), got shape {p.shape}")
        if t.ndim != 2 or t.shape[1] != 3:
            raise CaseError(f"surface triangles must be (m, 3), got shape {t.shape}")
        if t.size and (t.min() < 0 or t.max() >= len(p)):
            raise CaseError(f"triangle vertex ids out of range [0, {len(p)})")
        if not np.all(np.isfinite(p)):
            raise CaseError("surface points contain NaN or infinite coordinates")
        object.__setattr__(self, "points", p)
        object.__setattr__(self, "triangles", t)

    @property
    def n_points(self) -> int:
        return len(self.points)

    def compact(self) -> TriSurface:
        """Drop vertices used by no triangle (renumbering the triangles)."""
        used = np.unique(self.triangles)
        remap = -np.ones(len(self.points), dtype=np.int64)
        remap[used] = np.arange(len(used))
        return TriSurface(self.points[used], remap[self.triangles])

    def area(self) -> float:
        x = self.points[self.triangles]
        return float(0.5 * np.linalg.norm(np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0]), axis=1).sum())

    def mean_edge(self) -> float:
        x = self.points[self.triangles]
        return float(np.mean([np.linalg.norm(x[:, i] - x[:, (i + 1) % 3], axis=1) for i in range(3)]))


def read_surface(path) -> TriSurface:
    """Read a triangle surface (STL, PLY, OBJ, VTK, VTU, OFF) through meshio; quads are split.

    Raises ReadError (missing / unreadable / no triangles) naming the path. Coordinates in mm.
    """
    import meshio

    path = Path(path)
    if not path.is_file():
        raise ReadError(f"skin surface file {str(path)!r} does not exist")
    try:
        m = meshio.read(str(path))
    except Exception as exc:  # meshio raises many types
        raise ReadError(f"cannot read skin surface {str(path)!r}: {exc}") from exc
    tris = []
    for block in m.cells:
        if block.type == "triangle":
            tris.append(np.asarray(block.data))
        elif block.type == "quad":
            q = np.asarray(block.data)
            tris += [q[:, [0, 1, 2]], q[:, [0, 2, 3]]]
    if not tris:
        raise ReadError(f"{str(path)!r} holds no triangles or quads "
                        f"(found {sorted({b.type for b in m.cells})})")
    pts = np.asarray(m.points, dtype=np.float64)
    if pts.shape[1] == 2:
        raise ReadError(f"{str(path)!r}: a skin surface needs 3D points, got 2D")
    try:
        surf = TriSurface(pts, np.concatenate(tris))
    except CaseError as exc:
        raise ReadError(f"{str(path)!r}: {exc}") from exc
    return surf.compact()


def _edges(tris: np.ndarray):
    e = np.sort(np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]), axis=1)
    return np.unique(e, axis=0, return_counts=True)


def boundary_edges(tris: np.ndarray) -> np.ndarray:
    """Edges (sorted vertex ids) used by exactly one triangle."""
    u, c = _edges(tris)
    return u[c == 1]


def check_single_sheet(surf: TriSurface, *, source: str = "skin surface") -> TriSurface:
    """Raise CaseError unless ``surf`` is one connected, manifold sheet with a border.

    Returns the surface without unused vertices. Checked: at least one triangle, no degenerate
    triangles, one connected component (through shared vertices), every edge used by at most two
    triangles, and a non-empty border (a closed surface is not a skin sheet).
    """
    if len(surf.triangles) == 0:
        raise CaseError(f"{source}: no triangles")
    s = surf.compact()
    t = s.triangles
    if np.any((t[:, 0] == t[:, 1]) | (t[:, 1] == t[:, 2]) | (t[:, 0] == t[:, 2])):
        raise CaseError(f"{source}: triangles with repeated vertices")
    n = s.n_points
    rows = np.concatenate([t[:, 0], t[:, 1], t[:, 2]])
    cols = np.concatenate([t[:, 1], t[:, 2], t[:, 0]])
    g = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n))
    ncomp, labels = connected_components(g, directed=False)
    if ncomp != 1:
        sizes = np.bincount(labels)
        raise CaseError(f"{source} is not a single connected sheet: {ncomp} separate pieces with "
                        f"{sorted(sizes.tolist(), reverse=True)[:6]} vertices")
    u, c = _edges(t)
    if np.any(c > 2):
        bad = u[c > 2]
        raise CaseError(f"{source} is not a sheet: {len(bad)} edges shared by more than two "
                        f"triangles (first {bad[:3].tolist()})")
    if not np.any(c == 1):
        raise CaseError(f"{source} is a closed surface; a skin sheet must have a border")
    return s


def triangle_normals(points: np.ndarray, tris: np.ndarray, *, unit: bool = True) -> np.ndarray:
    x = points[tris]
    n = np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0])
    if unit:
        n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    return n


def vertex_normals(points: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals (orientation follows the triangles' winding)."""
    fn = triangle_normals(points, tris, unit=False)
    vn = np.zeros_like(points)
    for k in range(3):
        np.add.at(vn, tris[:, k], fn)
    return vn / np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-300)


def ray_hits(origins: np.ndarray, dirs: np.ndarray, points: np.ndarray, tris: np.ndarray, *,
             chunk: int = 256, eps: float = 1e-9):
    """Intersect rays (lines) o + t d with triangles (Moller-Trumbore, vectorized).

    Returns (t, hit): for each ray the signed parameter of the intersection with the smallest
    |t| (lines are followed both ways), and whether it hit at all (t is NaN where not).
    """
    o = np.asarray(origins, float)
    d = np.asarray(dirs, float)
    v0 = points[tris[:, 0]]
    e1 = points[tris[:, 1]] - v0
    e2 = points[tris[:, 2]] - v0
    t_out = np.full(len(o), np.nan)
    for s in range(0, len(o), chunk):
        oo, dd = o[s:s + chunk, None, :], d[s:s + chunk, None, :]
        p = np.cross(dd, e2[None])
        det = np.einsum("ijk,jk->ij", p, e1)
        ok = np.abs(det) > eps * (np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1))[None]
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        tv = oo - v0[None]
        u = np.einsum("ijk,ijk->ij", tv, p) * inv
        q = np.cross(tv, e1[None])
        v = np.einsum("ijk,ijk->ij", dd, q) * inv
        t = np.einsum("ijk,jk->ij", q, e2) * inv
        tol = 1e-9
        hit = ok & (u >= -tol) & (v >= -tol) & (u + v <= 1 + tol)
        ta = np.where(hit, np.abs(t), np.inf)
        j = np.argmin(ta, axis=1)
        rows = np.arange(len(j))
        good = np.isfinite(ta[rows, j])
        t_out[s:s + chunk] = np.where(good, t[rows, j], np.nan)
    return t_out, np.isfinite(t_out)


def _closest_on_triangles(p, a, b, c):
    """Closest points on triangles (a, b, c) to points p, all (k, 3) (Ericson, vectorized)."""
    ab, ac, ap = b - a, c - a, p - a
    d1 = np.einsum("ij,ij->i", ab, ap)
    d2 = np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3 = np.einsum("ij,ij->i", ab, bp)
    d4 = np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5 = np.einsum("ij,ij->i", ab, cp)
    d6 = np.einsum("ij,ij->i", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    denom = va + vb + vc
    with np.errstate(divide="ignore", invalid="ignore"):
        v = vb / denom
        w = vc / denom
        out = a + ab * v[:, None] + ac * w[:, None]  # interior
        # edge regions
        m_ab = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
        t_ab = d1 / (d1 - d3)
        out = np.where(m_ab[:, None], a + ab * t_ab[:, None], out)
        m_ac = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
        t_ac = d2 / (d2 - d6)
        out = np.where(m_ac[:, None], a + ac * t_ac[:, None], out)
        m_bc = (va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        out = np.where(m_bc[:, None], b + (c - b) * t_bc[:, None], out)
    # vertex regions last (they take precedence)
    out = np.where(((d1 <= 0) & (d2 <= 0))[:, None], a, out)
    out = np.where(((d3 >= 0) & (d4 <= d3))[:, None], b, out)
    out = np.where(((d6 >= 0) & (d5 <= d6))[:, None], c, out)
    return out


def closest_points(query: np.ndarray, points: np.ndarray, tris: np.ndarray):
    """Exact closest points on a triangle surface and the distances (mm), vectorized.

    Candidate triangles per query are those whose centroid lies within (an upper bound of the
    distance) + (the largest centroid-to-vertex radius), which keeps the result exact.
    Returns (closest (k, 3), distance (k,), triangle id (k,)).
    """
    q = np.asarray(query, float)
    x = points[tris]
    cen = x.mean(axis=1)
    rad = np.max(np.linalg.norm(x - cen[:, None], axis=2), axis=1)
    rmax = float(rad.max())
    tree = cKDTree(cen)
    # upper bound: exact distance to the triangle of the nearest centroid
    _, j0 = tree.query(q)
    c0 = _closest_on_triangles(q, x[j0, 0], x[j0, 1], x[j0, 2])
    ub = np.linalg.norm(c0 - q, axis=1)
    cand = tree.query_ball_point(q, ub + rmax + 1e-9)
    lens = np.fromiter((len(c) for c in cand), int, len(q))
    qi = np.repeat(np.arange(len(q)), lens)
    tj = np.fromiter((i for c in cand for i in c), int, int(lens.sum()))
    cp = _closest_on_triangles(q[qi], x[tj, 0], x[tj, 1], x[tj, 2])
    dist = np.linalg.norm(cp - q[qi], axis=1)
    best = np.full(len(q), np.inf)
    np.minimum.at(best, qi, dist)
    is_best = dist <= best[qi]
    # pick one best candidate per query
    order = np.flatnonzero(is_best)
    first = np.full(len(q), -1)
    first[qi[order[::-1]]] = order[::-1]
    return cp[first], best, tj[first]
