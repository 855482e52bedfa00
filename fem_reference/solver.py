"""The ground-truth solver: the Case's energy as a UFL form (displacement, or mixed u-p for
nearly incompressible tissue), PETSc Newton, load stepping with automatic cut-back, converged
reason checked every step.

Units: mm, kPa, mN. Serial or under ``mpirun``; every array returned is in the Case's vertex
numbering and identical on all ranks.

    ref = ReferenceSolver(case, degree=2)     # forms compiled once
    res = ref.solve(pushes={"A1": 15.0})      # SolveResult
    tan = ref.tangent(res)                    # exact tangent K as scipy CSR

This module holds the solver's spaces and load stepping (``ReferenceSolver.solve``).
The solver owns one object per concern, each in a module of its own: ``state``
(``outputs_state.NodalState``: the fields' numbering, states in and out), ``boundary``
(``boundary.Boundary``: Dirichlet conditions), ``contact`` (``contact.Contact``: rigid tips),
``linear`` (``linalg.LinearSolver``: factorizations and Krylov solves; the mixed
formulation's fieldsplit in ``saddle``) and ``newton`` (``newton.Newton``: iterations at a fixed
load and the assembly they iterate on; settings in ``newton_settings``). What it hands out is
``outputs`` (the SolveResult, probes, reactions, discretization) and ``outputs_tangent`` (the
exact tangent and internal forces), functions of a solver. The energy densities are ``forms``;
``energy_forms`` assembles them, with the loads and penalties, into the Constants, the total
energy and the compiled residual and tangent the solver iterates on; the defaults (degree,
formulation, quadrature) are ``discretization``'s. ``kept`` keeps solvers for reuse and
``answer`` composes the one-call ``solve``; ``petsc_memory`` frees a solver's PETSc memory
(``close``).
"""
from __future__ import annotations

import logging
import sys
import time
from dataclasses import replace

import dolfinx
import dolfinx.fem
import dolfinx.fem.petsc
import numpy as np
import ufl
from mpi4py import MPI
from petsc4py import PETSc

from tissue_reference.errors import CaseError, ConvergenceError
from tissue_reference.model.case import Case
from tissue_reference.model.results import SolveResult
from tissue_reference.model.tips import default_contact_rule, default_tip_start

from .boundary import Boundary
from .contact import DEFAULT_CONTACT_PENALTY, Contact
from .discretization import (
    DEFAULT_QUADRATURE,
    FORMULATIONS,
    MIXED_FROM_NU,
    checked_degree,
    geometry_order,
    resolve_formulation,
)
from .dolfinx_mesh import DolfinxMesh, to_dolfinx
from .energy_forms import (
    compile_forms,
    external_work,
    internal_energy,
    material_constants,
    measures,
    oblique_sliding_penalty,
)
from .factor import has_cholmod
from .linalg import LinearSolver, choose_linear_solver
from .logs import install_log_filters
from .newton import Newton
from .newton_settings import NewtonSettings, Timings
from .outputs import discretization, solve_result
from .outputs_state import NodalState
from .outputs_tangent import Tangent, internal_forces, tangent
from .petsc_memory import release_petsc_garbage
from .saddle import FieldSplit

__all__ = [
    "DEFAULT_QUADRATURE",
    "FORMULATIONS",
    "MIXED_FROM_NU",
    "NewtonSettings",
    "ReferenceSolver",
    "Tangent",
    "resolve_formulation",
]

log = logging.getLogger("tissue.fem")
install_log_filters()

class ReferenceSolver:
    """Neo-Hookean / linear-elastic reference on one Case mesh; build once, solve many times.

    Parameters
    ----------
    case : Case
        the Case (mesh, material, boundaries, probes).
    degree : int or None
        Lagrange degree of the displacement, 1, 2 or 3 (the mixed formulation is
        Taylor-Hood: pressure one degree lower, so degree >= 2); None: the case's
        ``reference_degree``, else 2 for mixed, 1 for displacement (``default_degree``).
    formulation : str
        "displacement" (the energy of u alone), "mixed" (u-p perturbed Lagrangian,
        see ``forms``: locking-free up to the incompressible limit nu = 0.5) or "auto" (mixed
        from nu >= MIXED_FROM_NU).
    quadrature_degree : int or None
        override DEFAULT_QUADRATURE[degree].
    settings : NewtonSettings or None
        NewtonSettings: Newton's and the load stepping's controls; None: the defaults.
    comm : MPI communicator
        MPI communicator (default ``MPI.COMM_WORLD``).
    sliding_penalty : float
        factor beta of the oblique-sliding penalty (beta * E / h_min per mm^2).
    body_force : callable or None
        optional callable x -> UFL vector (mN/mm^3) of the reference coordinates,
        added to gravity (used for manufactured solutions).
    linear_solver : str
        "direct" (MUMPS LDL^T of every Newton tangent), "lagged" (GMRES on the
        exact tangent, preconditioned by the factor of an earlier tangent, which is
        refactorized only when GMRES needs more than ``settings.lag_max_its`` iterations),
        "iterative" (CG + GAMG with rigid-body near null space, MUMPS fallback; displacement
        formulation only), "fieldsplit" (FGMRES with a Schur-complement fieldsplit
        preconditioner: AMG on the displacement block, the scaled pressure mass matrix on the
        Schur complement; MUMPS fallback; mixed formulation only) or "auto" ("lagged" above
        LAGGED_ABOVE_DOFS dofs, "direct" below and with indenters; the mixed formulation
        "fieldsplit" above FIELDSPLIT_ABOVE_DOFS).
    curved : bool or None
        isoparametric (second-order) geometry from the mesh's curved edges (the builtin
        curved bodies and any order-2 .msh carry them). None: curved at degree >= 2 when the
        mesh has them (at degree 1 the straight cells the fast solvers use); False: straight.
    contact_penalty : float
        beta of the indenters' contact penalty k = beta E / h (kPa/mm, h the
        cell size; see ``contact``: the penetration (p_c / E + 1/2) h / beta, mm, is the
        method's error).
    contact_quadrature : str or int or None
        where the contact penalty is sampled: "nodal" (one point per
        displacement node of the skin) or an int, a Gauss rule of that degree on each skin
        facet, which also penalizes the facets' interiors; None: the case's (``[reference]
        contact_quadrature``), else "nodal". The nodal rule is the more accurate for shallow
        pushes, a Gauss rule holds the skin on a tip pushed deeper than about two of its
        radii (``contact``).
    tip_start : str or None
        where each indenter starts: "nodes", touching the skin's displacement nodes,
        or "surface", touching the skin's facets as the geometry curves them, which the
        first contact with the meshed body generally lies between (``contact``); None: the
        case's (``[reference] tip_start``), else "nodes" with the nodal contact rule and
        "surface" with a Gauss rule (``default_tip_start``).

    Raises
    ------
    CaseError
        For a degree other than 1, 2 or 3 (or 1 with the mixed formulation), nu = 0.5 without
        the mixed formulation, ``curved=True`` on a mesh with no curved edges, or a linear
        solver that does not fit the formulation or the material.
    """

    def __init__(self, case: Case, *, degree: int | None = None, formulation: str = "auto",
                 quadrature_degree: int | None = None, settings: NewtonSettings | None = None,
                 comm=MPI.COMM_WORLD, sliding_penalty: float = 1e4, body_force=None,
                 linear_solver: str = "auto", curved: bool | None = None,
                 contact_penalty: float = DEFAULT_CONTACT_PENALTY,
                 contact_quadrature: str | int | None = None, tip_start: str | None = None):
        self.formulation = resolve_formulation(formulation, case.material)
        degree = checked_degree(case, self.formulation, degree, requested=formulation)
        t0 = time.perf_counter()
        self.case = case
        self.degree = degree
        self.comm = comm
        self.settings = settings or NewtonSettings()
        self.qdeg = quadrature_degree or DEFAULT_QUADRATURE[degree]
        self.geometry_order = geometry_order(case.mesh, curved, degree)
        self.dm: DolfinxMesh = to_dolfinx(case.mesh, comm, geometry_order=self.geometry_order)
        self.gdim = case.mesh.gdim
        self._spaces(self.dm.mesh, degree)
        # the material and the load scale as Constants: a changed E or load needs no
        # recompilation (``energy_forms``)
        self.constants = material_constants(self.dm.mesh, case.material)
        self.E, self.nu = self.constants.E, self.constants.nu
        self.inv_kappa, self.coefficients = self.constants.inv_kappa, self.constants.coefficients
        self.load = self.constants.load
        # the fields' numbering: dolfinx's nodes <-> the Case's vertices, states in and out
        self.state = NodalState(V=self.V, Q=self.Q, x=self.x, u=self.u, p=self.p, umap=self._umap,
                                pmap=getattr(self, "_pmap", None), dm=self.dm,
                                n_vertices=case.mesh.n_vertices, degree=degree, comm=comm,
                                material=case.material, inv_kappa=self.inv_kappa, qdeg=self.qdeg)
        # the energy's parts (``energy_forms``; the laws' densities: ``forms``)
        mesh, tags = self.dm.mesh, self.dm.region_tags
        dx, ds = measures(mesh, self.dm.facet_tags, self.qdeg)
        internal, self.fields, self._vol_form = internal_energy(
            case.material, self.formulation, self.constants, mesh=mesh, x=self.x, u=self.u_ufl,
            p=getattr(self, "p_ufl", None), quadrature_degree=self.qdeg, dx=dx)
        external, self.body, self.tractions = external_work(
            case, mesh=mesh, u=self.u_ufl, gdim=self.gdim, region_tags=tags,
            body_force=body_force, dx=dx, ds=ds)
        penalty, oblique = oblique_sliding_penalty(case, sliding_penalty, mesh=mesh,
                                                   u=self.u_ufl, load=self.load,
                                                   h_min=self.dm.h_min, region_tags=tags, ds=ds)
        # the Dirichlet conditions and the nodes of each facet region (``boundary``)
        self.boundary = Boundary(Wu=self.Wu, V=self.V, dm=self.dm, gdim=self.gdim,
                                 oblique=oblique, degree=degree,
                                 node_vertex=self.state.node_vertex,
                                 n_vertices=case.mesh.n_vertices,
                                 n_unknowns=len(self.x.x.array), umap=self._umap)
        self.contact = self._contact(case, contact_penalty, contact_quadrature, tip_start)
        # Newton's residual and tangent and the outputs' forms, compiled once
        f = compile_forms(internal, external, penalty + self.contact.energy, x=self.x, W=self.W,
                          load=self.load, formulation=self.formulation, fields=self.fields,
                          contact=self.contact, refresh=self.refresh_fields)
        self.energy_internal, self.R_ufl, self.R_int_ufl, self.K_ufl = \
            f.energy_internal, f.R_ufl, f.R_int_ufl, f.K_ufl
        self.R_form, self.R_int_form, self.K_form = f.R_form, f.R_int_form, f.K_form
        self.K_halved_form, self.W_form = f.K_halved_form, f.W_form
        n_dofs = self.W.dofmap.index_map.size_global * self.W.dofmap.index_map_bs
        self.linear_solver = choose_linear_solver(linear_solver, self.formulation, n_dofs,
                                                  bool(self.contact.indenters))
        self._linear_solve()
        self.newton = self._newton()
        self.timings.setup = time.perf_counter() - t0

    def _contact(self, case: Case, contact_penalty: float, contact_quadrature, tip_start):
        """The rigid indenters' contact (``contact.Contact``), with the contact rule and tip
        start the case's where not given (``default_contact_rule``, ``default_tip_start``).

        Parameters
        ----------
        case : Case
            The Case (its indenters).
        contact_penalty : float
            beta of the contact penalty k = beta E / h (kPa/mm).
        contact_quadrature : str or int or None
            "nodal" or a Gauss degree; None: the case's.
        tip_start : str or None
            "nodes" or "surface"; None: the case's for the rule.

        Returns
        -------
        Contact
            The indenters' contact: its energy (uJ), ramps and reports.
        """
        if contact_quadrature is None:
            contact_quadrature = default_contact_rule(case)
        return Contact(case, comm=self.comm, dm=self.dm, gdim=self.gdim, degree=self.degree,
                       V=self.V, u=self.u, u_ufl=self.u_ufl, E=self.E,
                       formulation=self.formulation, penalty=contact_penalty,
                       quadrature=contact_quadrature,
                       tip_start=tip_start or default_tip_start(case, contact_quadrature))

    def _linear_solve(self) -> None:
        """The tangent matrix ``A``, the residual vector ``b`` and Newton's linear solves
        (``linear``: ``linalg.LinearSolver`` in the mode ``linear_solver``), with the per-solve
        counters ``timings`` they share."""
        comm, linear_solver = self.comm, self.linear_solver
        # The tangent A is assembled as BAIJ (node blocks: about 2x faster insertion than AIJ)
        # and converted to SBAIJ, the upper half MUMPS's LDL^T reads, whenever it is factorized.
        # GAMG ("iterative") and the mixed space (no common block size) use AIJ.
        blocked = linear_solver != "iterative" and self.formulation == "displacement"
        self.A = dolfinx.fem.petsc.create_matrix(self.K_form, "baij" if blocked else "aij")
        self.b = dolfinx.fem.petsc.create_vector(self.R_form)
        # The tangent is symmetric (Dirichlet rows and columns are both zeroed).
        self.A.setOption(PETSc.Mat.Option.SYMMETRIC, True)
        fieldsplit = None
        if linear_solver == "fieldsplit":
            # FGMRES + Schur-complement fieldsplit (``saddle``), MUMPS as the fallback
            fieldsplit = FieldSplit(self.A, W=self.W, V=self.V, umap=self._umap, pmap=self._pmap,
                                    E=self.E, nu=self.nu, inv_kappa=self.inv_kappa, dm=self.dm,
                                    comm=comm)
        # serial "lagged": CHOLMOD's supernodal LL^T (METIS ordering) factorizes ~1.6x and
        # solves ~3x faster than MUMPS here; a tangent that is not positive definite switches
        # the solver to MUMPS LDL^T, which "direct" (exact solves of indefinite tangents),
        # the mixed formulation's saddle-point tangent and MPI runs always use ("direct" with
        # CHOLMOD first measured 0.88-1.14x on the contact cases: docs/figures.md).
        pkg = "cholmod" if linear_solver == "lagged" and comm.size == 1 and has_cholmod() \
            and self.formulation == "displacement" else "mumps"
        self.timings = Timings()   # per-solve counters, shared with the parts below
        self.linear = LinearSolver(self.A, self.b, self.du, mode=linear_solver, comm=comm,
                                   lag_max_its=self.settings.lag_max_its, V=self.V, package=pkg,
                                   fieldsplit=fieldsplit, timings=self.timings)

    def _newton(self) -> Newton:
        """Newton's iterations at a fixed load and the assembly they iterate on (``newton``).

        Returns
        -------
        Newton
            On the solver's unknown, forms, linear solves and contact.
        """
        return Newton(x=self.x, du=self.du, A=self.A, b=self.b, R_form=self.R_form,
                      K_form=self.K_form, K_halved_form=self.K_halved_form, E=self.E,
                      h_min=float(self.dm.h_min), linear=self.linear, contact=self.contact,
                      umap=self._umap, comm=self.comm, timings=self.timings,
                      refresh=self.refresh_fields)

    def set_material(self, material) -> None:
        """Give the forms ``material``'s values (the same law: E, nu, the volumetric modulus,
        the law's coefficients; the Ogden law's on its quadrature Functions)."""
        self.constants.set(material)
        if self.fields is not None:
            self.fields.set_material(material)

    def set_load_fraction(self, fraction: float) -> None:
        """Scale the external loads (gravity, body forces, tractions) by ``fraction`` (1: the
        case's loads in full)."""
        self.load.value = fraction

    def use_case(self, case: Case) -> None:
        """Make ``case`` this solver's Case: another Case on the same mesh and discretization
        (``kept.solver_for``), whose pushes and loads the next ``solve`` starts from."""
        if case.mesh is not self.case.mesh:
            raise CaseError("ReferenceSolver.use_case: the case mesh differs from the solver's "
                            "mesh")
        self.case = case

    def refresh_fields(self) -> None:
        """Bring the forms' quadrature-point Functions (the Ogden law's isochoric psi, P and A,
        ``ogden_fields``) to the unknown's current value; nothing for the other laws, whose
        forms read the unknown alone. Whatever assembles ``R_form``, ``R_int_form``, ``K_form``,
        ``K_halved_form`` or ``W_form`` calls it first (Newton's assembly and the contact line
        search through the hook they were given, the outputs directly)."""
        if self.fields is not None:
            self.fields.update()

    def close(self) -> None:
        """Free the solver's matrices, vectors and factorizations now; it cannot solve again.
        Collective: every rank calls it. Without it they are freed only at the process's end
        (petsc4py defers destroying them: ``petsc_memory``). Also ``with ReferenceSolver(...) as s:``."""
        if self.__dict__.get("_closed"):
            return
        mesh = self.dm.mesh   # holds its communicator (freed with it) through the cleanup
        comm = self.comm
        self.__dict__.clear()
        self._closed = True
        release_petsc_garbage(mesh.comm, comm)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def __getattr__(self, name):
        if self.__dict__.get("_closed"):
            raise RuntimeError(f"this ReferenceSolver was closed (its {name!r} is freed): "
                               f"build a new one")
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    def solve(self, pushes=None, *, case: Case | None = None, initial=None, dirichlet_override=None,
              progress: bool = False, cases_first=None, settings: NewtonSettings | None = None,
              extra_terms=None, residual_line_search: bool = False) -> SolveResult:
        """Solve ``case`` (default: the one given at construction) with ``pushes`` applied.

        Parameters
        ----------
        pushes : dict or None
            Actuator name -> push (mm) along its direction.
        case : Case or None
            The Case to solve, on the solver's mesh and with its material law; None: the one
            given at construction.
        initial : array_like or SolveResult or None
            Warm start: (n_vertices, gdim) in the Case numbering (at degree 2 the edge
            nodes start at the mean of their end vertices), the full (n_nodes, gdim) degree-2
            nodal state in Tangent node order, or a previous SolveResult of a reference solve on
            this mesh (degree 2: its full nodal state); the load path starts from the case's
            prescribed values at fraction 0 scaled from there.
        dirichlet_override : tuple or None
            (dofs, values): extra per-vertex prescriptions (node-major Case dofs, mm at full
            load), degree 1.
        progress : bool
            Log each load step and Newton iteration.
        cases_first : iterable or None
            Accepted and not used: a solve starts from ``initial`` or from rest.
        settings : NewtonSettings or None
            This solve's Newton and load-stepping settings (NewtonSettings); None: the
            solver's own (``settings`` of the constructor). ``lag_max_its`` stays the solver's
            own: its linear solver was built with it.
        extra_terms : object or None
            Terms Newton adds to the residual, the tangent and the line search's energy
            (``Newton``: e.g. the inertia of an implicit-Euler time step, ``dynamics``); None:
            none.
        residual_line_search : bool
            Without indenters, take a Newton correction after a load step's first only when it
            lowers the residual norm (``Contact.accepts``; a warm start's line search,
            ``transfer.warm_settings``); False: every finite correction is taken.

        Returns
        -------
        SolveResult
            The answer: ``u`` (mm), ``probes`` (mm), ``reactions`` (mN), ``strain_energy``
            (uJ), Newton's iterations and residual (mN), validity and discretization.

        Raises
        ------
        ConvergenceError
            With ``last_converged`` SolveResult and the load fraction reached, when a load step
            still fails after the cut-backs.
        CaseError
            When ``case`` is on another mesh or of another material law than the solver's.
        """
        t_start = time.perf_counter()
        self.timings.reset()   # per-solve counters
        self.linear.fresh()   # nothing of an earlier solve steers this one
        case = (case or self.case).with_pushes(pushes or {})
        if case.mesh is not self.case.mesh:
            raise CaseError("ReferenceSolver.solve: the case mesh differs from the solver's mesh")
        if (case.material.model, case.material.volumetric) != \
                (self.case.material.model, self.case.material.volumetric):
            raise CaseError(f"ReferenceSolver.solve: the case's material law "
                            f"({case.material.model}, volumetric {case.material.volumetric!r}) "
                            f"differs from the solver's ({self.case.material.model}, volumetric "
                            f"{self.case.material.volumetric!r}): build a solver for it")
        self.set_material(case.material)
        s = settings or self.settings
        warm = initial is not None
        if warm:
            self.state.set_state(initial)
        else:
            self.x.x.array[:] = 0.0
        # Dirichlet data at full load; each load step sets g = start + lam (full - start), where
        # start is the state's own boundary values (0 when cold), so a warm start ramps from
        # where it is to the new prescriptions.
        entries = self.boundary.dirichlet_bcs(case, 1.0, dirichlet_override)
        bcs = [e[0] for e in entries]
        values = [(gfun.x.array, parent, coll) for _, gfun, parent, coll in entries]
        ramps = []
        span = 0.0
        for _, gfun, parent, coll in entries:
            garr = gfun.x.array
            full = garr.copy()
            start = np.zeros_like(full)
            if warm:
                start[coll] = self.x.x.array[parent]
            ramps.append((garr, start, full))
            span = max(span, np.abs(full[coll] - start[coll]).max(initial=0.0))
        span = max(span, self.contact.ramps(case, ramps, initial, settings=s))  # indenters' tips
        span = self.comm.allreduce(span, op=MPI.MAX)
        inc = 1.0 if span <= s.max_step_mm else s.max_step_mm / span
        lam = 0.0
        steps = iters = 0
        last_good = self.x.x.array.copy()
        residual = 0.0
        # per load step reached; and per Newton iterate (failed steps too) its residual norm
        # and the load fraction it was tried at
        history = {"load_fraction": [], "newton_iterations": [], "residual": [],
                   "iterate_residual": [], "iterate_load": []}
        prev_good, prev_lam = None, 0.0
        predict = s.predictor == "secant"
        # with indenters the steps before the last end after the tips' predictor and do not
        # grow (NewtonSettings.contact_intermediate_rtol)
        step_rtol, grow = (s.contact_intermediate_rtol, s.contact_grow) \
            if self.contact.indenters else (s.intermediate_rtol, s.grow)
        # what each Newton iteration adds to the solver's own forms and line search
        newton = {"extra_terms": extra_terms, "residual_line_search": residual_line_search}
        while lam < 1.0 - 1e-14:
            trial = min(1.0, lam + inc)
            for garr, start, full in ramps:
                garr[:] = start + trial * (full - start)
            self.set_load_fraction(1.0 if warm else trial)
            if predict and prev_good is not None and lam > prev_lam:
                # linear extrapolation of the load path (secant predictor)
                self.x.x.array[:] += (trial - lam) / (lam - prev_lam) * (last_good - prev_good)
                self.x.x.scatter_forward()
            final = trial >= 1.0 - 1e-14
            tol = {} if final else {"rtol": step_rtol, "atol_mm": s.intermediate_atol_mm}
            trace = history["iterate_residual"]
            ok, it, res = self.newton.iterate(s, bcs, progress, f"load {trial:6.3f}", trace=trace,
                                              dirichlet_values=values, **tol, **newton)
            iters += it
            if not ok and predict and prev_good is not None:
                # retry the same step from the last converged state, without the predictor
                self.x.x.array[:] = last_good
                self.x.x.scatter_forward()
                ok, it, res = self.newton.iterate(s, bcs, progress, f"load {trial:6.3f}",
                                                  trace=trace, dirichlet_values=values, **tol,
                                                  **newton)
                iters += it
            history["iterate_load"] += [trial] * (len(trace) - len(history["iterate_load"]))
            if ok:
                prev_good, prev_lam = last_good.copy(), lam
                lam = trial
                steps += 1
                residual = res
                last_good[:] = self.x.x.array
                history["load_fraction"].append(lam)
                history["newton_iterations"].append(it)
                history["residual"].append(res)
                if progress and self.comm.rank == 0:
                    print(f"tissue fem: load fraction {lam:.4f} converged in {it} Newton "
                          f"iterations (|R| {res:.2e})", file=sys.stderr, flush=True)
                if it <= 5:
                    inc *= grow
            else:
                self.x.x.array[:] = last_good
                self.x.x.scatter_forward()
                inc /= 2.0
                if progress and self.comm.rank == 0:
                    print(f"tissue fem: load fraction {trial:.4f} failed, cutting the step to "
                          f"{inc:.4f}", file=sys.stderr, flush=True)
                if inc < s.min_fraction:
                    # the last converged state with its own prescriptions: the Dirichlet values
                    # and the indenters' tips back where that state was solved
                    for garr, start, full in ramps:
                        garr[:] = start + lam * (full - start)
                    self.set_load_fraction(1.0 if warm else lam)
                    if steps:
                        # that state was converged to the intermediate tolerances only (it was
                        # to start the next step): it is the answer now, converged as one
                        iters += self._converge_answer(s, bcs, values, progress, lam, history,
                                                       **newton)
                        residual = history["residual"][-1]
                    wall = time.perf_counter() - t_start
                    last = solve_result(self, case, False, iters, residual, wall, steps,
                                        history, lam)
                    raise ConvergenceError(
                        f"{case.source or case.name}: Newton did not converge beyond load fraction "
                        f"{lam:.4f} (tried {trial:.4f}) after cut-backs down to {inc * 2:.2e}"
                        f"{self.contact.failure_hint()}",
                        load_fraction=lam, last_converged=last)
        wall = time.perf_counter() - t_start
        return solve_result(self, case, True, iters, residual, wall, max(steps, 1), history, 1.0)

    def _converge_answer(self, s: NewtonSettings, bcs, values, progress, lam: float,
                         history: dict, extra_terms=None,
                         residual_line_search: bool = False) -> int:
        """Newton from the last converged state (at load fraction ``lam``, its prescriptions
        set) to the final load step's tolerances, as a failed solve's answer; its residual goes
        to ``history``. That state may have ended after its tips' predictor
        (``NewtonSettings.contact_intermediate_rtol``), far from converged, so it is given at
        least the default ``max_iterations`` whatever ``s`` asks for. A state that does not
        converge further stays as it was. ``extra_terms`` and ``residual_line_search``: the
        solve's (``solve``). Returns the Newton iterations."""
        x0 = self.x.x.array.copy()
        trace = history["iterate_residual"]
        s = replace(s, max_iterations=max(s.max_iterations, NewtonSettings.max_iterations))
        ok, it, res = self.newton.iterate(s, bcs, progress, f"load {lam:6.3f}", trace=trace,
                                          dirichlet_values=values, extra_terms=extra_terms,
                                          residual_line_search=residual_line_search)
        history["iterate_load"] += [lam] * (len(trace) - len(history["iterate_load"]))
        if ok:
            history["residual"][-1] = res
        else:
            self.x.x.array[:] = x0
            self.x.x.scatter_forward()
        return it

    def set_state(self, initial, *, exact: bool = False):
        """Load a displacement state into the solver's fields (``NodalState.set_state``)."""
        self.state.set_state(initial, exact=exact)

    def node_points(self):
        """(n_nodes, gdim) reference coordinates (mm) of the displacement nodes in the Tangent
        node order (Case vertices first, then the degree-2 edge nodes); serial."""
        return self.state.node_points()

    def gather_nodes(self, local_array):
        """(n_global_nodes, gdim) array of a nodal field (owned values), on every rank."""
        return self.state.gather_nodes(local_array)

    def tangent(self, u=None, *, pushes=None) -> Tangent:
        """Exact tangent K at state ``u`` (default: the current one): ``outputs_tangent``.

        Parameters
        ----------
        u : array_like or SolveResult or None
            The state: (n_vertices, gdim) displacement (mm), the full degree-2 nodal state
            (n_nodes, gdim) or a reference SolveResult on this mesh; None: the current state.
        pushes : dict or None
            Actuator name -> push (mm) at that state (where the rigid tips sit).

        Returns
        -------
        Tangent
            K (mN/mm, scipy CSR, node-major), its Dirichlet dofs and node points (mm).
        """
        return tangent(self, u, pushes=pushes)

    def internal_forces(self, u=None):
        """Node-major f_int - f_ext (mN) at state ``u``: ``outputs_tangent``."""
        return internal_forces(self, u)

    def discretization(self) -> dict:
        """What the reference solved: formulation, degrees, geometry order, cells and dofs."""
        return discretization(self)

    def _spaces(self, mesh, degree):
        """The unknown ``x`` on the space ``W`` and the displacement ``u`` on ``V``.

        Displacement formulation: W = V (vector Lagrange of ``degree``) and x is u. Mixed: W is
        Taylor-Hood (vector P2 x P1); u and the pressure p are collapsed copies of x's parts,
        refreshed after every solve (``NodalState.sync``); ``_umap`` / ``_pmap`` give the W dof of
        each V / Q dof."""
        cell = mesh.ufl_cell()
        if self.formulation == "mixed":
            el = ufl.MixedElement([ufl.VectorElement("Lagrange", cell, degree),
                                   ufl.FiniteElement("Lagrange", cell, degree - 1)])
            self.W = dolfinx.fem.FunctionSpace(mesh, el)
            self.Wu = self.W.sub(0)
            self.V, umap = self.Wu.collapse()
            self.Q, pmap = self.W.sub(1).collapse()
            self._umap = np.asarray(umap, np.int64)
            self._pmap = np.asarray(pmap, np.int64)
            self.x = dolfinx.fem.Function(self.W)
            self.u = dolfinx.fem.Function(self.V, name="displacement")
            self.p = dolfinx.fem.Function(self.Q, name="pressure")
            self.u_ufl, self.p_ufl = ufl.split(self.x)
        else:
            self.V = self.W = self.Wu = dolfinx.fem.VectorFunctionSpace(mesh, ("Lagrange", degree))
            self.x = self.u = dolfinx.fem.Function(self.V, name="displacement")
            self.u_ufl = self.u
            self.Q = self.p = None
            self._umap = np.arange(len(self.u.x.array), dtype=np.int64)
        self.du = dolfinx.fem.Function(self.W)

