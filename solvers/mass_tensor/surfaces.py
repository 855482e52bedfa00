"""Surfaces a sliding point stays on: ``Plane`` (linear, exact projection) and ``TriSurface``
(a triangulated 3D surface, exact closest point over the nearest candidate triangles), with the
check that a surface fits the mesh dimension."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tissue_reference.errors import CaseError


@dataclass(frozen=True)
class Plane:
    """The plane through ``point`` (mm) with normal ``normal`` (normalized on construction)."""

    point: tuple
    normal: tuple

    def __post_init__(self):
        p = np.asarray(self.point, float).reshape(-1)
        nv = np.asarray(self.normal, float).reshape(-1)
        nn = np.linalg.norm(nv)
        if p.shape != nv.shape or not np.isfinite(nn) or nn == 0 or not np.all(np.isfinite(p)):
            raise CaseError(f"Plane needs a finite point and a non-zero normal of the same "
                            f"dimension, got point={self.point!r}, normal={self.normal!r}")
        object.__setattr__(self, "point", tuple(p.tolist()))
        object.__setattr__(self, "normal", tuple((nv / nn).tolist()))

    def closest(self, x: np.ndarray):
        """Closest points (k, d) on the plane to x (k, d) and the unit normals there."""
        n = np.asarray(self.normal)
        y = x - ((x - np.asarray(self.point)) @ n)[:, None] * n
        return y, np.broadcast_to(n, x.shape).copy()


class TriSurface:
    """A triangulated surface in 3D: points (k, 3) mm, triangles (t, 3) vertex ids.

    ``closest(x)`` returns the closest surface points (exact point-triangle distance over the
    ``candidates`` triangles with the nearest centroids) and the unit face normals there.
    """

    def __init__(self, points, triangles, *, candidates: int = 16):
        from scipy.spatial import cKDTree

        self.points = np.asarray(points, float)
        self.triangles = np.asarray(triangles, np.int64)
        if self.points.ndim != 2 or self.points.shape[1] != 3 or self.triangles.ndim != 2 \
                or self.triangles.shape[1] != 3 or len(self.triangles) == 0:
            raise CaseError(f"TriSurface needs points (k, 3) and triangles (t, 3), got "
                            f"{self.points.shape} and {self.triangles.shape}")
        if self.triangles.min() < 0 or self.triangles.max() >= len(self.points):
            raise CaseError(f"TriSurface triangle ids out of range [0, {len(self.points)})")
        tri = self.points[self.triangles]
        nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        area2 = np.linalg.norm(nrm, axis=1)
        if np.any(area2 == 0):
            raise CaseError(f"TriSurface has degenerate triangles, first "
                            f"{np.flatnonzero(area2 == 0)[:5].tolist()}")
        self._tri = tri
        self._normals = nrm / area2[:, None]
        self._tree = cKDTree(tri.mean(axis=1))
        self._k = min(candidates, len(tri))

    def closest(self, x: np.ndarray):
        x = np.asarray(x, float)
        _, cand = self._tree.query(x, k=self._k)
        cand = cand.reshape(len(x), -1)
        a, b, c = (self._tri[cand, k] for k in range(3))          # (q, k, 3)
        p = x[:, None, :]
        best = closest_on_triangles(p, a, b, c)                  # (q, k, 3)
        dist = np.linalg.norm(best - p, axis=2)
        k = np.argmin(dist, axis=1)
        rows = np.arange(len(x))
        return best[rows, k], self._normals[cand[rows, k]]


def closest_on_segment(p, a, b):
    ab = b - a
    t = np.clip(np.sum((p - a) * ab, axis=-1) / np.maximum(np.sum(ab * ab, axis=-1), 1e-300), 0, 1)
    return a + t[..., None] * ab


def closest_on_triangles(p, a, b, c):
    """Exact closest point on triangles (a, b, c) to p (broadcast over leading axes)."""
    e0, e1 = b - a, c - a
    n = np.cross(e0, e1)
    n = n / np.linalg.norm(n, axis=-1, keepdims=True)
    q = p - np.sum((p - a) * n, axis=-1)[..., None] * n           # projection on the plane
    d00, d01, d11 = (np.sum(e0 * e0, -1), np.sum(e0 * e1, -1), np.sum(e1 * e1, -1))
    w = q - a
    d20, d21 = np.sum(w * e0, -1), np.sum(w * e1, -1)
    den = d00 * d11 - d01 * d01
    v = (d11 * d20 - d01 * d21) / den
    t = (d00 * d21 - d01 * d20) / den
    inside = (v >= 0) & (t >= 0) & (v + t <= 1)
    cands = [closest_on_segment(p, a, b), closest_on_segment(p, b, c), closest_on_segment(p, c, a)]
    dists = np.stack([np.linalg.norm(s - p, axis=-1) for s in cands])
    k = np.argmin(dists, axis=0)
    edge = np.choose(k[..., None], cands)
    return np.where(inside[..., None], q, edge)



def check_surface(s, d):
    if isinstance(s, Plane):
        if len(s.normal) != d:
            raise CaseError(f"Plane of dimension {len(s.normal)} used on a {d}D mesh")
    elif isinstance(s, TriSurface):
        if d != 3:
            raise CaseError("TriSurface sliding needs a 3D mesh")
    else:
        raise CaseError(f"a sliding surface must be a Plane or a TriSurface, got {type(s).__name__}")

