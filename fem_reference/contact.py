"""Rigid indenters in contact with the skin: UFL penalty forms for the reference.

Units: length mm, stress kPa (= mN/mm^2), force mN, energy uJ, penalty stiffness kPa/mm.

Geometry. An indenter (``meshes.case.Actuator`` of type "indenter") is a rigid rod of radius
R_o along its unit direction d whose end is a rounded punch: a flat disc of radius a_f with its
edge rounded by e (R_o = a_f + e); a sphere of radius R is the rod with a_f = 0, e = R (a
ball-ended rod). Let q be the tip's front point on the axis and o = q - e d. The gap of a skin
point at its current position y = X + u (mm), with h = (y - o).d, rho = |(y - o) - h d|,
rho_ex = max(rho - a_f, 0), is

    h >= 0 (the end):   sphere  g = |y - o| - R
                        punch   g = sqrt(rho_ex^2 + h^2) - e   (rho_ex > 0: the rounded edge)
                                g = h - e                      (rho_ex = 0: the flat face)
    h < 0 (the rod):            g = rho - R_o

negative inside the tip. The candidate surface Gamma_c is the facet regions
``Actuator.contact_regions``: the actuator's ``region`` and its ``contact_region`` (e.g. the skin
around the site: contact spreads as the tip goes in). At push 0 the tip touches Gamma_c: on its
axis through the site (``point``, or the area centroid of ``region``) it sits where the first
node of Gamma_c within R_o of the axis has zero gap (nodes more than R_o behind the site are
ignored). A push p (mm) moves it to q = q0 + p d. An indenter that is not pushed stays at its
start: a rigid obstacle the skin may press against (a negative push retracts it).

Method: a node-to-surface penalty added to the energy that the reference minimizes,

    Pi_c = int_Gamma_c  k phi(-g) dA                                  (frictionless)
         + int_Gamma_c  k/2 H(eps - g) |(I - n n)(u - (q - q0))|^2 dA  (tied: no slip)

integrated with one point per displacement node of the surface (``nodal_rule``: the lumped rule
of the P1 facets through the nodes, so the penalty constrains each node once; Gauss points
constrain P2 surfaces several times per node and lock: +3.7 % Hertz force at h = 0.5 mm).
k = beta E / h (kPa/mm): beta is the dimensionless ``contact_penalty`` of ReferenceSolver, E
Young's modulus, h the longest edge of the cell at the point (mm). phi is the penalty's kink
smoothed over eps = h / beta: phi(x) = 0 (x <= 0), x^3 / (6 eps) (x < eps),
x^2 / 2 - eps x / 2 + eps^2 / 6 (x >= eps), so the residual is continuous with its derivative.
n = grad_y g is the tip's normal; "tied" penalizes, on the nodes in contact, the skin's
tangential slip relative to the tip's translation q - q0 since push 0 (no slip relative to
where each point was at push 0; with a small push it matches a glued patch).

Error. The contact pressure is p_c = k (pen - eps / 2) for a penetration pen >= eps, so the
tip acts as if indented less by pen = p_c / k + eps / 2 = (p_c / E + 1 / 2) h / beta (mm), where
the exact answer has none: forces and displacements converge as O(1 / beta) (the Hertz force
of tests/test_contact.py, P1: 2.6 % below its beta = 1e4 value at beta = 1e2, 0.23 % at 1e3;
the penetration falls tenfold per decade). ``max_penetration`` is reported with every solve.

Newton. The tangent is UFL's exact derivative. Contact makes Newton's corrections unreliable
far from the answer (nodes entering and leaving contact, nodes sliding along a curved tip), so
with indenters (displacement formulation) a correction must lower the total energy, else it is
halved (``accepts``), and the load stepping's first increments move a tip by at most
STEP_FRACTION of its radius (``ramps``); failed steps are cut back as usual.

Each solve reports, per indenter, in ``SolveResult.extra["indenters"][name]``: ``push`` (mm),
``force`` (mN, the actuator force along its direction: the total force the tip exerts on the
skin, which the supports balance), ``force_vector`` (mN, that force; the same sign convention as
``SolveResult.reactions``), ``contact_area`` (mm^2: the reference area lumped to the surface
nodes with g < 0; it resolves the contact edge to about a cell), ``max_penetration`` (mm: max of
-g over those nodes), ``penalty_beta`` and ``penalty`` ([min, max] of k over the cells along
Gamma_c, kPa/mm), ``tip``, ``contact`` and ``tip_start`` (q0, mm). The exported tangent
(``ReferenceSolver.tangent``) uses the tips where the last solve left them.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import dolfinx
import dolfinx.fem
import numpy as np
import ufl
from mpi4py import MPI
from petsc4py import PETSc

from meshes.case import Actuator, Case
from meshes.errors import CaseError
from meshes.results import SolveResult

__all__ = ["DEFAULT_CONTACT_PENALTY", "Contact", "TipShape", "contact_key", "nodal_rule"]

DEFAULT_CONTACT_PENALTY = 1e3
"""beta in k = beta E / h: the penetration is (p_c / E + 1 / 2) h / beta (mm)."""


SLIP_FRACTION = 0.05
"""A contact facet deeper inside a tip than this fraction of its radius (and than 10x the
nodal penetration) means the tip passed between the surface's nodes: the state is invalid."""
SURFACE_SAMPLES = 4
"""Sampling of each contact facet for that check: points per facet edge."""


def _facet_samples(nv: int) -> np.ndarray:
    """Barycentric sample points (s, nv) of a facet with nv vertices (2: edge, 3: triangle)."""
    n = SURFACE_SAMPLES
    if nv == 2:
        t = np.linspace(0.0, 1.0, n + 1)
        return np.stack([1 - t, t], axis=1)
    pts = [(i / n, j / n) for i in range(n + 1) for j in range(n + 1 - i)]
    a = np.array(pts)
    return np.stack([1 - a.sum(axis=1), a[:, 0], a[:, 1]], axis=1)


STEP_FRACTION = 0.1
"""A load step moves an indenter by at most this fraction of its radius at first (the load
stepping grows the increments after steps that converge quickly)."""


def contact_key(case: Case) -> tuple:
    """What the compiled contact forms depend on: the Case's indenters without their pushes."""
    return tuple(replace(a, push=0.0) for a in case.indenters())


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


class _Indenter:
    """One indenter's constants, forms and start position on a ReferenceSolver."""

    def __init__(self, a: Actuator, solver, case: Case, beta: float, ds, X, u, h_cell):
        dm, gdim = solver.dm, solver.gdim
        mesh = dm.mesh
        self.name, self.actuator = a.name, a
        self.shape = TipShape.of(a)
        self.comm = solver.comm
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
        # the displacement nodes of the contact surface: start position and penetration
        V = solver.V
        self.dofs = dolfinx.fem.locate_dofs_topological(V, mesh.topology.dim - 1, facets)
        self.dofs = self.dofs[self.dofs < V.dofmap.index_map.size_local]
        self.x_nodes = V.tabulate_dof_coordinates()[self.dofs, :gdim]
        self._X = case.mesh.points
        self.site = self._site(a, case)
        self.q0 = self._start(a)
        # the contact surface's facets (Case vertex ids): the tip must not pass between nodes
        self.surface = np.concatenate([case.mesh.facet_regions[r] for r in regions]) \
            if regions else np.zeros((0, gdim), np.int64)
        # constants: tip front point (ramped by the load stepping), shape, axis
        sc = PETSc.ScalarType
        self.q = dolfinx.fem.Constant(mesh, sc(tuple(self.q0)))
        q0 = dolfinx.fem.Constant(mesh, sc(tuple(self.q0)))
        d = dolfinx.fem.Constant(mesh, sc(tuple(self.d)))
        flat = dolfinx.fem.Constant(mesh, sc(self.shape.flat))
        edge = dolfinx.fem.Constant(mesh, sc(self.shape.edge))
        k = beta * solver.E / h_cell
        self.E = solver.E
        y = ufl.variable(X + u)
        g = _gap_ufl(y, self.q - edge * d, d, flat, edge, self.shape.sphere)
        pen = -g
        eps = h_cell / beta  # smoothing width (mm) of the penalty's kink
        pi = k * ufl.conditional(ufl.le(pen, 0.0), 0.0, ufl.conditional(
            ufl.lt(pen, eps), pen ** 3 / (6 * eps), pen ** 2 / 2 - eps * pen / 2 + eps ** 2 / 6))
        if a.contact == "tied":
            n = ufl.diff(g, y)
            n = n / ufl.sqrt(ufl.dot(n, n))
            slip = (y - X) - (self.q - q0)
            slip = slip - ufl.dot(slip, n) * n
            # tied where touching: g <= eps (a node hovering at g = 0 stays tied)
            pi = pi + k / 2 * ufl.conditional(ufl.le(g, eps), 1.0, 0.0) * ufl.dot(slip, slip)
        self.energy = pi * ds(self.tags)
        # force on the skin (component along e, mN) and contact area (mm^2): one form, selected
        # by constants so that it compiles once
        self._e = dolfinx.fem.Constant(mesh, sc((0.0,) * gdim))
        self._w_area = dolfinx.fem.Constant(mesh, sc(0.0))
        report = -ufl.dot(ufl.diff(pi, y), self._e) + \
            self._w_area * ufl.conditional(ufl.lt(g, 0.0), 1.0, 0.0)
        self._report_form = dolfinx.fem.form(report * ds(self.tags))

    def _site(self, a: Actuator, case: Case) -> np.ndarray:
        if a.point is not None:
            return np.asarray(a.point, float)
        facets, area = case.mesh.facet_measures(a.region)
        return (area[:, None] * case.mesh.points[facets].mean(axis=1)).sum(0) / area.sum()

    def _start(self, a: Actuator) -> np.ndarray:
        """The tip's front point at push 0: where it first touches the contact surface's nodes
        within its radius of the axis (those more than a radius behind the site ignored)."""
        w = self.x_nodes - self.site
        s = w @ self.d
        rho = np.linalg.norm(w - s[:, None] * self.d, axis=1)
        R = self.shape.radius
        under = (rho <= R) & (s >= -R)
        t = float(np.min(s[under] + self.shape.lift(rho[under]), initial=np.inf))
        t = self.comm.allreduce(t, op=MPI.MIN)
        if not np.isfinite(t):
            raise CaseError(
                f"indenter {a.name!r}: no node of its contact surface "
                f"{list(a.contact_regions)} lies under the tip (within {R:g} mm of its axis "
                f"through {np.round(self.site, 6).tolist()} along {list(a.direction)})")
        return self.site + t * self.d

    def push_now(self) -> float:
        """The tip's current position (mm along its direction from its start)."""
        return float((np.asarray(self.q.value) - self.q0) @ self.d)

    def _assemble(self, e, w_area) -> float:
        self._e.value = e
        self._w_area.value = w_area
        return self.comm.allreduce(dolfinx.fem.assemble_scalar(self._report_form), op=MPI.SUM)

    def surface_penetration(self, u_vertices) -> float:
        """Deepest point (mm) of the contact surface's deformed facets inside the tip, sampled
        at SURFACE_SAMPLES points per facet: the penalty acts at the nodes only, so a tip
        narrower than the facets can slip between nodes; then this exceeds the nodal
        ``max_penetration`` by far."""
        if not len(self.surface):
            return 0.0
        gdim = len(self.d)
        y = np.asarray(u_vertices, float).reshape(-1, gdim) + self._X
        pts = np.einsum("sk,fkd->fsd", _facet_samples(self.surface.shape[1]),
                        y[self.surface]).reshape(-1, gdim)
        o = np.asarray(self.q.value) - self.shape.edge * self.d
        return float(max(np.max(-self.shape.gap(pts, o, self.d), initial=0.0), 0.0))

    def report(self, u_array, u_vertices=None) -> dict:
        """Force, area and penetration at the solver's current state (module docstring);
        ``u_vertices`` ((n, gdim), mm, Case numbering) adds the facet check."""
        gdim = len(self.d)
        eye = np.eye(gdim)
        f = np.array([self._assemble(eye[i], 0.0) for i in range(gdim)])
        area = self._assemble(np.zeros(gdim), 1.0)
        y = self.x_nodes + u_array.reshape(-1, gdim)[self.dofs]
        o = np.asarray(self.q.value) - self.shape.edge * self.d
        pen = float(np.max(-self.shape.gap(y, o, self.d), initial=0.0))
        pen = max(self.comm.allreduce(pen, op=MPI.MAX), 0.0)
        return {"push": self.push_now(), "force": float(f @ self.d),
                "force_vector": [float(v) for v in f], "contact_area": float(area),
                "max_penetration": pen, "penalty_beta": self.beta,
                "penalty": [float(self.beta * self.E.value / h) for h in self.h_range[::-1]],
                "tip": self.actuator.tip, "contact": self.actuator.contact,
                "tip_start": [float(v) for v in self.q0],
                **self._slip_check(u_vertices, pen)}

    def _slip_check(self, u_vertices, nodal_pen) -> dict:
        if u_vertices is None:
            return {}
        deep = self.surface_penetration(u_vertices)
        through = deep > max(SLIP_FRACTION * self.shape.radius, 10.0 * nodal_pen)
        return {"surface_penetration": deep, "tip_through_surface": bool(through)}


class Contact:
    """The contact of a Case's indenters on a ReferenceSolver: ``energy`` (UFL, 0 without
    indenters) joins the solver's energy; ``ramps`` moves the tips with the load stepping;
    ``extra`` reports them; ``accepts`` is Newton's line search with indenters. penalty: beta,
    the ``contact_penalty`` (module docstring); quadrature_degree: a Gauss rule of that degree
    for the contact integrals instead of the nodal rule (for comparisons; it locks at P2)."""

    def __init__(self, solver, case: Case, *, penalty: float = DEFAULT_CONTACT_PENALTY,
                 quadrature_degree: int | None = None):
        if not (isinstance(penalty, (int, float)) and np.isfinite(penalty) and penalty > 0):
            raise CaseError(f"contact_penalty must be a finite number > 0, got {penalty!r}")
        self.solver = solver
        self.comm = solver.comm
        self._total, self._energy = None, 0.0
        self.key = contact_key(case)
        self.indenters: list[_Indenter] = []
        self.energy = 0
        if not self.key:
            return
        mesh = solver.dm.mesh
        if quadrature_degree is None:
            pts, wts = nodal_rule(solver.gdim - 1, solver.degree)
            md = {"quadrature_rule": "custom", "quadrature_degree": 1,
                  "quadrature_points": pts.tolist(), "quadrature_weights": wts.tolist()}
        else:
            md = {"quadrature_degree": quadrature_degree}
        ds = ufl.Measure("ds", domain=mesh, subdomain_data=solver.dm.facet_tags, metadata=md)
        X = ufl.SpatialCoordinate(mesh)
        for a in case.indenters():
            ind = _Indenter(a, solver, case, penalty, ds, X, solver.u_ufl, self._cell_sizes())
            self.indenters.append(ind)
            self.energy = self.energy + ind.energy

    def _cell_sizes(self):
        """h (mm): the longest edge of each cell (between its vertices), a DG0 Function."""
        if getattr(self, "_h", None) is None:
            mesh = self.solver.dm.mesh
            tdim = mesh.topology.dim
            V0 = dolfinx.fem.FunctionSpace(mesh, ("DG", 0))
            x = mesh.geometry.x[:, :self.solver.gdim]
            n_cells = mesh.topology.index_map(tdim).size_local + \
                mesh.topology.index_map(tdim).num_ghosts
            geo = mesh.geometry.dofmap.array.reshape(n_cells, -1)[:, :tdim + 1]
            v = x[geo]
            h = np.max([np.linalg.norm(v[:, i] - v[:, j], axis=1)
                        for i in range(tdim + 1) for j in range(i)], axis=0)
            self._h = dolfinx.fem.Function(V0)
            self._h.x.array[V0.dofmap.list.array.reshape(n_cells, -1)[:, 0]] = h
        return self._h

    def ramps(self, case: Case, ramps: list, initial=None) -> float:
        """Append (tip position, start, full) per indenter to the load stepping's ``ramps``
        (its Dirichlet ramps: value = start + fraction (full - start)); returns the largest tip
        travel (mm). The start is the push of ``initial`` (a SolveResult that reports it), else
        where the last solve left the tip for a warm start, else push 0."""
        if contact_key(case) != self.key:
            raise CaseError(f"{case.source or case.name}: the indenters differ from those this "
                            f"solver was built with; build a new ReferenceSolver")
        span = 0.0
        for ind in self.indenters:
            full_push = case.actuator(ind.name).push
            start_push = 0.0
            if isinstance(initial, SolveResult):
                start_push = initial.extra.get("indenters", {}).get(ind.name, {}).get(
                    "push", ind.push_now())
            elif initial is not None:
                start_push = ind.push_now()
            ramps.append((ind.q.value, ind.q0 + start_push * ind.d, ind.q0 + full_push * ind.d))
            # the load stepping's first increments move a tip by at most STEP_FRACTION of its
            # radius (each increment changes the contact set a little: fewer Newton iterations)
            limit = STEP_FRACTION * ind.shape.radius
            span = max(span, abs(full_push - start_push)
                       * max(1.0, self.solver.settings.max_step_mm / limit))
        return span

    def line_search_energy(self, total):
        """Compile the solver's total energy (UFL, uJ) for ``accepts`` (with indenters, in the
        displacement formulation, whose answer minimizes it)."""
        if self.indenters and self.solver.formulation == "displacement":
            self._total = dolfinx.fem.form(total)

    def accepts(self, r_new: float, r_old: float, forced: bool) -> bool:
        """Newton's line search with indenters: is the correction just tried (the solver's
        current state) taken, or halved? Taken when it lowers the total energy (uJ; the
        residual norm r_new < r_old (mN) in the mixed formulation, a saddle point), or when
        ``forced`` (the first correction of a load step, which also moves the Dirichlet values,
        and the last halving). A node sliding along a curved tip leaves it by s^2 / (2 R) at
        second order, which the stiff penalty turns into a large residual, so the residual norm
        would refuse steps that the energy takes. Without indenters every correction is taken."""
        if not self.indenters:
            return True
        if self._total is None:
            return forced or r_new < r_old
        energy = self.comm.allreduce(dolfinx.fem.assemble_scalar(self._total), op=MPI.SUM)
        if forced or energy <= self._energy + 1e-12 * abs(self._energy):
            self._energy = energy
            return True
        return False

    def extra(self, u_vertices=None) -> dict:
        """{"indenters": {name: report}} at the solver's current state; {} without indenters.
        With the vertex field ``u_vertices`` each report has the facet check, and a tip that
        passed between the surface's nodes makes the state invalid (``through_surface``)."""
        if not self.indenters:
            return {}
        arr = self.solver.u.x.array
        return {"indenters": {ind.name: ind.report(arr, u_vertices) for ind in self.indenters}}
