"""Linear algebra of the reference's Newton: the factorizing KSPs (CHOLMOD in serial, MUMPS
LDL^T for indefinite tangents, saddle-point systems and MPI), the lagged-factor GMRES, the
CG + GAMG iterative mode and the fieldsplit (Schur complement) FGMRES of the mixed formulation
(``saddle``), as one object the ReferenceSolver owns (``LinearSolver``); units are those of
the assembled tangent (mN/mm) and residual (mN)."""
from __future__ import annotations

import logging

import dolfinx
import dolfinx.fem
from dolfinx.la import orthonormalize
from petsc4py import PETSc

from tissue_reference.errors import CaseError

from .factor import cholmod_pc, quiet_c_output
from .mumps import grown_mumps_workspace, mumps_failure, set_mumps_workspace, solve_mumps
from .newton_settings import NewtonSettings, Timings
from .saddle import FieldSplit

log = logging.getLogger("tissue.fem")

# linear_solver="auto": above this many dofs Newton reuses a MUMPS factorization as the GMRES
# preconditioner of later tangents instead of refactorizing every iteration (measured faster from
# 1.8k tets up: 0.97 vs 1.27 s; at 26.6k tets 9.7 vs 22 s, bench/bench_reference.py).
LAGGED_ABOVE_DOFS = 1000
# linear_solver="auto" with the mixed formulation: above this many dofs Newton solves the
# saddle-point tangent by fieldsplit FGMRES (``saddle``) instead of the lagged MUMPS factor.
FIELDSPLIT_ABOVE_DOFS = 100_000
LINEAR_SOLVERS = ("direct", "lagged", "iterative", "fieldsplit")


def choose_linear_solver(linear_solver: str, formulation: str, n_dofs: int,
                         indenters: bool) -> str:
    """The linear solver of Newton's tangents, "auto" resolved and checked against the
    formulation.

    Parameters
    ----------
    linear_solver : str
        "auto", "direct", "lagged", "iterative" or "fieldsplit" (``ReferenceSolver``).
    formulation : str
        "displacement" or "mixed".
    n_dofs : int
        The unknowns of the whole problem (global).
    indenters : bool
        Whether rigid tips press: "auto" then factorizes every tangent.

    Returns
    -------
    str
        "direct", "lagged", "iterative" or "fieldsplit".

    Raises
    ------
    CaseError
        For an unknown name, "iterative" with the mixed formulation or "fieldsplit" with the
        displacement one.
    """
    if linear_solver == "auto":
        # with indenters the tips' contact set moves between Newton iterations: an earlier
        # tangent's factor preconditions the next one poorly (GMRES runs to its restart and
        # the tangent is factorized anyway), so each is factorized
        lagged = n_dofs > LAGGED_ABOVE_DOFS and not indenters
        linear_solver = "lagged" if lagged else "direct"
        if formulation == "mixed" and n_dofs > FIELDSPLIT_ABOVE_DOFS:
            linear_solver = "fieldsplit"
    if linear_solver not in LINEAR_SOLVERS:
        raise CaseError(f"linear_solver must be 'auto', 'direct', 'lagged', 'iterative' or "
                        f"'fieldsplit', got {linear_solver!r}")
    if linear_solver == "iterative" and formulation == "mixed":
        raise CaseError("linear_solver='iterative' (CG + GAMG) needs a positive definite "
                        "tangent: use 'direct', 'lagged' or 'fieldsplit' with the mixed "
                        "formulation")
    if linear_solver == "fieldsplit" and formulation != "mixed":
        raise CaseError("linear_solver='fieldsplit' splits the mixed formulation's "
                        "displacement and pressure: use 'iterative' for the displacement one")
    return linear_solver


class LinearSolver:
    """Newton's linear solves of the reference: ``solve(eta)`` sets du = -A^-1 b for the
    assembled tangent ``A`` and residual ``b`` (PETSc Mat and Vec) into ``du`` (a dolfinx
    Function). mode: "direct" (a factorization of every tangent), "lagged" (GMRES on the current
    tangent preconditioned by the factorization of an earlier one, refactorized when GMRES
    needs more than ``lag_max_its`` iterations, ``NewtonSettings.lag_max_its``), "iterative"
    (CG + GAMG with the rigid-body modes of ``V`` as near null space, MUMPS as the fallback) or
    "fieldsplit" (the
    mixed formulation's ``FieldSplit``, MUMPS as the fallback). ``package``: "cholmod" or
    "mumps", the factorization of "direct" and "lagged" (CHOLMOD falls back on MUMPS for a
    tangent that is not positive definite, to the end of the solve). ``timings`` (``Timings``)
    counts factorizations, Krylov iterations and preconditioner builds; an owner may share its
    own and reset it per solve."""

    def __init__(self, A, b, du, *, mode: str, comm,
                 lag_max_its: int = NewtonSettings.lag_max_its, V=None, package: str = "mumps",
                 fieldsplit: FieldSplit | None = None, timings: Timings | None = None):
        self.A, self.b, self.du, self.mode, self.comm = A, b, du, mode, comm
        self.lag_max_its = int(lag_max_its)
        self.V = V
        self.timings = timings if timings is not None else Timings()
        self.negative_pivots = None  # the inertia of the last factorized tangent
        self.mumps_workspace = None  # MUMPS's ICNTL(14) (percent), None: its default
        self.fieldsplit = fieldsplit
        self._factor_broken = False  # the factor's last factorization failed: it needs a new one
        if mode == "iterative":
            # CG + smoothed-aggregation AMG with the rigid-body modes as near null space;
            # tight tolerance so Newton keeps its quadratic convergence; MUMPS as the fallback
            self.ksp = PETSc.KSP().create(comm)
            self.ksp.setOperators(A)
            self.ksp.setType("cg")
            self.ksp.setTolerances(rtol=1e-10, atol=1e-14, max_it=2000)
            self.ksp.getPC().setType("gamg")
            A.setNearNullSpace(self._rigid_body_nullspace())
            self.factor_package = "mumps"
            self.direct_ksp = self._factor_ksp("mumps")
            self.refactor = True
        elif mode == "fieldsplit":
            self._use_fallback_factor()
        else:
            self.use_factor(package)
        self.first_factor_package = self.factor_package

    def tangent_changed(self):
        """The tangent was changed after it was assembled (e.g. shifted): the next solve
        factorizes it again, whatever the mode's reuse of an earlier factorization."""
        self.refactor = True

    def _rigid_body_nullspace(self):
        d = int(self.V.dofmap.index_map_bs)
        x = self.V.tabulate_dof_coordinates()[:, :d]
        n_own = self.V.dofmap.index_map.size_local
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
        orthonormalize(vecs)
        return PETSc.NullSpace().create(vectors=vecs, comm=self.comm)

    def _factor_ksp(self, pkg: str):
        """KSP whose preconditioner is a Cholesky factorization by ``pkg`` ("mumps" or
        "cholmod"): GMRES around it for "lagged", the factorization alone otherwise."""
        k = PETSc.KSP().create(self.comm)
        k.setOperators(self.A)
        if pkg == "cholmod":
            cholmod_pc(k)   # LL^T: a tangent that is not positive definite fails, to MUMPS
        else:
            k.getPC().setType("cholesky")
            k.getPC().setFactorSolverType(pkg)
        if self.mode == "lagged":
            # right preconditioning: GMRES then tests the true residual of the current tangent
            k.setType("gmres")
            k.setPCSide(PETSc.PC.Side.RIGHT)
            m = max(30, self.lag_max_its + 1)
            k.setGMRESRestart(m)
            k.setTolerances(rtol=1e-10, atol=1e-300, max_it=m)
        else:
            k.setType("preonly")
        return k

    def _fallback_factor(self, percent=None):
        """A new MUMPS KSP for the iterative mode's fallback, ICNTL(14) = ``percent``."""
        k = self._factor_ksp("mumps")
        set_mumps_workspace(k, percent)
        return k

    def _use_fallback_factor(self):
        """The fieldsplit mode's fallback: MUMPS LDL^T of A itself (refactorized whenever A
        changed)."""
        self.use_factor("mumps")
        self.ksp.setOperators(self.A, self.A)
        set_mumps_workspace(self.ksp, self.mumps_workspace)

    def fresh(self):
        """Forget what earlier solves left, so that a solve's Newton path, and so its answer
        and verdict, depend on its inputs alone, not on what this (kept) solver solved before:
        the first tangent of the solve is factorized afresh (a lagged factorization or
        fieldsplit preconditioner comes only from this solve's own iterations), and a CHOLMOD
        solver that an earlier indefinite tangent switched to MUMPS is CHOLMOD again (the
        inertia that MUMPS reports steers Newton's descent test; CHOLMOD reports none). What
        stays is what cannot change an answer: allocated matrices, the symbolic analysis of the
        fixed pattern and a grown MUMPS workspace."""
        if self.mode in ("direct", "lagged") and self.factor_package != self.first_factor_package:
            self.use_factor(self.first_factor_package)
        self.refactor = True
        if self.fieldsplit is not None:
            self.fieldsplit.forget()

    def use_factor(self, pkg: str):
        """(Re)build the factorizing KSP with ``pkg``; P is made at the next refresh. A new
        KSP every time: keeping each package's factor across solves (to save CHOLMOD's
        analysis, about 0.8 s at 38-64k unknowns) made a marginal load's Newton path depend on
        what the solver had solved before, 19 iterations against 4 at one load step
        (tests/test_same_input_same_answer.py)."""
        self.factor_package = pkg
        self.P = None
        self._T = None
        self.refactor = True
        self._factor_broken = False
        self.ksp = self.direct_ksp = self._factor_ksp(pkg)

    def _after_mumps_failure(self, ksp) -> bool:
        """After a solve of ``ksp``: whether MUMPS's factorization failed for want of workspace
        and the solve is worth repeating, with ICNTL(14) grown (``grown_mumps_workspace``). Any
        failed factorization marks the factor broken: PETSc 3.18 never factorizes a MUMPS factor
        again once a factorization failed in it, so a new one is built."""
        if self.factor_package != "mumps" or not mumps_failure(ksp):
            return False
        self._factor_broken = True
        grown = grown_mumps_workspace(ksp, self.mumps_workspace)
        if grown is None:
            return False
        self.mumps_workspace = grown
        return True

    def _refresh_factor(self):
        """Copy the current tangent into the matrix that is factorized (the factorization itself
        happens at the next solve; PETSc reuses the symbolic analysis, the pattern being fixed).
        MUMPS reads SBAIJ (the upper half) or AIJ; CHOLMOD reads a point-block (bs 1) AIJ."""
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
        elif self.A.getType().endswith("baij"):
            if first:
                self.P = PETSc.Mat()
            self.A.convert("sbaij", self.P)
        else:
            # AIJ (the mixed space has no common block size): MUMPS's LDL^T reads the upper
            # triangle of AIJ itself; a copy keeps the factorized tangent apart from A (an AIJ ->
            # SBAIJ conversion into an existing matrix fails in PETSc 3.18)
            if first:
                self.P = self.A.duplicate(copy=True)
            else:
                self.A.copy(self.P, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
        if first:
            self.ksp.setOperators(self.A, self.P)
            if self.factor_package == "mumps":
                set_mumps_workspace(self.ksp, self.mumps_workspace)
        self.refactor = False
        self.timings.factorizations += 1

    def factor_solve(self, eta):
        """One solve of the current factorizing KSP; a CHOLMOD failure (tangent not positive
        definite) switches to MUMPS and solves again. ``negative_pivots``: the inertia of the
        tangent when it was factorized for this solve, else None."""
        if self._factor_broken:
            self.use_factor(self.factor_package)
        refresh = self.mode == "direct" or self.refactor
        if refresh:
            self._refresh_factor()
        self.negative_pivots = None
        if self.mode == "lagged":
            self.ksp.setTolerances(rtol=eta)
        try:
            if self.factor_package == "cholmod":
                with quiet_c_output():  # CHOLMOD printf's a warning on an indefinite tangent
                    self.ksp.solve(self.b, self.du.vector)
            else:
                self.ksp.solve(self.b, self.du.vector)
        except PETSc.Error:
            if self.factor_package != "cholmod":
                raise
            log.info("tangent not positive definite for CHOLMOD: switching to MUMPS LDL^T")
            self.use_factor("mumps")
            self.factor_solve(eta)
            return
        if self._after_mumps_failure(self.ksp):
            self.factor_solve(eta)
            return
        if refresh:
            self.negative_pivots = self._inertia()

    def _inertia(self):
        """Negative pivots of the factorization just made (0 after a CHOLMOD Cholesky, MUMPS
        LDL^T's INFOG(12)); None when unknown (MUMPS LU)."""
        if self.factor_package == "cholmod":
            return 0
        try:
            return int(self.ksp.getPC().getFactorMatrix().getMumpsInfog(12))
        except PETSc.Error:
            return None

    def _fieldsplit_solve(self, eta) -> tuple[int, object]:
        """The fieldsplit solve, or where it does not converge the MUMPS fallback's; returns
        (Krylov iterations, the KSP whose answer stands)."""
        its, built, ok = self.fieldsplit.solve(self.b, self.du.vector, eta)
        self.timings.preconditioner_builds += built
        if ok:
            return its, self.fieldsplit.ksp
        while True:
            if self._factor_broken:
                self._use_fallback_factor()
            self.ksp.solve(self.b, self.du.vector)
            self.timings.factorizations += 1
            if not self._after_mumps_failure(self.ksp):
                return its, self.ksp

    def solve(self, eta: float) -> bool:
        """du = -A^-1 b at relative tolerance ``eta`` (Krylov modes); False when it fails."""
        lagged = self.mode == "lagged"
        self.b.scale(-1.0)
        try:
            if self.mode == "fieldsplit":
                its, ksp = self._fieldsplit_solve(eta)
            elif self.mode == "iterative":
                ksp = self.ksp
                ksp.solve(self.b, self.du.vector)
                its = ksp.getIterationNumber()
                if ksp.getConvergedReason() < 0:
                    ksp = self.direct_ksp = solve_mumps(self.direct_ksp, self.b,
                                                        self.du.vector, self._fallback_factor)
                    self.timings.factorizations += 1
            else:
                self.factor_solve(eta)
                ksp = self.ksp
                its = ksp.getIterationNumber()
                if ksp.getConvergedReason() < 0 and lagged:
                    # the old factor is too far from this tangent: refactorize and solve again
                    self.refactor = True
                    self.factor_solve(eta)
                    ksp = self.ksp
                    its += ksp.getIterationNumber()
        except PETSc.Error as exc:  # MUMPS on NaN entries (error 76) and the like
            log.debug("linear solve failed: %s", exc)
            self.refactor = True
            # the factor may be left half set up: the next solve builds a new one
            self._factor_broken = self.mode in ("direct", "lagged")
            return False
        finally:
            self.b.scale(-1.0)
        if self.mode != "direct":
            self.timings.krylov_iterations += its
            if lagged and its > self.lag_max_its:
                self.refactor = True
        self.du.x.scatter_forward()
        return ksp.getConvergedReason() > 0
