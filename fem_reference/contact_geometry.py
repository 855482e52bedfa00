"""The geometry of a rigid indenter's tip and the quadrature of the contact integrals.

Units: length mm.

``gap_ufl``: the gap of ``model.tips.TipShape`` (a rounded punch; a sphere is the punch with
no flat) as a UFL expression of the current position, for the penalty forms. ``TipShape`` (the
gap in numpy) and ``nodal_rule`` (one quadrature point per displacement node of a contact facet,
``meshes.facet_quadrature``) live in the meshes layer, which the fast solvers share; they are
re-exported here. The formulas are in the ``fem_reference.contact`` module docstring.
"""
from __future__ import annotations

import ufl

from tissue_reference.meshes.facet_quadrature import nodal_rule
from tissue_reference.model.tips import TipShape

__all__ = ["TipShape", "nodal_rule"]


def gap_ufl(y, o, d, flat, edge, sphere: bool):
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
