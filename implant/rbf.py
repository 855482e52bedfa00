"""RBF implicit surface of seed 001 (eq. 1-3): the muscle surface from the skin and three
thickness estimates. Lengths in mm.

    s(x) = p(x) + sum_i lambda_i Phi(|x - x_i|),   Phi(r) = r (biharmonic in 3D),
    p(x) = c0 + c . x (degree 1),
    s = 0 on the skin points {x_s} (breast region removed), s = 1 on the projected muscle points
    {x_m} = x_s - t(x_s) n(x_s), with t the thickness interpolated from the estimates A, B, C.

The thickness is constant in each sagittal plane (x = const) through the estimate points and
linear in x between them (seed 001 section 2.1), constant outside. The muscle surface is the
isosurface s = 1: every skin vertex is moved inward along the unit gradient of s at that vertex
until s = 1 (vectorized bracketing + bisection).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import solve
from scipy.spatial.distance import cdist

from tissue_reference.errors import CaseError

from .surface import TriSurface, triangle_normals, vertex_normals

__all__ = ["ImplicitRBF", "MuscleFit", "Thickness", "breast_mask", "muscle_surface"]


@dataclass(frozen=True)
class ImplicitRBF:
    """s(x) = c0 + c . x + sum lambda_i |x - x_i| (mm in, dimensionless out)."""

    centres: np.ndarray
    weights: np.ndarray
    poly: np.ndarray  # (4,): c0, cx, cy, cz

    @classmethod
    def fit(cls, centres, values) -> ImplicitRBF:
        """Solve [[A, P], [P^T, 0]] [lambda; c] = [f; 0] with A_ij = |x_i - x_j|."""
        x = np.asarray(centres, float)
        f = np.asarray(values, float)
        if x.ndim != 2 or x.shape[1] != 3 or len(x) != len(f):
            raise CaseError(f"RBF needs (n, 3) centres and n values, got {x.shape} and {f.shape}")
        n = len(x)
        if n < 5:
            raise CaseError(f"RBF needs at least 5 centres, got {n}")
        A = cdist(x, x)
        P = np.column_stack([np.ones(n), x])
        M = np.zeros((n + 4, n + 4))
        M[:n, :n] = A
        M[:n, n:] = P
        M[n:, :n] = P.T
        rhs = np.concatenate([f, np.zeros(4)])
        try:
            sol = solve(M, rhs, assume_a="sym")
        except np.linalg.LinAlgError as exc:
            raise CaseError(f"RBF system is singular ({n} centres; duplicate points?)") from exc
        return cls(x, sol[:n], sol[n:])

    def __call__(self, q, *, chunk: int = 2048) -> np.ndarray:
        q = np.atleast_2d(np.asarray(q, float))
        out = np.empty(len(q))
        for s in range(0, len(q), chunk):
            qq = q[s:s + chunk]
            out[s:s + chunk] = cdist(qq, self.centres) @ self.weights + self.poly[0] + qq @ self.poly[1:]
        return out

    def gradient(self, q, *, chunk: int = 2048) -> np.ndarray:
        q = np.atleast_2d(np.asarray(q, float))
        out = np.empty_like(q)
        for s in range(0, len(q), chunk):
            qq = q[s:s + chunk]
            w = self.weights[None] / np.maximum(cdist(qq, self.centres), 1e-12)
            # grad_x sum_i w_i |x - x_i| = sum_i w_i (x - x_i) / |x - x_i|
            out[s:s + chunk] = (qq * w.sum(1)[:, None] - w @ self.centres) + self.poly[1:]
        return out


@dataclass(frozen=True)
class Thickness:
    """Three tissue thickness estimates (mm) at sagittal planes x = x_A, x_B, x_C (mm).

    A: lateral on the patient's right (smallest x), B: above the sternum, C: lateral on the
    patient's left. Linear in x between the planes, constant outside.
    """

    A: float
    B: float
    C: float
    x_A: float
    x_B: float
    x_C: float

    def __post_init__(self):
        for name in ("A", "B", "C"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float, np.floating)) and np.isfinite(v) and v > 0):
                raise CaseError(f"thickness estimate {name}={v!r} mm puts the muscle on or outside "
                                "the skin; thickness estimates must be > 0 mm")
        if not (self.x_A < self.x_B < self.x_C):
            raise CaseError(f"thickness planes must be ordered x_A < x_B < x_C, got "
                            f"{self.x_A}, {self.x_B}, {self.x_C} mm")

    def __call__(self, x) -> np.ndarray:
        return np.interp(np.asarray(x, float), [self.x_A, self.x_B, self.x_C],
                         [self.A, self.B, self.C])

    @property
    def values(self):
        return (float(self.A), float(self.B), float(self.C))


def breast_mask(skin: TriSurface, *, threshold: float = 4.0, margin: float = 20.0,
                degree: int = 4, iterations: int = 6) -> np.ndarray:
    """Vertices of the breast regions: where the skin stands out of a smooth chest-wall fit.

    The skin's depth z(x, y) is fitted by a polynomial of the given degree in (x, y) by trimmed
    least squares (breast points excluded iteratively); vertices more than ``threshold`` mm in
    front of the fit, and every vertex within ``margin`` mm of those, are the breast region.
    """
    p = skin.points
    xy = (p[:, :2] - p[:, :2].mean(0)) / max(np.ptp(p[:, :2]), 1e-9)
    cols = [xy[:, 0] ** i * xy[:, 1] ** j for i in range(degree + 1) for j in range(degree + 1 - i)]
    V = np.column_stack(cols)
    base = np.ones(len(p), bool)
    for _ in range(iterations):
        coef, *_ = np.linalg.lstsq(V[base], p[base, 2], rcond=None)
        r = p[:, 2] - V @ coef
        new = r < threshold
        if np.array_equal(new, base):
            break
        base = new
    core = ~base
    mask = core.copy()
    if core.any():
        from scipy.spatial import cKDTree

        d, _ = cKDTree(p[core]).query(p)
        mask = d <= margin
    return mask


@dataclass(frozen=True)
class MuscleFit:
    """The muscle sheet (same triangles as the skin) and the RBF that defines it."""

    muscle: TriSurface
    rbf: ImplicitRBF
    depth: np.ndarray  # (n,) distance each skin vertex moved to reach s = 1 (mm)
    mask: np.ndarray  # (n,) breast-region vertices excluded from the RBF constraints


def muscle_surface(skin: TriSurface, thickness: Thickness, *, mask=None, max_centres: int = 900,
                   seed: int = 0) -> MuscleFit:
    """Seed 001's muscle estimate: fit s (skin 0, projected muscle points 1), then move every skin
    vertex inward along grad s until s = 1.

    ``mask`` marks breast-region skin vertices (default: ``breast_mask``). At most ``max_centres``
    skin points (evenly subsampled) constrain the RBF. Raises CaseError when an estimate puts the
    muscle outside the body: thickness >= half the skin's smallest extent, no s = 1 crossing
    inside the body, or a muscle sheet folded through itself (inverted triangles).
    """
    p = skin.points
    ext = np.ptp(p, axis=0)
    limit = 0.5 * min(ext[0], ext[1])
    for name, v in zip("ABC", thickness.values):
        if v >= limit:
            raise CaseError(f"thickness estimate {name}={v} mm is larger than the body allows "
                            f"(half the skin's extent, {limit:.1f} mm): the muscle would lie "
                            "outside the skin")
    if mask is None:
        mask = breast_mask(skin)
    mask = np.asarray(mask, bool)
    n = vertex_normals(p, skin.triangles)
    # orient normals outward (anterior, +z on average)
    if n[:, 2].mean() < 0:
        n = -n
    keep = np.flatnonzero(~mask)
    if len(keep) < 10:
        raise CaseError(f"only {len(keep)} skin vertices outside the breast regions; the RBF "
                        "needs the surrounding skin to estimate the muscle")
    if len(keep) > max_centres:
        rng = np.random.default_rng(seed)
        keep = np.sort(rng.choice(keep, max_centres, replace=False))
    xs = p[keep]
    t = thickness(xs[:, 0])
    xm = xs - t[:, None] * n[keep]
    rbf = ImplicitRBF.fit(np.vstack([xs, xm]), np.concatenate([np.zeros(len(xs)), np.ones(len(xm))]))
    # march every skin vertex inward along grad s until s = 1
    g = rbf.gradient(p)
    d = g / np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-300)
    s_max = 2.0 * limit
    step = max(0.5 * min(thickness.values), 2.0)
    lo = np.zeros(len(p))
    hi = np.full(len(p), np.nan)
    f_prev = rbf(p) - 1.0
    s = 0.0
    while s < s_max and np.isnan(hi).any():
        s += step
        open_ = np.flatnonzero(np.isnan(hi))
        f = rbf(p[open_] + s * d[open_]) - 1.0
        crossed = (f >= 0) & (f_prev[open_] < 0)
        hi[open_[crossed]] = s
        lo[open_[~crossed]] = s
        f_prev[open_] = f
    if np.isnan(hi).any():
        bad = np.flatnonzero(np.isnan(hi))
        raise CaseError(f"no muscle surface (s = 1) within {s_max:.0f} mm behind {len(bad)} skin "
                        f"vertices (first at {np.round(p[bad[0]], 1).tolist()} mm): the thickness "
                        f"estimates {thickness.values} mm are inconsistent with this skin")
    lo = hi - step
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        f = rbf(p + mid[:, None] * d) - 1.0
        lo = np.where(f < 0, mid, lo)
        hi = np.where(f < 0, hi, mid)
    depth = 0.5 * (lo + hi)
    muscle = TriSurface(p + depth[:, None] * d, skin.triangles)
    if np.any(depth <= 0):
        raise CaseError(f"the muscle estimate lies on or outside the skin at {int(np.sum(depth <= 0))} "
                        "vertices; check the thickness estimates")
    ns = triangle_normals(p, skin.triangles)
    nm = triangle_normals(muscle.points, skin.triangles)
    flipped = np.einsum("ij,ij->i", ns, nm) <= 0
    if flipped.any():
        raise CaseError(f"the muscle sheet folds through itself at {int(flipped.sum())} triangles: "
                        f"thickness estimates {thickness.values} mm are larger than the skin's "
                        "curvature allows")
    return MuscleFit(muscle, rbf, depth, mask)

