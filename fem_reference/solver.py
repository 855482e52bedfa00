"""The ground-truth solver: the Case's energy as a UFL form, PETSc Newton with MUMPS LU, load
stepping with automatic cut-back, converged reason checked every step.

Units: mm, kPa, mN. Serial or under ``mpirun``; every array returned is in the Case's vertex
numbering and identical on all ranks.

    ref = ReferenceSolver(case, degree=2)     # forms compiled once
    res = ref.solve(pushes={"A1": 15.0})      # SolveResult
    tan = ref.tangent(res.u)                  # exact tangent K as scipy CSR
"""
from __future__ import annotations

import functools
import logging
import math
import os
import sys
import time
from dataclasses import dataclass

import dolfinx
import dolfinx.fem
import dolfinx.fem.petsc
import numpy as np
import ufl
from mpi4py import MPI
from petsc4py import PETSc

from meshes.case import Case
from meshes.errors import CaseError, ConvergenceError
from meshes.results import SolveResult

from .dolfinx_mesh import DolfinxMesh, to_dolfinx
from .forms import strain_energy_density

__all__ = [
    "DEFAULT_QUADRATURE",
    "NewtonSettings",
    "ReferenceSolver",
    "Tangent",
    "solve",
    "tangent_stiffness",
]

log = logging.getLogger("tissue.fem")
for _name in ("UFL", "FFCx", "ffcx", "root"):
    logging.getLogger(_name).setLevel(logging.WARNING)

# Quadrature degree per Lagrange degree. P1: F is constant per cell, degree 1 integrates the
# energy and the body-force term exactly. P2: F is linear; psi is not polynomial, degree 4 is
# checked against degree 6 in tests (UFL would estimate ~ 146 points per cell for J**(-2/3)).
DEFAULT_QUADRATURE = {1: 1, 2: 4}
# linear_solver="auto": above this many dofs Newton reuses a MUMPS factorization as the GMRES
# preconditioner of later tangents instead of refactorizing every iteration (measured faster from
# 1.8k tets up: 0.97 vs 1.27 s; at 26.6k tets 9.7 vs 22 s, bench/bench_reference.py).
LAGGED_ABOVE_DOFS = 1000


@functools.cache
def _has_cholmod() -> bool:
    """Whether this PETSc build has SuiteSparse's CHOLMOD (Debian's has)."""
    try:
        m = PETSc.Mat().createAIJ((1, 1), nnz=1, comm=PETSc.COMM_SELF)
        m.setValue(0, 0, 1.0)
        m.assemble()
        k = PETSc.KSP().create(PETSc.COMM_SELF)
        k.setOperators(m)
        k.setType("preonly")
        k.getPC().setType("cholesky")
        k.getPC().setFactorSolverType("cholmod")
        k.setUp()
        return True
    except PETSc.Error:
        return False


class _quiet_c_output:
    """Silences C-level stdout and stderr (file descriptors 1 and 2) inside the block (CHOLMOD
    prints its warnings with printf)."""

    def __enter__(self):
        sys.stdout.flush()
        sys.stderr.flush()
        self._saved = [(fd, os.dup(fd)) for fd in (1, 2)]
        null = os.open(os.devnull, os.O_WRONLY)
        for fd, _ in self._saved:
            os.dup2(null, fd)
        os.close(null)

    def __exit__(self, *exc):
        for fd, saved in self._saved:
            os.dup2(saved, fd)
            os.close(saved)
        return False


@dataclass(frozen=True)
class NewtonSettings:
    """Newton and load-stepping controls.

    rtol, atol: residual reduction within the final load step / absolute residual (mN);
    atol_mm: Newton correction (inf-norm, mm) under which the final step is converged;
    intermediate_rtol, intermediate_atol_mm: the same, for load steps before the last (their states
        only start the next step, so they need not be converged to round-off);
    max_step_mm: largest prescribed-displacement increment of the first try;
    line_search: halvings of a Newton correction allowed when it inverts an element (non-finite
        residual) before the step counts as failed;
    lag_max_its: "lagged" linear solver: GMRES iterations above which the tangent is refactorized.
    """

    rtol: float = 1e-10
    atol: float = 1e-10
    atol_mm: float = 1e-10
    intermediate_rtol: float = 1e-6
    intermediate_atol_mm: float = 1e-6
    max_iterations: int = 25
    max_step_mm: float = 5.0
    min_fraction: float = 1.0 / 1024
    grow: float = 1.5
    line_search: int = 4
    lag_max_its: int = 12

    def __post_init__(self):
        for name in ("rtol", "atol", "atol_mm", "intermediate_rtol", "intermediate_atol_mm",
                     "max_step_mm", "min_fraction"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and v > 0 and math.isfinite(v)):
                raise ValueError(f"NewtonSettings.{name} must be a positive number, got {v!r}")
        if self.max_iterations < 1:
            raise ValueError(f"NewtonSettings.max_iterations must be >= 1, got {self.max_iterations}")
        if self.line_search < 0 or self.lag_max_its < 1:
            raise ValueError("NewtonSettings.line_search must be >= 0 and lag_max_its >= 1")


@dataclass(frozen=True)
class Tangent:
    """Exact tangent stiffness K (mN/mm), node-major (dof = gdim*node + component).

    Nodes 0..n_vertices-1 are the Case's vertices in its own numbering; for degree 2 the edge
    nodes follow, with coordinates ``node_points``. ``dirichlet_dofs`` are the prescribed dofs.
    """

    K: object
    dirichlet_dofs: np.ndarray
    node_points: np.ndarray
    n_vertices: int
    degree: int


@dataclass
class _Timings:
    assemble: float = 0.0
    solve: float = 0.0
    setup: float = 0.0
    factorizations: int = 0
    krylov_iterations: int = 0


class ReferenceSolver:
    """Neo-Hookean / linear-elastic reference on one Case mesh; build once, solve many times.

    Args:
        case: the Case (mesh, material, boundaries, probes).
        degree: Lagrange degree, 1 or 2.
        quadrature_degree: override DEFAULT_QUADRATURE[degree].
        settings: NewtonSettings.
        comm: MPI communicator.
        sliding_penalty: factor beta of the oblique-sliding penalty (beta * E / h_min per mm^2).
        body_force: optional callable x -> UFL vector (mN/mm^3) of the reference coordinates,
            added to gravity (used for manufactured solutions).
        linear_solver: "direct" (MUMPS LDL^T of every Newton tangent), "lagged" (GMRES on the
            exact tangent, preconditioned by the MUMPS factor of an earlier tangent, which is
            refactorized only when GMRES needs more than ``settings.lag_max_its`` iterations),
            "iterative" (CG + GAMG with rigid-body near null space, MUMPS fallback) or "auto"
            ("lagged" above LAGGED_ABOVE_DOFS dofs, "direct" below).
    """

    def __init__(self, case: Case, *, degree: int = 1, quadrature_degree: int | None = None,
                 settings: NewtonSettings | None = None, comm=MPI.COMM_WORLD,
                 sliding_penalty: float = 1e4, body_force=None, linear_solver: str = "auto"):
        if degree not in (1, 2):
            raise CaseError(f"degree must be 1 or 2, got {degree!r}")
        t0 = time.perf_counter()
        self.case = case
        self.degree = degree
        self.comm = comm
        self.settings = settings or NewtonSettings()
        self.qdeg = quadrature_degree or DEFAULT_QUADRATURE[degree]
        self.dm: DolfinxMesh = to_dolfinx(case.mesh, comm)
        mesh = self.dm.mesh
        self.gdim = case.mesh.gdim
        self.V = dolfinx.fem.VectorFunctionSpace(mesh, ("Lagrange", degree))
        self.u = dolfinx.fem.Function(self.V, name="displacement")
        self.du = dolfinx.fem.Function(self.V)
        self._node_map()
        # material and loads as Constants: a changed E or load scale needs no recompilation
        self.E = dolfinx.fem.Constant(mesh, PETSc.ScalarType(case.material.E))
        self.nu = dolfinx.fem.Constant(mesh, PETSc.ScalarType(case.material.nu))
        self.load = dolfinx.fem.Constant(mesh, PETSc.ScalarType(1.0))
        E, nu = self.E, self.nu
        mu = E / (2 * (1 + nu))
        kappa = E / (3 * (1 - 2 * nu))
        lmbda = E * nu / ((1 + nu) * (1 - 2 * nu))
        psi, _ = strain_energy_density(self.u, case.material.model, mu, kappa, lmbda)
        md = {"quadrature_degree": self.qdeg}
        dx = ufl.Measure("dx", domain=mesh, metadata=md)
        ds = ufl.Measure("ds", domain=mesh, subdomain_data=self.dm.facet_tags, metadata=md)
        g = case.gravity if case.gravity is not None else (0.0,) * self.gdim
        self.body = dolfinx.fem.Constant(mesh, PETSc.ScalarType(
            tuple(case.material.density * np.asarray(g, float))))
        internal = psi * dx
        external = ufl.inner(self.body, self.u) * dx
        if body_force is not None:
            external = external + ufl.inner(body_force(ufl.SpatialCoordinate(mesh)), self.u) * dx
        self.tractions = {}
        for b in case.boundaries:
            if b.type == "traction":
                t = dolfinx.fem.Constant(mesh, PETSc.ScalarType(tuple(map(float, b.value))))
                self.tractions[b.region] = t
                external = external + ufl.inner(t, self.u) * ds(self.dm.region_tags[b.region])
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
                    penalty = penalty + beta / 2 * (ufl.dot(self.u, nn) - self.load * gval) ** 2 * \
                        ds(self.dm.region_tags[b.region])
        self.energy_internal = internal
        total = internal - self.load * external + penalty
        v = ufl.TestFunction(self.V)
        w = ufl.TrialFunction(self.V)
        self.R_ufl = ufl.derivative(total, self.u, v)
        self.R_int_ufl = ufl.derivative(internal - self.load * external, self.u, v)
        self.K_ufl = ufl.derivative(self.R_ufl, self.u, w)
        self.R_form = dolfinx.fem.form(self.R_ufl)
        self.R_int_form = dolfinx.fem.form(self.R_int_ufl)
        self.K_form = dolfinx.fem.form(self.K_ufl)
        self.W_form = dolfinx.fem.form(internal)
        n_dofs = self.V.dofmap.index_map.size_global * self.V.dofmap.index_map_bs
        if linear_solver == "auto":
            linear_solver = "lagged" if n_dofs > LAGGED_ABOVE_DOFS else "direct"
        if linear_solver not in ("direct", "lagged", "iterative"):
            raise CaseError(f"linear_solver must be 'auto', 'direct', 'lagged' or 'iterative', "
                            f"got {linear_solver!r}")
        self.linear_solver = linear_solver
        # The tangent A is assembled as BAIJ (node blocks: about 2x faster insertion than AIJ)
        # and converted to SBAIJ, the upper half MUMPS's LDL^T reads, whenever it is factorized.
        # GAMG ("iterative") needs AIJ.
        self.A = dolfinx.fem.petsc.create_matrix(
            self.K_form, "aij" if linear_solver == "iterative" else "baij")
        self.b = dolfinx.fem.petsc.create_vector(self.R_form)
        # The tangent is symmetric (Dirichlet rows and columns are both zeroed).
        self.A.setOption(PETSc.Mat.Option.SYMMETRIC, True)
        self._refactor = True
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
        else:
            # serial "lagged": CHOLMOD's supernodal LL^T (METIS ordering) factorizes ~1.6x and
            # solves ~3x faster than MUMPS here; a tangent that is not positive definite switches
            # the solver to MUMPS LDL^T, which "direct" (exact solves of indefinite tangents)
            # and MPI runs always use.
            pkg = "cholmod" if linear_solver == "lagged" and comm.size == 1 and _has_cholmod() \
                else "mumps"
            self._use_factor(pkg)
        self._region_dofs = {}
        self.timings = _Timings(setup=time.perf_counter() - t0)

    def _rigid_body_nullspace(self):
        x = self.V.tabulate_dof_coordinates()[:, :self.gdim]
        n_own = self.V.dofmap.index_map.size_local
        d = self.gdim
        # keep the Functions alive: their vectors share the Functions' memory
        self._ns_funcs = [dolfinx.fem.Function(self.V) for _ in range(6 if d == 3 else 3)]
        vecs = [f.vector for f in self._ns_funcs]
        arrs = [v.array.reshape(-1, d) for v in vecs]  # owned part, (n_own, d) views
        xo = x[:n_own]
        for k in range(d):
            arrs[k][:, k] = 1.0
        if d == 3:
            arrs[3][:, 0], arrs[3][:, 1] = -xo[:, 1], xo[:, 0]
            arrs[4][:, 1], arrs[4][:, 2] = -xo[:, 2], xo[:, 1]
            arrs[5][:, 0], arrs[5][:, 2] = xo[:, 2], -xo[:, 0]
        else:
            arrs[2][:, 0], arrs[2][:, 1] = -xo[:, 1], xo[:, 0]
        for v in vecs:
            v.assemble()
        from dolfinx.la import orthonormalize

        orthonormalize(vecs)
        return PETSc.NullSpace().create(vectors=vecs, comm=self.comm)

    # ------------------------------------------------------------------ numbering
    def _node_map(self):
        """Map dolfinx (local) dof nodes of V to Case vertices / extra nodes."""
        V, dm = self.V, self.dm
        tdim = dm.mesh.topology.dim
        nv = tdim + 1
        cell_dofs = V.dofmap.list.array.reshape(-1, V.dofmap.dof_layout.num_dofs)
        geo = dm.mesh.geometry.dofmap.array.reshape(-1, nv)
        imap = V.dofmap.index_map
        n_local = imap.size_local + imap.num_ghosts
        node_vertex = -np.ones(n_local, np.int64)
        node_vertex[cell_dofs[:, :nv].ravel()] = dm.node_to_vertex[geo.ravel()]
        self.n_local_nodes = imap.size_local
        self.node_vertex = node_vertex  # -1 for edge nodes (degree 2)
        self.global_nodes = imap.local_to_global(np.arange(n_local, dtype=np.int32))
        self.n_global_nodes = imap.size_global

    # ------------------------------------------------------------------ boundary conditions
    def _bcs(self, case: Case, scale: float, override=None):
        """Dirichlet conditions of ``case`` at load ``scale`` (topological on facet regions), as
        (DirichletBC, its value Function, parent dofs, collapsed dofs) per component."""
        V, mesh = self.V, self.dm.mesh
        tdim = mesh.topology.dim
        bcs = []
        for b in case.boundaries:
            if b.type in ("traction",) or b.region in self._oblique:
                continue
            facets = self._facets(b.region)
            if b.type == "fixed":
                comps = {c: (lambda x: np.zeros(x.shape[1])) for c in range(self.gdim)}
            elif b.type == "displacement":
                val = np.asarray(b.value, float)
                cs = b.components if b.components is not None else range(self.gdim)
                comps = {c: (lambda x, c=c, val=val: np.full(x.shape[1], scale * val[c])) for c in cs}
            elif b.type == "affine":
                G = np.asarray(b.gradient if b.gradient is not None else np.zeros((self.gdim,) * 2))
                c0 = np.asarray(b.offset if b.offset is not None else np.zeros(self.gdim))
                comps = {c: (lambda x, c=c, G=G, c0=c0: scale * (G[c] @ x[:self.gdim] + c0[c]))
                         for c in range(self.gdim)}
            elif b.type == "sliding":
                n = np.asarray(b.normal, float)
                n = n / np.linalg.norm(n)
                k = int(np.argmax(np.abs(n)))
                g = scale * float(b.value or 0.0) * np.sign(n[k])
                comps = {k: (lambda x, g=g: np.full(x.shape[1], g))}
            else:  # pragma: no cover - Boundary validates types
                raise CaseError(f"unknown boundary type {b.type!r}")
            for c, fn in comps.items():
                Vc, _ = self._sub(c)
                dofs = dolfinx.fem.locate_dofs_topological((V.sub(c), Vc), tdim - 1, facets)
                bcs.append(self._component_bc(c, dofs, fn))
        if override is not None:
            bcs.extend(self._override_bcs(*override))
        return bcs

    def _sub(self, c):
        """(collapsed component space, parent dof of each collapsed dof), cached."""
        if not hasattr(self, "_subs"):
            self._subs = {}
        if c not in self._subs:
            Vc, cmap = self.V.sub(c).collapse()
            self._subs[c] = (Vc, np.asarray(cmap, np.int64))
        return self._subs[c]

    def _component_bc(self, c, dofs, fn=None, values=None):
        """(DirichletBC, value Function, parent dofs, collapsed dofs) of one component."""
        Vc, _ = self._sub(c)
        gfun = dolfinx.fem.Function(Vc)
        if fn is not None:
            gfun.interpolate(fn)
        else:
            gfun.x.array[dofs[1]] = values
        bc = dolfinx.fem.dirichletbc(gfun, dofs, self.V.sub(c))
        return bc, gfun, np.asarray(dofs[0]), np.asarray(dofs[1])

    def _override_bcs(self, dofs, values):
        """Per-vertex prescriptions (Case node-major dofs, values at full load); degree 1."""
        if self.degree != 1:
            raise CaseError("dirichlet_override is supported for degree 1 only")
        dofs = np.asarray(dofs, np.int64)
        values = np.asarray(values, float)
        vert_to_node = -np.ones(self.case.mesh.n_vertices, np.int64)
        has = self.node_vertex >= 0
        vert_to_node[self.node_vertex[has]] = np.flatnonzero(has)
        node = vert_to_node[dofs // self.gdim]
        comp = dofs % self.gdim
        out = []
        for c in range(self.gdim):
            sel = (node >= 0) & (comp == c)
            if not np.any(sel):
                continue
            _, cmap = self._sub(c)
            inv = np.full(len(self.u.x.array), -1, np.int64)
            inv[cmap] = np.arange(len(cmap))
            parent = node[sel] * self.gdim + c
            pair = [parent.astype(np.int32), inv[parent].astype(np.int32)]
            out.append(self._component_bc(c, pair, values=values[sel]))
        return out

    def _facets(self, region):
        if region not in self.dm.region_tags:
            raise CaseError(f"Dirichlet conditions need a boundary (facet) region; {region!r} is "
                            f"not one; facet regions: {sorted(self.dm.region_tags)}")
        ft = self.dm.facet_tags
        return ft.indices[ft.values == self.dm.region_tags[region]]

    def region_dofs(self, region) -> np.ndarray:
        """Local (owned + ghost) block indices of the nodes on a facet region."""
        if region not in self._region_dofs:
            self._region_dofs[region] = dolfinx.fem.locate_dofs_topological(
                self.V, self.dm.mesh.topology.dim - 1, self._facets(region))
        return self._region_dofs[region]

    # ------------------------------------------------------------------ Newton
    def _assemble_residual(self, bcs) -> float:
        """b = R(u) with the Dirichlet rows set to u - g (lifting included); returns |b|."""
        t0 = time.perf_counter()
        b = self.b
        with b.localForm() as bl:
            bl.set(0.0)
        dolfinx.fem.petsc.assemble_vector(b, self.R_form)
        dolfinx.fem.petsc.apply_lifting(b, [self.K_form], bcs=[bcs], x0=[self.u.vector], scale=-1.0)
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        dolfinx.fem.petsc.set_bc(b, bcs, self.u.vector, -1.0)
        self.timings.assemble += time.perf_counter() - t0
        return b.norm()

    def _assemble_tangent(self, bcs):
        t0 = time.perf_counter()
        self.A.zeroEntries()
        dolfinx.fem.petsc.assemble_matrix(self.A, self.K_form, bcs=bcs)
        self.A.assemble()
        self.timings.assemble += time.perf_counter() - t0

    def _factor_ksp(self, pkg: str):
        """KSP whose preconditioner is a Cholesky factorization by ``pkg`` ("mumps" or
        "cholmod"): GMRES around it for "lagged", the factorization alone otherwise."""
        k = PETSc.KSP().create(self.comm)
        k.setOperators(self.A)
        k.getPC().setType("cholesky")
        k.getPC().setFactorSolverType(pkg)
        if self.linear_solver == "lagged":
            # right preconditioning: GMRES then tests the true residual of the current tangent
            k.setType("gmres")
            k.setPCSide(PETSc.PC.Side.RIGHT)
            m = max(30, self.settings.lag_max_its + 1)
            k.setGMRESRestart(m)
            k.setTolerances(rtol=1e-10, atol=1e-300, max_it=m)
        else:
            k.setType("preonly")
        return k

    def _use_factor(self, pkg: str):
        """(Re)build the factorizing KSP with ``pkg``; P is made at the next refresh."""
        self.factor_package = pkg
        self.P = None
        self._T = None
        self._refactor = True
        self.ksp = self.direct_ksp = self._factor_ksp(pkg)

    def _refresh_factor(self):
        """Copy the current tangent into the matrix that is factorized (the factorization itself
        happens at the next solve; PETSc reuses the symbolic analysis, the pattern being fixed).
        MUMPS reads SBAIJ (the upper half); CHOLMOD reads a point-block (bs 1) AIJ."""
        # (petsc4py's convert() without a target converts in place: always pass one)
        first = self.P is None
        if self.factor_package == "cholmod":
            if self._T is None:
                self._T = PETSc.Mat()
            self.A.convert("aij", self._T)
            ai, aj, av = self._T.getValuesCSR()
            if first:
                self.P = PETSc.Mat().createAIJ(self.A.getSize(), csr=(ai, aj, av), comm=self.comm)
                self.P.setOption(PETSc.Mat.Option.SYMMETRIC, True)
            else:
                self.P.setValuesCSR(ai, aj, av)
                self.P.assemble()
        else:
            if first:
                self.P = PETSc.Mat()
            self.A.convert("sbaij", self.P)
        if first:
            self.ksp.setOperators(self.A, self.P)
        self._refactor = False
        self.timings.factorizations += 1

    def _krylov_solve(self, eta):
        """One solve of the current factorizing KSP; a CHOLMOD failure (tangent not positive
        definite) switches to MUMPS and solves again."""
        if self.linear_solver == "direct" or self._refactor:
            self._refresh_factor()
        if self.linear_solver == "lagged":
            self.ksp.setTolerances(rtol=eta)
        try:
            if self.factor_package == "cholmod":
                with _quiet_c_output():  # CHOLMOD printf's a warning on an indefinite tangent
                    self.ksp.solve(self.b, self.du.vector)
            else:
                self.ksp.solve(self.b, self.du.vector)
        except PETSc.Error:
            if self.factor_package != "cholmod":
                raise
            log.info("tangent not positive definite for CHOLMOD: switching to MUMPS LDL^T")
            self._use_factor("mumps")
            self._krylov_solve(eta)

    def _linear_solve(self, eta: float) -> bool:
        """du = -A^-1 b at relative tolerance ``eta`` (Krylov modes); False when it fails."""
        lagged = self.linear_solver == "lagged"
        self.b.scale(-1.0)
        try:
            if self.linear_solver == "iterative":
                ksp = self.ksp
                ksp.solve(self.b, self.du.vector)
                its = ksp.getIterationNumber()
                if ksp.getConvergedReason() < 0:
                    ksp = self.direct_ksp
                    ksp.solve(self.b, self.du.vector)
                    self.timings.factorizations += 1
            else:
                self._krylov_solve(eta)
                ksp = self.ksp
                its = ksp.getIterationNumber()
                if ksp.getConvergedReason() < 0 and lagged:
                    # the old factor is too far from this tangent: refactorize and solve again
                    self._refactor = True
                    self._krylov_solve(eta)
                    ksp = self.ksp
                    its += ksp.getIterationNumber()
        except PETSc.Error as exc:  # MUMPS on NaN entries (error 76) and the like
            log.debug("linear solve failed: %s", exc)
            self._refactor = True
            return False
        finally:
            self.b.scale(-1.0)
        if self.linear_solver != "direct":
            self.timings.krylov_iterations += its
            if lagged and its > self.settings.lag_max_its:
                self._refactor = True
        self.du.x.scatter_forward()
        return ksp.getConvergedReason() > 0

    def _newton(self, bcs, progress, label, rtol=None, atol_mm=None):
        """Newton iterations at fixed load; returns (converged, iterations, residual).

        Residual first, tangent only when another correction is needed. A correction that
        inverts an element (non-finite residual) is halved up to ``settings.line_search`` times.
        """
        s = self.settings
        rtol = s.rtol if rtol is None else rtol
        atol_mm = s.atol_mm if atol_mm is None else atol_mm
        u, du = self.u, self.du
        r0 = rprev = None
        rnorm = self._assemble_residual(bcs)
        for it in range(1, s.max_iterations + 1):
            if not math.isfinite(rnorm):
                return False, it, rnorm
            if r0 is None:
                r0 = max(rnorm, 1e-300)
            elif rnorm <= s.atol or rnorm <= rtol * r0:
                return True, it - 1, rnorm
            # forcing term of the inexact (Krylov) solves: no more accuracy than Newton can use
            eta = 1e-3 if rprev is None else \
                min(1e-3, max((rnorm / rprev) ** 2, 0.1 * rtol * r0 / rnorm, 1e-12))
            self._assemble_tangent(bcs)
            t0 = time.perf_counter()
            ok = self._linear_solve(eta)
            self.timings.solve += time.perf_counter() - t0
            if not ok:
                return False, it, rnorm
            step = du.vector.norm(PETSc.NormType.NORM_INFINITY)
            if not math.isfinite(step):
                return False, it, float("nan")
            u_old = u.x.array.copy()
            alpha = 1.0
            for _ in range(s.line_search + 1):
                u.x.array[:] = u_old + alpha * du.x.array
                rnew = self._assemble_residual(bcs)
                if math.isfinite(rnew):
                    break
                alpha *= 0.5
            else:
                u.x.array[:] = u_old
                return False, it, float("nan")
            if progress and self.comm.rank == 0:
                ls = "" if alpha == 1.0 else f"  (step x{alpha:g}: inverted elements)"
                print(f"  {label} newton {it:2d}  |R| {rnorm:.3e}  |du|_max {step:.3e} mm{ls}",
                      file=sys.stderr, flush=True)
            rprev, rnorm = rnorm, rnew
            if alpha == 1.0 and step <= atol_mm and it > 1:
                return True, it, rnorm
        return False, s.max_iterations, rnorm

    def _max_prescribed(self, case, override):
        m = np.abs(case.constraints.values).max(initial=0.0)
        for b in case.boundaries:
            if b.type == "sliding":
                m = max(m, abs(float(b.value or 0.0)))
        if override is not None:
            m = max(m, np.abs(np.asarray(override[1], float)).max(initial=0.0))
        return m

    def solve(self, pushes=None, *, case: Case | None = None, initial=None, dirichlet_override=None,
              progress: bool = False, cases_first=None) -> SolveResult:
        """Solve ``case`` (default: the one given at construction) with ``pushes`` applied.

        pushes: actuator name -> push (mm) along its direction.
        initial: warm start: (n_vertices, gdim) in the Case numbering (at degree 2 the edge
            nodes start at the mean of their end vertices), the full (n_nodes, gdim) degree-2
            nodal state in Tangent node order, or a previous SolveResult of a reference solve on
            this mesh (degree 2: its full nodal state); the load path starts from the case's
            prescribed values at fraction 0 scaled from there.
        dirichlet_override: (dofs, values): extra per-vertex prescriptions (node-major Case dofs,
            mm at full load), degree 1.
        Raises ConvergenceError (with ``last_converged`` SolveResult and the load fraction reached)
        when a load step still fails after the cut-backs.
        """
        t_start = time.perf_counter()
        self.timings = _Timings(setup=self.timings.setup)  # per-solve counters
        case = (case or self.case).with_pushes(pushes or {})
        if case.mesh is not self.case.mesh:
            raise CaseError("ReferenceSolver.solve: the case mesh differs from the solver's mesh")
        self.E.value = case.material.E
        self.nu.value = case.material.nu
        s = self.settings
        warm = initial is not None
        if warm:
            self._set_state(initial)
        else:
            self.u.x.array[:] = 0.0
        # Dirichlet data at full load; each load step sets g = start + lam (full - start), where
        # start is the state's own boundary values (0 when cold), so a warm start ramps from
        # where it is to the new prescriptions.
        entries = self._bcs(case, 1.0, dirichlet_override)
        bcs = [e[0] for e in entries]
        ramps = []
        span = 0.0
        for _, gfun, parent, coll in entries:
            garr = gfun.x.array
            full = garr.copy()
            start = np.zeros_like(full)
            if warm:
                start[coll] = self.u.x.array[parent]
            ramps.append((garr, start, full))
            span = max(span, np.abs(full[coll] - start[coll]).max(initial=0.0))
        span = self.comm.allreduce(span, op=MPI.MAX)
        inc = 1.0 if span <= s.max_step_mm else s.max_step_mm / span
        lam = 0.0
        steps = iters = 0
        last_good = self.u.x.array.copy()
        residual = 0.0
        history = {"load_fraction": [], "newton_iterations": [], "residual": []}
        prev_good, prev_lam = None, 0.0
        predict = True
        while lam < 1.0 - 1e-14:
            trial = min(1.0, lam + inc)
            for garr, start, full in ramps:
                garr[:] = start + trial * (full - start)
            self.load.value = 1.0 if warm else trial
            if predict and prev_good is not None and lam > prev_lam:
                # linear extrapolation of the load path (secant predictor)
                self.u.x.array[:] += (trial - lam) / (lam - prev_lam) * (last_good - prev_good)
                self.u.x.scatter_forward()
            final = trial >= 1.0 - 1e-14
            tol = {} if final else {"rtol": s.intermediate_rtol, "atol_mm": s.intermediate_atol_mm}
            ok, it, res = self._newton(bcs, progress, f"load {trial:6.3f}", **tol)
            iters += it
            if not ok and predict and prev_good is not None:
                # retry the same step from the last converged state, without the predictor
                self.u.x.array[:] = last_good
                self.u.x.scatter_forward()
                ok, it, res = self._newton(bcs, progress, f"load {trial:6.3f}", **tol)
                iters += it
            if ok:
                prev_good, prev_lam = last_good.copy(), lam
                lam = trial
                steps += 1
                residual = res
                last_good[:] = self.u.x.array
                history["load_fraction"].append(lam)
                history["newton_iterations"].append(it)
                history["residual"].append(res)
                if progress and self.comm.rank == 0:
                    print(f"tissue fem: load fraction {lam:.4f} converged in {it} Newton "
                          f"iterations (|R| {res:.2e})", file=sys.stderr, flush=True)
                if it <= 5:
                    inc *= s.grow
            else:
                self.u.x.array[:] = last_good
                self.u.x.scatter_forward()
                inc /= 2.0
                if progress and self.comm.rank == 0:
                    print(f"tissue fem: load fraction {trial:.4f} failed, cutting the step to "
                          f"{inc:.4f}", file=sys.stderr, flush=True)
                if inc < s.min_fraction:
                    self.load.value = 1.0 if warm else lam
                    wall = time.perf_counter() - t_start
                    last = self._result(case, False, iters, residual, wall, steps, history, lam)
                    raise ConvergenceError(
                        f"{case.source or case.name}: Newton did not converge beyond load fraction "
                        f"{lam:.4f} (tried {trial:.4f}) after cut-backs down to {inc * 2:.2e}",
                        load_fraction=lam, last_converged=last)
        wall = time.perf_counter() - t_start
        return self._result(case, True, iters, residual, wall, max(steps, 1), history, 1.0)

    # ------------------------------------------------------------------ state I/O
    def _set_state(self, initial, *, exact: bool = False):
        """Load a displacement state into the solver's field.

        initial: a SolveResult of a reference solve (at degree 2 it carries the full nodal state,
            ``extra["node_u"]`` with ``extra["node_points"]``), a (n_nodes, gdim) nodal array in
            the ``Tangent`` node order (Case vertices first, then the edge nodes of
            ``Tangent.node_points``), or (n_vertices, gdim) vertex values.
        exact: the state itself is needed (tangent, internal forces), not a warm start. At degree
            2 vertex values do not determine the edge nodes: a warm start fills them with the mean
            of their end vertices (the P1 field), which is not the degree-2 solution away from
            rest, so ``exact`` refuses vertex values unless they are all zero.
        """
        n = self.case.mesh.n_vertices
        d = self.gdim
        arr = self.u.x.array.reshape(-1, d)
        if isinstance(initial, SolveResult):
            node_u = initial.extra.get("node_u") if self.degree == 2 else None
            if node_u is not None:
                self._set_nodes(self._nodes_in_own_order(np.asarray(node_u, float),
                                                         initial.extra.get("node_points")))
                return
            u0 = np.asarray(initial.u, float)
            source = f"a degree-{initial.degree} {initial.solver} SolveResult without the nodal " \
                     f"state (extra['node_u'])"
        else:
            u0 = np.asarray(initial, float)
            source = "vertex values"
            if self.degree == 2 and u0.shape == (len(self.node_vertex), d) and u0.shape[0] != n:
                if self.comm.size > 1:
                    raise CaseError("a degree-2 nodal state array is accepted in serial only")
                self._set_nodes(u0)
                return
        if u0.shape != (n, d):
            shapes = f"{(n, d)}" if self.degree == 1 else \
                f"{(len(self.node_vertex), d)} (all degree-2 nodes) or {(n, d)}"
            raise CaseError(f"displacement state must have shape {shapes}, got {u0.shape}")
        if exact and self.degree == 2 and np.any(u0):
            raise CaseError(
                f"degree-2 state from {source}: the edge nodes are not determined by the vertex "
                f"values (their midpoint means are not the solver's state away from rest); pass "
                f"the SolveResult of a degree-2 reference solve, the full nodal array "
                f"({len(self.node_vertex)}, {d}) in Tangent node order (vertices, then edge "
                f"nodes), or None for the solver's current state")
        vmask = self.node_vertex >= 0
        arr[vmask] = u0[self.node_vertex[vmask]]
        if self.degree == 2:
            # edge nodes: mean of the two end vertices (P1 field interpolated into P2)
            self._p1_into_p2(u0, arr)
        self.u.x.scatter_forward()

    def _set_nodes(self, nodes):
        """Set every node from a (n_nodes, gdim) array in the Tangent node order (serial)."""
        self.u.x.array.reshape(-1, self.gdim)[:] = nodes[self._out_permutation()[0]]
        self.u.x.scatter_forward()

    def _output_node_points(self) -> np.ndarray:
        """Coordinates of the nodes in the Tangent node order (vertices first, then edge nodes)."""
        out_node = self._out_permutation()[0]
        pts = np.empty((len(out_node), self.gdim))
        pts[out_node] = self.V.tabulate_dof_coordinates()[:, :self.gdim]
        return pts

    def _nodes_in_own_order(self, node_u, node_points):
        """A nodal state of some degree-2 reference solve on this mesh, reordered to this solver's
        node order by the node coordinates."""
        if self.comm.size > 1:
            raise CaseError("a degree-2 nodal state is accepted in serial only")
        own = self._output_node_points()
        if node_u.shape != own.shape or node_points is None or \
                np.shape(node_points) != own.shape:
            raise CaseError(f"nodal state of shape {node_u.shape} does not fit this degree-2 "
                            f"solver's {own.shape[0]} nodes")
        node_points = np.asarray(node_points, float)
        if np.array_equal(node_points, own):
            return node_u
        from scipy.spatial import cKDTree

        dist, idx = cKDTree(node_points).query(own)
        if np.any(dist > 1e-9 * max(1.0, np.abs(own).max())):
            raise CaseError("nodal state: its node points are not this solver's degree-2 nodes")
        return node_u[idx]

    def _p1_into_p2(self, u0, arr):
        V = self.V
        cell_dofs = V.dofmap.list.array.reshape(-1, V.dofmap.dof_layout.num_dofs)
        geo = self.dm.mesh.geometry.dofmap.array.reshape(-1, self.gdim + 1)
        verts = self.dm.node_to_vertex[geo]
        # basix P2 edge ordering on the reference simplex: edge i opposite ... use coordinates
        x = V.tabulate_dof_coordinates()[:, :self.gdim]
        X = self.case.mesh.points
        for k in range(self.gdim + 1, cell_dofs.shape[1]):
            nodes = cell_dofs[:, k]
            # find the two cell vertices whose midpoint is the node
            mids = 0.5 * (X[verts][:, :, None, :] + X[verts][:, None, :, :])
            d = np.linalg.norm(mids - x[nodes][:, None, None, :], axis=3)
            flat = d.reshape(len(nodes), -1).argmin(axis=1)
            a, b = np.unravel_index(flat, d.shape[1:])
            arr[nodes] = 0.5 * (u0[verts[np.arange(len(nodes)), a]] + u0[verts[np.arange(len(nodes)), b]])

    def gather_nodes(self, local_array) -> np.ndarray:
        """(n_global_nodes, gdim) array of a nodal field (owned values), on every rank."""
        n_own = self.n_local_nodes
        vals = np.asarray(local_array).reshape(-1, self.gdim)[:n_own]
        gidx = self.global_nodes[:n_own]
        all_idx = self.comm.allgather(gidx)
        all_val = self.comm.allgather(vals)
        out = np.zeros((self.n_global_nodes, self.gdim))
        for i, v in zip(all_idx, all_val):
            out[i] = v
        return out

    def _vertex_field(self) -> np.ndarray:
        """Displacement at the Case vertices (Case numbering), on every rank."""
        n_own = self.n_local_nodes
        arr = self.u.x.array.reshape(-1, self.gdim)[:n_own]
        nv = self.node_vertex[:n_own]
        mask = nv >= 0
        ids = self.comm.allgather(nv[mask])
        vals = self.comm.allgather(arr[mask])
        out = np.zeros((self.case.mesh.n_vertices, self.gdim))
        for i, v in zip(ids, vals):
            out[i] = v
        return out

    def _probes(self, case: Case, u_vertices) -> dict:
        if self.degree == 1:
            return case.probe_values(u_vertices)
        mesh = self.dm.mesh
        out = {}
        tree = dolfinx.geometry.BoundingBoxTree(mesh, mesh.topology.dim)
        cells_all = case.mesh.cells
        for loc in case.probe_locations:
            # nudge the snapped point into its cell so the collision test is unambiguous
            c = case.mesh.points[cells_all[loc.cell]].mean(axis=0)
            y = loc.snapped_point + 1e-9 * (c - loc.snapped_point)
            p = np.zeros((1, 3))
            p[0, :self.gdim] = y
            cand = dolfinx.geometry.compute_collisions(tree, p)
            coll = dolfinx.geometry.compute_colliding_cells(mesh, cand, p)
            cells = coll.links(0)
            val = np.zeros(self.gdim)
            found = 0
            if len(cells):
                val = self.u.eval(p, cells[:1])
                found = 1
            count = self.comm.allreduce(found)
            tot = self.comm.allreduce(np.asarray(val, float) * found)
            out[loc.name] = tot / max(count, 1)
        return out

    def _reactions(self, case: Case) -> dict:
        """Force (mN) the supports exert on the body, per Dirichlet region: sum of the internal-minus-
        external residual over the region's dofs (owned dofs only, summed over ranks)."""
        r = dolfinx.fem.petsc.assemble_vector(self.R_int_form)
        r.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        arr = r.array.reshape(-1, self.gdim)
        out = {}
        seen = set()
        for b in case.boundaries:
            if b.type == "traction" or b.region in seen:
                continue
            seen.add(b.region)
            if b.region not in self.dm.region_tags:
                continue
            dofs = self.region_dofs(b.region)
            dofs = dofs[dofs < self.n_local_nodes]
            out[b.region] = self.comm.allreduce(arr[dofs].sum(axis=0))
        r.destroy()
        return out

    def _result(self, case, converged, iters, residual, wall, steps, history, lam) -> SolveResult:
        u_v = self._vertex_field()
        energy = self.comm.allreduce(dolfinx.fem.assemble_scalar(self.W_form))
        state = {}
        if self.degree == 2 and self.comm.size == 1:
            # the full P2 state (u holds the vertices only): tangent / internal_forces / warm
            # starts from this result use it; arrays, so the JSON form leaves them out
            nodes = np.empty((len(self.node_vertex), self.gdim))
            nodes[self._out_permutation()[0]] = self.u.x.array.reshape(-1, self.gdim)
            state = {"node_u": nodes, "node_points": self._output_node_points()}
        return SolveResult(
            u=u_v, converged=converged, iterations=iters, residual=float(residual),
            wall_time_s=wall, solver="fem", probes=self._probes(case, u_v),
            reactions=self._reactions(case), strain_energy=float(energy), load_steps=steps,
            degree=self.degree, case_name=case.name, n_vertices=case.mesh.n_vertices,
            n_cells=case.mesh.n_cells, history=history,
            extra={"load_fraction": lam, "n_dofs": int(self.V.dofmap.index_map.size_global * self.gdim),
                   "assemble_s": self.timings.assemble, "linear_solve_s": self.timings.solve,
                   "linear_solver": self.linear_solver,
                   "factorizations": self.timings.factorizations,
                   "krylov_iterations": self.timings.krylov_iterations, **state})

    # ------------------------------------------------------------------ residual / tangent
    def _out_permutation(self):
        nv = self.case.mesh.n_vertices
        out_node = np.empty(len(self.node_vertex), np.int64)
        vm = self.node_vertex >= 0
        out_node[vm] = self.node_vertex[vm]
        out_node[~vm] = nv + np.arange(np.count_nonzero(~vm))
        return out_node, (out_node[:, None] * self.gdim + np.arange(self.gdim)).ravel()

    def internal_forces(self, u=None) -> np.ndarray:
        """Node-major residual f_int - f_ext (mN) at state ``u`` in the Case numbering (serial).

        u: as for :meth:`tangent`."""
        if self.comm.size > 1:
            raise CaseError("internal_forces export runs in serial")
        if u is not None:
            self._set_state(u, exact=True)
        r = dolfinx.fem.petsc.assemble_vector(self.R_int_form)
        out = np.empty(len(r.array))
        out[self._out_permutation()[1]] = r.array
        r.destroy()
        return out

    def tangent(self, u=None, *, pushes=None) -> Tangent:
        """Exact tangent K at state ``u`` (default: the solver's current state).

        u: a SolveResult of a reference solve on this mesh, or an array: (n_vertices, gdim)
        vertex values at degree 1; at degree 2 the full (n_nodes, gdim) nodal state in the
        Tangent node order (vertices, then the edge nodes of ``Tangent.node_points``) -- degree-2
        vertex values alone raise CaseError unless all zero (see :meth:`_set_state`).
        """
        if self.comm.size > 1:
            raise CaseError("tangent export runs in serial (it returns one scipy matrix)")
        import scipy.sparse as sp

        if u is not None:
            self._set_state(u, exact=True)
        case = self.case.with_pushes(pushes or {})
        self.load.value = 1.0
        A = dolfinx.fem.petsc.assemble_matrix(self.K_form)
        A.assemble()
        indptr, indices, data = A.getValuesCSR()
        n = A.getSize()[0]
        K = sp.csr_matrix((data, indices, indptr), shape=(n, n))
        A.destroy()
        # permutation: local node -> output node (vertices first in Case order, then edge nodes)
        nv = self.case.mesh.n_vertices
        perm = self._out_permutation()[1]  # local dof -> output dof
        P = sp.csr_matrix((np.ones(len(perm)), (perm, np.arange(len(perm)))), shape=(n, n))
        K = (P @ K @ P.T).tocsr()
        node_points = self._output_node_points()
        bc_dofs = [perm[e[2]] for e in self._bcs(case, 1.0)]
        dd = np.unique(np.concatenate(bc_dofs)) if bc_dofs else np.zeros(0, np.int64)
        return Tangent(K, dd, node_points, nv, self.degree)


_CACHE: dict = {}


def _solver_for(case: Case, degree: int, **kw) -> ReferenceSolver:
    key = (id(case.mesh), degree, case.material.model, case.gravity,
           tuple((b.region, b.type, str(b.normal), str(b.value)) for b in case.boundaries
                 if b.type in ("traction", "sliding")), tuple(sorted(kw.items())))
    s = _CACHE.get(key)
    if s is None or s.case.mesh is not case.mesh:
        if len(_CACHE) > 8:
            _CACHE.clear()
        s = ReferenceSolver(case, degree=degree, **kw)
        _CACHE[key] = s
    s.case = case
    return s


def solve(case: Case, *, degree: int = 1, pushes=None, initial=None, dirichlet_override=None,
          progress: bool = False, **kw) -> SolveResult:
    """Solve a Case with the reference (compiled forms are cached per mesh and degree).

    pushes: actuator name -> push (mm); initial: warm start (n_vertices, gdim) mm;
    dirichlet_override: (node-major Case dofs, values in mm) added to the Case's prescriptions.
    """
    s = _solver_for(case, degree, **kw)
    return s.solve(pushes, case=case, initial=initial, dirichlet_override=dirichlet_override,
                   progress=progress)


def tangent_stiffness(case: Case, u=None, *, degree: int = 1, pushes=None) -> Tangent:
    """Exact tangent K (scipy CSR, node-major, Case vertex numbering) at displacement ``u``
    (default: rest). Degree 2: pass the SolveResult of a degree-2 reference solve (or its full
    nodal state ``res.extra["node_u"]``); vertex values alone raise CaseError unless all zero."""
    s = _solver_for(case, degree)
    if u is None:
        u = np.zeros((case.mesh.n_vertices, case.mesh.gdim))
    return s.tangent(u, pushes=pushes)
