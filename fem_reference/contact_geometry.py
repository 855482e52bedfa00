"""The geometry of a rigid indenter's tip and the quadrature of the contact integrals.

Units: length mm.

``TipShape``: a rounded punch (flat radius, edge radius; a sphere is the punch with no flat)
and its gap g (mm, negative inside the tip) in numpy; ``_gap_ufl`` is the same gap as a UFL
expression of the current position, for the penalty forms. ``nodal_rule``: one quadrature
point per displacement node of a contact facet (the lumped rule of the P1 facets through the
nodes). The formulas are in the ``fem_reference.contact`` module docstring.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import ufl

from tissue_reference.meshes.case import Actuator

__all__ = ["TipShape", "nodal_rule"]


def nodal_rule(fdim: int, degree: int) -> tuple[np.ndarray, np.ndarray]:
    """Points and weights on the reference facet (interval or triangle) at the nodes of the
    Lagrange element of ``degree``, each weighted by its share of the facet split into degree^fdim
    sub-simplices (each sub-simplex gives its measure equally to its vertices): the lumped rule
    of the P1 facets through the nodes. One point per displacement node: the penalty constrains
    each surface node once (degree 2 triangle: corners 1/24, edge midpoints 1/8)."""
    k = degree
    if fdim == 1:
        pts = np.arange(k + 1, dtype=float)[:, None] / k
        w = np.full(k + 1, 1.0 / k)
        w[[0, -1]] = 0.5 / k
        return pts, w
    index = {(i, j): n for n, (i, j) in enumerate((i, j) for j in range(k + 1)
                                                 for i in range(k + 1 - j))}
    w = np.zeros(len(index))
    area = 0.5 / k ** 2 / 3.0
    for (i, j) in index:
        if i + j <= k - 1:
            for v in ((i, j), (i + 1, j), (i, j + 1)):
                w[index[v]] += area
        if i + j <= k - 2:
            for v in ((i + 1, j), (i, j + 1), (i + 1, j + 1)):
                w[index[v]] += area
    pts = np.array([[i / k, j / k] for (i, j) in index])
    return pts, w


@dataclass(frozen=True)
class TipShape:
    """A rounded punch: flat radius ``flat`` (mm) and edge radius ``edge`` (mm); a sphere of
    radius R has flat = 0, edge = R."""

    flat: float
    edge: float
    sphere: bool

    @classmethod
    def of(cls, a: Actuator) -> TipShape:
        if a.tip == "sphere":
            return cls(0.0, float(a.radius), True)
        return cls(float(a.radius - a.edge_radius), float(a.edge_radius), False)

    @property
    def radius(self) -> float:
        return self.flat + self.edge

    def lift(self, rho: np.ndarray) -> np.ndarray:
        """Height (mm) of the tip's surface above its front point at distance rho from the axis
        (rho <= radius)."""
        r = np.clip(np.asarray(rho, float) - self.flat, 0.0, self.edge)
        return self.edge - np.sqrt(self.edge ** 2 - r ** 2)

    def gap(self, y: np.ndarray, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        """The gap g (mm) of points y (n, gdim) (module docstring), numpy."""
        w = np.asarray(y, float) - o
        h = w @ d
        rho = np.linalg.norm(w - h[:, None] * d, axis=1)
        if self.sphere:
            front = np.linalg.norm(w, axis=1) - self.edge
        else:
            rex = np.maximum(rho - self.flat, 0.0)
            front = np.where(rex > 0, np.sqrt(rex ** 2 + np.maximum(h, 0.0) ** 2) - self.edge,
                             h - self.edge)
        return np.where(h >= 0, front, rho - self.radius)


def _gap_ufl(y, o, d, flat, edge, sphere: bool):
    """The gap g (mm) of the current position y (UFL), as TipShape.gap."""
    w = y - o
    h = ufl.dot(w, d)
    wp = w - h * d
    rho = ufl.sqrt(ufl.dot(wp, wp) + (1e-9 * edge) ** 2)  # smooth on the axis
    if sphere:
        front = ufl.sqrt(ufl.dot(w, w)) - edge
    else:
        rex = ufl.max_value(rho - flat, 0.0)
        front = ufl.conditional(ufl.gt(rex, 0.0),
                                ufl.sqrt(rex ** 2 + ufl.max_value(h, 0.0) ** 2) - edge, h - edge)
    return ufl.conditional(ufl.ge(h, 0.0), front, rho - (flat + edge))
