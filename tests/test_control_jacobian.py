"""Jacobians of seed 000 eq. 19 and of rigid actuator pushes, checked on a linear P1 model where
the finite difference of the solve is exact, plus their structural properties."""
import numpy as np
import pytest
import scipy.sparse as sp
from test_control_support import LinearPlant, linear_p1_stiffness, phantom

from tissue_reference.control.dof_maps import point_matrix, probe_matrix
from tissue_reference.control.jacobian import (
    dirichlet_jacobian,
    fd_jacobian,
    force_jacobian,
    max_rel_error,
)
from tissue_reference.errors import CaseError


@pytest.fixture(scope="module")
def model():
    case = phantom()
    K = linear_p1_stiffness(case)
    return case, K


def test_dirichlet_jacobian_equals_central_fd_of_linear_solve(model):
    case, K = model
    J = dirichlet_jacobian(case, K)
    Jfd = fd_jacobian(LinearPlant(K), case, {"A1": 2.0}, h=0.5)
    assert J.J.shape == (15, 4)
    assert J.rows[:4] == ["T1.x", "T1.y", "T1.z", "T2.x"]
    assert max_rel_error(J.J, Jfd.J) < 1e-9


def test_pushing_inward_moves_centre_target_along_push(model):
    case, K = model
    J = dirichlet_jacobian(case, K).block("T1")
    # A1 pushes along -x, A2 along -y, A3 +x, A4 +y: the centre target follows each push
    for j, d in enumerate([(-1, 0), (0, -1), (1, 0), (0, 1)]):
        assert np.dot(J[:2, j], d) > 0.1
        assert np.dot(J[:2, j], d) < 1.0


def test_probe_matrix_reproduces_case_probe_values(model):
    case, _ = model
    u = np.random.default_rng(0).normal(size=(case.mesh.n_vertices, 3))
    P = probe_matrix(case)
    ref = np.concatenate(list(case.probe_values(u).values()))
    assert np.allclose(P @ u.ravel(), ref, rtol=0, atol=1e-13)


def test_point_matrix_interpolates_linear_field_exactly(model):
    case, _ = model
    X = case.mesh.points
    u = X @ np.array([[1.0, 2.0, 0.5], [0.0, -1.0, 3.0], [2.0, 0.0, 1.0]]).T
    pts = np.array([[0.0, 0.0, 15.0], [10.0, -7.0, 15.0], [200.0, 0.0, 15.0]])
    P, inside = point_matrix(case.mesh, pts)
    assert inside.tolist() == [True, True, False]
    vals = (P @ u.ravel()).reshape(-1, 3)
    exact = pts @ np.array([[1.0, 2.0, 0.5], [0.0, -1.0, 3.0], [2.0, 0.0, 1.0]]).T
    assert np.allclose(vals[:2], exact[:2], atol=1e-10)
    assert np.all(vals[2] == 0)


def test_degree2_style_extended_K_gives_same_jacobian_with_supplied_P(model):
    # pad K with extra decoupled 'edge' nodes (identity block) after the vertices: the Jacobian
    # computed with P and region_nodes supplied by the caller must not change
    case, K = model
    n = K.shape[0]
    Kx = sp.block_diag([K, sp.identity(30)]).tocsr()
    P = probe_matrix(case, n_dofs=n + 30)
    J1 = dirichlet_jacobian(case, K).J
    J2 = dirichlet_jacobian(case, Kx, P=P, region_nodes=case.mesh.region_vertices).J
    assert np.allclose(J1, J2, rtol=0, atol=1e-12 * np.abs(J1).max())


def test_extended_K_without_P_is_refused_by_name(model):
    case, K = model
    Kx = sp.block_diag([K, sp.identity(30)]).tocsr()
    with pytest.raises(CaseError, match="degree 2"):
        dirichlet_jacobian(case, Kx)


def test_force_jacobian_eq19_matches_definition(model):
    # J_s = G C^-1 with G = Jm^T K^-1 Jc and C = Jc^T K^-1 Jc computed by dense algebra
    case, K = model
    Js = force_jacobian(case, K)
    free = case.free_dofs()
    Kd = K.toarray()[np.ix_(free, free)]
    n = K.shape[0]
    Jc = np.zeros((n, 4))
    X = case.mesh.points
    for j, a in enumerate(case.actuators):
        verts = case.mesh.region_vertices(a.region)
        v = verts[np.argmin(np.linalg.norm(X[verts] - X[verts].mean(0), axis=1))]
        Jc[3 * v: 3 * v + 3, j] = a.direction
    Kinv_Jc = np.linalg.solve(Kd, Jc[free])
    G = (probe_matrix(case).toarray()[:, free]) @ Kinv_Jc
    C = Jc[free].T @ Kinv_Jc
    assert np.allclose(Js.J, G @ np.linalg.inv(C), rtol=0, atol=1e-10 * np.abs(Js.J).max())
    # unit control displacement of actuator j: C^-1 applied gives exactly the identity on x_c
    assert np.allclose(Js.extra["C"] @ np.linalg.inv(Js.extra["C"]), np.eye(4))


def test_missing_actuator_and_target_are_named(model):
    case, K = model
    with pytest.raises(CaseError, match="'A9'"):
        dirichlet_jacobian(case, K, actuators=["A1", "A9"])
    with pytest.raises(CaseError, match="'T7'"):
        dirichlet_jacobian(case, K, targets=["T7"])
