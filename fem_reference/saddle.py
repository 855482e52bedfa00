"""Iterative solves of the mixed formulation's saddle-point tangent

    [ K_uu   B^T            ] [du]     [r_u]
    [ B     -(1/kappa) M_p  ] [dp]  = -[r_p]

(Taylor-Hood P2/P1; K_uu: the isochoric and pressure stiffness of the displacement, B: the
linearized volume change, M_p: the P1 pressure mass matrix). Outer FGMRES (right
preconditioned: it tests the true residual, at Newton's forcing tolerance), preconditioned by
PETSc's PCFIELDSPLIT Schur factorization: K_uu approximately inverted by one cycle of
smoothed-aggregation AMG (GAMG with the rigid-body modes as near null space), the Schur
complement S = -(1/kappa) M_p - B K_uu^-1 B^T by -(1/mu + 1/kappa) M_p (its spectral
equivalent for an inf-sup stable pair), applied by a Cholesky factorization of the pressure
mass matrix. An indefinite K_uu (near a buckling instability) leaves GMRES valid; a solve that
does not converge falls back to the MUMPS factorization of the whole tangent.

The preconditioner is lagged as the direct solvers' factorizations are: built on one Newton
iteration's tangent (the AMG hierarchy's Galerkin products are most of its cost), it is reused
for the next ones while FGMRES, which always multiplies by the current tangent, needs at most
LAG_GROWTH times the iterations it took when fresh (and at least LAG_MIN_ITS); past that, or
when a lagged solve does not converge, it is rebuilt on the current tangent.
Owned by the reference's ``linalg.LinearSolver``; units: mm, kPa, mN."""
from __future__ import annotations

import logging

import dolfinx
import dolfinx.fem
import dolfinx.fem.petsc
import numpy as np
import ufl
from dolfinx.la import orthonormalize
from petsc4py import PETSc

from .jit import compile_form

log = logging.getLogger("tissue.fem")

# PETSc options of the fieldsplit KSP (prefix SADDLE_PREFIX); an entry already in PETSc's options
# database (e.g. -saddle_pc_fieldsplit_schur_fact_type full on the command line) wins.
SADDLE_PREFIX = "saddle_"
SADDLE_OPTIONS = {
    "ksp_type": "fgmres",
    "ksp_gmres_restart": 200,
    "ksp_max_it": 400,
    "pc_fieldsplit_schur_fact_type": "upper",
    "fieldsplit_u_ksp_type": "preonly",
    "fieldsplit_u_pc_type": "gamg",
    "fieldsplit_u_pc_gamg_threshold": 0.02,
    "fieldsplit_u_pc_gamg_square_graph": 1,
    "fieldsplit_u_mg_levels_ksp_type": "chebyshev",
    "fieldsplit_u_mg_levels_ksp_max_it": 2,
    "fieldsplit_u_mg_levels_pc_type": "jacobi",
    "fieldsplit_p_ksp_type": "preonly",
    "fieldsplit_p_pc_type": "cholesky",
}


LAG_GROWTH = 2.0
"""A lagged fieldsplit preconditioner is rebuilt after a solve that needed more than this times
the iterations of its fresh solve."""
LAG_MIN_ITS = 30
"""... and more than this many iterations (a fresh solve may take only a handful)."""
LAG = True
"""Reuse the preconditioner as above (False: build it at every Newton iteration, for
comparisons: bench/bench_mixed.py --lag)."""


class FieldSplit:
    """The "fieldsplit" linear solve of the mixed formulation's tangent ``A`` (module docstring):
    ``solve(b, x, eta)``. W, V: the mixed space and its collapsed displacement space; umap,
    pmap: the W dof of each V / Q dof; E, nu, inv_kappa: the material's Constants (the Schur
    preconditioner is reassembled when they change); dm: the DolfinxMesh."""

    def __init__(self, A, *, W, V, umap, pmap, E, nu, inv_kappa, dm, comm):
        self.A, self.W, self.V, self.umap, self.pmap = A, W, V, umap, pmap
        self.E, self.nu, self.inv_kappa, self.dm, self.comm = E, nu, inv_kappa, dm, comm
        self.gdim = int(V.dofmap.index_map_bs)
        self.is_u, self.is_p, ns = self._split_sets()
        # fieldsplit sets a near null space composed with a split's IS on that split's matrix
        self.is_u.compose("nearnullspace", ns)
        self._null_space = ns
        opts = PETSc.Options()
        for k, v in SADDLE_OPTIONS.items():
            if not opts.hasName(SADDLE_PREFIX + k):
                opts[SADDLE_PREFIX + k] = v
        k = PETSc.KSP().create(comm)
        k.setOptionsPrefix(SADDLE_PREFIX)
        k.setOperators(A)
        pc = k.getPC()
        pc.setType("fieldsplit")
        pc.setFieldSplitType(PETSc.PC.CompositeType.SCHUR)
        pc.setFieldSplitIS(("u", self.is_u), ("p", self.is_p))
        k.setPCSide(PETSc.PC.Side.RIGHT)
        k.setFromOptions()
        self.ksp = k
        self._mp_form = None
        self._sp_key = None
        self._Sp = None
        self.fresh_its = None  # iterations of the last solve with a freshly built preconditioner

    def forget(self):
        """Build the preconditioner afresh at the next solve."""
        self.fresh_its = None

    def _split_sets(self):
        """Index sets (global W dofs, ascending) of the displacement (block size gdim: the
        components of a node are consecutive in W) and of the pressure, and the rigid-body modes
        on the displacement set as a PETSc NullSpace."""
        imap = self.W.dofmap.index_map
        n_own, first = imap.size_local, imap.local_range[0]
        d = self.gdim
        umap = self.umap.reshape(-1, d)
        own = umap[:, 0] < n_own
        order = np.argsort(umap[own, 0], kind="stable")
        nodes = umap[own][order]  # (owned nodes, d) W dofs, ascending
        if not np.all(nodes[:, 1:] == nodes[:, :1] + np.arange(1, d)):
            raise RuntimeError("the displacement components of a node are not consecutive in W")
        is_u = PETSc.IS().createGeneral((nodes.ravel() + first).astype(PETSc.IntType),
                                        comm=self.comm)
        is_u.setBlockSize(d)
        p = np.sort(self.pmap[self.pmap < n_own])
        is_p = PETSc.IS().createGeneral((p + first).astype(PETSc.IntType), comm=self.comm)
        # rigid-body modes at the owned displacement nodes, in is_u's order
        xv = self.V.tabulate_dof_coordinates()[:, :d]
        x = xv[np.flatnonzero(own)[order]]
        m = len(x)
        modes = np.zeros((6 if d == 3 else 3, m, d))
        for k in range(d):
            modes[k, :, k] = 1.0
        if d == 3:
            modes[3, :, 0], modes[3, :, 1] = -x[:, 1], x[:, 0]
            modes[4, :, 1], modes[4, :, 2] = -x[:, 2], x[:, 1]
            modes[5, :, 0], modes[5, :, 2] = x[:, 2], -x[:, 0]
        else:
            modes[2, :, 0], modes[2, :, 1] = -x[:, 1], x[:, 0]
        vecs = []
        for mode in modes:
            v = PETSc.Vec().createMPI((m * d, PETSc.DECIDE), bsize=d, comm=self.comm)
            v.array[:] = mode.ravel()
            vecs.append(v)
        orthonormalize(vecs)
        return is_u, is_p, PETSc.NullSpace().create(vectors=vecs, comm=self.comm)

    def _schur_preconditioner(self):
        """-(1/mu + 1/kappa) M_p on the pressure set (kPa^-1 mm^3), reassembled when E or nu
        changed since the last one."""
        key = (float(self.E.value), float(self.nu.value), float(self.inv_kappa.value))
        if self._sp_key == key:
            return self._Sp
        if self._mp_form is None:
            _, p = ufl.TrialFunctions(self.W)
            _, q = ufl.TestFunctions(self.W)
            mu = self.E / (2 * (1 + self.nu))
            dx = ufl.Measure("dx", domain=self.dm.mesh, metadata={"quadrature_degree": 2})
            self._mp_form = compile_form(-(1 / mu + self.inv_kappa) * p * q * dx)
        Mw = dolfinx.fem.petsc.assemble_matrix(self._mp_form)
        Mw.assemble()
        Sp = Mw.createSubMatrix(self.is_p, self.is_p)
        Mw.destroy()
        Sp.setOption(PETSc.Mat.Option.SYMMETRIC, True)
        self._Sp, self._sp_key = Sp, key
        self.fresh_its = None  # a new Schur block: the lagged preconditioner is rebuilt
        self.ksp.getPC().setFieldSplitSchurPreType(PETSc.PC.SchurPreType.USER, Sp)
        return Sp

    def solve(self, b, x, eta: float) -> tuple[int, int, bool]:
        """x = A^-1 b by fieldsplit FGMRES at relative tolerance ``eta``, the preconditioner
        lagged (module docstring). Returns (Krylov iterations, preconditioners built,
        converged); a solve that does not converge with a fresh preconditioner is left to the
        caller's factorization."""
        self._schur_preconditioner()
        k = self.ksp
        k.setTolerances(rtol=eta, atol=1e-300)
        total = built = 0
        while True:
            fresh = self.fresh_its is None or not LAG
            k.getPC().setReusePreconditioner(not fresh)
            k.solve(b, x)
            its = k.getIterationNumber()
            total += its
            if k.getConvergedReason() > 0:
                if fresh:
                    built += 1
                    self.fresh_its = its
                elif its > max(LAG_GROWTH * self.fresh_its, LAG_MIN_ITS):
                    self.fresh_its = None  # too far from this tangent: rebuild next time
                return total, built, True
            if fresh:
                break
            log.debug("lagged fieldsplit preconditioner: no convergence in %d iterations, "
                      "rebuilding it on the current tangent", its)
            self.fresh_its = None
        log.info("fieldsplit FGMRES did not converge (reason %d after %d iterations): "
                 "solving with the MUMPS factorization", k.getConvergedReason(), its)
        return total, built, False
