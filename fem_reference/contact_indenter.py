"""One rigid indenter on a ReferenceSolver: its penalty energy and report forms, its start
position on the contact surface, and what each solve reports about it.

Units: length mm, force mN, area mm^2, penalty stiffness kPa/mm.

``Indenter`` builds the node-to-surface penalty (``fem_reference.contact`` module docstring)
for one actuator of type "indenter". Its ``report`` gives the push, force, contact area and
nodal penetration and the surface-penetration check: the penalty acts at the surface's nodes
only, so a tip narrower than the facets can pass between them; each contact facet is sampled
at ``SURFACE_SAMPLES`` points per edge, and a facet deeper inside the tip than
``SLIP_FRACTION`` of its radius (and than 10x the nodal penetration) marks the state invalid
(``tip_through_surface``). The deformed facets are the field's own surface:
the displacement evaluated at the sample points, flat between the vertices at degree 1, bending
at degree >= 2, its values at the fixed sample points one sparse product of its nodal
values (``point_values.evaluation_rows``).
"""
from __future__ import annotations

import dolfinx
import dolfinx.fem
import numpy as np
import ufl
from mpi4py import MPI
from petsc4py import PETSc

from tissue_reference.errors import CaseError
from tissue_reference.model.case import Actuator, Case
from tissue_reference.model.tips import (
    SLIP_FRACTION,
    START_SAMPLES,
    SURFACE_SAMPLES,
    TipShape,
    curvilinear_shift,
    facet_samples,
    first_touch,
    indenter_site,
    no_node_under,
    passed_through,
)

from .contact_geometry import gap_ufl
from .jit import compile_form
from .point_values import evaluation_rows

__all__ = ["SLIP_FRACTION", "START_SAMPLES", "SURFACE_SAMPLES"]


def facet_sample_points(nv: int, n: int | None = None) -> np.ndarray:
    """Barycentric sample points (s, nv) of a facet with nv vertices (2: edge, 3: triangle),
    ``n`` (default SURFACE_SAMPLES) per edge."""
    return facet_samples(nv, SURFACE_SAMPLES if n is None else n)


def _facet_sample_points(mesh, facets, f2c):
    """(points (n, gdim), cells (n,)): SURFACE_SAMPLES per edge of each dolfinx facet in
    ``facets``, between the facet's vertices, and the cell each facet belongs to."""
    gdim = mesh.geometry.dim
    fdim = mesh.topology.dim - 1
    if not len(facets):
        return np.zeros((0, gdim)), np.zeros(0, np.int32)
    geo = dolfinx.cpp.mesh.entities_to_geometry(getattr(mesh, "_mesh", mesh), fdim,
                                                np.asarray(facets, np.int32), False)
    corners = mesh.geometry.x[geo[:, :fdim + 1], :gdim]     # the facets' vertices first
    bary = facet_sample_points(fdim + 1)
    pts = np.einsum("sk,fkd->fsd", bary, corners).reshape(-1, gdim)
    cells = np.repeat([f2c.links(f)[0] for f in facets], len(bary)).astype(np.int32)
    return pts, cells


def _curved_facet_points(mesh, facets, f2c, n: int, keep=None) -> np.ndarray:
    """Points (m, gdim) on the facets as the mesh's geometry maps them, ``n`` per facet edge:
    on a second-order geometry each facet is the quadratic through its vertices and the
    cell's mid-edge nodes on its edges (found as the cell's nodes nearest the chords' middles),
    on a first-order one the flat facet. keep: a mask of the facets to sample from their
    vertices' coordinates (f, nv, gdim); default all."""
    gdim, fdim = mesh.geometry.dim, mesh.topology.dim - 1
    x = mesh.geometry.x[:, :gdim]
    if len(facets):
        geo = dolfinx.cpp.mesh.entities_to_geometry(getattr(mesh, "_mesh", mesh), fdim,
                                                    np.asarray(facets, np.int32), False)
        verts = x[geo[:, :fdim + 1]]                                # (f, nv, gdim)
        if keep is not None:
            mask = keep(verts)
            facets, verts = np.asarray(facets)[mask], verts[mask]
    if not len(facets):
        return np.zeros((0, gdim))
    bary = facet_sample_points(fdim + 1, n)                               # (s, nv)
    dofmap = mesh.geometry.dofmap
    if len(dofmap.links(0)) == fdim + 2:                             # straight cells
        return np.einsum("sk,fkd->fsd", bary, verts).reshape(-1, gdim)
    pairs = [(i, j) for i in range(fdim + 1) for j in range(i + 1, fdim + 1)]
    out = []
    for f, v in zip(facets, verts):
        nodes = x[dofmap.links(f2c.links(f)[0])]
        mids = [nodes[np.argmin(np.linalg.norm(nodes - (v[i] + v[j]) / 2, axis=1))]
                for i, j in pairs]
        shape = [bary[:, i] * (2 * bary[:, i] - 1) for i in range(fdim + 1)] + \
            [4 * bary[:, i] * bary[:, j] for i, j in pairs]
        out.append(np.stack(shape, axis=1) @ np.vstack([v, mids]))
    return np.vstack(out)


class Indenter:
    """One indenter's constants, forms and start position on a ReferenceSolver: the actuator
    ``a`` of ``case``, the penalty's ``beta``, the contact measure ``ds``, the reference
    coordinates ``X`` and displacement ``u`` (UFL), the cell sizes ``h_cell`` (DG0 Function,
    mm) and ``tip_start``. The solver's parts it works on: ``comm``, ``dm``
    (``dolfinx_mesh.DolfinxMesh``), ``gdim``, ``V`` (the displacement's space), ``u_field``
    (the displacement Function on ``V``, for the surface check) and ``E`` (the material's
    Constant, kPa)."""

    def __init__(self, a: Actuator, case: Case, beta: float, ds, X, u, h_cell,
                 tip_start: str = "nodes", *, comm, dm, gdim: int, V, u_field, E):
        mesh = dm.mesh
        self.name, self.actuator = a.name, a
        self.shape = TipShape.of(a)
        self.comm = comm
        regions = a.contact_regions
        missing = [r for r in regions if r not in dm.region_tags]
        if missing:
            raise CaseError(f"indenter {a.name!r}: contact regions must be boundary (facet) "
                            f"regions; {missing} are not; facet regions: "
                            f"{sorted(dm.region_tags)}")
        self.tags = tuple(dm.region_tags[r] for r in regions)
        ft = dm.facet_tags
        facets = ft.indices[np.isin(ft.values, self.tags)]
        self.d = np.asarray(a.direction, float)
        self.beta = float(beta)
        # the cell sizes h (mm) along the contact surface, for the report
        mesh.topology.create_connectivity(mesh.topology.dim - 1, mesh.topology.dim)
        f2c = mesh.topology.connectivity(mesh.topology.dim - 1, mesh.topology.dim)
        cells = np.unique(np.concatenate([f2c.links(f) for f in facets])) if len(facets) \
            else np.zeros(0, np.int32)
        hs = h_cell.x.array[cells]
        self.h_range = (self.comm.allreduce(float(hs.min(initial=np.inf)), op=MPI.MIN),
                        self.comm.allreduce(float(hs.max(initial=0.0)), op=MPI.MAX))
        # the penalty's smoothing width eps = h / beta (mm) on the coarsest contact cell: a tip
        # touching the skin presses with the full penalty stiffness once this far in
        self.smoothing_width = self.h_range[1] / self.beta
        # the displacement nodes of the contact surface: start position and penetration
        self.dofs = dolfinx.fem.locate_dofs_topological(V, mesh.topology.dim - 1, facets)
        self.dofs = self.dofs[self.dofs < V.dofmap.index_map.size_local]
        self.x_nodes = V.tabulate_dof_coordinates()[self.dofs, :gdim]
        self.site = indenter_site(a, case)
        self.tip_start = tip_start
        self.q0 = self._start(a, (mesh, facets, f2c) if tip_start == "surface" else None)
        # the tip must not pass between the contact surface's nodes: sample points on its
        # undeformed facets and the cell of each, where the displacement is evaluated
        self._u_field = u_field
        self._samples, self._sample_cells = _facet_sample_points(mesh, facets, f2c)
        self._sample_values = evaluation_rows(V, self._samples, self._sample_cells)
        # constants: tip front point (ramped by the load stepping), shape, axis
        sc = PETSc.ScalarType
        self.q = dolfinx.fem.Constant(mesh, sc(tuple(self.q0)))
        q0 = dolfinx.fem.Constant(mesh, sc(tuple(self.q0)))
        d = dolfinx.fem.Constant(mesh, sc(tuple(self.d)))
        flat = dolfinx.fem.Constant(mesh, sc(self.shape.flat))
        edge = dolfinx.fem.Constant(mesh, sc(self.shape.edge))
        k = beta * E / h_cell
        self.E = E
        y = ufl.variable(X + u)
        g = gap_ufl(y, self.q - edge * d, d, flat, edge, self.shape.sphere)
        pen = -g
        eps = h_cell / beta  # smoothing width (mm) of the penalty's kink
        pi = k * ufl.conditional(ufl.le(pen, 0.0), 0.0, ufl.conditional(
            ufl.lt(pen, eps), pen ** 3 / (6 * eps), pen ** 2 / 2 - eps * pen / 2 + eps ** 2 / 6))
        self.normal_energy = pi * ds(self.tags)
        # the normal penalty's Hessian without the tip's curvature term: k phi''(pen) n n,
        # positive semi-definite (``Contact.tangent_without_curvature``)
        n_y = ufl.diff(g, y)
        self._normal_stiffness = (k * ufl.conditional(ufl.le(pen, 0.0), 0.0, ufl.conditional(
            ufl.lt(pen, eps), pen / eps, 1.0)), n_y, ds(self.tags))
        if a.contact == "tied":
            n = n_y / ufl.sqrt(ufl.dot(n_y, n_y))
            slip = (y - X) - (self.q - q0)
            slip = slip - ufl.dot(slip, n) * n
            # tied where touching: g <= eps (a node hovering at g = 0 stays tied)
            pi = pi + k / 2 * ufl.conditional(ufl.le(g, eps), 1.0, 0.0) * ufl.dot(slip, slip)
        self.energy = pi * ds(self.tags)
        # force on the skin (component along e, mN) and contact area (mm^2): one form, selected
        # by constants so that it compiles once
        self._e = dolfinx.fem.Constant(mesh, sc((0.0,) * gdim))
        self._w_area = dolfinx.fem.Constant(mesh, sc(0.0))
        # and the contact's moments for ``contact_width``: rho^2 (squared distance from the
        # tip's axis) and h over the contact, weighted by the same constant vector
        self._w_moments = dolfinx.fem.Constant(mesh, sc((0.0, 0.0)))
        w = y - (self.q - edge * d)
        rho2 = ufl.dot(w, w) - ufl.dot(w, d) ** 2
        touching = ufl.conditional(ufl.lt(g, 0.0), 1.0, 0.0)
        report = -ufl.dot(ufl.diff(pi, y), self._e) + self._w_area * touching + \
            touching * (self._w_moments[0] * rho2 + self._w_moments[1] * h_cell)
        self._report_form = compile_form(report * ds(self.tags))

    def tangent_without_curvature(self, v, w):
        """k phi''(pen) (n . w) (n . v) over the contact surface (UFL bilinear form): the normal
        penalty's Hessian less -k phi'(pen) Hess(g), the tip's curvature, which makes the
        tangent indefinite where a node sits deep in a convex tip."""
        kk, n_y, dsc = self._normal_stiffness
        return kk * ufl.dot(n_y, w) * ufl.dot(n_y, v) * dsc

    def _start(self, a: Actuator, surface=None) -> np.ndarray:
        """The tip's front point at push 0: where it first touches the contact surface's nodes
        (``model.tips.first_touch``); with ``surface`` (mesh, facets, facet-to-cell
        connectivity), where it first touches those facets as the geometry curves them
        (TIP_STARTS)."""
        R = self.shape.radius
        t = first_touch(self.shape, self.site, self.d, self.x_nodes)
        if surface is not None:
            reach = R + float(self.h_range[1])

            def near(verts):   # facets with a vertex within a radius (and a cell) of the axis
                w = verts.reshape(-1, verts.shape[-1]) - self.site
                cs = w @ self.d
                crho = np.linalg.norm(w - cs[:, None] * self.d, axis=1)
                return ((crho <= reach) & (cs >= -reach)).reshape(len(verts), -1).any(axis=1)

            pts = _curved_facet_points(*surface, START_SAMPLES, keep=near)
            t = min(t, first_touch(self.shape, self.site, self.d, pts))
        t = self.comm.allreduce(t, op=MPI.MIN)
        if not np.isfinite(t):
            raise no_node_under(a, self.site)
        return self.site + t * self.d

    def curvilinear_shift(self, y0: np.ndarray, y1: np.ndarray) -> np.ndarray:
        """``model.tips.curvilinear_shift`` for this tip where the load step puts it: the
        shift (k, gdim) (mm) that bends the straight Newton trial y1 of contact-surface nodes
        at y0 (each (k, gdim), mm) along the tip."""
        return curvilinear_shift(y0, y1, self._origin(), self.d, self.shape.flat,
                                 self.shape.edge)

    def place(self, q) -> None:
        """Put the tip's end at ``q`` (mm, (gdim,)): where the contact forms see it."""
        self.q.value = q

    def push_now(self) -> float:
        """The tip's current position (mm along its direction from its start)."""
        return float((np.asarray(self.q.value) - self.q0) @ self.d)

    def _assemble(self, e, w_area, w_moments=(0.0, 0.0)) -> float:
        self._e.value = e
        self._w_area.value = w_area
        self._w_moments.value = w_moments
        return self.comm.allreduce(dolfinx.fem.assemble_scalar(self._report_form), op=MPI.SUM)

    def contact_width(self) -> tuple[float, float]:
        """(a, h) mm: the contact's radius and the mean longest edge of the cells in contact,
        both by the contact rule's own points. a = sqrt(2 <rho^2>) with <rho^2> the mean squared
        distance from the tip's axis over the contact: exact for a disc, and for a sector of
        one cut by symmetry planes through the axis; (0, 0) out of contact."""
        zero = np.zeros(len(self.d))
        area = self._assemble(zero, 1.0)
        if area <= 0.0:
            return 0.0, 0.0
        rho2 = self._assemble(zero, 0.0, (1.0, 0.0)) / area
        h = self._assemble(zero, 0.0, (0.0, 1.0)) / area
        return float(np.sqrt(2.0 * max(rho2, 0.0))), float(h)

    def surface_penetration(self) -> float:
        """Deepest point (mm) of the contact surface's deformed facets inside the tip, sampled
        at SURFACE_SAMPLES points per facet edge: the penalty acts at the nodes only, so a tip
        narrower than the facets can slip between nodes; then this exceeds the nodal
        ``max_penetration`` by far. The facets are the field's own surface, the displacement
        evaluated between the vertices (flat for P1, bending for P2)."""
        gdim = len(self.d)
        pts = self._samples
        deep = 0.0
        if len(pts):
            y = pts + self._sample_values @ self._u_field.x.array.reshape(-1, gdim)
            deep = float(np.max(-self.shape.gap(y, self._origin(), self.d), initial=0.0))
        return max(self.comm.allreduce(deep, op=MPI.MAX), 0.0)

    def _origin(self) -> np.ndarray:
        """Centre (mm) of the tip's rounded end where the tip is now."""
        return np.asarray(self.q.value) - self.shape.edge * self.d

    def report(self, u_array) -> dict:
        """Force, area and penetration at the solver's current state (module docstring);
        with the facet check (``surface_penetration``, ``tip_through_surface``)."""
        gdim = len(self.d)
        eye = np.eye(gdim)
        f = np.array([self._assemble(eye[i], 0.0) for i in range(gdim)])
        area = self._assemble(np.zeros(gdim), 1.0)
        y = self.x_nodes + u_array.reshape(-1, gdim)[self.dofs]
        pen = float(np.max(-self.shape.gap(y, self._origin(), self.d), initial=0.0))
        pen = max(self.comm.allreduce(pen, op=MPI.MAX), 0.0)
        return {"push": self.push_now(), "force": float(f @ self.d),
                "force_vector": [float(v) for v in f], "contact_area": float(area),
                "max_penetration": pen, "penalty_beta": self.beta,
                "penalty": [float(self.beta * self.E.value / h) for h in self.h_range[::-1]],
                "tip": self.actuator.tip, "contact": self.actuator.contact,
                "tip_start": [float(v) for v in self.q0], "started_on": self.tip_start,
                **self._slip_check(pen)}

    def _slip_check(self, nodal_pen) -> dict:
        deep = self.surface_penetration()
        return {"surface_penetration": deep,
                "tip_through_surface": passed_through(self.shape, deep, nodal_pen)}
