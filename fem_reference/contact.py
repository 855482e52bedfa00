"""Rigid indenters in contact with the skin: UFL penalty forms for the reference.

Units: length mm, stress kPa (= mN/mm^2), force mN, energy uJ, penalty stiffness kPa/mm.

Geometry. An indenter (``model.case.Actuator`` of type "indenter") is a rigid rod of radius
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
ignored). The first point of contact with the body it meshes generally lies between nodes, so the
tip starts deeper than on that body by up to the surface's sag between nodes, differently on
every mesh (the indenter phantom's 8 mm tip: 0.0002-0.019 mm, up to 0.55 % of its force at 5 mm;
bench/bench_tip_start.py); ``tip_start = "surface"`` starts it where it first touches the
facets as the geometry curves them instead (``TIP_STARTS``). Each start goes with a contact rule
and is its default (``model.case.tip_start_for``): the nodal rule knows the gap only at the
nodes, so a tip started on the surface would travel through the skin until it reached one; a
Gauss rule samples the facets' interiors, so a tip started on the nodes would start inside
them, pressing at rest. A push p (mm) moves it to
q = q0 + p d. An indenter that is not pushed stays at its start: a rigid obstacle the skin may
press against (a negative push retracts it).

Method: a node-to-surface penalty added to the energy that the reference minimizes,

    Pi_c = int_Gamma_c  k phi(-g) dA                                  (frictionless)
         + int_Gamma_c  k/2 H(eps - g) |(I - n n)(u - (q - q0))|^2 dA  (tied: no slip)

integrated by default with one point per displacement node of the surface (``nodal_rule``: the
lumped rule of the P1 facets through the nodes, so the penalty constrains each node once), or
with a Gauss rule on each facet (``contact_quadrature`` of ReferenceSolver: its degree).

Which rule (bench/bench_contact_rule.py, quarter block, P2, beta = 1e3). Shallow: Gauss points
sample the gap more often than a P2 skin has nodes and stiffen the contact a little: Hertz
force +1.11 / +0.84 / +0.74 % at h = 0.5 / 0.35 / 0.25 mm against the nodal rule's +0.47 /
+0.43 / +0.61 % (degree 2; about 0.4 % of each is the block's fixed bottom). Deep: the nodal
rule knows the gap only at the nodes, so the skin's facets can bulge into the tip between them.
Past about two tip radii the exact tangent gains a negative eigenvalue whose mode moves a few
skin nodes under the tip's front along it, and Newton stops: a ball-ended rod R = 1 mm stops at
2.41 R on 0.3 mm cells, R = 0.5 mm at 2.0 R (the same cells, twice as coarse relative to the
tip), R = 1.5 mm at 2.89 R. A Gauss rule of degree 2 penalizes the facets' interiors too and
goes to 3 R in a few Newton iterations per step, the work of the tip's force then equal to the
stored strain energy within 0.4 % (tests/test_contact_rule.py).
A Gauss rule needs a contact wider than the cells under it: on cells of twice the Hertz
contact radius the degree-2 rule's force is +22 % (degree 4: -6.7 %; nodal +0.17 %), on cells
of 1-1.5 contact radii +3.5-4.3 % (nodal +3.1-3.2 %); a solve with a Gauss rule warns when a
contact is narrower than GAUSS_NARROW times its cells. So the nodal rule is the default of a
case that names no rule, for shallow pushes on coarse cells, and a push past about two tip
radii asks for the Gauss rule (``failure_hint``); the indenter phantom's cases, whose path
cells are finer than their tips' contact from about 0.3 mm of push, name the Gauss rule.
Deeper than UNCONVERGED_RADII (2.5) of its radius a rounded tip has no mesh-converged answer
known (the indenter phantom's 5 mm tips at 15 mm part from level to level): a solve there warns
that its answer has no error bar.
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
halved (``accepts``), and each load increment moves a tip by at most
``NewtonSettings.tip_step`` of its radius (``ramps``); failed steps are cut back as usual. The
steps before the last end once their residual has fallen 100-fold
(``NewtonSettings.contact_intermediate_rtol``), mostly after their first correction, the
tangent's predictor of the tips' increment: the corrections after it are cut short while the
contact set moves, and only the last step's state is the answer.
A load step that moves the tips but no Dirichlet value tests its first correction on the
energy too (with the tips where the step puts them): the tangent at the step's start does not
see a tip that has moved away, and a tip retracted from a pressed skin would otherwise have its
first correction spring the skin back through it, taken whole.
Curvilinear trials (``NewtonSettings.follow_tips``, off by default). Newton's correction is a
straight line, but a node pressed on a convex tip slides along a curve: moved by s along the
tip's tangent it leaves the surface by about s^2 / (2 R), which the stiff penalty charges as a
penetration the tangent never predicted. On the indenter phantom such slides of a few tenths of
a millimetre cost the last load step a see-saw of halved corrections (the exact tangent
overshooting twice, the one without the tip's curvature undershooting). With the setting each
trial is also bent along the tips (``follow_tips``, a second-order correction of the step): a
contact node inside a tip where the correction starts, and still inside by its linearization
g(y0) + n(y0).(y1 - y0), is moved along the tip's normal at its trial position to that
linearized gap (O(|du|^2), so Newton keeps its quadratic convergence; the discrete problem is
unchanged), and the line search tries the bent or the straight trial, whichever has the lower
energy (skin that a retracting tip releases leaves it along the straight line). Quarter indenter
phantom, P2, four tips from rest: 37 -> 31 Newton iterations at 10 mm, 52 -> 47 at 12.5 mm, 19
at 5 mm either way (bench/bench_indenter_newton.py --settings default bent).
Newton's matrix leaves the tips' curvature term out of the penalty's Hessian
(``tangent_without_curvature``, positive semi-definite) while the residual is far above its
converged size (``NewtonSettings.contact_curvature_below``) and after a halved correction; the
exact tangent returns near the answer, so the last iterations converge quadratically and the
exported tangent is exact. Far from the answer the curvature of a tip that skin nodes sit deep
in makes the corrections long, and the line search cut them to 1/16-1/128 of their length.
Under several tips the tissue crushed against them makes the tangent indefinite (negative pivots
in its factorization) and the corrections huge: such a correction is solved again without the
curvature, then with a Levenberg-Marquardt shift (``NewtonSettings.descent_shift``).

Each solve reports, per indenter, in ``SolveResult.indenters[name]``: ``push`` (mm),
``force`` (mN, the actuator force along its direction: the total force the tip exerts on the
skin, which the supports balance), ``force_vector`` (mN, that force; the same sign convention as
``SolveResult.reactions``), ``contact_area`` (mm^2: the reference area lumped to the surface
nodes with g < 0; it resolves the contact edge to about a cell), ``max_penetration`` (mm: max of
-g over those nodes), ``penalty_beta`` and ``penalty`` ([min, max] of k over the cells along
Gamma_c, kPa/mm), ``quadrature`` (the contact rule), ``tip``, ``contact`` and ``tip_start`` (q0,
mm). The exported tangent (``ReferenceSolver.tangent``) uses the tips where the last solve left
them.

Where it lives: ``fem_reference.contact_geometry`` (the tip's shape and gap, ``nodal_rule``),
``fem_reference.contact_indenter`` (one indenter's forms, start position and report, with the
surface-penetration check) and this module (``Contact``: the indenters of a Case on a
ReferenceSolver, the load stepping's tip ramps and the line search; ``contact_key``).
"""
from __future__ import annotations

from dataclasses import replace

import dolfinx
import dolfinx.fem
import numpy as np
import ufl
from mpi4py import MPI

from tissue_reference.errors import CaseError
from tissue_reference.model.case import CONTACT_RULES, TIP_STARTS, Case, is_contact_rule
from tissue_reference.model.converged_range import UNCONVERGED_RADII, past_converged_depth
from tissue_reference.model.results import SolveResult
from tissue_reference.model.tips import DEFAULT_CONTACT_PENALTY

from .contact_geometry import TipShape, gap_ufl, nodal_rule  # noqa: F401  (re-exported)
from .contact_indenter import (  # noqa: F401  (re-exported)
    SLIP_FRACTION,
    SURFACE_SAMPLES,
    Indenter,
    facet_sample_points,
)
from .jit import compile_form
from .newton_settings import NewtonSettings

__all__ = ["DEFAULT_CONTACT_PENALTY", "Contact", "TipShape", "contact_key", "nodal_rule"]

DEEP_RADII = 1.8
"""Depth (in tip radii) past which a failed solve with the nodal rule names the contact rule as
a likely cause: a ball-ended rod stops at 2.0-2.9 radii on cells of 0.6-0.2 radii."""


GAUSS_NARROW = 0.75
"""A Gauss contact rule warns when an indenter's contact radius is below this fraction of the
longest edge of the cells in contact."""


def contact_key(case: Case) -> tuple:
    """What the compiled contact forms depend on: the Case's indenters without their pushes."""
    return tuple(replace(a, push=0.0) for a in case.indenters())


class Contact:
    """The contact of a Case's indenters on a ReferenceSolver: ``energy`` (UFL, 0 without
    indenters) joins the solver's energy; ``ramps`` moves the tips with the load stepping;
    ``extra`` reports them; ``accepts`` is Newton's line search. penalty: beta, the
    ``contact_penalty`` (module docstring); quadrature: "nodal" (``nodal_rule``) or the degree
    (int) of a Gauss rule on each facet for the contact integrals (module docstring);
    tip_start: where each tip starts, "nodes" or "surface" (``TIP_STARTS``).

    What it works on, the solver's: ``comm``; ``dm`` (``dolfinx_mesh.DolfinxMesh``: the mesh,
    its facet tags and regions); ``gdim`` and ``degree`` (of the displacement); ``V`` (the
    displacement's space) and ``u`` (the displacement Function on it, which the reports read);
    ``u_ufl`` (the displacement in the forms: ``u``, or the mixed unknown's part); ``E`` (the
    material's Constant, kPa); ``formulation`` ("displacement" or "mixed")."""

    def __init__(self, case: Case, *, comm, dm, gdim: int, degree: int, V, u, u_ufl, E,
                 formulation: str, penalty: float = DEFAULT_CONTACT_PENALTY,
                 quadrature: str | int = "nodal", tip_start: str = "nodes"):
        if not (isinstance(penalty, (int, float)) and np.isfinite(penalty) and penalty > 0):
            raise CaseError(f"contact_penalty must be a finite number > 0, got {penalty!r}")
        if not is_contact_rule(quadrature):
            raise CaseError(f"contact_quadrature must be {CONTACT_RULES}, got {quadrature!r}")
        if tip_start not in TIP_STARTS:
            raise CaseError(f"tip_start must be one of {list(TIP_STARTS)}, got {tip_start!r}")
        self.quadrature = quadrature
        self.comm, self.dm, self.gdim, self.formulation = comm, dm, gdim, formulation
        self._u_field = u
        self._total, self._energy, self._refresh = None, 0.0, None
        self.key = contact_key(case)
        self.indenters: list[Indenter] = []
        self.energy = 0
        self.normal_energy = 0
        if not self.key:
            return
        mesh = dm.mesh
        if quadrature == "nodal":
            pts, wts = nodal_rule(gdim - 1, degree)
            md = {"quadrature_rule": "custom", "quadrature_degree": 1,
                  "quadrature_points": pts.tolist(), "quadrature_weights": wts.tolist()}
        else:
            md = {"quadrature_degree": quadrature}
        ds = ufl.Measure("ds", domain=mesh, subdomain_data=dm.facet_tags, metadata=md)
        X = ufl.SpatialCoordinate(mesh)
        for a in case.indenters():
            ind = Indenter(a, case, penalty, ds, X, u_ufl, self._cell_sizes(), tip_start,
                           comm=comm, dm=dm, gdim=gdim, V=V, u_field=u, E=E)
            self.indenters.append(ind)
            self.energy = self.energy + ind.energy
            self.normal_energy = self.normal_energy + ind.normal_energy

    def follow_tips(self, trial: np.ndarray, start: np.ndarray, umap: np.ndarray) -> bool:
        """Bend Newton's straight trial along the tips, in place (module docstring,
        "Curvilinear trials"); energy line search only (``energy_search``).

        Parameters
        ----------
        trial : ndarray
            The unknown's values at the trial (the owned displacement dofs of the contact
            surfaces change; the caller updates the ghosts).
        start : ndarray
            The unknown's values where the correction starts.
        umap : ndarray
            The unknown's dof of each displacement dof (``Newton.umap``).

        Returns
        -------
        bool
            Whether any node moved.
        """
        if not self.energy_search:
            return False
        moved = False
        for ind in self.indenters:
            idx = umap[ind.dofs[:, None] * self.gdim + np.arange(self.gdim)]
            shift = ind.curvilinear_shift(ind.x_nodes + start[idx], ind.x_nodes + trial[idx])
            if np.any(shift):
                trial[idx] += shift
                moved = True
        return moved

    def tangent_without_curvature(self, v, w):
        """Newton's iteration matrix for the contact after a halved correction (UFL bilinear
        form, or None without indenters): the normal penalties' Hessians less the tips'
        curvature terms (``Indenter.tangent_without_curvature``). Away from the answer a node
        pressed deep into a convex tip makes the exact tangent indefinite and its corrections
        huge; this part is positive semi-definite. Subtract ``normal_energy``'s own Hessian
        from the exact tangent to use it."""
        if not self.indenters:
            return None
        return sum((ind.tangent_without_curvature(v, w) for ind in self.indenters[1:]),
                   self.indenters[0].tangent_without_curvature(v, w))

    def _cell_sizes(self):
        """h (mm): the longest edge of each cell (between its vertices), a DG0 Function."""
        if getattr(self, "_h", None) is None:
            mesh = self.dm.mesh
            tdim = mesh.topology.dim
            V0 = dolfinx.fem.FunctionSpace(mesh, ("DG", 0))
            x = mesh.geometry.x[:, :self.gdim]
            n_cells = mesh.topology.index_map(tdim).size_local + \
                mesh.topology.index_map(tdim).num_ghosts
            geo = mesh.geometry.dofmap.array.reshape(n_cells, -1)[:, :tdim + 1]
            v = x[geo]
            h = np.max([np.linalg.norm(v[:, i] - v[:, j], axis=1)
                        for i in range(tdim + 1) for j in range(i)], axis=0)
            self._h = dolfinx.fem.Function(V0)
            self._h.x.array[V0.dofmap.list.array.reshape(n_cells, -1)[:, 0]] = h
        return self._h

    def ramps(self, case: Case, ramps: list, initial=None, *,
              settings: NewtonSettings) -> float:
        """Append (tip position, start, full) per indenter to the load stepping's ``ramps``
        (its Dirichlet ramps: value = start + fraction (full - start)); returns the largest tip
        travel (mm), scaled so that the solve's ``settings`` (``max_step_mm``, ``tip_step``)
        give each tip its increments. The start is the push of ``initial`` (a SolveResult that
        reports it), else where the last solve left the tip for a warm start, else push 0."""
        if contact_key(case) != self.key:
            raise CaseError(f"{case.source or case.name}: the indenters differ from those this "
                            f"solver was built with; build a new ReferenceSolver")
        span = 0.0
        for ind in self.indenters:
            full_push = case.actuator(ind.name).push
            start_push = 0.0
            if isinstance(initial, SolveResult):
                start_push = initial.indenters.get(ind.name, {}).get(
                    "push", ind.push_now())
            elif initial is not None:
                start_push = ind.push_now()
            ramps.append((ind.q.value, ind.q0 + start_push * ind.d, ind.q0 + full_push * ind.d))
            # each load increment moves a tip by at most settings.tip_step of its radius (each
            # then changes the contact set a little)
            limit = settings.tip_step * ind.shape.radius
            span = max(span, abs(full_push - start_push)
                       * max(1.0, settings.max_step_mm / limit))
        return span

    def line_search_energy(self, total, refresh=None):
        """Compile the solver's total energy (UFL, uJ) for ``accepts`` (with indenters, in the
        displacement formulation, whose answer minimizes it). ``refresh``: called with no
        argument before each assembly of it (``ReferenceSolver.refresh_fields``: the
        quadrature-point Functions of the Ogden law); None: the energy reads the unknown
        alone."""
        self._refresh = refresh
        if self.indenters and self.formulation == "displacement":
            self._total = compile_form(total)

    @property
    def energy_search(self) -> bool:
        """Whether Newton's line search tests the total energy (indenters, displacement
        formulation): the slope and the interpolated step lengths of ``Newton.iterate`` then
        apply."""
        return self._total is not None

    def total_energy(self, extra_energy: float = 0.0) -> float:
        """The total energy (uJ) at the solver's current state plus ``extra_energy`` (uJ: that
        of the terms Newton adds to the solver's, e.g. the inertia of a dynamics time step,
        ``Newton.iterate``'s ``extra_terms``); kept as ``trial_energy``. Energy line search
        only (``energy_search``)."""
        if self._refresh is not None:
            self._refresh()
        energy = self.comm.allreduce(dolfinx.fem.assemble_scalar(self._total), op=MPI.SUM)
        energy += extra_energy
        self.trial_energy = energy
        return energy

    def lowers(self, energy: float) -> bool:
        """Whether a trial of total energy ``energy`` (uJ) is not above the state last taken
        (to 1e-12 of it): what ``accepts`` takes when the step is not forced."""
        return energy <= self._energy + 1e-12 * abs(self._energy)

    def accepts(self, r_new: float, r_old: float, forced: bool,
                energy: float | None = None, *, residual: bool = False) -> bool:
        """Newton's line search: is the correction just tried (the solver's current state)
        taken, or shortened? With indenters: taken when it lowers the total energy (uJ; the
        residual norm r_new < r_old (mN) in the mixed formulation, a saddle point), or when
        ``forced`` (the first correction of a load step that also moves the Dirichlet values,
        and the shortest step). A node sliding along a curved tip leaves it by s^2 / (2 R) at
        second order, which the stiff penalty turns into a large residual, so the residual norm
        would refuse steps that the energy takes. Without indenters every correction is taken,
        or with ``residual`` only one that lowers the residual norm (r_new < r_old) or is
        ``forced`` (a warm start's line search, ``transfer.warm_settings``).
        ``accepted_energy`` is then the taken state's energy and ``trial_energy`` the one just
        tried (``total_energy``; ``energy``: that of the current state, already computed with
        any extra terms' energy; None: computed here, without them)."""
        if not self.indenters:
            return (forced or r_new < r_old) if residual else True
        if self._total is None:
            return forced or r_new < r_old
        if energy is None:
            energy = self.total_energy()
        if forced or self.lowers(energy):
            self._energy = energy
            return True
        return False

    @property
    def accepted_energy(self) -> float:
        """The total energy (uJ) of the state the line search last took."""
        return self._energy

    def failure_hint(self) -> str:
        """Why a solve that stopped with the tips where they are may have stopped, for its
        error message: with the nodal rule, a tip deeper than DEEP_RADII of its radii (the
        discrete equilibrium there can turn unstable: module docstring); "" otherwise."""
        if self.quadrature != "nodal":
            return ""
        deep = [f"{ind.name} ({ind.push_now() / ind.shape.radius:.2f})" for ind in self.indenters
                if ind.push_now() > DEEP_RADII * ind.shape.radius]
        if not deep:
            return ""
        return (f"; indenter tips deeper than {DEEP_RADII:g} of their radii: "
                f"{', '.join(deep)}. With the nodal contact rule the skin's facets bulge into a tip "
                f"that deep and the discrete equilibrium can turn unstable (docs/verification.md, "
                f"Known limits): a Gauss rule holds it ([reference] contact_quadrature = 2, or "
                f"contact_quadrature=2)")

    def unconverged(self) -> list[str]:
        """One line per indenter deeper than UNCONVERGED_RADII of its radius, where no
        mesh-converged answer is known; [] when none is."""
        out = []
        for ind in self.indenters:
            depth, radius = ind.push_now(), ind.shape.radius
            if past_converged_depth(depth, radius):
                out.append(f"indenter {ind.name}: {depth / radius:.2f} radii deep ({depth:.3g} "
                           f"mm, tip radius {radius:.3g} mm): past {UNCONVERGED_RADII:g} radii "
                           f"no mesh-converged answer is known (on the indenter phantom the "
                           f"refinement levels part by 2-5 % at 3 radii, the skin slid over "
                           f"the buried tip: docs/verification.md, \"Indenters at 15 mm\"); "
                           f"this answer has no error bar. A wider tip converges "
                           f"(meshes/cases/phantom-indenter-wide.toml at 15 mm)")
        return out

    def warnings(self) -> list[str]:
        """The ``unconverged`` lines and, with a Gauss rule, one per indenter whose contact is
        narrower than the cells under it (``Indenter.contact_width``: radius below GAUSS_NARROW
        x their longest edge), where the rule over-constrains the skin (module docstring); []
        when neither."""
        out = self.unconverged()
        for ind in self.indenters:
            if self.quadrature == "nodal":
                continue
            a, h = ind.contact_width()
            if 0.0 < a < GAUSS_NARROW * h:
                out.append(f"indenter {ind.name}: contact radius {a:.2f} mm is narrower than the "
                           f"cells under the tip ({h:.2f} mm): a Gauss contact rule "
                           f"over-constrains such a contact (Hertz force +22 % on cells twice "
                           f"the contact radius); the nodal rule is the accurate one for "
                           f"shallow pushes, or refine the site")
        return out

    def extra(self) -> dict:
        """{"indenters": {name: report}} at the solver's current state; {} without indenters.
        Each report has the facet check: a tip that passed between the surface's nodes makes
        the state invalid (``through_surface``)."""
        if not self.indenters:
            return {}
        arr = self._u_field.x.array
        return {"indenters": {ind.name: {**ind.report(arr), "quadrature": self.quadrature}
                              for ind in self.indenters}}
