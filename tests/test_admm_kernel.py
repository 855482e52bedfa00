"""The compiled ADMM element loop (solvers/admm_kernel.c) against the numpy loop it replaces:
same z-step (safeguarded model-Newton step, line search included), dual update, residuals and
x-step data, element by element, and the same ADMM iterates in whole solves (3D and 2D,
Neo-Hookean and linear elasticity, oblique sliding, implicit-Euler dynamics)."""
import functools

import numpy as np
import pytest
import scipy.sparse as sp
from fem_checks import laplacian_1d

from tissue_reference.meshes.builders import box, rectangle
from tissue_reference.model.case import Boundary, Case, Material
from tissue_reference.solvers import admm, ckernel
from tissue_reference.solvers.admm import amg, factor, kernel_array, kernel_c, mechanics, operators


def test_the_compiled_loop_is_built_here():
    # `make test` installs gcc and python3-dev (as dolfinx's own JIT needs); without them the
    # solver falls back to numpy and every comparison below would compare numpy with itself
    assert ckernel.load() is not None, "the ADMM kernel did not build: is gcc installed?"
    assert admm.use_kernel()


def _case(mesh, model, boundaries=None, nu=0.45):
    b = boundaries or [Boundary("xmin", "fixed"),
                       Boundary("xmax", "displacement",
                                value=(1.5, 0.5, -0.3)[:mesh.gdim])]
    return Case(mesh, Material(model=model, E=6.0, nu=nu), boundaries=b)


def _both(fn, monkeypatch):
    out = []
    for use in (False, True):
        monkeypatch.setattr(kernel_c, "USE_CKERNEL", use)
        assert admm.use_kernel() is use
        out.append(fn())
    return out


@pytest.mark.parametrize("model", ["neo-hookean", "linear-elastic"])
def test_one_update_from_a_strained_state_matches_numpy_element_by_element(model, monkeypatch):
    """A state with nearly inverted elements and large steps: the line search, the repeated
    rounds and the fast path all run."""
    case = _case(box(4.0), model)
    ops = admm.prepare(case)
    rng = np.random.default_rng(3)
    d, m = ops.d, ops.m
    up = operators.particular(case, ops)
    F = np.eye(d)[:, :, None] + 0.35 * rng.standard_normal((d, d, m))
    F[:, :, :5] = np.eye(d)[:, :, None] * 0.2  # J = 0.008: below the safe-step bound
    lam = 0.2 * rng.standard_normal((d, d, m))
    q = rng.standard_normal(ops.nq)
    zstep = kernel_array.ZStep(ops, 2.0 * ops.rho)  # as after one rho doubling
    if model == "neo-hookean":
        J0, _ = mechanics.det_cof(kernel_array.aos(F))
        assert (J0 <= 0.05).sum() >= 5 and (J0 > 0.5).sum() > m // 4
    res = {}
    for cls in (kernel_array.NumpyElements, kernel_c.KernelElements):
        el = cls(ops, zstep, up, F.copy(), lam.copy())
        x0 = el.xdata().copy()
        r, dsq = el.update(q)
        res[cls] = (x0, r.copy(), dsq.copy(), np.array(el.F), np.array(el.lam), el.xdata().copy())
    a, b = res[kernel_array.NumpyElements], res[kernel_c.KernelElements]
    names = ["x-step data (start)", "primal r", "dual dsq", "F", "lambda", "x-step data"]
    for name, x, y in zip(names, a, b):
        assert np.all(np.isfinite(x)), name
        assert np.abs(x - y).max() <= 1e-11 * max(1.0, np.abs(x).max()), name


@pytest.mark.parametrize("kind", ["3d-neo-hookean", "3d-linear", "2d-neo-hookean",
                                  "3d-oblique-sliding", "3d-dynamics"])
def test_whole_solves_give_the_numpy_iterates(kind, monkeypatch):
    kw = {"polish": False, "tol_mm": 1e-7, "max_iter": 400, "lift": False}
    if kind == "2d-neo-hookean":
        case = _case(rectangle(1.5), "neo-hookean")
    elif kind == "3d-oblique-sliding":
        # u.n = 0 on ymin, n = (0, 1, 1)/sqrt(2): consistent with both prescribed faces
        n = np.array([0.0, 1.0, 1.0]) / np.sqrt(2.0)
        case = _case(box(4.0), "neo-hookean", [
            Boundary("xmin", "fixed"), Boundary("xmax", "displacement", value=(1.5, 0.3, -0.3)),
            Boundary("ymin", "sliding", normal=n.tolist(), value=0.0)])
    else:
        case = _case(box(4.0), "linear-elastic" if kind == "3d-linear" else "neo-hookean")
    if kind == "3d-dynamics":
        kw = {**kw, "dynamics": admm.ImplicitEuler(dt=0.05, steps=3)}
    ref, fast = _both(lambda: admm.solve(case, **kw), monkeypatch)
    assert ref.extra["admm_iterations"] == fast.extra["admm_iterations"] > 5
    for key in ("primal", "dual"):
        h0, h1 = np.array(ref.history[key]), np.array(fast.history[key])
        assert np.abs(h0 - h1).max() <= 1e-9 * h0.max(), key
    assert np.abs(ref.u - fast.u).max() <= 1e-9


@pytest.mark.parametrize("coarse_factors", [False, True])
@pytest.mark.parametrize("mode", ["solve", "step"])
def test_compiled_amg_pcg_matches_the_numpy_one(mode, coarse_factors, monkeypatch):
    """The large-mesh x-step (CG with the AMG V-cycle) in C against its numpy form on the x-step
    matrix of a box mesh fixed on one face, with two AMG levels, the coarsest solved by its
    dense inverse or by SuperLU's factors: same iterates, same iteration counts."""
    monkeypatch.setattr(amg.AmgPcg, "coarse", 100)
    mesh = box(0.8)
    L = operators.scalar_laplacian(admm.element_kinematics(mesh), 9.0, mesh.n_vertices).tocsr()
    free = np.setdiff1d(np.arange(mesh.n_vertices), mesh.region_vertices("xmin"))
    A = L[free][:, free].tocsr()
    M = amg.AmgPcg(A, coarse_factors=coarse_factors)
    assert M._c is not None and len(M.levels) >= 2
    rng = np.random.default_rng(4)
    B = rng.standard_normal((A.shape[0], 3))
    X0 = rng.standard_normal(B.shape)
    args = (500, 1e-12, 0.0) if mode == "solve" else (25, 0.0, 1e-3)
    out = []
    for compiled in (True, False):
        c = M._c
        if not compiled:
            M._c = None
        M.count = [0, 0]
        X = M._pcg(B, X0.copy(), *args)
        out.append((X, M.count[1], M.last_update))
        M._c = c
    (Xc, nc, lc), (Xn, nn, ln) = out
    assert nc == nn > 1
    assert np.abs(Xc - Xn).max() <= 1e-9 * np.abs(Xn).max()
    assert lc == pytest.approx(ln, rel=1e-6)
    if mode == "solve":
        assert np.linalg.norm(B - A @ Xc) <= 1e-10 * np.linalg.norm(B)


def test_compiled_aggregates_are_the_python_ones():
    """The aggregation in C against its Python form, entry by entry: on a mesh Laplacian's
    graph and on a random symmetric graph with isolated rows."""
    mesh = box(0.8)
    L = operators.scalar_laplacian(admm.element_kinematics(mesh), 9.0, mesh.n_vertices).tocsr()
    rng = np.random.default_rng(6)
    R = sp.random(3000, 3000, density=0.002, random_state=7, format="csr")
    keep = np.ones(3000)
    keep[rng.choice(3000, 50, replace=False)] = 0.0   # rows and columns with no neighbour
    R = (sp.diags(keep) @ (R + R.T + sp.identity(3000)) @ sp.diags(keep)).tocsr()
    R.eliminate_zeros()
    for A in (L, R):
        agg_c, na_c = amg.strength_aggregates(A)
        agg_p, na_p = amg.python_aggregates(A)
        assert na_c == na_p and np.array_equal(agg_c, agg_p)
        assert agg_p.min() == 0 and agg_p.max() == na_p - 1


@pytest.mark.parametrize("coarse", [100, 5000])
def test_compiled_vcycle_matches_the_numpy_one(coarse, monkeypatch):
    """One V-cycle alone (the Mass Tensor method's preconditioner) in C, the coarsest level by
    SuperLU's factors, against amg_array's in numpy: with levels, and with none (the coarsest
    matrix is the matrix, its V-cycle a direct solve, checked against scipy's)."""
    monkeypatch.setattr(amg.AmgPcg, "coarse", coarse)
    mesh = box(0.8)
    L = operators.scalar_laplacian(admm.element_kinematics(mesh), 9.0, mesh.n_vertices).tocsr()
    free = np.setdiff1d(np.arange(mesh.n_vertices), mesh.region_vertices("xmin"))
    A = L[free][:, free].tocsr()
    M = amg.AmgPcg(A, coarse_factors=True)
    assert M._c is not None and (len(M.levels) >= 1) is (coarse < A.shape[0])
    B = np.random.default_rng(5).standard_normal((A.shape[0], 3))
    Xc = M.vcycle(B)
    X1 = M.vcycle(B[:, :1])          # another number of columns, then three again
    assert np.array_equal(M.vcycle(B), Xc)
    c, M._c = M._c, None
    Xn = M.vcycle(B)
    assert np.abs(X1 - M.vcycle(B[:, :1])).max() <= 1e-10 * np.abs(Xn).max()
    M._c = c
    assert np.abs(Xc - Xn).max() <= 1e-10 * np.abs(Xn).max()
    if not M.levels:
        from scipy.sparse.linalg import spsolve
        X = spsolve(A.tocsc(), B)
        assert np.abs(Xc - X).max() <= 1e-10 * np.abs(X).max()
        # and the PCG around it (its compiled form needs a level: numpy's runs)
        assert np.abs(M.solve(B) - X).max() <= 1e-10 * np.abs(X).max()


def test_polish_factorization_is_cholmod_while_definite_and_superlu_otherwise():
    """The Newton polish's tangent factorization with the ``factorize`` hook that ``tissue``
    passes (fem_reference.cholmod_factor): CHOLMOD while positive definite (symbolic analysis
    kept for the next tangent of the same pattern), SuperLU otherwise; same solutions. Without
    the hook: SuperLU."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    from tissue_reference.fem_reference import cholmod_factor
    from tissue_reference.fem_reference.factor import PetscFactor, has_cholmod
    case = _case(box(1.5), "neo-hookean")
    ops = admm.prepare(case)
    u = admm.solve(case, polish=False, max_iter=50).u.ravel()
    K, _ = ops.reduced_tangent(u)
    assert K.shape[0] >= 500
    b = np.random.default_rng(5).standard_normal(K.shape[0])
    assert not isinstance(factor.sym_splu(K), PetscFactor)
    cache = {}
    f1 = factor.sym_splu(K, cache, cholmod_factor)
    assert isinstance(f1, PetscFactor) == has_cholmod()
    ref = spla.spsolve(K.tocsc(), b)
    assert np.abs(f1.solve(b) - ref).max() <= 1e-9 * np.abs(ref).max()
    K2 = K * 1.5 + sp.diags(np.full(K.shape[0], 0.1 * abs(K.diagonal()).max()))
    f2 = factor.sym_splu(K2.tocsc(), cache, cholmod_factor)
    if has_cholmod():
        assert f2 is f1  # same pattern: the same CHOLMOD matrix, refactorized
    ref2 = spla.spsolve(K2.tocsc(), b)
    assert np.abs(f2.solve(b) - ref2).max() <= 1e-9 * np.abs(ref2).max()
    # several right-hand sides at once (CHOLMOD's multi-column solve), and one as a column
    B = np.random.default_rng(6).standard_normal((K.shape[0], 3))
    refB = spla.spsolve(K2.tocsc(), B)
    assert f2.solve(B).shape == B.shape
    assert np.abs(f2.solve(B) - refB).max() <= 1e-9 * np.abs(refB).max()
    assert np.abs(f2.solve(B[:, 1:2])[:, 0] - refB[:, 1]).max() <= 1e-9 * np.abs(refB).max()
    # indefinite (shifted): SuperLU, still solved
    K3 = (K - sp.diags(np.full(K.shape[0], 0.5 * abs(K.diagonal()).min()))).tocsc()
    assert np.linalg.eigvalsh(K3.toarray()).min() < 0
    f3 = factor.sym_splu(K3, cache, cholmod_factor)
    assert not isinstance(f3, PetscFactor)
    ref3 = spla.spsolve(K3, b)
    assert np.abs(f3.solve(b) - ref3).max() <= 1e-8 * np.abs(ref3).max()


def test_cholmod_refuses_a_sparse_indefinite_matrix():
    """A matrix sparse enough that CHOLMOD would pick its simplicial LDL^T (which factorizes
    an indefinite matrix without complaint) is still refused when it is not positive definite:
    the tridiagonal 1-D Laplacian shifted by -0.1, 80 negative eigenvalues of 800; shifted by
    +0.1 it is factorized, and solved as SciPy's LU solves it."""
    import scipy.sparse.linalg as spla

    from tissue_reference.fem_reference import cholmod_factor
    from tissue_reference.fem_reference.factor import has_cholmod
    if not has_cholmod():
        pytest.skip("PETSc has no CHOLMOD")
    n = 800
    laplacian = functools.partial(laplacian_1d, n)
    assert np.linalg.eigvalsh(laplacian(-0.1).toarray()).min() < 0
    assert cholmod_factor(laplacian(-0.1)) is None
    f = cholmod_factor(laplacian(0.1))
    b = np.random.default_rng(3).standard_normal(n)
    ref = spla.spsolve(laplacian(0.1).tocsc(), b)
    assert f is not None and np.abs(f.solve(b) - ref).max() <= 1e-9 * np.abs(ref).max()


def test_polished_solve_is_the_same_with_cholmod_and_superlu():
    from tissue_reference.fem_reference import cholmod_factor
    case = _case(box(1.5), "neo-hookean")
    a = admm.solve(case)
    b = admm.solve(case, factorize=cholmod_factor)
    assert a.converged and b.converged
    assert np.abs(a.u - b.u).max() <= 1e-8


@pytest.mark.parametrize("mesh", [box(3.0), rectangle(2.0)], ids=["3d", "2d"])
@pytest.mark.parametrize("model", ["neo-hookean", "linear-elastic"])
def test_compiled_forces_are_the_energy_gradient(mesh, model, monkeypatch):
    """The compiled internal forces (``kernel_c.KernelForces``, what the polishes' residual
    uses) against central differences of the P1 energy, an independent route to the same
    gradient, and against the numpy stress path; an inverted or non-finite state is flagged."""
    ops = operators.prepare(_case(mesh, model))
    rng = np.random.default_rng(3)
    X = mesh.points
    u = (0.05 * np.sin(X @ rng.normal(size=(mesh.gdim, mesh.gdim)))).reshape(-1)
    fext = rng.normal(size=ops.N)
    forces = {}
    for use in (False, True):
        monkeypatch.setattr(kernel_c, "USE_CKERNEL", use)
        ops._kernel_forces = None
        forces[use], ok = ops._forces(u, fext)
        assert ok
    assert ops._kernel_forces, "the compiled forces did not run"
    scale = np.abs(forces[True]).max()
    assert np.abs(forces[True] - forces[False]).max() < 1e-12 * scale
    h = 1e-6
    for i in rng.choice(ops.N, 12, replace=False):
        e = np.zeros(ops.N)
        e[i] = h
        fd = (ops.energy(u + e, fext)[0] - ops.energy(u - e, fext)[0]) / (2 * h)
        assert abs(forces[True][i] - fd) < 1e-6 * scale
    if model == "neo-hookean":
        inverted = u.copy()
        inverted[:mesh.gdim] += 10.0 * np.ptp(X)
        assert ops.residual_if_valid(inverted, fext) is None
        nan = u.copy()
        nan[1] = np.nan
        assert ops.residual_if_valid(nan, fext) is None
