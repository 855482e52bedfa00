"""P1 mechanics of the ADMM solver: element kinematics (shape-function gradients, volumes), the
material laws (Neo-Hookean, seed eq. 14, and linear elasticity; 2D is plane strain), and the
P1 strain energy, internal forces and exact tangent of a displacement (mm, kPa, mN).

Everything here is host (numpy/scipy) code: the Newton polish, the tangent lift and the final
checks use it whatever backend ran the ADMM iterations."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from tissue_reference.meshes.errors import CaseError

ADMM_LAWS = ("neo-hookean", "linear-elastic")
"""The strain-energy laws the ADMM solver implements; it refuses the others by name."""


@dataclass(frozen=True)
class ElementKinematics:
    """P1 kinematics: G (m, d+1, d) reference shape-function gradients (1/mm), V (m,) volumes
    (mm^3), dofs (m, (d+1)*d) node-major dof ids, d the dimension."""

    G: np.ndarray
    V: np.ndarray
    dofs: np.ndarray
    d: int


def element_kinematics(mesh) -> ElementKinematics:
    """Shape-function gradients and volumes of a MeshData (points in mm)."""
    X = mesh.points
    cells = mesh.cells
    d = X.shape[1]
    T = np.transpose(X[cells[:, 1:]] - X[cells[:, :1]], (0, 2, 1))  # columns = edges
    Tinv = np.linalg.inv(T)  # rows = grad N_1..d
    G = np.concatenate([-Tinv.sum(axis=1, keepdims=True), Tinv], axis=1)
    V = np.abs(np.linalg.det(T)) / (6.0 if d == 3 else 2.0)
    dofs = (cells[:, :, None] * d + np.arange(d)).reshape(len(cells), -1)
    return ElementKinematics(G, V, dofs, d)


def displacement_gradient(kin: ElementKinematics, u: np.ndarray) -> np.ndarray:
    """H_e = grad u (m, d, d), H_iJ = sum_a u_ai G_aJ."""
    ue = u.reshape(-1)[kin.dofs].reshape(len(kin.V), kin.d + 1, kin.d)
    return np.einsum("mai,maj->mij", ue, kin.G)


def scatter_forces(kin: ElementKinematics, Pv: np.ndarray, n: int) -> np.ndarray:
    """Nodal forces sum_e V_e P_e : grad N_a, with Pv = V_e P_e (m, d, d); node-major (n,)."""
    fe = np.einsum("mij,maj->mai", Pv, kin.G).reshape(len(kin.V), -1)
    return np.bincount(kin.dofs.ravel(), weights=fe.ravel(), minlength=n)


# =========================================================================== material laws
def det_closed_form(F):
    """det of (m, d, d), closed form."""
    if F.shape[1] == 3:
        return (F[:, 0, 0] * (F[:, 1, 1] * F[:, 2, 2] - F[:, 1, 2] * F[:, 2, 1])
                - F[:, 0, 1] * (F[:, 1, 0] * F[:, 2, 2] - F[:, 1, 2] * F[:, 2, 0])
                + F[:, 0, 2] * (F[:, 1, 0] * F[:, 2, 1] - F[:, 1, 1] * F[:, 2, 0]))
    return F[:, 0, 0] * F[:, 1, 1] - F[:, 0, 1] * F[:, 1, 0]


def det_cof(F):
    """det and cofactor (J F^-T) of (m, d, d) with closed forms."""
    cof = np.empty_like(F)
    if F.shape[1] == 3:
        for i in range(3):
            i1, i2 = (i + 1) % 3, (i + 2) % 3
            for j in range(3):
                j1, j2 = (j + 1) % 3, (j + 2) % 3
                cof[:, i, j] = F[:, i1, j1] * F[:, i2, j2] - F[:, i1, j2] * F[:, i2, j1]
        J = np.einsum("mj,mj->m", F[:, 0, :], cof[:, 0, :])
        return J, cof
    J = F[:, 0, 0] * F[:, 1, 1] - F[:, 0, 1] * F[:, 1, 0]
    cof[:, 0, 0], cof[:, 1, 1] = F[:, 1, 1], F[:, 0, 0]
    cof[:, 0, 1], cof[:, 1, 0] = -F[:, 1, 0], -F[:, 0, 1]
    return J, cof


class Law:
    """Energy density psi (kPa), first Piola stress P = dpsi/dH (kPa) and A = dP/dH (kPa) of the
    displacement gradient H (m, d, d)."""

    def __init__(self, material, d):
        material.require_law(ADMM_LAWS, "the ADMM solver")
        material.require_compressible("the ADMM solver")
        material.require_seed_volumetric("the ADMM solver")
        self.model = material.model
        self.mu, self.kappa, self.lmbda = material.mu, material.kappa, material.lmbda
        self.d = d

    def psi_J(self, H):
        d = self.d
        if self.model == "linear-elastic":
            eps = 0.5 * (H + np.transpose(H, (0, 2, 1)))
            tr = np.einsum("mii->m", eps)
            return self.mu * np.einsum("mij,mij->m", eps, eps) + 0.5 * self.lmbda * tr ** 2, None
        F = H + np.eye(d)
        J, _ = det_cof(F)
        I1 = np.einsum("mij,mij->m", F, F) + (3 - d)
        # (no np.errstate here: it costs more than the arithmetic at these sizes; J == 0
        # exactly is measure-zero and only gives an inf)
        Jm = np.abs(J) ** (-2.0 / 3.0)
        psi = 0.5 * self.mu * (Jm * I1 - 3.0) + 0.5 * self.kappa * (J - 1.0) ** 2
        psi[~(J > 0)] = np.inf
        return psi, J

    def stress(self, H):
        """(P, J); J is None for linear elasticity."""
        d = self.d
        if self.model == "linear-elastic":
            eps = 0.5 * (H + np.transpose(H, (0, 2, 1)))
            tr = np.einsum("mii->m", eps)
            P = 2.0 * self.mu * eps
            P[:, np.arange(d), np.arange(d)] += (self.lmbda * tr)[:, None]
            return P, None
        F = H + np.eye(d)
        J, cof = det_cof(F)
        I1 = np.einsum("mij,mij->m", F, F) + (3 - d)
        a = self.mu * np.abs(J) ** (-2.0 / 3.0)
        # P = mu J^-2/3 (F - I1/3 F^-T) + kappa J (J - 1) F^-T,  J F^-T = cof
        b = self.kappa * (J - 1.0) - a * I1 / (3.0 * J)
        P = a[:, None, None] * F
        P += b[:, None, None] * cof
        return P, J

    def tangent(self, H):
        """A (m, d*d, d*d), rows (iJ), columns (kL): A_iJkL = d P_iJ / d H_kL."""
        d = self.d
        m = len(H)
        if self.model == "linear-elastic":
            I = np.eye(d)
            A = self.mu * (np.einsum("ik,jl->ijkl", I, I) + np.einsum("il,jk->ijkl", I, I)) \
                + self.lmbda * np.einsum("ij,kl->ijkl", I, I)
            return np.broadcast_to(A.reshape(d * d, d * d), (m, d * d, d * d)).copy()
        F = H + np.eye(d)
        J, cof = det_cof(F)
        I1 = np.einsum("mij,mij->m", F, F) + (3 - d)
        Jm = np.abs(J) ** (-2.0 / 3.0)
        Fi = (cof / J[:, None, None]).reshape(m, -1)
        Ff = F.reshape(m, -1)
        mu, kappa = self.mu, self.kappa
        c1 = mu * Jm
        c2 = -2.0 / 3.0 * mu * Jm
        c3 = 2.0 / 9.0 * mu * Jm * I1 + kappa * (2.0 * J - 1.0) * J
        c4 = mu * Jm * I1 / 3.0 - kappa * J * (J - 1.0)
        Fi3 = Fi.reshape(m, d, d)
        T = np.einsum("mil,mkj->mijkl", Fi3, Fi3).reshape(m, d * d, d * d)
        A = c2[:, None, None] * (Ff[:, :, None] * Fi[:, None, :] + Fi[:, :, None] * Ff[:, None, :])
        A += c3[:, None, None] * (Fi[:, :, None] * Fi[:, None, :])
        A += c4[:, None, None] * T
        A[:, np.arange(d * d), np.arange(d * d)] += c1[:, None]
        return A


# =========================================================================== energy, forces, K
def case_parts(case):
    kin = element_kinematics(case.mesh)
    return kin, Law(case.material, kin.d)


def as_u(case, u):
    n, d = case.mesh.n_vertices, case.mesh.gdim
    u = np.asarray(u, dtype=np.float64)
    if u.size != n * d:
        raise CaseError(f"displacement has {u.size} values, expected {n}x{d} = {n * d} "
                        f"(n_vertices x gdim, mm)")
    return u.reshape(-1)


def strain_energy(case, u) -> float:
    """P1 strain energy sum_e V_e psi(F_e) (uJ = kPa mm^3) of displacement u (mm, (n, gdim))."""
    kin, law = case_parts(case)
    psi, _ = law.psi_J(displacement_gradient(kin, as_u(case, u)))
    return float(kin.V @ psi)


def internal_forces(case, u) -> np.ndarray:
    """f_int = dU/du (mN), node-major (n*gdim,), of displacement u (mm)."""
    kin, law = case_parts(case)
    uu = as_u(case, u)
    P, _ = law.stress(displacement_gradient(kin, uu))
    return scatter_forces(kin, kin.V[:, None, None] * P, uu.size)


def element_K(kin, A):
    """Element stiffness (m, (d+1)d, (d+1)d): V B^T A B, B_(iJ),(a i') = delta_ii' G_aJ, i.e.
    Ke_(a i),(b k) = V sum_JL G_aJ A_iJkL G_bL, as two stacked matrix products."""
    m, d = len(kin.V), kin.d
    k = d + 1
    C = np.matmul(A.reshape(m, d * d * d, d), kin.G.transpose(0, 2, 1))  # (m, iJk, b)
    Ke = np.matmul(kin.G[:, None], C.reshape(m, d, d, d * k))  # (m, i, a, kb)
    Ke = Ke.reshape(m, d, k, d, k).transpose(0, 2, 1, 4, 3) * kin.V[:, None, None, None, None]
    return Ke.reshape(m, k * d, k * d)


def assemble(kin, Ke, n):
    nd = kin.dofs.shape[1]
    rows = np.repeat(kin.dofs, nd, axis=1).ravel()
    cols = np.tile(kin.dofs, (1, nd)).ravel()
    return sp.csr_matrix((Ke.ravel(), (rows, cols)), shape=(n, n))


def tangent_stiffness(case, u) -> sp.csr_matrix:
    """Exact Hessian d^2 U / du^2 (mN/mm) of the P1 energy at displacement u (mm), CSR,
    node-major dofs (gdim*v + c) in the Case vertex numbering, no boundary conditions applied."""
    kin, law = case_parts(case)
    uu = as_u(case, u)
    return assemble(kin, element_K(kin, law.tangent(displacement_gradient(kin, uu))), uu.size)

