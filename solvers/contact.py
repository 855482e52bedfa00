"""Frictionless rigid tips on a P1 mesh, shared by the fast solvers (ADMM, ``solvers.admm.contact``;
the Mass Tensor Method, ``solvers.mass_tensor.contact``): the reference's discrete contact energy
(``fem_reference.contact``) at its contact points, with its gradient, Hessian and per-tip report.

Energy (``fem_reference.contact``, at P1): each contact facet f of an indenter's contact
surface carries the points p of a contact rule (``meshes.facet_quadrature``: "nodal", one point
per facet vertex, or a Gauss degree), with weight W_p (mm^2: the rule's weight times the facet's
area over the reference facet's), penalty stiffness k_p = beta E / h_f and smoothing width
eps_p = h_f / beta (h_f the longest edge of the facet's cell, mm), at the position
y_p = X_p + S_p u (S_p: the facet's P1 shape functions at the point):

    Pi_c(u) = sum_p W_p k_p phi(-g(y_p)),
    phi(x) = 0 (x <= 0), x^3 / (6 eps) (x < eps), x^2 / 2 - eps x / 2 + eps^2 / 6 (x >= eps),

g the tip's gap (``model.tips``) with the tip where its push puts it. ``ContactSet`` holds the
points of a Case's indenters (built once per Case structure: the pushes are not part of it), the
energy, its gradient, its exact Hessian (with the tips' curvature, or without it: positive
semi-definite), the derivative of the contact forces by the pushes and the report of each tip as
the reference writes it; ``point_terms`` / ``point_hessians`` give the same per point, and
``spread`` assembles the Hessian of some of them on a block of vertices, for a solver that works
on a subset of them.

Units: mm, kPa, mN.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from tissue_reference.errors import CaseError, NotModeledError
from tissue_reference.meshes.facet_quadrature import facet_rule
from tissue_reference.model.case import CONTACT_RULES, TIP_STARTS, is_contact_rule
from tissue_reference.model.tips import (
    DEFAULT_CONTACT_PENALTY,
    START_SAMPLES,
    SURFACE_SAMPLES,
    TipShape,
    default_contact_rule,
    default_tip_start,
    facet_samples,
    first_touch,
    gap_and_normal,
    gap_hessian,
    indenter_site,
    no_node_under,
    passed_through,
)

__all__ = ["ContactSet", "penalty_phi", "require_frictionless"]


def require_frictionless(case, who: str) -> None:
    """NotModeledError when ``case`` has a tip that ``who`` (a solver modelling frictionless
    tips) does not model: a tied one."""
    for a in case.indenters():
        if a.contact not in (None, "frictionless"):
            raise NotModeledError(f"{who} models frictionless tips; indenter {a.name!r} is "
                                  f"{a.contact!r} (the reference solves it: fem_reference.solve)")


def penalty_phi(pen, eps, xp=np):
    """(phi, phi', phi'') of the smoothed penalty at penetrations pen (mm) with smoothing widths
    eps (mm) (module docstring); ``xp`` the array module (numpy or CuPy)."""
    p = xp.maximum(pen, 0.0)
    small = p < eps
    phi = xp.where(small, p ** 3 / (6 * eps), p * p / 2 - eps * p / 2 + eps * eps / 6)
    d1 = xp.where(small, p * p / (2 * eps), p - eps / 2)
    d2 = xp.where(small, p / eps, 1.0)
    return phi, d1, d2


def _owner_cells(cells, facets):
    """The cell each boundary facet (rows of vertex ids) belongs to (of two, the first); CaseError
    for a facet that is no cell's face."""
    k = cells.shape[1]
    m = len(cells)
    faces = np.sort(np.concatenate([np.delete(cells, j, axis=1) for j in range(k)]), axis=1)
    want = np.sort(facets, axis=1)
    n = int(max(cells.max(initial=0), want.max(initial=0))) + 1
    if float(n) ** (k - 1) < 2.0 ** 62:   # each face as one integer
        def key(f):
            out = np.zeros(len(f), np.int64)
            for c in range(k - 1):
                out = out * n + f[:, c]
            return out
        kf, kw = key(faces), key(want)
    else:
        kf = faces.view([("", faces.dtype)] * (k - 1)).ravel()
        kw = np.ascontiguousarray(want, faces.dtype).view([("", faces.dtype)] * (k - 1)).ravel()
    order = np.argsort(kf, kind="stable")    # equal faces in cell order: the first cell first
    sk = kf[order]
    pos = np.minimum(np.searchsorted(sk, kw), max(len(sk) - 1, 0))
    ok = (sk[pos] == kw) if len(sk) else np.zeros(len(kw), bool)
    if not np.all(ok):
        raise CaseError(f"contact facet {want[~ok][0].tolist()} is not a face of any cell")
    return order[pos] % max(m, 1)


def _longest_edges(points, cells):
    """The longest edge (mm) of each cell."""
    x = points[cells]
    k = cells.shape[1]
    return np.max([np.linalg.norm(x[:, i] - x[:, j], axis=1)
                   for i in range(k) for j in range(i)], axis=0)


@dataclass(frozen=True)
class _Tip:
    """One indenter: its name, shape, direction, start q0 (mm), points ``sl`` (a slice of the
    contact set's), the vertices of its contact surface, its facets and the penalty range."""

    name: str
    actuator: object
    shape: TipShape
    d: np.ndarray
    q0: np.ndarray
    sl: slice
    nodes: np.ndarray
    facets: np.ndarray
    penalty: tuple
    started_on: str


class ContactSet:
    """The contact points of a Case's indenters (module docstring), built once per Case
    structure (pushes are not part of it): S (P, n) CSR, X (P, gdim) mm, W (P,) mm^2, Wk = W k
    (P,) mN/mm, k (P,) kPa/mm, eps (P,) mm, the per-point tip direction, flat and edge radii,
    each point's facet vertices ``pv`` (P, gdim) and their shape functions there ``pN``, and the
    tips (``tips``, with their starts q0). rule, penalty (beta) and tip_start: the contact's
    options, each by default the case's own as the reference takes it. It checks nothing about
    the tips' kind of contact: a solver that models frictionless tips only says so itself
    (``require_frictionless``)."""

    def __init__(self, case, *, rule=None, penalty: float | None = None,
                 tip_start: str | None = None):
        rule = default_contact_rule(case) if rule is None else rule
        if not is_contact_rule(rule):
            raise CaseError(f"contact_quadrature must be {CONTACT_RULES}, got {rule!r}")
        penalty = DEFAULT_CONTACT_PENALTY if penalty is None else penalty
        if not (isinstance(penalty, (int, float)) and np.isfinite(penalty) and penalty > 0):
            raise CaseError(f"contact_penalty must be a finite number > 0, got {penalty!r}")
        tip_start = default_tip_start(case, rule) if tip_start is None else tip_start
        if tip_start not in TIP_STARTS:
            raise CaseError(f"tip_start must be one of {list(TIP_STARTS)}, got {tip_start!r}")
        mesh = case.mesh
        self.rule, self.beta, self.tip_start = rule, float(penalty), tip_start
        n, gdim = mesh.n_vertices, mesh.gdim
        self.n, self.d = n, gdim
        self._points = mesh.points
        E = float(case.material.E)
        ref_pts, ref_w = facet_rule(gdim - 1, rule)
        N = (np.column_stack([1.0 - ref_pts.sum(axis=1), ref_pts]))          # (q, nv)
        ref_measure = 0.5 if gdim == 3 else 1.0
        h_cell = _longest_edges(mesh.points, mesh.cells)
        pv, X, W, k, eps, dirs, flat, edge = [], [], [], [], [], [], [], []
        self.tips: list[_Tip] = []
        start = 0
        for a in case.indenters():
            missing = [r for r in a.contact_regions if r not in mesh.facet_regions]
            if missing:
                raise CaseError(f"indenter {a.name!r}: contact regions must be boundary (facet) "
                                f"regions; {missing} are not; facet regions: "
                                f"{sorted(mesh.facet_regions)}")
            facets = np.unique(np.sort(np.concatenate(
                [mesh.facet_regions[r] for r in a.contact_regions]), axis=1), axis=0)
            xf = mesh.points[facets]                                          # (F, nv, gdim)
            if gdim == 3:
                area = 0.5 * np.linalg.norm(np.cross(xf[:, 1] - xf[:, 0], xf[:, 2] - xf[:, 0]),
                                            axis=1)
            else:
                area = np.linalg.norm(xf[:, 1] - xf[:, 0], axis=1)
            hf = h_cell[_owner_cells(mesh.cells, facets)]
            nf, q = len(facets), len(ref_w)
            X.append(np.einsum("qk,fkd->fqd", N, xf).reshape(-1, gdim))
            W.append((ref_w[None, :] * (area / ref_measure)[:, None]).reshape(-1))
            k.append(np.repeat(penalty * E / hf, q))
            eps.append(np.repeat(hf / penalty, q))
            pv.append(np.repeat(facets, q, axis=0))
            shape = TipShape.of(a)
            d = np.asarray(a.direction, float)
            dirs.append(np.tile(d, (nf * q, 1)))
            flat.append(np.full(nf * q, shape.flat))
            edge.append(np.full(nf * q, shape.edge))
            nodes = np.unique(facets)
            site = indenter_site(a, case)
            t = first_touch(shape, site, d, mesh.points[nodes])
            if tip_start == "surface":
                bary = facet_samples(gdim, START_SAMPLES)
                t = min(t, first_touch(shape, site, d,
                                       np.einsum("sk,fkd->fsd", bary, xf).reshape(-1, gdim)))
            if not np.isfinite(t):
                raise no_node_under(a, site)
            self.tips.append(_Tip(a.name, a, shape, d, site + t * d, slice(start, start + nf * q),
                                  nodes, facets, (penalty * E / hf.max(), penalty * E / hf.min()),
                                  tip_start))
            start += nf * q
        self.P = start
        cat = (lambda v: np.concatenate(v)) if start else (lambda v: np.zeros(0))
        nv = gdim
        # each point's facet vertices and their shape functions there: (P, nv) each
        self.pv = np.concatenate(pv).astype(np.int64) if start else np.zeros((0, nv), np.int64)
        self.pN = np.tile(N, (len(self.pv) // len(ref_w), 1)) if start else np.zeros((0, nv))
        self.S = sp.csr_matrix((self.pN.reshape(-1), (np.repeat(np.arange(start), nv),
                                                      self.pv.reshape(-1))), shape=(start, n))
        self.S.eliminate_zeros()
        self.X = np.concatenate(X) if start else np.zeros((0, gdim))
        self.W, self.k, self.eps = cat(W), cat(k), cat(eps)
        self.Wk = self.W * self.k
        self.dirs = np.concatenate(dirs) if start else np.zeros((0, gdim))
        self.flat, self.edge = cat(flat), cat(edge)

    # ------------------------------------------------------------------ the tips' positions
    def pushes_of(self, case) -> np.ndarray:
        """The pushes (mm) of the tips in ``case`` (a Case of this structure), in tip order."""
        return np.array([case.actuator(t.name).push for t in self.tips], float)

    def origins(self, pushes) -> np.ndarray:
        """(P, gdim): the centre of each point's tip's rounded end with the tips pushed by
        ``pushes`` (mm, in tip order)."""
        o = np.empty((self.P, self.d))
        for t, p in zip(self.tips, np.asarray(pushes, float)):
            o[t.sl] = t.q0 + (p - t.shape.edge) * t.d
        return o

    # ------------------------------------------------------------------ energy on the host
    def _state(self, u, o):
        y = self.X + self.S @ np.asarray(u, float).reshape(self.n, self.d)
        g, nrm = gap_and_normal(y, o, self.dirs, self.flat, self.edge)
        return y, g, nrm

    def energy(self, u, o) -> float:
        """Pi_c (uJ) at displacement u (mm, node-major) with the tips' ends at o."""
        if not self.P:
            return 0.0
        _, g, _ = self._state(u, o)
        return float(self.Wk @ penalty_phi(-g, self.eps)[0])

    def gradient(self, u, o) -> np.ndarray:
        """dPi_c / du (mN, node-major (N,)): S^T of -W k phi'(pen) n at each point."""
        if not self.P:
            return np.zeros(self.n * self.d)
        _, g, nrm = self._state(u, o)
        return (self.S.T @ (-(self.Wk * penalty_phi(-g, self.eps)[1])[:, None] * nrm)).reshape(-1)

    def active(self, u, o) -> np.ndarray:
        """The points in contact (phi' > 0, those ``hessian`` spreads) at u with the tips' ends
        at o, as sorted indices."""
        if not self.P:
            return np.zeros(0, np.int64)
        _, g, _ = self._state(u, o)
        return np.flatnonzero(penalty_phi(-g, self.eps)[1] > 0)

    def point_terms(self, y, o, at=slice(None)):
        """At the points ``at`` (indices or a slice) placed at y (k, gdim) mm, their tips' ends
        at o (k, gdim): (e, f, g, nrm, d1, d2): their energies W k phi(-g) (k,) uJ, the forces
        they put on the skin f = W k phi' n (k, gdim) mN (f = -dPi_c / dy_p), their gaps (mm),
        the tips' normals there, and phi', phi'' at their penetrations -g."""
        g, nrm = gap_and_normal(y, o, self.dirs[at], self.flat[at], self.edge[at])
        phi, d1, d2 = penalty_phi(-g, self.eps[at])
        Wk = self.Wk[at]
        return Wk * phi, (Wk * d1)[:, None] * nrm, g, nrm, d1, d2

    def point_hessians(self, y, o, nrm, d1, d2, at=slice(None), curvature: bool = True):
        """d^2 Pi_c / dy_p^2 (k, gdim, gdim), mN/mm, at the points ``at`` in contact placed at
        y with their tips' ends at o, given the normals and phi', phi'' of ``point_terms``:
        W k (phi'' n n^T - phi' Hess g), the tips' curvature term -phi' Hess g only with
        ``curvature``."""
        Wk = self.Wk[at]
        H = Wk[:, None, None] * (d2[:, None, None] * np.einsum("ki,kj->kij", nrm, nrm))
        if curvature and len(H):
            Hg = gap_hessian(y, o, self.dirs[at], self.flat[at], self.edge[at])
            H -= (Wk * d1)[:, None, None] * Hg
        return H

    def _point_hessians(self, u, o, curvature: bool = True):
        """(on, H): the points in contact (phi' > 0) and d^2 Pi_c / dy_p^2 at each of them
        (``point_hessians``)."""
        y, g, nrm = self._state(u, o)
        _, d1, d2 = penalty_phi(-g, self.eps)
        on = np.flatnonzero(d1 > 0)
        return on, self.point_hessians(y[on], o[on], nrm[on], d1[on], d2[on], on, curvature)

    def hessian(self, u, o, curvature: bool = True) -> sp.csr_matrix:
        """d^2 Pi_c / du^2 (mN/mm, (N, N) node-major): W k (phi'' n n^T - phi' Hess g) at each
        point in contact, spread over its facet's vertices. ``curvature`` False leaves the tips'
        curvature term -phi' Hess g out: the rest is positive semi-definite (a skin node
        pressed on a convex tip makes the exact Hessian indefinite away from the answer)."""
        N = self.n * self.d
        if not self.P:
            return sp.csr_matrix((N, N))
        on, Hp = self._point_hessians(u, o, curvature)
        if not len(on):
            return sp.csr_matrix((N, N))
        return self.spread(Hp, self.pv[on], self.pN[on], self.n).tocsr()

    def spread(self, Hp, vertices, shapes, n: int) -> sp.coo_matrix:
        """The points' Hessians spread over their facets' vertices: the (n d, n d) matrix (node-
        major) with the entries N_a N_b H_ij at (d v_a + i, d v_b + j) for each pair of vertices
        a, b of each point's facet (duplicates not yet summed).

        Parameters
        ----------
        Hp : numpy.ndarray
            (k, d, d) d^2 Pi_c / dy_p^2 at k points (mN/mm), as ``point_hessians`` gives them.
        vertices : numpy.ndarray
            (k, nv) each point's facet vertices, numbered in the matrix's space: the mesh's
            (``pv`` of the points) or a block's of n vertices.
        shapes : numpy.ndarray
            (k, nv) the facet's P1 shape functions at each point (no unit; ``pN`` of the points).
        n : int
            The vertices of the matrix's space.

        Returns
        -------
        scipy.sparse.coo_matrix
            (n d, n d) d^2 Pi_c / du^2 of those points (mN/mm), entries in the order of the
            points: ``tocsr()`` / ``toarray()`` sum them.
        """
        d = self.d
        vals = np.einsum("ka,kb,kij->kaibj", shapes, shapes, Hp)
        rows = np.broadcast_to((d * vertices)[:, :, None, None, None]
                               + np.arange(d)[None, None, :, None, None], vals.shape)
        cols = np.broadcast_to((d * vertices)[:, None, None, :, None]
                               + np.arange(d)[None, None, None, None, :], vals.shape)
        return sp.coo_matrix((vals.reshape(-1), (rows.reshape(-1), cols.reshape(-1))),
                             shape=(n * d, n * d))

    def push_derivative(self, u, o) -> np.ndarray:
        """d (dPi_c / du) / d push_t (mN/mm, (N, n_tips)): how the contact forces change as each
        tip moves along its direction at fixed u. The gap depends on y - o, so the derivative
        is -S^T (H_p d_t) over tip t's points (H_p: the point's Hessian in y)."""
        N = self.n * self.d
        out = np.zeros((N, len(self.tips)))
        if not self.P:
            return out
        on, Hp = self._point_hessians(u, o)
        Hd = np.zeros((self.P, self.d))                           # H_p d (P, gdim)
        Hd[on] = np.einsum("kij,kj->ki", Hp, self.dirs[on])
        for i, t in enumerate(self.tips):
            part = np.zeros_like(Hd)
            part[t.sl] = Hd[t.sl]
            out[:, i] = -(self.S.T @ part).reshape(-1)
        return out

    def smoothing_width(self, name: str) -> float:
        """The largest smoothing width eps (mm) of tip ``name``'s penalty: a tip that touches
        the skin presses with the full penalty stiffness once this far in."""
        t = next(t for t in self.tips if t.name == name)
        return float(self.eps[t.sl].max(initial=0.0))

    def pressed(self, pushes: dict, widths: float) -> dict:
        """``pushes`` (name -> mm) with each tip at 0 <= push < ``widths`` of its smoothing
        widths (a tip missing from ``pushes`` is at 0) pushed to that depth: a tip touching the
        skin without pressing it has a zero Jacobian column (``control.plants.PRESS_WIDTHS``)."""
        out = dict(pushes)
        for t in self.tips:
            floor = widths * self.smoothing_width(t.name)
            if 0.0 <= float(out.get(t.name, 0.0)) < floor:
                out[t.name] = floor
        return out

    # ------------------------------------------------------------------ report
    def report(self, u, pushes) -> dict:
        """Per tip, what the reference reports (``fem_reference.contact`` module docstring):
        push, force (mN along its direction: the force it exerts on the skin), force_vector,
        contact_area (mm^2, the rule's weight of the points with g < 0), max_penetration (mm,
        over the surface's nodes), the penalty, the rule, the start, and the facet check
        (surface_penetration, tip_through_surface)."""
        o = self.origins(pushes)
        uu = np.asarray(u, float).reshape(self.n, self.d)
        _, g, nrm = self._state(uu, o)
        f = (self.Wk * penalty_phi(-g, self.eps)[1])[:, None] * nrm    # -dPi_c / dy_p: on the skin
        out = {}
        bary = facet_samples(self.d, SURFACE_SAMPLES)
        for t, p in zip(self.tips, np.asarray(pushes, float)):
            sl = t.sl
            fv = f[sl].sum(axis=0)
            oc = t.q0 + (p - t.shape.edge) * t.d
            pen = float(np.max(-t.shape.gap(self._points[t.nodes] + uu[t.nodes], oc, t.d),
                               initial=0.0))
            xs = np.einsum("sk,fkd->fsd", bary, (self._points[t.facets]
                                                 + uu[t.facets])).reshape(-1, self.d)
            deep = max(float(np.max(-t.shape.gap(xs, oc, t.d), initial=0.0)), 0.0)
            out[t.name] = {
                "push": float(p), "force": float(fv @ t.d), "force_vector": [float(v) for v in fv],
                "contact_area": float(self.W[sl][g[sl] < 0].sum()),
                "max_penetration": max(pen, 0.0), "penalty_beta": self.beta,
                "penalty": [float(v) for v in t.penalty], "quadrature": self.rule,
                "tip": t.actuator.tip, "contact": t.actuator.contact or "frictionless",
                "tip_start": [float(v) for v in t.q0], "started_on": t.started_on,
                "surface_penetration": deep,
                "tip_through_surface": passed_through(t.shape, deep, max(pen, 0.0))}
        return out
