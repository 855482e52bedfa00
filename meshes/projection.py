"""Projections onto the true curved boundaries of the builtin bodies, for refinements that put
new boundary vertices on the surface (``meshes.refine.refine_uniform``, ``meshes.refine_local``).

``projector_for(builder)`` gives a builtin mesh's projection: ``DomeProjection`` for the phantom
and its parts, ``ShellProjection`` for the thick sphere's octant, None for flat bodies. A
projection is a callable ``project(x, regions) -> x'``: the points ``x`` (k, gdim) mm of new
boundary vertices and, for each, the frozenset of facet-region names of the boundary facets
around it; it returns the points moved onto the true geometry. Lengths in mm.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["DomeProjection", "ShellProjection", "dome_side_point"]


def dome_side_point(radius: float, height: float, z: float, azimuth_deg: float) -> np.ndarray:
    """The point (mm) of the half-ellipsoid (x^2 + y^2) / radius^2 + z^2 / height^2 = 1 at
    height ``z`` and the given azimuth (degrees from +x): an actuator site of the phantom."""
    r = radius * math.sqrt(1.0 - (z / height) ** 2)
    a = math.radians(azimuth_deg)
    return np.array([r * math.cos(a), r * math.sin(a), z])


def _ellipsoid(x, R, H):
    """f = (x^2 + y^2) / R^2 + z^2 / H^2 - 1 and its gradient (1/mm)."""
    f = (x[:, 0] ** 2 + x[:, 1] ** 2) / R ** 2 + x[:, 2] ** 2 / H ** 2 - 1.0
    g = np.stack([2 * x[:, 0] / R ** 2, 2 * x[:, 1] / R ** 2, 2 * x[:, 2] / H ** 2], axis=1)
    return f, g


def _cylinder(x, p, axis, r):
    """f = (|w_perp|^2 - r^2) / r^2 for the cylinder of radius r (mm) through p along unit axis."""
    w = x - p
    wp = w - (w @ axis)[:, None] * axis
    return (np.sum(wp * wp, axis=1) - r * r) / (r * r), 2 * wp / (r * r)


@dataclass(frozen=True)
class ShellProjection:
    """Projection onto the spheres of ``meshes.builders.shell_octant``: a boundary edge of the
    ``inner`` (``outer``) region goes radially onto the sphere of radius ``inner`` (``outer``),
    mm; edges only on the symmetry planes stay (radial scaling keeps them in their planes)."""

    inner: float = 10.0
    outer: float = 20.0

    def __call__(self, x: np.ndarray, regions) -> np.ndarray:
        x = np.array(x, dtype=np.float64)
        for i, reg in enumerate(regions):
            r = self.inner if "inner" in reg else self.outer if "outer" in reg else None
            if r is not None:
                x[i] *= r / max(float(np.linalg.norm(x[i])), 1e-300)
        return x


@dataclass(frozen=True)
class DomeProjection:
    """Projection onto the phantom of ``meshes.builders``: the half-ellipsoid
    (x^2 + y^2) / R^2 + z^2 / H^2 = 1, z >= 0, on the flat base z = 0, with actuator patches
    bounded by cylinders of radius ``patch_radius`` along the inward horizontal radial direction
    at height ``actuator_height`` (mm).

    A boundary edge only on ``base`` and mirror-plane facets (``mirrors``: the half and quarter
    phantoms' cuts) stays (flat); one between ``base`` and the curved
    surface goes to the base circle of radius R; one between an actuator patch and the skin goes
    to the patch rim (ellipsoid and cylinder, by minimum-norm Newton); any other boundary edge
    with a named region goes to the ellipsoid (minimum-norm Newton from the chord midpoint, close
    to the nearest surface point for these short chords). Edges of unnamed facets stay.
    """

    radius: float
    height: float
    actuator_height: float
    patch_radius: float
    patches: tuple          # ((region name, azimuth in degrees), ...)
    base: str = "base"
    mirrors: tuple = ("sym_y0", "sym_x0")  # flat mirror planes of the half and quarter parts

    def _rim(self, name):
        """A patch's site (mm) and the unit axis of its rim cylinder (inward, horizontal)."""
        p = dome_side_point(self.radius, self.height, self.actuator_height,
                            dict(self.patches)[name])
        return p, -np.array([p[0], p[1], 0.0]) / math.hypot(p[0], p[1])

    def __call__(self, x: np.ndarray, regions) -> np.ndarray:
        x = np.array(x, dtype=np.float64)
        R, H = self.radius, self.height
        patch_names = {name for name, _ in self.patches}
        groups: dict = {}
        flat = {self.base, *self.mirrors}
        for i, reg in enumerate(regions):
            if not reg or reg <= flat:
                continue
            curved = reg - flat
            if self.base in reg:
                key = ("circle",)
            else:
                rims = sorted(curved & patch_names)
                key = ("rim", rims[0]) if rims and len(curved) > 1 else ("ellipsoid",)
            groups.setdefault(key, []).append(i)
        for key, idx in groups.items():
            idx = np.array(idx)
            y = x[idx]
            if key[0] == "circle":
                rxy = np.linalg.norm(y[:, :2], axis=1, keepdims=True)
                y[:, :2] *= R / np.maximum(rxy, 1e-300)
                y[:, 2] = 0.0
            elif key[0] == "ellipsoid":
                for _ in range(30):
                    f, g = _ellipsoid(y, R, H)
                    y -= (f / np.sum(g * g, axis=1))[:, None] * g
                    if np.abs(f).max() < 1e-15:
                        break
            else:
                p, axis = self._rim(key[1])
                for _ in range(30):
                    f1, g1 = _ellipsoid(y, R, H)
                    f2, g2 = _cylinder(y, p, axis, self.patch_radius)
                    J = np.stack([g1, g2], axis=1)                 # (k, 2, 3)
                    JJ = J @ np.transpose(J, (0, 2, 1))             # (k, 2, 2)
                    lam = np.linalg.solve(JJ, np.stack([f1, f2], axis=1)[:, :, None])
                    y -= (np.transpose(J, (0, 2, 1)) @ lam)[:, :, 0]
                    if max(np.abs(f1).max(), np.abs(f2).max()) < 1e-15:
                        break
            x[idx] = y
        return x
