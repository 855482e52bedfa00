"""Surface validation of seed 001 section 3: rigid ICP registration of two surfaces and the
point-to-surface distances d_max and mean distance mu_d over a chosen region. Lengths in mm.

ICP (Besl & McKay 1992): repeat { closest points of the moving points on the fixed surface
(cKDTree on its vertices for point-to-point, exact closest points on its triangles otherwise);
best rigid transform by Kabsch/SVD (point-to-point) or by the linearized point-to-plane least
squares (Chen & Medioni) } until the transform update is below tolerance.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from tissue_reference.errors import CaseError

from .surface import closest_points

__all__ = [
    "DistanceStats",
    "ICPResult",
    "RigidTransform",
    "icp",
    "kabsch",
    "rotation_angle_deg",
    "surface_distances",
]


@dataclass(frozen=True)
class RigidTransform:
    """x -> R x + t (R (3, 3) rotation, t (3,) mm)."""

    R: np.ndarray
    t: np.ndarray

    @classmethod
    def identity(cls):
        return cls(np.eye(3), np.zeros(3))

    @classmethod
    def from_axis_angle(cls, axis, angle_deg: float, t=(0.0, 0.0, 0.0)):
        a = np.asarray(axis, float)
        a = a / np.linalg.norm(a)
        th = np.radians(angle_deg)
        K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
        R = np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K
        return cls(R, np.asarray(t, float))

    def apply(self, x) -> np.ndarray:
        return np.asarray(x, float) @ self.R.T + self.t

    def compose(self, other: RigidTransform) -> RigidTransform:
        """self after other."""
        return RigidTransform(self.R @ other.R, self.R @ other.t + self.t)

    def inverse(self) -> RigidTransform:
        return RigidTransform(self.R.T, -self.R.T @ self.t)


def rotation_angle_deg(R) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))))


def kabsch(src, dst, w=None) -> RigidTransform:
    """Least-squares rigid transform mapping src (k, 3) onto dst (k, 3), optional weights."""
    src, dst = np.asarray(src, float), np.asarray(dst, float)
    w = np.ones(len(src)) if w is None else np.asarray(w, float)
    w = w / w.sum()
    cs, cd = w @ src, w @ dst
    H = (src - cs).T @ ((dst - cd) * w[:, None])
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return RigidTransform(R, cd - R @ cs)


@dataclass(frozen=True)
class ICPResult:
    transform: RigidTransform  # maps the moving points onto the fixed surface
    rms_mm: float
    iterations: int
    converged: bool


def icp(moving, fixed_points, fixed_triangles=None, *, initial: RigidTransform | None = None,
        method: str = "point-to-plane", max_iter: int = 100, tol: float = 1e-9,
        reject_mm: float | None = None) -> ICPResult:
    """Rigidly register the points ``moving`` (k, 3) mm onto the fixed surface.

    method 'point-to-point' (closest fixed vertices, Kabsch) or 'point-to-plane' (needs
    ``fixed_triangles``; exact closest points on the triangles and their normals). initial: an
    initial transform (seed 001: manual initialization). reject_mm: ignore pairs farther apart
    (robustness to non-overlapping parts). Stops when the update moves no point by more than
    ``tol`` times the moving cloud's size.
    """
    mv = np.asarray(moving, float)
    fp = np.asarray(fixed_points, float)
    if mv.ndim != 2 or mv.shape[1] != 3 or len(mv) < 3:
        raise CaseError(f"ICP needs at least 3 moving points (k, 3), got {mv.shape}")
    if method not in ("point-to-point", "point-to-plane"):
        raise CaseError(f"unknown ICP method {method!r}; methods: ['point-to-point', 'point-to-plane']")
    if method == "point-to-plane" and fixed_triangles is None:
        raise CaseError("point-to-plane ICP needs the fixed surface's triangles")
    T = initial or RigidTransform.identity()
    tree = cKDTree(fp)
    if fixed_triangles is not None:
        tris = np.asarray(fixed_triangles, np.int64)
        x = fp[tris]
        fn = np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0])
        fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-300)
    scale = max(np.ptp(mv, axis=0).max(), 1e-9)
    converged = False
    it = 0
    for it in range(1, max_iter + 1):
        cur = T.apply(mv)
        if method == "point-to-point":
            d, j = tree.query(cur)
            q = fp[j]
        else:
            q, d, tj = closest_points(cur, fp, tris)
            nq = fn[tj]
        keep = np.ones(len(cur), bool) if reject_mm is None else d <= reject_mm
        if keep.sum() < 6:
            raise CaseError(f"ICP: only {int(keep.sum())} point pairs within {reject_mm} mm")
        if method == "point-to-point":
            dT = kabsch(cur[keep], q[keep])
        else:
            p, qq, n = cur[keep], q[keep], nq[keep]
            A = np.column_stack([np.cross(p, n), n])
            b = np.einsum("ij,ij->i", qq - p, n)
            x, *_ = np.linalg.lstsq(A, b, rcond=None)
            dT = RigidTransform.from_axis_angle(x[:3] if np.linalg.norm(x[:3]) > 0 else [0, 0, 1],
                                                np.degrees(np.linalg.norm(x[:3])), x[3:])
        T = dT.compose(T)
        step = np.abs(dT.apply(cur) - cur).max()
        if step < tol * scale:
            converged = True
            break
    cur = T.apply(mv)
    if fixed_triangles is not None:
        _, d, _ = closest_points(cur, fp, tris)
    else:
        d = tree.query(cur)[0]
    return ICPResult(T, float(np.sqrt(np.mean(d ** 2))), it, converged)


@dataclass(frozen=True)
class DistanceStats:
    """Point-to-surface distances (mm): per point, the maximum d_max and the mean mu_d over the
    chosen region."""

    distance: np.ndarray
    d_max_mm: float
    mean_distance_mm: float
    n_points: int


def surface_distances(points, surf_points, surf_triangles, *, region=None) -> DistanceStats:
    """Distance of each point (k, 3) to the triangle surface (exact closest point on the
    triangles), and d_max / mean over ``region`` (boolean mask or ids; default all)."""
    pts = np.asarray(points, float)
    _, d, _ = closest_points(pts, np.asarray(surf_points, float), np.asarray(surf_triangles))
    sel = np.arange(len(pts)) if region is None else np.asarray(region)
    ds = d[sel]
    if ds.size == 0:
        raise CaseError("distance region is empty")
    return DistanceStats(d, float(ds.max()), float(ds.mean()), int(ds.size))


