"""Mass Tensor Method (seed 001) against an independent P1 assembly (B^T D B V) and exact fields.

Every expected value here comes from code written in this file (Voigt-notation assembly, scipy
direct solves, KKT systems, closed-form affine fields), never from solvers.mass_tensor.
"""
import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from tissue_reference.errors import CaseError, SolverDivergedError
from tissue_reference.meshes.builders import box, rectangle
from tissue_reference.model.case import Boundary, Case, Material, Probe
from tissue_reference.solvers import mass_tensor as mt
from tissue_reference.solvers.admm import kernel_c
from tissue_reference.solvers.mass_tensor import driver
from tissue_reference.solvers.mass_tensor.iterations import IterationState

MAT = Material(model="linear-elastic", E=48.0, nu=0.45)


# ----------------------------------------------------------------- independent reference
def voigt_D(E, nu, d):
    lam = E * nu / ((1 + nu) * (1 - 2 * nu))
    mu = E / (2 * (1 + nu))
    if d == 3:
        D = np.zeros((6, 6))
        D[:3, :3] = lam
        D[np.arange(3), np.arange(3)] += 2 * mu
        D[3:, 3:] = mu * np.eye(3)
    else:  # plane strain
        D = np.array([[lam + 2 * mu, lam, 0], [lam, lam + 2 * mu, 0], [0, 0, mu]])
    return D


def assemble_reference(points, cells, E, nu):
    """Standard P1 stiffness: K_e = V B^T D B, engineering shear strains, node-major dofs."""
    n, d = points.shape
    D = voigt_D(E, nu, d)
    rows, cols, vals = [], [], []
    for cell in cells:
        x = points[cell]
        A = np.hstack([np.ones((d + 1, 1)), x])          # rows [1, x_a]
        coef = np.linalg.inv(A)                          # N_a = coef[:, a] . [1, x]
        grads = coef[1:, :].T                            # (d+1, d)
        V = abs(np.linalg.det(A)) / (6.0 if d == 3 else 2.0)
        if d == 3:
            B = np.zeros((6, 12))
            for a, (gx, gy, gz) in enumerate(grads):
                B[:, 3 * a:3 * a + 3] = [[gx, 0, 0], [0, gy, 0], [0, 0, gz],
                                         [gy, gx, 0], [0, gz, gy], [gz, 0, gx]]
        else:
            B = np.zeros((3, 6))
            for a, (gx, gy) in enumerate(grads):
                B[:, 2 * a:2 * a + 2] = [[gx, 0], [0, gy], [gy, gx]]
        Ke = V * B.T @ D @ B
        dofs = (d * cell[:, None] + np.arange(d)).ravel()
        rows.append(np.repeat(dofs, len(dofs)))
        cols.append(np.tile(dofs, len(dofs)))
        vals.append(Ke.ravel())
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                         shape=(d * n, d * n))


def direct_solve(K, n, d, dofs, values, f=None):
    """Dirichlet elimination + sparse LU; returns (n, d) mm."""
    f = np.zeros(n * d) if f is None else f
    ub = np.zeros(n * d)
    ub[dofs] = values
    free = np.setdiff1d(np.arange(n * d), dofs)
    u = ub.copy()
    u[free] = spla.spsolve(K[free][:, free].tocsc(), (f - K @ ub)[free])
    return u.reshape(n, d)


def kkt_solve(K, n, d, dofs, values, slides, f=None):
    """Dirichlet dofs plus linear constraints u_v . nrm = g (Lagrange multipliers)."""
    f = np.zeros(n * d) if f is None else f
    rows, rhs = [], []
    for k, v in zip(dofs, values):
        r = np.zeros(n * d)
        r[k] = 1
        rows.append(r)
        rhs.append(v)
    for verts, nrm, g in slides:
        for v in verts:
            r = np.zeros(n * d)
            r[d * v:d * v + d] = nrm
            rows.append(r)
            rhs.append(g)
    C = sp.csr_matrix(np.array(rows))
    A = sp.bmat([[K, C.T], [C, None]]).tocsc()
    sol = spla.spsolve(A, np.concatenate([f, rhs]))
    return sol[:n * d].reshape(n, d)


# ----------------------------------------------------------------- meshes
@pytest.fixture(scope="module")
def cube():
    return box(3.5, lengths=(10.0, 10.0, 10.0))


@pytest.fixture(scope="module")
def cube_model(cube):
    return mt.MassTensorModel(cube.points, cube.cells, MAT)


@pytest.fixture(scope="module")
def K_ref(cube):
    return assemble_reference(cube.points, cube.cells, MAT.E, MAT.nu)


@pytest.fixture(params=["numpy", "compiled"])
def kernel(request, monkeypatch):
    """The tensors' sums and the "amg" iteration in numpy, then in the compiled kernel (built
    here: ``make test`` installs gcc), each from an empty model cache."""
    monkeypatch.setattr(kernel_c, "USE_CKERNEL", request.param == "compiled")
    assert kernel_c.use_kernel() is (request.param == "compiled")
    driver.MODEL_CACHE.clear()
    yield request.param
    driver.MODEL_CACHE.clear()


# ----------------------------------------------------------------- tensors
def test_tensors_equal_independent_BtDB_assembly(cube, cube_model, K_ref):
    K = cube_model.matrix()
    assert abs(K - K_ref).max() <= 1e-12 * abs(K_ref).max()
    u = np.random.default_rng(0).normal(size=(cube.n_vertices, 3))
    F_edges = cube_model.forces(u)
    np.testing.assert_allclose(F_edges.ravel(), K_ref @ u.ravel(), rtol=0,
                               atol=1e-11 * np.abs(K_ref @ u.ravel()).max())


def test_vertex_tensors_symmetric_and_edge_tensors_transpose_pairs(cube_model, K_ref):
    T = cube_model.T_ii
    np.testing.assert_allclose(T, np.transpose(T, (0, 2, 1)), atol=1e-12 * np.abs(T).max())
    assert np.all(np.linalg.eigvalsh(T) > 0)
    i, j = cube_model.edges.T
    assert np.all(i < j)
    K = K_ref.toarray()
    for e in range(0, len(i), max(1, len(i) // 50)):
        np.testing.assert_allclose(cube_model.T_ij[e], K[3 * i[e]:3 * i[e] + 3, 3 * j[e]:3 * j[e] + 3],
                                   atol=1e-12 * np.abs(K).max())


def test_rigid_motions_give_zero_force(cube, cube_model):
    X = cube.points - cube.points.mean(axis=0)
    scale = np.abs(cube_model.T_ii).max() * 10.0
    for t in np.eye(3):
        assert np.abs(cube_model.forces(np.broadcast_to(t, X.shape))).max() < 1e-11 * scale
    for w in np.eye(3):
        u = np.cross(w, X)           # infinitesimal rotation
        assert np.abs(cube_model.forces(u)).max() < 1e-11 * scale * 10


def test_2d_plane_strain_tensors_equal_independent_assembly(kernel):
    rect = rectangle(2.5, lengths=(10.0, 6.0))
    m = mt.MassTensorModel(rect.points, rect.cells, MAT)
    K_ref = assemble_reference(rect.points, rect.cells, MAT.E, MAT.nu)
    assert abs(m.matrix() - K_ref).max() <= 1e-12 * abs(K_ref).max()


def test_3d_tensors_summed_in_numpy_or_compiled_equal_independent_assembly(cube, K_ref, kernel):
    m = mt.MassTensorModel(cube.points, cube.cells, MAT)
    assert abs(m.matrix() - K_ref).max() <= 1e-12 * abs(K_ref).max()


# ----------------------------------------------------------------- equilibrium
def stretch_case(mesh, gravity=None):
    return Case(mesh=mesh, material=MAT, gravity=gravity,
                boundaries=[Boundary("xmin", "fixed"),
                            Boundary("xmax", "displacement", value=(1.5, 0.5, -0.3))])


@pytest.mark.parametrize("method", ["pcg", "descent"])
def test_converged_mass_tensor_equals_direct_linear_fem(cube, K_ref, method):
    case = stretch_case(cube)
    c = case.constraints
    ref = direct_solve(K_ref, cube.n_vertices, 3, c.dofs, c.values)
    res = mt.solve(case, method=method, stop_mm=1e-9)
    assert res.converged and res.solver == "mass-tensor"
    assert np.abs(res.u - ref).max() < 1e-6
    # the stopping rule: last step below stop_mm, every earlier one at or above it
    steps = res.history["max_step_mm"]
    assert len(steps) == res.iterations and steps[-1] < 1e-9 and min(steps[:-1]) >= 1e-9


def test_the_distance_to_go_of_geometric_moves_is_their_remaining_sum():
    """Moves s_k = s_0 r^k: the estimate after move k is the rest of the geometric series,
    s_k r / (1 - r) = sum_{j>k} s_j; none before TAIL_RATES rates, none for growing moves."""
    from tissue_reference.solvers.mass_tensor.iterations import TAIL_RATES, distance_to_go
    for r in (0.2, 0.5, 0.9):
        moves = [3.0 * r ** k for k in range(TAIL_RATES + 3)]
        rest = 3.0 * r ** len(moves) / (1.0 - r)
        assert distance_to_go(moves) == pytest.approx(rest, rel=1e-12)
        assert distance_to_go(moves[:TAIL_RATES]) == np.inf
    assert distance_to_go([1.0, 0.5, 0.25, 0.125, 0.2]) == np.inf
    # the slowest of the last rates decides
    assert distance_to_go([1.0, 0.1, 0.05, 0.005, 0.004]) == pytest.approx(0.004 * 0.8 / 0.2)


@pytest.mark.parametrize("stop", [1e-2, 1e-4, 1e-6])
def test_amg_stops_within_its_stop_of_the_direct_linear_fem(stop, kernel):
    """method "amg" on a mesh with an AMG hierarchy: the answer within stop_mm of the
    independently assembled stiffness's direct solve at every vertex."""
    mesh = box(1.0, lengths=(10.0, 10.0, 10.0))
    case = stretch_case(mesh)
    c = case.constraints
    ref = direct_solve(assemble_reference(mesh.points, mesh.cells, MAT.E, MAT.nu),
                       mesh.n_vertices, 3, c.dofs, c.values)
    res = mt.solve(case, method="amg", stop_mm=stop)
    assert res.converged and res.extra["method"] == "amg"
    assert np.linalg.norm(res.u - ref, axis=1).max() < stop
    assert 5 < res.iterations < 60


def test_amg_in_2d_and_its_kept_hierarchy(kernel):
    """Plane strain: within stop_mm of the independent assembly's direct solve; the hierarchy
    is kept for the next solve of the same point types (another push) and dropped by
    ``forget_factorizations``."""
    mesh = rectangle(0.25)
    case = Case(mesh=mesh, material=MAT, boundaries=[
        Boundary("xmin", "fixed"), Boundary("xmax", "displacement", value=(1.5, 0.5))])
    c = case.constraints
    ref = direct_solve(assemble_reference(mesh.points, mesh.cells, MAT.E, MAT.nu),
                       mesh.n_vertices, 2, c.dofs, c.values)
    driver.MODEL_CACHE.clear()
    res = mt.solve(case, method="amg", stop_mm=1e-5)
    assert np.linalg.norm(res.u - ref, axis=1).max() < 1e-5
    (model,) = driver.MODEL_CACHE.values()
    (kept,) = model._factors.values()
    assert kept.amg is not None and len(kept.amg.levels) >= 1   # a multilevel V-cycle
    assert model.kept_bytes() > 0
    mt.solve(case, method="amg", stop_mm=1e-5)
    assert list(model._factors.values()) == [kept]
    mt.forget_factorizations()
    assert not model._factors and model.kept_bytes() == 0


@pytest.mark.parametrize("sliding", [False, True], ids=["free-or-held", "oblique-sliding"])
def test_the_compiled_amg_iteration_is_the_numpy_iteration(cube, monkeypatch, sliding):
    """The same eight iterations (no stopping rule reached: max_iter) in numpy and in the
    compiled kernel: the same moves and displacements to round-off, with each vertex free or
    held (the projector a mask) and with oblique sliding (3 x 3 projector blocks)."""
    nrm = [1.0, 0.0, 1.0]
    case = stretch_case(cube) if not sliding else Case(
        mesh=cube, material=MAT, gravity=(3000.0, 5000.0, -9810.0),
        boundaries=[Boundary("zmin", "fixed"),
                    Boundary("xmax", "sliding", value=0.0, normal=nrm)])
    out = []
    for compiled in (False, True):
        monkeypatch.setattr(kernel_c, "USE_CKERNEL", compiled)
        driver.MODEL_CACHE.clear()
        res = mt.solve(case, method="amg", stop_mm=1e-12, max_iter=8)
        (model,) = driver.MODEL_CACHE.values()
        (kept,) = model._factors.values()
        assert kept.compiled is compiled
        out.append(res)
    a, b = out
    assert a.iterations == b.iterations == 8 and not a.converged and not b.converged
    np.testing.assert_allclose(b.history["max_step_mm"], a.history["max_step_mm"], rtol=1e-9)
    assert np.abs(a.u - b.u).max() <= 1e-9 * np.abs(a.u).max()
    assert b.residual == pytest.approx(a.residual, rel=1e-6)
    # stopped by the rule: the same count, unless round-off moves the estimate across the stop
    counts = []
    for compiled in (False, True):
        monkeypatch.setattr(kernel_c, "USE_CKERNEL", compiled)
        driver.MODEL_CACHE.clear()
        res = mt.solve(case, method="amg", stop_mm=1e-4)
        assert res.converged
        counts.append(res.iterations)
    driver.MODEL_CACHE.clear()
    assert abs(counts[0] - counts[1]) <= 1 and min(counts) > 5


@pytest.mark.parametrize("how, why", [("curvature", "non-positive curvature"),
                                      ("blowup", "moved"), ("growth", "residual grew")])
def test_the_compiled_amg_iteration_fails_where_the_numpy_one_does(cube, monkeypatch, how, why):
    """Each divergence check of the "amg" iteration refuses at the same iteration, with the
    same reason, in numpy and in the compiled kernel: a stiffness made negative definite after
    the preconditioner was built from the true one (curvature), a runaway bound below the first
    move (blowup), and a huge skew pair in the stiffness (the residual grows)."""
    import re
    out = []
    for compiled in (False, True):
        monkeypatch.setattr(kernel_c, "USE_CKERNEL", compiled)
        m = mt.MassTensorModel(cube.points, cube.cells, MAT)
        types = m.point_types().border(cube.region_vertices("xmin")).displacement(
            cube.region_vertices("xmax"), (1.0, 0.5, 0.0))
        state = IterationState(m, np.zeros((m.n_vertices, 3)), 1e-9, 1000, None, None)
        if how == "curvature":
            state.K = -state.K
        elif how == "blowup":
            state.blowup = 1e-3
        else:
            K = state.K.tolil()
            dof = 3 * int(np.flatnonzero(types.m == 0)[5])
            K[dof, dof + 1], K[dof + 1, dof] = 1e20, -1e20
            state.K = K.tocsr()
        with pytest.raises(SolverDivergedError, match=why) as err:
            state.run(types, np.zeros((m.n_vertices, 3)), "amg")
        assert m._factors and next(iter(m._factors.values())).compiled is compiled
        out.append(int(re.search(r"iteration (\d+)", str(err.value)).group(1)))
    assert out[0] == out[1] >= 1


def test_amg_warns_near_incompressibility(cube, caplog):
    """Its stopping estimate is not a bound near nu = 0.5: the solve says so (and not at the
    tissue's nu = 0.45)."""
    import logging
    for nu, warned in ((0.45, False), (0.49, True)):
        case = Case(mesh=cube, material=Material(model="linear-elastic", E=48.0, nu=nu),
                    boundaries=[Boundary("xmin", "fixed"),
                                Boundary("xmax", "displacement", value=(1.5, 0.5, -0.3))])
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="tissue.mass_tensor"):
            mt.solve(case, method="amg", stop_mm=1e-3)
        assert any("close to 0.5" in r.getMessage() for r in caplog.records) == warned


def test_pcg_needs_fewer_iterations_than_descent_for_the_same_stopping_rule(cube):
    case = stretch_case(cube)
    a = mt.solve(case, method="pcg", stop_mm=0.001)
    b = mt.solve(case, method="descent", stop_mm=0.001)
    assert a.iterations < b.iterations


def test_patch_test_affine_boundary_gives_exact_affine_field(cube):
    G = np.array([[0.02, -0.01, 0.005], [0.01, -0.015, 0.0], [0.003, 0.004, 0.01]])
    off = np.array([0.1, -0.2, 0.05])
    faces = ["xmin", "xmax", "ymin", "ymax", "zmin", "zmax"]
    case = Case(mesh=cube, material=MAT,
                boundaries=[Boundary(f, "affine", gradient=G.tolist(), offset=off.tolist())
                            for f in faces])
    res = mt.solve(case, method="pcg", stop_mm=1e-13)
    exact = cube.points @ G.T + off
    assert np.abs(res.u - exact).max() < 1e-10
    assert res.strain_energy > 0


def test_gravity_load_matches_direct_solve_and_reactions_balance_it(cube, K_ref):
    case = Case(mesh=cube, material=Material("linear-elastic", E=1.0, nu=0.3, density=1e-3),
                gravity=(0.0, 0.0, -9810.0), boundaries=[Boundary("zmin", "fixed")])
    K = assemble_reference(cube.points, cube.cells, 1.0, 0.3)
    c = case.constraints
    f = case.external_forces(1.0)
    ref = direct_solve(K, cube.n_vertices, 3, c.dofs, c.values, f)
    res = mt.solve(case, method="pcg", stop_mm=1e-10)
    assert np.abs(res.u - ref).max() < 1e-7 * np.abs(ref).max()
    total_load = f.reshape(-1, 3).sum(axis=0)
    # the support holds the whole weight: reaction (force of the support on the body) = -load
    np.testing.assert_allclose(res.reactions["zmin"], -total_load, rtol=1e-7,
                               atol=1e-9 * np.abs(total_load).max())


def test_reactions_equal_direct_reactions_per_region(cube, K_ref):
    case = stretch_case(cube)
    c = case.constraints
    ref = direct_solve(K_ref, cube.n_vertices, 3, c.dofs, c.values)
    r_ref = (K_ref @ ref.ravel()).reshape(-1, 3)
    res = mt.solve(case, method="pcg", stop_mm=1e-10)
    for region in ("xmin", "xmax"):
        owned = np.array([k for k, o in zip(c.dofs, c.owner) if o == region])
        expect = np.array([r_ref.ravel()[owned[owned % 3 == k]].sum() for k in range(3)])
        np.testing.assert_allclose(res.reactions[region], expect, atol=1e-6 * np.abs(expect).max())
    np.testing.assert_allclose(res.reactions["xmin"] + res.reactions["xmax"], 0,
                               atol=1e-6 * np.abs(res.reactions["xmin"]).max())


def test_oblique_sliding_equals_kkt_solution_and_points_stay_on_plane(cube):
    nrm = np.array([1.0, 0.0, 1.0]) / np.sqrt(2)
    mat = Material("linear-elastic", E=1.0, nu=0.3, density=1e-3)
    case = Case(mesh=cube, material=mat, gravity=(3000.0, 5000.0, -9810.0), boundaries=[
        Boundary("zmin", "fixed"), Boundary("xmax", "sliding", value=0.0, normal=nrm.tolist())])
    c = case.constraints
    fixed = np.unique(c.dofs // 3)
    slides = [(np.setdiff1d(v, fixed), n, g) for v, n, g in c.sliding]  # drop redundant rows
    K = assemble_reference(cube.points, cube.cells, 1.0, 0.3)
    ref = kkt_solve(K, cube.n_vertices, 3, c.dofs, c.values, slides, case.external_forces(1.0))
    res = mt.solve(case, method="pcg", stop_mm=1e-10)
    assert np.abs(res.u - ref).max() < 1e-7 * np.abs(ref).max()
    xs = cube.region_vertices("xmax")
    np.testing.assert_allclose(res.u[xs] @ nrm, 0.0, atol=1e-12)
    # reactions balance the load; the sliding region's reaction is normal to it
    load = case.external_forces(1.0).reshape(-1, 3).sum(axis=0)
    np.testing.assert_allclose(res.reactions["zmin"] + res.reactions["xmax"], -load,
                               atol=1e-6 * np.abs(load).max())
    r = res.reactions["xmax"]
    assert np.linalg.norm(r) > 0 and np.linalg.norm(r - (r @ nrm) * nrm) < 1e-9 * np.linalg.norm(r)


def test_case_with_oblique_sliding_conflicting_with_fixed_vertex_rejected_naming_it(cube):
    """Rejected when the Case is built, not discovered mid-solve."""
    nrm = [1.0, 1.0, 0.0]
    shared = np.intersect1d(cube.region_vertices("zmin"), cube.region_vertices("xmax"))
    with pytest.raises(CaseError, match=f"vertex {shared[0]}"):
        Case(mesh=cube, material=MAT, boundaries=[
            Boundary("zmin", "fixed"), Boundary("xmax", "sliding", value=0.4, normal=nrm)])


def test_callback_and_probes(cube):
    case = Case(mesh=cube, material=MAT, probes=[Probe("P", (5, 5, 5))],
                boundaries=[Boundary("xmin", "fixed"), Boundary("xmax", "displacement",
                                                                 value=(1.0, 0, 0))])
    seen = []
    res = mt.solve(case, callback=lambda it, u: seen.append((it, u.shape)))
    assert [s[0] for s in seen] == list(range(1, res.iterations + 1))
    assert all(s[1] == (cube.n_vertices, 3) for s in seen)
    np.testing.assert_allclose(res.probes["P"], case.probe_values(res.u)["P"])


# ----------------------------------------------------------------- point types (low level)
@pytest.fixture(scope="module")
def slab():
    return box(3.0, lengths=(10.0, 10.0, 4.0))


def test_conflicting_target_and_border_rejected_naming_the_vertex(slab):
    m = mt.MassTensorModel(slab.points, slab.cells, MAT)
    pts = m.point_types().border([5])
    with pytest.raises(CaseError, match="vertex 5"):
        pts.target([5], slab.points[[5]] + [0.0, 0.0, 1.0])
    # the same prescription twice, or a plane through the fixed point, is consistent
    pts.border([5]).sliding([5], mt.Plane(slab.points[5], (0.0, 0.0, 1.0)))
    with pytest.raises(CaseError, match="vertex 7"):
        m.point_types().target([7], slab.points[[7]] + 1.0).sliding(
            [7], mt.Plane(slab.points[7], (1.0, 0.0, 0.0)))


def test_target_points_reach_their_positions_and_free_points_balance(slab):
    m = mt.MassTensorModel(slab.points, slab.cells, MAT)
    base = slab.region_vertices("zmin")
    top = slab.region_vertices("zmax")
    pos = slab.points[top] + [0.5, 0.0, -0.4]
    pts = m.point_types().border(base).target(top, pos)
    sol = m.solve(pts, stop_mm=1e-10)
    np.testing.assert_allclose(slab.points[top] + sol.u[top], pos, atol=1e-12)
    K = assemble_reference(slab.points, slab.cells, MAT.E, MAT.nu)
    c = np.concatenate([3 * base[:, None] + np.arange(3), 3 * top[:, None] + np.arange(3)]).ravel()
    v = np.concatenate([np.zeros(3 * len(base)), (pos - slab.points[top]).ravel()])
    np.testing.assert_allclose(sol.u, direct_solve(K, slab.n_vertices, 3, c, v), atol=1e-7)


def plane_triangulation(z0, half=40.0, k=6):
    g = np.linspace(-half, half, k + 1)
    X, Y = np.meshgrid(g, g, indexing="ij")
    P = np.stack([X.ravel(), Y.ravel(), np.full(X.size, z0)], axis=1)
    tris = []
    for a in range(k):
        for b in range(k):
            i = a * (k + 1) + b
            tris += [(i, i + k + 1, i + 1), (i + 1, i + k + 1, i + k + 2)]
    return mt.TriSurface(P, np.array(tris))


def _slab_pushed_down(slab):
    """The slab's model, its base, top and free xmax side, and the top's targets 0.5 mm down."""
    m = mt.MassTensorModel(slab.points, slab.cells, MAT)
    base = slab.region_vertices("zmin")
    top = slab.region_vertices("zmax")
    xmax = np.setdiff1d(slab.region_vertices("xmax"), np.r_[base, top])
    return m, base, top, xmax, slab.points[top] + [0.0, 0.0, -0.5]


@pytest.mark.parametrize("method", ["pcg", "amg", "descent"])
def test_sliding_on_triangulated_plane_equals_sliding_on_plane(slab, method):
    m, base, top, xmax, push = _slab_pushed_down(slab)
    a = m.solve(m.point_types().target(top, push).sliding(base, mt.Plane((0, 0, 0), (0, 0, 1)))
                .border(xmax), method=method, stop_mm=1e-9)
    b = m.solve(m.point_types().target(top, push).sliding(base, plane_triangulation(0.0))
                .border(xmax), method=method, stop_mm=1e-9)
    assert np.abs(a.u[base, 2]).max() < 1e-12
    assert np.abs(b.u[base, 2]).max() < 1e-9
    assert np.abs(a.u - b.u).max() < 1e-6


def test_trisurface_closest_point_matches_brute_force():
    rng = np.random.default_rng(3)
    # a bumpy surface z = f(x, y) triangulated
    k = 8
    g = np.linspace(0, 10, k + 1)
    X, Y = np.meshgrid(g, g, indexing="ij")
    P = np.stack([X.ravel(), Y.ravel(), np.sin(X.ravel() / 3) + 0.3 * Y.ravel()], axis=1)
    tris = []
    for a in range(k):
        for b in range(k):
            i = a * (k + 1) + b
            tris += [(i, i + k + 1, i + 1), (i + 1, i + k + 1, i + k + 2)]
    surf = mt.TriSurface(P, np.array(tris), candidates=len(tris))
    q = rng.uniform([0, 0, -2], [10, 10, 5], size=(30, 3))
    y, _ = surf.closest(q)
    # brute force: dense sampling of every triangle
    s = np.linspace(0, 1, 41)
    A, B = np.meshgrid(s, s)
    keep = A + B <= 1
    A, B = A[keep], B[keep]
    tri = P[np.array(tris)]
    samples = (tri[:, 0, None] + A[None, :, None] * (tri[:, 1] - tri[:, 0])[:, None]
               + B[None, :, None] * (tri[:, 2] - tri[:, 0])[:, None]).reshape(-1, 3)
    dbrute = np.min(np.linalg.norm(q[:, None] - samples[None], axis=2), axis=1)
    dmt = np.linalg.norm(q - y, axis=1)
    assert np.all(dmt <= dbrute + 1e-12)
    assert np.all(dmt >= dbrute - 0.1)   # sampling spacing bound


def test_target_switched_to_sliding_ends_at_the_sliding_equilibrium(slab):
    m = mt.MassTensorModel(slab.points, slab.cells, MAT)
    base = slab.region_vertices("zmin")
    top = slab.region_vertices("zmax")
    plane = mt.Plane((0.0, 0.0, 3.5), (0.0, 0.0, 1.0))       # top pushed down 0.5 mm
    pos = slab.points[top] + [0.3, 0.0, -0.5]
    sw = m.solve(m.point_types().border(base).target(top, pos, then_slide=plane), stop_mm=1e-10)
    direct = m.solve(m.point_types().border(base).sliding(top, plane), stop_mm=1e-10)
    assert len(sw.phases) == 2 and sw.phases[0] < sw.phases[1] == sw.iterations
    np.testing.assert_allclose(slab.points[top, 2] + sw.u[top, 2], 3.5, atol=1e-12)
    assert np.abs(sw.u - direct.u).max() < 1e-6


# ----------------------------------------------------------------- bad input
def test_descent_with_unstable_fixed_step_raises_naming_iteration_and_vertex(cube):
    case = stretch_case(cube)
    with pytest.raises(SolverDivergedError, match=r"iteration \d+.*vertex \d+|vertex \d+"):
        mt.solve(case, method="descent", step_scale=50.0, max_iter=5000)


@pytest.mark.parametrize("method", ["pcg", "amg"])
def test_indefinite_stiffness_raises_diverged(cube, method, kernel):
    m = mt.MassTensorModel(cube.points, cube.cells, mu=-1.0, lmbda=0.5)
    pts = m.point_types().border(cube.region_vertices("xmin")).displacement(
        cube.region_vertices("xmax"), (1.0, 0.0, 0.0))
    with pytest.raises(SolverDivergedError, match="iteration"):
        m.solve(pts, method=method, stop_mm=1e-12, max_iter=10000)


def test_a_cell_of_zero_volume_is_rejected_naming_it(kernel):
    points = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0]], float)
    cells = np.array([[0, 1, 2, 3], [0, 1, 4, 2]])        # the second is flat (z = 0)
    with pytest.raises(CaseError, match=r"zero volume \(cell 1, vertices \[0, 1, 4, 2\]\)"):
        mt.MassTensorModel(points, cells, MAT)


def test_bad_options_rejected(cube):
    case = stretch_case(cube)
    with pytest.raises(CaseError, match="method"):
        mt.solve(case, method="newton")
    with pytest.raises(CaseError, match="stop_mm"):
        mt.solve(case, stop_mm=0.0)


def test_surface_sliding_that_cycles_between_planes_stops_as_not_converged():
    """A vertex at a crease can bounce between two triangles' tangent planes forever (seen on
    the implant plan with OpenBLAS); the rounds must stop once their move stops shrinking and
    the result must say it did not converge, not loop to max_iter."""
    state = IterationState.__new__(IterationState)
    state.stop, state.max_iter, state.it, state.ok = 0.01, 200000, 0, True
    rounds = []

    def linear(types, u, method, refresh=None):
        state.it += 4
        rounds.append(1)
        return u + 0.08 * (1 if len(rounds) % 2 else -1)   # moves 0.08 mm, then back

    state.solve_linear = linear
    state.active_planes = lambda types, u: (types, 0.0)
    types = type("T", (), {"surface_of": {0: object()}})()
    state.run(types, np.zeros((3, 3)), "pcg")
    assert state.ok is False
    assert len(rounds) <= IterationState.STALL_ROUNDS + 2


# ----------------------------------------------------------------- the direct solve
def test_the_direct_solve_equals_the_independent_assembly_and_reuses_its_factorization(cube,
                                                                                       K_ref):
    """method "direct" (the default): the equilibrium of the independently assembled stiffness
    to round-off; a second solve with other prescribed values on the same point types reuses
    the model's factorization (one back-substitution) and is as exact."""

    driver.MODEL_CACHE.clear()
    calls = []

    def counted(A, cache):                             # no factorization: SuperLU, as
        calls.append(A.shape)                          # without the hook

    case = stretch_case(cube)
    c = case.constraints
    res = mt.solve(case, factorize=counted)
    assert res.converged and res.iterations == 1 and res.extra["method"] == "direct"
    assert np.abs(res.u - direct_solve(K_ref, cube.n_vertices, 3, c.dofs, c.values)).max() < 1e-10
    other = Case(mesh=cube, material=MAT, boundaries=[
        Boundary("xmin", "fixed"), Boundary("xmax", "displacement", value=(-0.7, 0.2, 0.9))])
    c2 = other.constraints
    res2 = mt.solve(other, factorize=counted)
    assert np.abs(res2.u - direct_solve(K_ref, cube.n_vertices, 3, c2.dofs, c2.values)).max() \
        < 1e-10
    assert len(calls) == 1                             # the second solve factorized nothing


def test_the_direct_solve_with_surface_sliding_equals_sliding_on_the_plane(slab):
    m, base, top, xmax, push = _slab_pushed_down(slab)
    a = m.solve(m.point_types().target(top, push).sliding(base, mt.Plane((0, 0, 0), (0, 0, 1)))
                .border(xmax), method="direct", stop_mm=1e-9)
    b = m.solve(m.point_types().target(top, push).sliding(base, plane_triangulation(0.0))
                .border(xmax), method="pcg", stop_mm=1e-12)
    c = m.solve(m.point_types().target(top, push).sliding(base, plane_triangulation(0.0))
                .border(xmax), method="direct", stop_mm=1e-9)
    assert a.iterations == 1
    assert np.abs(a.u - b.u).max() < 1e-6 and np.abs(c.u - b.u).max() < 1e-6


def test_the_direct_solve_refuses_an_indefinite_stiffness(cube):
    m = mt.MassTensorModel(cube.points, cube.cells, mu=-1.0, lmbda=0.5)
    pts = m.point_types().border(cube.region_vertices("xmin")).displacement(
        cube.region_vertices("xmax"), (1.0, 0.0, 0.0))
    with pytest.raises(SolverDivergedError, match="not positive definite"):
        m.solve(pts, method="direct")


def test_the_direct_solve_refuses_a_body_held_by_nothing(cube):
    m = mt.MassTensorModel(cube.points, cube.cells, MAT)
    with pytest.raises(SolverDivergedError, match="singular|not positive definite|runaway"):
        m.solve(m.point_types(), f_ext=np.ones((cube.n_vertices, 3)), method="direct")


def test_the_direct_solve_by_cholmod_equals_the_one_by_superlu():
    """The command line's factorization hook (CHOLMOD through PETSc, from 500 unknowns on)
    gives SuperLU's answer."""
    from tissue_reference.fem_reference import cholmod_factor

    case = stretch_case(box(2.0, lengths=(10.0, 10.0, 10.0)))
    driver.MODEL_CACHE.clear()
    a = mt.solve(case)
    driver.MODEL_CACHE.clear()
    used = []

    def hook(A, cache):
        f = cholmod_factor(A, cache)
        used.append(f is not None)
        return f

    b = mt.solve(case, factorize=hook)
    assert used == [True] and np.abs(a.u - b.u).max() < 1e-10
