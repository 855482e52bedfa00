"""Rigid indenters' tips, whatever solver presses them: the tip's shape and gap (with its normal
and curvature), where a tip starts on the skin, and the contact defaults a solve takes from its
Case. The reference's contact forms (``fem_reference.contact``) and the fast solvers' contact
points (``solvers.contact``: ADMM's and the Mass Tensor Method's) both build on this module, so
that they minimize the same discrete energy.

Units: length mm.

Geometry (``fem_reference.contact`` has the whole story). A tip is a rigid rod of radius R_o
along its unit direction d whose end is a rounded punch: a flat disc of radius a_f with its edge
rounded by e (R_o = a_f + e); a sphere of radius R is the punch with a_f = 0, e = R. With q the
tip's front point on its axis, o = q - e d, w = y - o for a point at y, h = w.d, rho the distance
from the axis and rho_ex = max(rho - a_f, 0), the gap is

    h >= 0 (the end):   g = sqrt(rho_ex^2 + h^2) - e   (the flat face: rho_ex = 0, g = h - e)
    h < 0 (the rod):    g = rho - R_o

negative inside the tip; n = grad_y g is the tip's outward normal (a unit vector), and the
curvature Hess_y g is zero on the flat face.

Start. At push 0 the tip touches the contact surface: on its axis through the site (``point``,
or the area centroid of the actuator's ``region``) it sits where the first of the surface's
points within R_o of the axis has zero gap (points more than R_o behind the site ignored); the
points are the surface's nodes ("nodes") or the facets sampled START_SAMPLES times per edge
("surface"; ``model.case.TIP_STARTS``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tissue_reference.errors import CaseError

from .case import Actuator, Case, tip_start_for

__all__ = ["DEFAULT_CONTACT_PENALTY", "SHORT_STEP", "SLIP_FRACTION", "START_SAMPLES",
           "SURFACE_SAMPLES", "TipShape", "curvilinear_shift", "default_contact_rule", "default_tip_start", "facet_samples",
           "first_touch", "gap_and_normal", "gap_hessian", "indenter_site", "passed_through",
           "through_surface_state"]

DEFAULT_CONTACT_PENALTY = 1e3
"""beta in the contact penalty's stiffness k = beta E / h (kPa/mm, E Young's modulus, h the
longest edge of the cell at the point): the penetration is (p_c / E + 1 / 2) h / beta (mm)."""

SURFACE_SAMPLES = 4
"""The facet check of a solve with tips: points per facet edge at which each contact facet is
sampled (``through_surface_state``)."""

SLIP_FRACTION = 0.05
"""A contact facet deeper inside a tip than this fraction of its radius (and than 10x the
nodal penetration) means the tip passed between the surface's nodes: the state is invalid."""

START_SAMPLES = 24
"""Sampling of each facet near a tip's axis for the "surface" start: points per facet edge. The
first point of contact generally lies between nodes, which would start the tip deeper than on
the meshed body."""


def default_contact_rule(case: Case):
    """Where a solve that names none samples the contact penalty: the case's own
    (``[reference] contact_quadrature``, a Gauss degree), else "nodal"."""
    return case.reference_contact_quadrature or "nodal"


def default_tip_start(case: Case, rule=None) -> str:
    """Where a solve that names none starts its indenters: the case's own (``[reference]
    tip_start``), else the one that goes with its contact rule ``rule`` (None: the case's;
    ``model.case.tip_start_for``: "nodes" with the nodal rule, "surface" with a Gauss rule)."""
    if case.reference_tip_start:
        return case.reference_tip_start
    return tip_start_for(default_contact_rule(case) if rule is None else rule)


def _gap_parts(y, o, d, flat, edge, xp=np):
    """The pieces of the gap at points y (k, gdim) (``gap_and_normal``'s arguments): h (k,)
    along the axis, rho (k,) from it, e_rho (k, gdim) (zero on the axis), rho_ex (k,), r (k,)
    from the rim's centre circle, g (k,) and n (k, gdim)."""
    w = y - o
    h = (w * d).sum(axis=1)
    wp = w - h[:, None] * d
    rho = xp.sqrt((wp * wp).sum(axis=1))
    er = wp / xp.where(rho > 0, rho, 1.0)[:, None]       # zero on the axis
    rex = xp.maximum(rho - flat, 0.0)
    hc = xp.maximum(h, 0.0)
    r = xp.sqrt(rex * rex + hc * hc)
    front = h >= 0
    g = xp.where(front, r - edge, rho - (flat + edge))
    nf = (rex[:, None] * er + hc[:, None] * d) / xp.where(r > 0, r, 1.0)[:, None]
    nf = xp.where((r > 0)[:, None], nf, d + 0.0 * nf)
    return h, rho, er, rex, r, g, xp.where(front[:, None], nf, er)


def gap_and_normal(y, o, d, flat, edge, xp=np):
    """(g (k,), n (k, gdim)): the gap (mm) of points y (k, gdim) from tips whose rounded ends
    are centred at o and which point along d (each (gdim,) or (k, gdim)), flat and edge radii
    ``flat``, ``edge`` (scalars or (k,)); n = grad_y g (module docstring). ``xp``: the array
    module (numpy or CuPy)."""
    return _gap_parts(y, o, d, flat, edge, xp)[5:]


SHORT_STEP = 0.5
"""``curvilinear_shift`` bends steps up to this fraction of a tip's edge radius: the shift is
then at most about a quarter of the step (s^2 / (2 R) for a slide s)."""


def curvilinear_shift(y0, y1, o, d, flat, edge) -> np.ndarray:
    """The shift that bends a straight step of points along a tip (numpy).

    A point pressed on a convex tip slides along a curve, but a Newton correction moves it on a
    straight line, which leaves the tip's surface by about s^2 / (2 R) after a slide s; the
    shift puts the gap back to the one the step's linearization predicts (a second-order
    correction of the step: O(|y1 - y0|^2)).

    Parameters
    ----------
    y0 : ndarray
        (k, gdim) positions (mm) where the step starts.
    y1 : ndarray
        (k, gdim) positions (mm) after the straight step.
    o, d : array_like
        The centre of the tip's rounded end and its direction (``gap_and_normal``).
    flat, edge : float
        The tip's flat and edge radii (mm).

    Returns
    -------
    ndarray
        (k, gdim) (mm): for a point inside the tip at y0 (g < 0) whose linearized gap
        g_lin = g(y0) + n(y0).(y1 - y0) is still negative, g_lin - g(y1) along the normal at y1
        (after it the gap is g_lin to first order in the shift; exactly on a sphere); zero for
        points entering or leaving the tip, for those outside it, and for steps longer than
        SHORT_STEP of the edge radius, where the linearization says nothing of the gap (a
        skin springing back from a retracted tip moves a radius at once).
    """
    y0 = np.asarray(y0, float)
    y1 = np.asarray(y1, float)
    g0, n0 = gap_and_normal(y0, o, d, flat, edge)
    g_lin = g0 + np.einsum("ki,ki->k", n0, y1 - y0)
    g1, n1 = gap_and_normal(y1, o, d, flat, edge)
    short = np.linalg.norm(y1 - y0, axis=1) <= SHORT_STEP * edge
    pressed = (g0 < 0.0) & (g_lin < 0.0) & short
    return np.where(pressed[:, None], (g_lin - g1)[:, None] * n1, 0.0)


def gap_hessian(y, o, d, flat, edge) -> np.ndarray:
    """Hess_y g (k, gdim, gdim) (1/mm) of the gap of ``gap_and_normal`` (numpy): on the rounded
    end t t^T / r + (rho_ex / (r rho)) e_phi e_phi^T (t the meridional tangent, e_phi the
    azimuthal direction, r the distance from the rim's centre circle), zero on the flat face,
    e_phi e_phi^T / rho along the rod."""
    y = np.asarray(y, float)
    k, gdim = y.shape
    d = np.broadcast_to(np.asarray(d, float), (k, gdim))
    flat = np.broadcast_to(np.asarray(flat, float), (k,))
    h, rho, er, rex, r, _, n = _gap_parts(y, o, d, flat, edge)
    eye = np.eye(gdim)
    ephi = eye - np.einsum("ki,kj->kij", d, d) - np.einsum("ki,kj->kij", er, er)
    tt = eye - np.einsum("ki,kj->kij", n, n) - ephi
    # rho_ex / rho: 1 for a sphere (also on its axis), 0 on a punch's flat face
    ratio = np.where(rho > 0, rex / np.where(rho > 0, rho, 1.0), (flat == 0).astype(float))
    rs = np.where(r > 0, r, np.inf)
    end = tt / rs[:, None, None] + (ratio / rs)[:, None, None] * ephi
    end[(rex == 0) & (flat > 0)] = 0.0
    rod = ephi / np.where(rho > 0, rho, np.inf)[:, None, None]
    return np.where((h >= 0)[:, None, None], end, rod)


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
        y = np.asarray(y, float).reshape(-1, len(d))
        return gap_and_normal(y, np.asarray(o, float), np.asarray(d, float), self.flat,
                              self.edge)[0]


def indenter_site(a: Actuator, case: Case) -> np.ndarray:
    """The point (mm) the tip's axis passes through: ``point``, else the area centroid of the
    actuator's ``region``."""
    if a.point is not None:
        return np.asarray(a.point, float)
    facets, area = case.mesh.facet_measures(a.region)
    return (area[:, None] * case.mesh.points[facets].mean(axis=1)).sum(0) / area.sum()


def first_touch(shape: TipShape, site, d, pts) -> float:
    """How far (mm) along d from ``site`` the tip's front point sits when the tip first touches
    the points ``pts`` (k, gdim) within its radius of the axis (those more than a radius behind
    the site ignored); inf when none is under the tip."""
    R = shape.radius
    w = np.asarray(pts, float) - site
    s = w @ d
    rho = np.linalg.norm(w - s[:, None] * d, axis=1)
    under = (rho <= R) & (s >= -R)
    return float(np.min(s[under] + shape.lift(rho[under]), initial=np.inf))


def facet_samples(nv: int, n: int) -> np.ndarray:
    """Barycentric sample points (s, nv) of a facet with nv vertices (2: edge, 3: triangle),
    ``n`` per edge."""
    if nv == 2:
        t = np.linspace(0.0, 1.0, n + 1)
        return np.stack([1 - t, t], axis=1)
    pts = [(i / n, j / n) for i in range(n + 1) for j in range(n + 1 - i)]
    a = np.array(pts)
    return np.stack([1 - a.sum(axis=1), a[:, 0], a[:, 1]], axis=1)


def no_node_under(a: Actuator, site) -> CaseError:
    """The error of a tip under which no point of its contact surface lies."""
    return CaseError(
        f"indenter {a.name!r}: no node of its contact surface {list(a.contact_regions)} lies "
        f"under the tip (within {TipShape.of(a).radius:g} mm of its axis through "
        f"{np.round(site, 6).tolist()} along {list(a.direction)})")


def passed_through(shape: TipShape, deep: float, nodal_pen: float) -> bool:
    """Whether a tip passed between its contact surface's nodes: a facet ``deep`` mm inside it,
    deeper than SLIP_FRACTION of its radius and than 10x the nodal penetration (mm)."""
    return bool(deep > max(SLIP_FRACTION * shape.radius, 10.0 * nodal_pen))


def through_surface_state(state: dict, contact: dict) -> dict:
    """The deformation state, made invalid where a tip passed between the contact surface's
    nodes (the node-to-surface penalty cannot see it; the answer is then not a contact
    solution at all). ``contact``: {"indenters": {name: report}}."""
    bad = [n for n, r in (contact.get("indenters") or {}).items() if r.get("tip_through_surface")]
    if not bad:
        return state
    why = "; ".join(
        f"indenter {n!r} passed between the nodes of its contact surface (a facet "
        f"{contact['indenters'][n]['surface_penetration']:.3g} mm inside the tip): the surface's "
        f"cells are too coarse for the tip; refine the mesh under it (cells <= radius / 3)"
        for n in bad)
    reason = "; ".join(r for r in (state.get("invalid_reason"), why) if r)
    return {**state, "valid": False, "invalid_reason": reason}
