"""The reference's factorizing solves recover from a failed MUMPS factorization.

Two failures are exercised on real factorizations (serial, so they are deterministic):
- MUMPS's workspace, sized at its analysis, too small for the pivots an indefinite matrix
  delays (INFOG(1) = -9): the solve is repeated with a larger ICNTL(14). Two MPI ranks meet
  this at random on the mixed formulation's saddle-point tangent (the pivots delayed depend on
  the order in which messages arrive).
- PETSc 3.18 never factorizes a MUMPS factor again once a factorization failed in it: after a
  singular tangent, the solver must build a new factor, or every later solve fails at once.
"""
from itertools import pairwise
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import scipy.sparse as sp
from fem_checks import laplacian_1d
from petsc4py import PETSc

import tissue_reference.fem_reference as fr
from tissue_reference.fem_reference.factor import has_cholmod
from tissue_reference.fem_reference.linalg import LinearSolver
from tissue_reference.fem_reference.mumps import mumps_failure, set_mumps_workspace, solve_mumps
from tissue_reference.model.case import load_case

ROOT = Path(__file__).resolve().parents[1]


def _zero_diagonal_matrix(m=1000, density=0.001):
    """[[0, C], [C^T, 0]] with C = 2 I + a sparse random part: symmetric, indefinite and well
    conditioned (condition number 3.2), with a zero diagonal. Every 1x1 pivot is refused and
    MUMPS delays pivots beyond its analysis's estimate when ICNTL(14) leaves no margin."""
    C = 2 * sp.identity(m) + sp.random(m, m, density=density, random_state=1)
    return sp.bmat([[None, C], [C.T, None]]).tocsr()


def _bare_solve(M, workspace):
    """A direct MUMPS LinearSolver of the matrix M alone, its workspace ICNTL(14) = workspace."""
    A = PETSc.Mat().createAIJ(M.shape, comm=PETSc.COMM_SELF, csr=(
        M.indptr.astype(PETSc.IntType), M.indices.astype(PETSc.IntType), M.data))
    A.setOption(PETSc.Mat.Option.SYMMETRIC, True)
    b, x = A.createVecLeft(), A.createVecRight()
    s = LinearSolver(A, b, SimpleNamespace(vector=x), mode="direct", comm=PETSc.COMM_SELF)
    s.mumps_workspace = workspace
    s.use_factor("mumps")
    return s


def test_workspace_too_small_is_grown_and_the_solve_repeated():
    M = _zero_diagonal_matrix()
    rhs = np.random.default_rng(0).standard_normal(M.shape[0])
    s = _bare_solve(M, workspace=0)
    s.b.array[:] = rhs
    s.factor_solve(1e-8)
    # the first factorization failed for want of workspace and a grown one solved the system
    assert s.mumps_workspace > 0
    assert s.timings.factorizations >= 2
    assert s.ksp.getConvergedReason() > 0
    x = s.du.vector.array
    assert np.linalg.norm(M @ x - rhs) <= 1e-10 * np.linalg.norm(rhs)


def _petsc(M):
    return PETSc.Mat().createAIJ(M.shape, comm=PETSc.COMM_SELF, csr=(
        M.indptr.astype(PETSc.IntType), M.indices.astype(PETSc.IntType), M.data))


def _mumps_ksp(A, percent):
    k = PETSc.KSP().create(PETSc.COMM_SELF)
    k.setOperators(A)
    k.setType("preonly")
    k.getPC().setType("cholesky")
    k.getPC().setFactorSolverType("mumps")
    set_mumps_workspace(k, percent)
    return k


def test_no_margin_does_fail_without_the_retry():
    """The matrix above does need the retry: with no margin MUMPS refuses it (INFOG(1) = -9)."""
    A = _petsc(_zero_diagonal_matrix())
    k = _mumps_ksp(A, 0)
    b, x = A.createVecLeft(), A.createVecRight()
    b.set(1.0)
    k.solve(b, x)
    assert k.getConvergedReason() < 0
    assert k.getPC().getFactorMatrix().getMumpsInfog(1) == -9
    assert mumps_failure(k) == -9


def test_one_off_solves_grow_the_workspace_too():
    M = _zero_diagonal_matrix()
    A = _petsc(M)
    made = []

    def rebuild(percent):
        made.append(percent)
        return _mumps_ksp(A, percent)

    b, x = A.createVecLeft(), A.createVecRight()
    rhs = np.random.default_rng(1).standard_normal(M.shape[0])
    b.array[:] = rhs
    k = solve_mumps(_mumps_ksp(A, 0), b, x, rebuild)
    assert made and made[0] == 20 and all(q > p for p, q in pairwise(made))
    assert k.getConvergedReason() > 0
    assert np.linalg.norm(M @ x.array - rhs) <= 1e-10 * np.linalg.norm(rhs)


def test_one_off_solve_of_a_singular_matrix_fails_and_leaves_a_new_factor():
    M = _zero_diagonal_matrix()
    A0 = _petsc(M * 0.0)  # the same pattern, all zero
    b, x = A0.createVecLeft(), A0.createVecRight()
    b.set(1.0)
    k = solve_mumps(_mumps_ksp(A0, None), b, x, lambda p: _mumps_ksp(A0, p))
    assert k.getConvergedReason() == 0  # a new, unsolved factor: the solve failed
    assert mumps_failure(k) == 0


def test_a_singular_tangent_does_not_break_later_solves():
    case = load_case(ROOT / "meshes/cases/phantom.toml", size=14)
    pushes = {"A1": 4.0, "A3": 2.0}
    expected = fr.ReferenceSolver(case, degree=1, linear_solver="direct").solve(pushes).probes
    s = fr.ReferenceSolver(case, degree=1, linear_solver="direct")
    assert s.solve({"A1": 1.0}).converged  # an assembled tangent, factorized
    s.A.scale(0.0)  # the same pattern, all zero: MUMPS's factorization fails (singular)
    s.b.set(1.0)
    assert not s.linear.solve(1e-3)   # (where CHOLMOD stands first, it hands it to MUMPS)
    broken = s.linear.ksp
    assert s.linear.factor_package == "mumps"
    assert broken.getPC().getFactorMatrix().getMumpsInfog(1) < 0
    r = s.solve(pushes)
    assert r.converged
    for name, u in expected.items():
        assert np.allclose(r.probes[name], u, rtol=1e-6, atol=1e-9), name
    # MUMPS factorizes again, in a new factor: the failed one is never reused
    s.linear.use_factor("mumps")
    s.b.set(1.0)
    assert s.linear.solve(1e-3)
    assert s.linear.ksp is not broken


def test_cholmod_hands_an_indefinite_tangent_to_mumps_and_the_next_solve_is_cholmods():
    """The lagged mode's CHOLMOD (serial): a tangent that is not positive definite is solved by
    MUMPS LDL^T (its inertia reported) to the end of the solve, and the next solve is CHOLMOD's
    again (``fresh``). The tridiagonal Laplacian shifted by -0.1 is sparse enough that
    CHOLMOD, left to choose, would factorize it by a simplicial LDL^T without complaint: the
    project's CHOLMOD is always the supernodal LL^T, which refuses it. Answers against SciPy's
    sparse LU."""
    if not has_cholmod():
        pytest.skip("PETSc has no CHOLMOD")
    shifts = (0.5, -0.1, 0.3, 0.7)
    A = _petsc(laplacian_1d(shift=shifts[0]))
    A.setOption(PETSc.Mat.Option.SYMMETRIC, True)
    b, x = A.createVecLeft(), A.createVecRight()
    du = SimpleNamespace(vector=x, x=SimpleNamespace(scatter_forward=lambda: None))
    s = LinearSolver(A, b, du, mode="lagged", comm=PETSc.COMM_SELF, package="cholmod")
    rhs = np.random.default_rng(2).standard_normal(A.getSize()[0])
    used, inertia, kernels = [], [], []
    for i, shift in enumerate(shifts):
        if i == 3:
            s.fresh()   # a new solve
        M = laplacian_1d(shift=shift)
        A.zeroEntries()
        A.setValuesCSR(M.indptr.astype(PETSc.IntType), M.indices.astype(PETSc.IntType), M.data)
        A.assemble()
        s.tangent_changed()   # each tangent factorized, as Newton does when GMRES would lag
        s.b.array[:] = rhs
        assert s.solve(1e-12)
        used.append(s.factor_package)
        inertia.append(s.negative_pivots)
        kernels.append(s.ksp)
        expected = -sp.linalg.spsolve(M.tocsc(), rhs)   # Newton's correction: -A^-1 b
        assert np.abs(s.du.vector.array - expected).max() <= 1e-9 * np.abs(expected).max()
    assert used == ["cholmod", "mumps", "mumps", "cholmod"]
    # MUMPS counts the indefinite tangent's negative eigenvalues, 2 (1 - cos(k pi / 801)) < 0.1
    n_neg = sum(2 * (1 - np.cos(k * np.pi / 801)) < 0.1 for k in range(1, 801))
    assert inertia == [0, n_neg, 0, 0]
    # MUMPS to the end of the solve, and the next solve's CHOLMOD a new factor
    assert kernels[1] is kernels[2] and kernels[3] is not kernels[0]
