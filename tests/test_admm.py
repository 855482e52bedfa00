"""ADMM solver (seed 000 eqs. 5-10): exact linearization, patch tests, boundary conditions,
bad input, and agreement with the FEniCSx reference on the same P1 mesh."""
import itertools

import numpy as np
import pytest
import scipy.sparse.linalg as spla
from fem_checks import central_differences, linear_p1_stiffness

from tissue_reference.errors import SolverDivergedError
from tissue_reference.meshes.builders import box
from tissue_reference.meshes.mesh import cell_volumes
from tissue_reference.model.case import Boundary, Case, Material, load_case
from tissue_reference.solvers import admm
from tissue_reference.solvers.admm import amg, operators, polisher

CASE_TOML = "meshes/cases/phantom.toml"


@pytest.fixture(scope="module")
def small_box():
    return box(5.0)


def _box_case(mesh, model="neo-hookean", boundaries=None, gravity=None):
    b = boundaries or [Boundary("xmin", "fixed"),
                       Boundary("xmax", "displacement", value=(1.0, 0.5, -0.3))]
    return Case(mesh, Material(model=model, E=6.0, nu=0.45), boundaries=b, gravity=gravity)


def _random_u(case, scale=0.3, seed=0):
    rng = np.random.default_rng(seed)
    return scale * rng.standard_normal((case.mesh.n_vertices, 3))


@pytest.mark.parametrize("model", ["neo-hookean", "linear-elastic"])
def test_internal_forces_are_central_difference_of_strain_energy(small_box, model):
    case = _box_case(small_box, model)
    u = _random_u(case).ravel()
    f = admm.internal_forces(case, u)
    for k, fd in central_differences(lambda v: admm.strain_energy(case, v), u, 12, seed=1):
        assert fd == pytest.approx(f[k], rel=1e-6, abs=1e-7)


@pytest.mark.parametrize("model", ["neo-hookean", "linear-elastic"])
def test_tangent_is_central_difference_of_internal_forces(small_box, model):
    case = _box_case(small_box, model)
    u = _random_u(case).ravel()
    K = admm.tangent_stiffness(case, u)
    for k, fd in central_differences(lambda v: admm.internal_forces(case, v), u, 8, seed=2):
        col = K[:, k].toarray().ravel()
        assert np.abs(fd - col).max() <= 1e-6 * np.abs(col).max()
    assert abs(K - K.T).max() <= 1e-12 * abs(K).max()


@pytest.mark.parametrize("model", ["neo-hookean", "linear-elastic"])
def test_affine_boundary_values_give_the_affine_field_exactly(small_box, model):
    """Patch test: u = G X + c on the whole boundary -> the same affine field everywhere."""
    G = np.array([[0.05, 0.02, 0.0], [-0.01, -0.04, 0.03], [0.0, 0.01, 0.06]])
    c = np.array([0.1, -0.2, 0.3])
    b = [Boundary(f, "affine", gradient=G.tolist(), offset=c.tolist())
         for f in ("xmin", "xmax", "ymin", "ymax", "zmin", "zmax")]
    case = _box_case(small_box, model, b)
    res = admm.solve(case)
    exact = case.mesh.points @ G.T + c
    assert res.converged
    assert np.abs(res.u - exact).max() < 1e-9


def test_linear_elastic_solution_matches_direct_solve_of_independent_stiffness(small_box):
    case = _box_case(small_box, "linear-elastic", gravity=(0.0, 0.0, -9810.0))
    K = linear_p1_stiffness(case.mesh, 6.0, 0.45)
    c = case.constraints
    u = np.zeros(K.shape[0])
    u[c.dofs] = c.values
    free = case.free_dofs()
    f = case.external_forces()
    u[free] = spla.spsolve(K[free][:, free].tocsc(), f[free] - K[free][:, c.dofs] @ c.values)
    res = admm.solve(case)
    assert np.abs(res.u.ravel() - u).max() < 1e-8
    assert admm.tangent_stiffness(case, u).toarray() == pytest.approx(K.toarray(), abs=1e-10)


def test_plain_admm_without_polish_approaches_the_linear_solution(small_box):
    """The ADMM fixed point is the equilibrium: error falls with the tolerance."""
    case = _box_case(small_box, "linear-elastic")
    exact = admm.solve(case).u
    errs = [np.abs(admm.solve(case, polish=False, lift=False, tol_mm=t, max_iter=20000).u
                   - exact).max()
            for t in (1e-3, 1e-6)]
    assert errs[1] < 1e-4
    assert errs[1] < errs[0]


def test_oblique_sliding_holds_exactly_and_its_reaction_is_normal(small_box):
    n = np.array([1.0, 1.0, 0.0]) / np.sqrt(2)
    b = [Boundary("zmin", "fixed"), Boundary("xmax", "sliding", normal=n.tolist(), value=0.0),
         Boundary("zmax", "displacement", value=(0.0, 0.0, -1.0), components=(2,))]
    case = _box_case(small_box, "neo-hookean", b)
    res = admm.solve(case)
    verts = case.mesh.region_vertices("xmax")
    assert np.abs(res.u[verts] @ n).max() < 1e-12
    assert np.abs(res.u[verts]).max() > 0.05  # it does slide
    free_of_fixed = np.setdiff1d(verts, np.concatenate([case.mesh.region_vertices("zmin"),
                                                        case.mesh.region_vertices("zmax")]))
    r = admm.internal_forces(case, res.u) - case.external_forces()
    R = r.reshape(-1, 3)[free_of_fixed]
    tangential = R - np.outer(R @ n, n)
    assert np.abs(tangential).max() < 1e-6 * max(1.0, np.abs(R).max())


def test_reactions_balance_gravity(small_box):
    """Sum of support reactions (r = f_int - f_ext) = minus the total body force, mN."""
    case = _box_case(small_box, "neo-hookean", [Boundary("zmin", "fixed")],
                     gravity=(0.0, 0.0, -9810.0))
    res = admm.solve(case)
    total = sum(res.reactions.values())
    weight = 1e-6 * cell_volumes(case.mesh.points, case.mesh.cells).sum() * np.array([0, 0, -9810.0])
    assert total == pytest.approx(-weight, abs=1e-8)  # r = f_int - f_ext: support pushes up


def test_history_and_callback_cover_every_iteration(small_box):
    case = _box_case(small_box)
    seen = []
    res = admm.solve(case, callback=lambda it, u: seen.append((it, u.shape)))
    assert [s[0] for s in seen] == list(range(1, res.iterations + 1))
    assert all(s[1] == res.u.shape for s in seen)
    assert len(res.history["primal"]) == res.extra["admm_iterations"]
    assert res.extra["newton_iterations"] >= 1


def test_inverted_warm_start_raises_naming_iteration_and_element(small_box):
    case = _box_case(small_box)
    u = np.zeros((case.mesh.n_vertices, 3))
    cells = case.mesh.cells
    v = cells[0, 0]
    # move vertex v through the opposite face of cell 0
    X = case.mesh.points
    centroid = X[cells[0, 1:]].mean(axis=0)
    u[v] = 3.0 * (centroid - X[v])
    with pytest.raises(SolverDivergedError, match=r"iteration 0.*element \d+"):
        admm.solve(case, initial=u)


def test_warm_start_from_the_solution_converges_at_once(small_box):
    case = _box_case(small_box)
    res = admm.solve(case)
    again = admm.solve(case, initial=res.u)
    assert again.extra["admm_iterations"] <= 2
    assert np.abs(again.u - res.u).max() < 1e-8


def test_implicit_euler_settles_to_the_static_solution(small_box):
    case = _box_case(small_box).with_material(density=1e-6)
    static = admm.solve(case)
    dyn = admm.solve(case, dynamics=admm.ImplicitEuler(dt=0.05, steps=20))
    assert np.abs(dyn.u - static.u).max() < 1e-3


@pytest.fixture(scope="module")
def phantom12():
    return load_case(CASE_TOML, size=12.0)


@pytest.mark.parametrize("device", ["cpu", "array-cpu"])
def test_admm_matches_fem_reference_on_phantom(phantom12, device):
    """Both backends (the C kernel, and the array code of the GPU path run on numpy)."""
    from tissue_reference.fem_reference import solve as fem_solve
    pushes = {"A1": 5.0, "A2": 5.0, "A3": 5.0, "A4": 5.0}
    ref = fem_solve(phantom12, degree=1, pushes=pushes)
    res = admm.solve(phantom12, pushes=pushes, max_iter=300, device=device)
    assert res.converged
    assert np.abs(res.u - ref.u).max() < 1e-6
    for k in ref.probes:
        assert np.linalg.norm(res.probes[k] - ref.probes[k]) < 1e-6
    for reg, r in ref.reactions.items():
        assert np.asarray(res.reactions[reg]) == pytest.approx(np.asarray(r), abs=1e-5)
    assert res.strain_energy == pytest.approx(ref.strain_energy, rel=1e-8)


def test_tangent_matches_fem_reference_tangent(phantom12):
    from tissue_reference.fem_reference import tangent_stiffness as fem_tangent
    pushes = {"A1": 3.0}
    u = admm.solve(phantom12, pushes=pushes, max_iter=100).u
    K = admm.tangent_stiffness(phantom12.with_pushes(pushes), u)
    Kref = fem_tangent(phantom12, u, degree=1, pushes=pushes).K
    assert abs(K - Kref).max() <= 1e-9 * abs(Kref).max()


def test_plain_admm_without_polish_meets_the_fast_solver_tolerances_on_phantom(phantom12):
    """The fast solvers' accuracy target (probes 0.05 mm, vertices 0.1 mm), by ADMM iterations
    alone."""
    from tissue_reference.fem_reference import solve as fem_solve
    pushes = {"A1": 8.0, "A2": 8.0, "A3": 8.0, "A4": 8.0}
    ref = fem_solve(phantom12, degree=1, pushes=pushes)
    res = admm.solve(phantom12, pushes=pushes, polish=False, tol_mm=1e-3, max_iter=5000)
    assert res.extra["newton_iterations"] == 0
    assert np.abs(res.u - ref.u).max() < 0.1
    for k in ref.probes:
        assert np.linalg.norm(res.probes[k] - ref.probes[k]) < 0.05


def test_iterative_x_step_of_large_meshes_gives_the_same_answer(phantom12, monkeypatch):
    """The AMG-preconditioned CG x-step (used from operators.PCG_MIN free vertices on) converges to
    the same ADMM fixed point as the SuperLU one."""
    pushes = {"A1": 3.0, "A3": 3.0}
    kw = {"pushes": pushes, "polish": False, "tol_mm": 1e-6, "max_iter": 5000}
    direct = admm.solve(phantom12, **kw)
    assert admm.prepare(phantom12.with_pushes(pushes)).lu.kind == "Direct"
    monkeypatch.setattr(operators, "PCG_MIN", 0)
    monkeypatch.setattr(amg.AmgPcg, "coarse", 50)  # several AMG levels on this small mesh
    operators.OPERATOR_CACHE.clear()
    try:
        ops = admm.prepare(phantom12.with_pushes(pushes))
        assert ops.lu.kind == "AmgPcg" and len(ops.lu.groups[0][0].levels) >= 1
        cg = admm.solve(phantom12, **kw)
    finally:
        operators.OPERATOR_CACHE.clear()
    assert cg.converged and direct.converged
    assert np.abs(cg.u - direct.u).max() < 1e-4


def test_amg_pcg_solves_a_poisson_matrix_to_the_requested_accuracy(monkeypatch):
    import scipy.sparse as sp
    monkeypatch.setattr(amg.AmgPcg, "coarse", 100)
    k = 14
    T = sp.diags([-np.ones(k - 1), 2.0 * np.ones(k), -np.ones(k - 1)], [-1, 0, 1])
    I = sp.identity(k)
    A = (sp.kron(sp.kron(T, I), I) + sp.kron(sp.kron(I, T), I) + sp.kron(sp.kron(I, I), T)).tocsr()
    M = amg.AmgPcg(A)
    assert len(M.levels) >= 1
    B = np.random.default_rng(0).standard_normal((A.shape[0], 3))
    X = M.solve(B)
    assert np.linalg.norm(B - A @ X) <= 1e-10 * np.linalg.norm(B)
    assert M.count[1] / M.count[0] < 40  # a working preconditioner, not plain CG
    # the inexact ADMM x-step from a warm start: stops on the size of its updates
    X0 = X + 1e-3 * np.random.default_rng(1).standard_normal(X.shape)
    Xs = M.step(B, X0, 1e-12)
    assert np.abs(Xs - X).max() < np.abs(X0 - X).max()


def test_reduced_tangent_from_the_cached_pattern_equals_the_assembled_one(phantom12):
    case = phantom12.with_pushes({"A2": 2.0})
    ops = admm.prepare(case)
    u = admm.solve(case, polish=False, max_iter=30).u.ravel()
    Kr, Ke = ops.reduced_tangent(u)
    Z = ops.red.Z
    ref = (Z.T @ admm.tangent_stiffness(case, u) @ Z)
    assert abs(Kr - ref).max() <= 1e-12 * abs(ref).max()
    v = np.random.default_rng(0).standard_normal(u.size)
    assert np.allclose(ops.apply_elements(Ke, v), admm.tangent_stiffness(case, u) @ v)


def test_polish_restart_starts_from_this_steps_boundary_values(small_box, monkeypatch):
    """A polish that leaves Newton's basin restarts from the load step's start state; without a
    lift that state still has the previous step's boundary values, which Newton (free dofs only)
    would keep: the restart must carry it to this step's values first."""
    case = _box_case(small_box)
    real = polisher.newton
    calls = {"n": 0}

    def newton_failing_once(*a, **kw):
        calls["n"] += 1
        if calls["n"] == 1:
            raise SolverDivergedError("forced: left Newton's basin")
        return real(*a, **kw)

    monkeypatch.setattr(polisher, "newton", newton_failing_once)
    res = admm.solve(case, lift=False, load_steps=1, max_iter=5)
    assert len(res.extra["polish_restarts"]) == 1 and res.converged
    c = case.constraints
    assert np.abs(res.u.ravel()[c.dofs] - c.values).max() < 1e-12
    assert np.abs(admm.internal_forces(case, res.u)[case.free_dofs()]).max() < 1e-6


def test_anderson_acceleration_reaches_the_same_answer_in_fewer_iterations(phantom12):
    """Plain ADMM and ADMM with Anderson acceleration, both to the same stopping tolerance,
    against the P1 reference; and with the polish, the reference's answer itself."""
    from tissue_reference.fem_reference import solve as fem_solve
    pushes = {"A1": 5.0, "A2": 5.0, "A3": 5.0, "A4": 5.0}
    ref = fem_solve(phantom12, degree=1, pushes=pushes)
    plain = admm.solve(phantom12, pushes=pushes, polish=False, tol_mm=1e-5, max_iter=20000)
    fast = admm.solve(phantom12, pushes=pushes, polish=False, tol_mm=1e-5, max_iter=20000,
                      anderson=5)
    assert plain.converged and fast.converged
    assert np.abs(plain.u - ref.u).max() < 1e-3 and np.abs(fast.u - ref.u).max() < 1e-3
    assert fast.extra["admm_iterations"] < plain.extra["admm_iterations"]
    polished = admm.solve(phantom12, pushes=pushes, anderson=5)
    assert np.abs(polished.u - ref.u).max() < 1e-8


def test_anderson_finds_a_linear_maps_fixed_point_and_its_safeguard_holds():
    """x = A x + b with a non-normal contraction A: the accelerated iteration reaches the fixed
    point (I - A)^-1 b (solved directly) far sooner than the plain one, and no accelerated iterate
    it keeps has a larger fixed-point residual |G(x) - x| than the one kept before it."""
    from tissue_reference.solvers.admm.loop import Anderson
    rng = np.random.default_rng(3)
    n = 60
    Q = np.linalg.qr(rng.normal(size=(n, n)))[0]
    A = Q @ np.diag(np.linspace(0.5, 0.995, n)) @ Q.T + 0.3 * np.triu(rng.normal(size=(n, n)), 1) / n
    b = rng.normal(size=n)
    exact = np.linalg.solve(np.eye(n) - A, b)

    def accelerated(m):
        aa, kept = Anderson(m), []
        aa.step(np.zeros(n))
        for k in range(1, 5000):
            g = A @ aa.x + b
            res = np.linalg.norm(g - aa.x)
            was_accelerated = aa.accelerated
            aa.step(g)
            if was_accelerated and aa.fnorm == res:   # an accelerated iterate kept
                kept.append(res)
            if res < 1e-12:
                return k, aa.x, kept
        return k, aa.x, kept

    x = np.zeros(n)
    for k_plain in range(1, 100000):
        g = A @ x + b
        if np.linalg.norm(g - x) < 1e-12:
            break
        x = g
    k_fast, x_fast, kept = accelerated(5)
    assert np.abs(x_fast - exact).max() < 1e-8 and np.abs(x - exact).max() < 1e-8
    assert k_fast < k_plain / 5 and len(kept) > 10
    assert all(b <= a for a, b in itertools.pairwise(kept))


def test_a_lift_from_rest_reuses_the_rest_tangent_factorization_and_gives_the_same_answer(
        small_box):
    """Every cold solve's first load step lifts the interior with the tangent at rest, which is
    the same matrix each time: the second cold solve factorizes it no more, and its answer is the
    first's."""
    case = _box_case(small_box)
    calls = []

    def counting(A, cache):   # a factorize hook that only counts: SuperLU does the work
        calls.append(A.shape)

    operators.OPERATOR_CACHE.clear()
    first = admm.solve(case, lift=True, factorize=counting)
    n_first = len(calls)
    calls.clear()
    second = admm.solve(case, lift=True, factorize=counting)
    assert len(calls) == n_first - 1
    np.testing.assert_array_equal(second.u, first.u)
    calls.clear()
    operators.OPERATOR_CACHE.clear()     # fresh operators: the rest tangent is factorized again
    third = admm.solve(case, lift=True, factorize=counting)
    assert len(calls) == n_first
    np.testing.assert_array_equal(third.u, first.u)
