"""The ground-truth solver: the Case's energy as a UFL form (displacement, or mixed u-p for
nearly incompressible tissue), PETSc Newton, load stepping with automatic cut-back, converged
reason checked every step.

Units: mm, kPa, mN. Serial or under ``mpirun``; every array returned is in the Case's vertex
numbering and identical on all ranks.

    ref = ReferenceSolver(case, degree=2)     # forms compiled once
    res = ref.solve(pushes={"A1": 15.0})      # SolveResult
    tan = ref.tangent(res)                    # exact tangent K as scipy CSR

The concerns live in their own modules, mixed into ReferenceSolver: ``forms`` (energies),
``boundary`` (Dirichlet conditions), ``newton`` (Newton and load stepping; its settings in
``newton_settings``), ``linalg`` (factorizations and Krylov solves), ``outputs`` (states,
probes, reactions, tangent export); its defaults (degree, formulation, quadrature) are
``discretization``'s. ``kept`` keeps solvers for reuse and ``answer`` composes the one-call
``solve``; ``petsc_memory`` frees a solver's PETSc memory (``close``).
"""
from __future__ import annotations

import logging
import time

import dolfinx
import dolfinx.fem
import dolfinx.fem.petsc
import numpy as np
import ufl
from mpi4py import MPI
from petsc4py import PETSc

from tissue_reference.meshes.case import Case, Material
from tissue_reference.meshes.errors import CaseError
from tissue_reference.meshes.tips import default_contact_rule, default_tip_start

from .boundary import BoundaryMixin
from .contact import DEFAULT_CONTACT_PENALTY, Contact
from .discretization import (
    DEFAULT_QUADRATURE,
    FORMULATIONS,
    MIXED_FROM_NU,
    default_degree,
    resolve_formulation,
)
from .dolfinx_mesh import DolfinxMesh, to_dolfinx
from .forms import mixed_energy_density, strain_energy_density
from .linalg import FIELDSPLIT_ABOVE_DOFS, LAGGED_ABOVE_DOFS, LinearSolveMixin, has_cholmod
from .logs import install_log_filters
from .newton import NewtonMixin, NewtonSettings, Timings
from .outputs import OutputsMixin, Tangent
from .petsc_memory import release_petsc_garbage

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

class ReferenceSolver(BoundaryMixin, LinearSolveMixin, NewtonMixin, OutputsMixin):
    """Neo-Hookean / linear-elastic reference on one Case mesh; build once, solve many times.

    Args:
        case: the Case (mesh, material, boundaries, probes).
        degree: Lagrange degree of the displacement, 1, 2 or 3 (the mixed formulation is
            Taylor-Hood: pressure one degree lower, so degree >= 2); None: the case's
            ``reference_degree``, else 2 for mixed, 1 for displacement (``default_degree``).
        formulation: "displacement" (the energy of u alone), "mixed" (u-p perturbed Lagrangian,
            see ``forms``: locking-free up to the incompressible limit nu = 0.5) or "auto" (mixed
            from nu >= MIXED_FROM_NU).
        quadrature_degree: override DEFAULT_QUADRATURE[degree].
        settings: NewtonSettings.
        comm: MPI communicator.
        sliding_penalty: factor beta of the oblique-sliding penalty (beta * E / h_min per mm^2).
        body_force: optional callable x -> UFL vector (mN/mm^3) of the reference coordinates,
            added to gravity (used for manufactured solutions).
        linear_solver: "direct" (MUMPS LDL^T of every Newton tangent), "lagged" (GMRES on the
            exact tangent, preconditioned by the factor of an earlier tangent, which is
            refactorized only when GMRES needs more than ``settings.lag_max_its`` iterations),
            "iterative" (CG + GAMG with rigid-body near null space, MUMPS fallback; displacement
            formulation only), "fieldsplit" (FGMRES with a Schur-complement fieldsplit
            preconditioner: AMG on the displacement block, the scaled pressure mass matrix on the
            Schur complement; MUMPS fallback; mixed formulation only) or "auto" ("lagged" above
            LAGGED_ABOVE_DOFS dofs, "direct" below; the mixed formulation "fieldsplit" above
            FIELDSPLIT_ABOVE_DOFS).
        curved: isoparametric (second-order) geometry from the mesh's curved edges (the builtin
            curved bodies and any order-2 .msh carry them). None: curved at degree >= 2 when the
            mesh has them (at degree 1 the straight cells the fast solvers use); False: straight.
        contact_penalty: beta of the indenters' contact penalty k = beta E / h (kPa/mm, h the
            cell size; see ``contact``: the penetration (p_c / E + 1/2) h / beta, mm, is the
            method's error).
        contact_quadrature: where the contact penalty is sampled: "nodal" (one point per
            displacement node of the skin) or an int, a Gauss rule of that degree on each skin
            facet, which also penalizes the facets' interiors; None: the case's (``[reference]
            contact_quadrature``), else "nodal". The nodal rule is the more accurate for shallow
            pushes, a Gauss rule holds the skin on a tip pushed deeper than about two of its
            radii (``contact``).
        tip_start: where each indenter starts: "nodes", touching the skin's displacement nodes,
            or "surface", touching the skin's facets as the geometry curves them, which the
            first contact with the meshed body generally lies between (``contact``); None: the
            case's (``[reference] tip_start``), else "nodes" with the nodal contact rule and
            "surface" with a Gauss rule (``default_tip_start``).
    """

    def __init__(self, case: Case, *, degree: int | None = None, formulation: str = "auto",
                 quadrature_degree: int | None = None, settings: NewtonSettings | None = None,
                 comm=MPI.COMM_WORLD, sliding_penalty: float = 1e4, body_force=None,
                 linear_solver: str = "auto", curved: bool | None = None,
                 contact_penalty: float = DEFAULT_CONTACT_PENALTY,
                 contact_quadrature: str | int | None = None, tip_start: str | None = None):
        self.formulation = resolve_formulation(formulation, case.material)
        if degree is None:
            degree = default_degree(case, self.formulation)
        if degree not in (1, 2, 3):
            raise CaseError(f"degree must be 1, 2 or 3, got {degree!r}")
        if self.formulation == "mixed" and degree < 2:
            why = "" if formulation == "mixed" else \
                f" (picked for nu = {case.material.nu} >= {MIXED_FROM_NU}: P1 displacement " \
                f"elements lock there; formulation='displacement' accepts that)"
            raise CaseError(f"the mixed u-p formulation is Taylor-Hood (P2/P1, P3/P2) and needs "
                            f"degree=2 or 3, got degree={degree}{why}")
        if self.formulation == "displacement" and case.material.nu >= 0.5:
            raise CaseError("an incompressible material (nu = 0.5) needs the mixed formulation")
        t0 = time.perf_counter()
        self.case = case
        self.degree = degree
        self.comm = comm
        self.settings = settings or NewtonSettings()
        self.qdeg = quadrature_degree or DEFAULT_QUADRATURE[degree]
        if curved and case.mesh.geometry_order == 1:
            raise CaseError("curved=True: this mesh has no curved (second-order) edges")
        self.geometry_order = 2 if case.mesh.geometry_order == 2 and \
            (curved or (curved is None and degree >= 2)) else 1
        self.dm: DolfinxMesh = to_dolfinx(case.mesh, comm, geometry_order=self.geometry_order)
        mesh = self.dm.mesh
        self.gdim = case.mesh.gdim
        self._spaces(mesh, degree)
        self._node_map()
        # material and loads as Constants: a changed E or load scale needs no recompilation
        self.E = dolfinx.fem.Constant(mesh, PETSc.ScalarType(case.material.E))
        self.nu = dolfinx.fem.Constant(mesh, PETSc.ScalarType(case.material.nu))
        self.inv_kappa = dolfinx.fem.Constant(mesh, PETSc.ScalarType(_inv_kappa(case.material)))
        self.load = dolfinx.fem.Constant(mesh, PETSc.ScalarType(1.0))
        E, nu = self.E, self.nu
        mu = E / (2 * (1 + nu))
        u = self.u_ufl
        md = {"quadrature_degree": self.qdeg}
        dx = ufl.Measure("dx", domain=mesh, metadata=md)
        ds = ufl.Measure("ds", domain=mesh, subdomain_data=self.dm.facet_tags, metadata=md)
        if self.formulation == "mixed":
            psi, vol = mixed_energy_density(u, self.p_ufl, case.material.model, mu, self.inv_kappa,
                                            case.material.volumetric)
            self._vol_form = vol
        else:
            kappa = E / (3 * (1 - 2 * nu))
            lmbda = E * nu / ((1 + nu) * (1 - 2 * nu))
            psi, _ = strain_energy_density(u, case.material.model, mu, kappa, lmbda,
                                           case.material.volumetric)
        g = case.gravity if case.gravity is not None else (0.0,) * self.gdim
        self.body = dolfinx.fem.Constant(mesh, PETSc.ScalarType(
            tuple(case.material.density * np.asarray(g, float))))
        internal = psi * dx
        external = ufl.inner(self.body, u) * dx
        if body_force is not None:
            external = external + ufl.inner(body_force(ufl.SpatialCoordinate(mesh)), u) * dx
        self.tractions = {}
        for b in case.boundaries:
            if b.type == "traction":
                t = dolfinx.fem.Constant(mesh, PETSc.ScalarType(tuple(map(float, b.value))))
                self.tractions[b.region] = t
                external = external + ufl.inner(t, u) * ds(self.dm.region_tags[b.region])
        penalty = 0
        self._oblique = []
        for b in case.boundaries:
            if b.type == "sliding":
                n = np.asarray(b.normal, float)
                n = n / np.linalg.norm(n)
                if np.count_nonzero(np.abs(n) > 1e-12) > 1:
                    self._oblique.append(b.region)
                    nn = ufl.as_vector(n.tolist())
                    gval = dolfinx.fem.Constant(mesh, PETSc.ScalarType(float(b.value or 0.0)))
                    beta = sliding_penalty * case.material.E / self.dm.h_min
                    penalty = penalty + beta / 2 * (ufl.dot(u, nn) - self.load * gval) ** 2 * \
                        ds(self.dm.region_tags[b.region])
        if contact_quadrature is None:
            contact_quadrature = default_contact_rule(case)
        self.contact = Contact(self, case, penalty=contact_penalty,  # rigid indenters
                               quadrature=contact_quadrature,
                               tip_start=tip_start or default_tip_start(case,
                                                                        contact_quadrature))
        penalty = penalty + self.contact.energy
        self.energy_internal = internal
        total = internal - self.load * external + penalty
        self.contact.line_search_energy(total)
        v = ufl.TestFunction(self.W)
        w = ufl.TrialFunction(self.W)
        self.R_ufl = ufl.derivative(total, self.x, v)
        self.R_int_ufl = ufl.derivative(internal - self.load * external, self.x, v)
        self.K_ufl = ufl.derivative(self.R_ufl, self.x, w)
        self.R_form = dolfinx.fem.form(self.R_ufl)
        self.R_int_form = dolfinx.fem.form(self.R_int_ufl)
        self.K_form = dolfinx.fem.form(self.K_ufl)
        # with indenters: Newton's matrix without the tips' curvature, far from the answer
        # and after a halved correction (fem_reference.contact)
        self.K_halved_form = None
        soft = self.contact.tangent_without_curvature(v, w)
        if soft is not None:
            self.K_halved_form = dolfinx.fem.form(
                self.K_ufl - ufl.derivative(ufl.derivative(self.contact.normal_energy, self.x, v),
                                            self.x, w) + soft)
        self.W_form = dolfinx.fem.form(internal)
        n_dofs = self.W.dofmap.index_map.size_global * self.W.dofmap.index_map_bs
        if linear_solver == "auto":
            linear_solver = "lagged" if n_dofs > LAGGED_ABOVE_DOFS else "direct"
            if self.formulation == "mixed" and n_dofs > FIELDSPLIT_ABOVE_DOFS:
                linear_solver = "fieldsplit"
        if linear_solver not in ("direct", "lagged", "iterative", "fieldsplit"):
            raise CaseError(f"linear_solver must be 'auto', 'direct', 'lagged', 'iterative' or "
                            f"'fieldsplit', got {linear_solver!r}")
        if linear_solver == "iterative" and self.formulation == "mixed":
            raise CaseError("linear_solver='iterative' (CG + GAMG) needs a positive definite "
                            "tangent: use 'direct', 'lagged' or 'fieldsplit' with the mixed "
                            "formulation")
        if linear_solver == "fieldsplit" and self.formulation != "mixed":
            raise CaseError("linear_solver='fieldsplit' splits the mixed formulation's "
                            "displacement and pressure: use 'iterative' for the displacement one")
        self.linear_solver = linear_solver
        # The tangent A is assembled as BAIJ (node blocks: about 2x faster insertion than AIJ)
        # and converted to SBAIJ, the upper half MUMPS's LDL^T reads, whenever it is factorized.
        # GAMG ("iterative") and the mixed space (no common block size) use AIJ.
        blocked = linear_solver != "iterative" and self.formulation == "displacement"
        self.A = dolfinx.fem.petsc.create_matrix(self.K_form, "baij" if blocked else "aij")
        self.b = dolfinx.fem.petsc.create_vector(self.R_form)
        # The tangent is symmetric (Dirichlet rows and columns are both zeroed).
        self.A.setOption(PETSc.Mat.Option.SYMMETRIC, True)
        self.refactor = True
        if linear_solver == "iterative":
            # CG + smoothed-aggregation AMG with the rigid-body modes as near null space;
            # tight tolerance so Newton keeps its quadratic convergence; MUMPS as the fallback
            self.ksp = PETSc.KSP().create(comm)
            self.ksp.setOperators(self.A)
            self.ksp.setType("cg")
            self.ksp.setTolerances(rtol=1e-10, atol=1e-14, max_it=2000)
            self.ksp.getPC().setType("gamg")
            self.A.setNearNullSpace(self._rigid_body_nullspace())
            self.direct_ksp = self._factor_ksp("mumps")
        elif linear_solver == "fieldsplit":
            # FGMRES + Schur-complement fieldsplit (``saddle``), MUMPS as the fallback
            self._use_fieldsplit()
        else:
            # serial "lagged": CHOLMOD's supernodal LL^T (METIS ordering) factorizes ~1.6x and
            # solves ~3x faster than MUMPS here; a tangent that is not positive definite switches
            # the solver to MUMPS LDL^T, which "direct" (exact solves of indefinite tangents),
            # the mixed formulation's saddle-point tangent and MPI runs always use.
            pkg = "cholmod" if linear_solver == "lagged" and comm.size == 1 and has_cholmod() \
                and self.formulation == "displacement" else "mumps"
            self.use_factor(pkg)
            self._first_factor_package = pkg
        self._region_dofs = {}
        self.timings = Timings(setup=time.perf_counter() - t0)

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

    def _spaces(self, mesh, degree):
        """The unknown ``x`` on the space ``W`` and the displacement ``u`` on ``V``.

        Displacement formulation: W = V (vector Lagrange of ``degree``) and x is u. Mixed: W is
        Taylor-Hood (vector P2 x P1); u and the pressure p are collapsed copies of x's parts,
        refreshed after every solve (``_sync_fields``); ``_umap`` / ``_pmap`` give the W dof of
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


def _inv_kappa(material: Material) -> float:
    """1/kappa (1/kPa) of the material, exactly 0 for nu = 0.5."""
    return 3.0 * (1.0 - 2.0 * material.nu) / material.E
