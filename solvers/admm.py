"""ADMM fast solver of seed 000 (eqs. 5-10; Overby et al. 2017, "ADMM ⊇ Projective Dynamics").

Problem (seed eq. 5/6), P1 simplices, displacement u (mm) node-major (dof = gdim*v + c):

    min_u  1/(2 dt^2) ||u - u_tilde||_M^2 + sum_e V_e psi(I + H_e) - f_ext . u,   H_e = D_e u = grad u

(the mass term only for implicit-Euler dynamics; quasi-static equilibrium drops it). ADMM splits
z_e ~ H_e with the constraint W (D u - z) = 0, W_e = w_e I, and iterates (scaled dual lam):

    x-step (eq. 7):  (M/dt^2 + D^T W^2 D) u = M u_tilde/dt^2 + D^T W^2 (z - lam) + f_ext
    z-step (eq. 8/10, every element at once):
                     z_e = argmin_z V_e psi(I + z) + w_e^2/2 |z - (D_e u + lam_e)|^2
    dual (eq. 9):    lam_e += D_e u - z_e

Weights: w_e^2 = rho * V_e (V_e the reference volume, mm^3; rho in kPa), i.e. one penalty
stiffness per unit volume for the whole mesh. D^T W^2 D is then rho times the P1 vector
Laplacian, factorized once per Case (scipy splu on the free dofs) and reused by every iteration,
every load value and every warm start. Default rho = kappa + 4 mu / 3 = lambda + 2 mu (the
P-wave modulus) for both materials; overridable (``rho=``).

Material (seed eq. 14, ``case.material``): psi = mu/2 (J^(-2/3) I1 - 3) + kappa/2 (J - 1)^2,
or linear elasticity psi = mu eps:eps + lambda/2 tr(eps)^2. 2D meshes are plane strain (F33 = 1).

z-step: linear elasticity in closed form (skew / deviatoric / volumetric parts). Neo-Hookean:
one Newton-type step per ADMM iteration for every element, warm-started from the previous z,
with the model Hessian (rho + mu J^(-2/3)) I + max(kappa (2 - 1/J), 0) cof (x) cof (the penalty
and volumetric parts of the exact one) inverted in closed form (Sherman-Morrison), so no
per-element 9x9 matrices are formed, stored or inverted; steps that are not provably safe
(large, or J near 0) get a backtracking line search keeping J > 0 and decreasing the local
objective. At a fixed point the z-step gradient vanishes, so the fixed point is exact whatever
the model. The loop carries F = I + z (the identity folded into the constant x-step terms).
The element work of an iteration (gather of D u, z-step, dual update, residuals, scatter of the
next x-step data) runs in one compiled pass (``admm_kernel.c``, built on first use, see
``use_kernel``; ``_KernelElements``), or, without a C compiler, in numpy on (d, d, m)
structure-of-arrays blocks of CHUNK elements (``_NumpyElements``, the same arithmetic; the
tests compare the two). Elements and vertices are ordered internally by reverse Cuthill-McKee
rank (locality on large meshes; element numbers in error messages are the mesh's). One
iteration at ~1.8k tets takes about 0.17-0.32 ms on the shared 2-core development machine,
depending on its load (``bench/bench_admm.py``).

Stopping rule (mm): primal = max_e h_e |D_e u - z_e|, dual = (rho/rho0) max_e h_e |z_e^k -
z_e^(k-1)| (h_e = V_e^(1/gdim), a length); both below ``tol_mm`` (and, with the iterative x-step of
large meshes, its last CG update below ``tol_mm``). Quasi-static solves double rho (up to 64 rho0;
free: the x-step matrix is rho times a fixed one) when the primal residual stagnates over 25
iterations (nonconvex elements can cycle between two local z-step minima); the changes are listed
in ``history["rho_changes"]``. ADMM converges linearly, so by default a "Newton polish" follows:
Newton steps on the same P1 energy with this module's exact tangent (``tangent_stiffness``,
assembled straight into a cached CSR pattern of the reduced unknowns) until the largest Newton step
is below ``polish_tol_mm``. With the polish, ADMM only has to bring each load step near Newton's
basin: it hands over at ``handoff_mm`` (0.01 mm) or after ``max_iter`` iterations (default 20 with
the polish, 20000 without); on the phantom with all four actuators pushed 15 mm (1782 tets) this
cut the solve from 6486 ADMM iterations + 10 Newton (about 12.6 s in ``make demo``) to 86 ADMM + 14
Newton iterations, same answer (to 1e-11 mm). Both iteration counts are reported
(``extra["admm_iterations"]``, ``extra["newton_iterations"]``); ``history["admm_clock_s"]`` holds
the wall-clock time (s, from the start of the solve) at the end of every ADMM iteration.

Large prescribed motions (e.g. 15 mm pushes) are applied in load steps of at most ``step_mm``;
each step moves the boundary and carries the interior along (tangent or harmonic lift), runs
ADMM (``max_iter`` per step) and, with ``polish``, Newton. When the ADMM state of a step is
outside Newton's basin (inverted elements along the Newton path), the polish restarts from the
step's lifted start state; such restarts are listed in ``extra["polish_restarts"]`` (then that
step's equilibrium is Newton's, not ADMM's, work).

x-step solver: without oblique sliding, D^T W^2 D (+ M/dt^2) is a scalar matrix times I_d in
node-major order, so one scalar SuperLU factorization per distinct free-vertex set serves all
components (multi-column solves; the reduced unknowns are ordered component-major, so the
right-hand side is a view, no gather); with oblique sliding the reduced coupled matrix is
factorized. From PCG_MIN (4000) free vertices on (about 20k tets) the scalar matrix is not
factorized (a direct factor's fill and solve time grow like n^1.4-1.5 on these 3D meshes: 28M
factor entries, 320 MiB and 130 ms per solve at 185k tets; at 50k tets SuperLU's solve took 12 ms,
CG 6 ms) but solved by conjugate gradients preconditioned with an aggregation AMG V-cycle built
here (scipy, the iteration in C; O(n) work and memory): the x-step is then inexact, warm-started
from the previous iterate and stopped when its largest vertex update is below PCG_RTOL (0.3) times
the first one or below XSTEP_TOL (0.1) times the ADMM tolerance; the ADMM stopping rule also
requires the last CG update below ``tol_mm``. The x-step matrix is constant, so at an ADMM fixed
point the warm start solves it exactly and the fixed point (the answer) is unchanged
(``tests/test_admm.py`` compares both x-steps).

Boundary conditions: prescribed dofs (fixed, displacement, affine, axis-aligned sliding) are
eliminated; oblique sliding u.n = g by a per-vertex change of basis (exact). Tractions and gravity
enter as external forces (``case.external_forces``) in the x-step.

Units: mm, kPa, mN, kg, s; energy uJ = kPa mm^3 = mN mm.
"""
from __future__ import annotations

import math
import time
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from meshes.errors import CaseError, SolverDivergedError
from meshes.mesh import deformation_state
from meshes.results import SolveResult
from solvers import _ckernel

__all__ = [
    "AdmmOperators",
    "ImplicitEuler",
    "element_kinematics",
    "internal_forces",
    "prepare",
    "solve",
    "strain_energy",
    "tangent_stiffness",
]


# =========================================================================== element kinematics
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


def _grad(kin: ElementKinematics, u: np.ndarray) -> np.ndarray:
    """H_e = grad u (m, d, d), H_iJ = sum_a u_ai G_aJ."""
    ue = u.reshape(-1)[kin.dofs].reshape(len(kin.V), kin.d + 1, kin.d)
    return np.einsum("mai,maj->mij", ue, kin.G)


def _scatter(kin: ElementKinematics, Pv: np.ndarray, n: int) -> np.ndarray:
    """Nodal forces sum_e V_e P_e : grad N_a, with Pv = V_e P_e (m, d, d); node-major (n,)."""
    fe = np.einsum("mij,maj->mai", Pv, kin.G).reshape(len(kin.V), -1)
    return np.bincount(kin.dofs.ravel(), weights=fe.ravel(), minlength=n)


# =========================================================================== material laws
def _det(F):
    """det of (m, d, d), closed form."""
    if F.shape[1] == 3:
        return (F[:, 0, 0] * (F[:, 1, 1] * F[:, 2, 2] - F[:, 1, 2] * F[:, 2, 1])
                - F[:, 0, 1] * (F[:, 1, 0] * F[:, 2, 2] - F[:, 1, 2] * F[:, 2, 0])
                + F[:, 0, 2] * (F[:, 1, 0] * F[:, 2, 1] - F[:, 1, 1] * F[:, 2, 0]))
    return F[:, 0, 0] * F[:, 1, 1] - F[:, 0, 1] * F[:, 1, 0]


def _det_cof(F):
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


class _Law:
    """Energy density psi (kPa), first Piola stress P = dpsi/dH (kPa) and A = dP/dH (kPa) of the
    displacement gradient H (m, d, d)."""

    def __init__(self, material, d):
        material.require_compressible("the ADMM solver")
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
        J, _ = _det_cof(F)
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
        J, cof = _det_cof(F)
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
        J, cof = _det_cof(F)
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
def _case_parts(case):
    kin = element_kinematics(case.mesh)
    return kin, _Law(case.material, kin.d)


def _as_u(case, u):
    n, d = case.mesh.n_vertices, case.mesh.gdim
    u = np.asarray(u, dtype=np.float64)
    if u.size != n * d:
        raise CaseError(f"displacement has {u.size} values, expected {n}x{d} = {n * d} "
                        f"(n_vertices x gdim, mm)")
    return u.reshape(-1)


def strain_energy(case, u) -> float:
    """P1 strain energy sum_e V_e psi(F_e) (uJ = kPa mm^3) of displacement u (mm, (n, gdim))."""
    kin, law = _case_parts(case)
    psi, _ = law.psi_J(_grad(kin, _as_u(case, u)))
    return float(kin.V @ psi)


def internal_forces(case, u) -> np.ndarray:
    """f_int = dU/du (mN), node-major (n*gdim,), of displacement u (mm)."""
    kin, law = _case_parts(case)
    uu = _as_u(case, u)
    P, _ = law.stress(_grad(kin, uu))
    return _scatter(kin, kin.V[:, None, None] * P, uu.size)


def _element_K(kin, A):
    """Element stiffness (m, (d+1)d, (d+1)d): V B^T A B, B_(iJ),(a i') = delta_ii' G_aJ, i.e.
    Ke_(a i),(b k) = V sum_JL G_aJ A_iJkL G_bL, as two stacked matrix products."""
    m, d = len(kin.V), kin.d
    k = d + 1
    C = np.matmul(A.reshape(m, d * d * d, d), kin.G.transpose(0, 2, 1))  # (m, iJk, b)
    Ke = np.matmul(kin.G[:, None], C.reshape(m, d, d, d * k))  # (m, i, a, kb)
    Ke = Ke.reshape(m, d, k, d, k).transpose(0, 2, 1, 4, 3) * kin.V[:, None, None, None, None]
    return Ke.reshape(m, k * d, k * d)


def _assemble(kin, Ke, n):
    nd = kin.dofs.shape[1]
    rows = np.repeat(kin.dofs, nd, axis=1).ravel()
    cols = np.tile(kin.dofs, (1, nd)).ravel()
    return sp.csr_matrix((Ke.ravel(), (rows, cols)), shape=(n, n))


def tangent_stiffness(case, u) -> sp.csr_matrix:
    """Exact Hessian d^2 U / du^2 (mN/mm) of the P1 energy at displacement u (mm), CSR,
    node-major dofs (gdim*v + c) in the Case vertex numbering, no boundary conditions applied."""
    kin, law = _case_parts(case)
    uu = _as_u(case, u)
    return _assemble(kin, _element_K(kin, law.tangent(_grad(kin, uu))), uu.size)


# =========================================================================== constraints
@dataclass(frozen=True)
class _Reduction:
    """u = up + Z q; Z (N, nq) orthonormal columns, each on one vertex. separable: no oblique
    sliding, Z selects the plain free dofs ``plain_dofs`` (in this order)."""

    Z: sp.csr_matrix
    up: np.ndarray
    separable: bool = False
    plain_dofs: np.ndarray | None = None
    ZT: sp.csr_matrix | None = None  # Z^T (scipy's .T builds a new matrix at every use)


def _scalar_laplacian(kin, rho, n):
    """sum_e rho V_e G_e G_e^T (n, n): D^T W^2 D = this (x) I_d in node-major order."""
    k = kin.G.shape[1]
    Ke = rho * kin.V[:, None, None] * np.einsum("maj,mbj->mab", kin.G, kin.G)
    cells = kin.dofs[:, ::kin.d] // kin.d
    rows = np.repeat(cells, k, axis=1).ravel()
    cols = np.tile(cells, (1, k)).ravel()
    return sp.csr_matrix((Ke.ravel(), (rows, cols)), shape=(n, n))


def _spd_splu(A):
    """SuperLU of a symmetric positive definite matrix: symmetric ordering, no pivoting (keeps
    the fill of the minimum-degree ordering; ~4x faster solves than partial pivoting here)."""
    return spla.splu(A, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                     options={"SymmetricMode": True})


def _sym_splu(A, cache=None, factorize=None):
    """Factorization of a symmetric tangent (CSC/CSR, mN/mm) with a ``solve(b)`` method.
    ``factorize(A, cache)`` (optional, e.g. ``fem_reference.cholmod_factor``: CHOLMOD through
    PETSc, which this package does not import) is tried first; when it is absent or returns None
    (e.g. the tangent is not positive definite), SuperLU with a symmetric minimum-degree
    ordering and diagonal pivots preferred (threshold 0.01) so the ordering's fill is kept.
    ``cache``: a dict per operator set that ``factorize`` may keep its symbolic analysis in.
    RuntimeError when the matrix is singular."""
    if factorize is not None:
        f = factorize(A, {} if cache is None else cache)
        if f is not None:
            return f
    return spla.splu(A, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.01,
                     options={"SymmetricMode": True})


class _Direct:
    """SuperLU of an SPD matrix; ``step`` (the ADMM x-step) is the exact solve."""

    def __init__(self, A):
        self.lu = _spd_splu(A.tocsc())
        self.nnz = self.lu.L.nnz + self.lu.U.nnz
        self.bytes = 12 * self.nnz  # factor values + row indices
        self.untracked_bytes = self.bytes  # SuperLU's own memory, not seen by tracemalloc

    def solve(self, B):
        return self.lu.solve(np.asfortranarray(B))

    def step(self, B, X0, tol_mm=0.0):
        return self.solve(B)


def _aggregate(A):
    """Smoothed-aggregation aggregates (Vanek, Mandel, Brezina 1996) on the graph of the
    strength matrix A (CSR): roots whose neighbourhood is still free, then the leftovers joined
    to a neighbouring aggregate, then isolated ones. Returns (agg (n,), number of aggregates)."""
    n = A.shape[0]
    ip, ind = A.indptr.tolist(), A.indices.tolist()
    agg = [-1] * n
    na = 0
    for i in range(n):
        if agg[i] >= 0:
            continue
        nb = ind[ip[i]:ip[i + 1]]
        if all(agg[j] < 0 for j in nb):
            for j in nb:
                agg[j] = na
            agg[i] = na
            na += 1
    first = list(agg)
    for i in range(n):
        if first[i] < 0:
            for j in ind[ip[i]:ip[i + 1]]:
                if first[j] >= 0:
                    agg[i] = first[j]
                    break
    for i in range(n):
        if agg[i] < 0:
            agg[i] = na
            na += 1
    return np.asarray(agg, dtype=np.int64), na


class _AmgPcg:
    """Preconditioned conjugate gradients on an SPD scalar matrix (the x-step matrix of a large
    mesh), multi-column, with an aggregation AMG V-cycle (strength theta = 0.08; Jacobi-smoothed
    prolongator on the finest level, plain aggregation below: smoothed coarse operators densify,
    at 185k tets the third level had 456 nonzeros per row and cost 40% of a V-cycle, 1.5x
    slower per warm-started x-step for the same PCG iterations; one pre/post damped-Jacobi
    sweep, omega = 4 / (3 rho(D^-1 A)); coarsest level <= 500 unknowns, solved directly) as
    preconditioner. Work and memory are O(n) (a direct factor's fill grows like n^(4/3) and more
    on 3D meshes). With the compiled kernel the PCG and V-cycle run in C (``amg_pcg``, all
    right-hand sides at once, the coarsest level by its dense inverse), otherwise in numpy
    (coarsest level by SuperLU); same arithmetic. ``step`` is the ADMM x-step: ``iters`` PCG
    iterations warm-started from the previous x (inexact; the x-step matrix is constant and at
    an ADMM fixed point the warm start solves it, so the fixed point is unchanged); ``solve``
    iterates to a relative residual of 1e-12."""

    theta = 0.08
    coarse = 500
    smooth_levels = 1  # levels with a smoothed prolongator (below: plain aggregation)

    def __init__(self, A, iters=1):
        self.iters = iters
        self.count = [0, 0]  # PCG calls, PCG iterations (statistics)
        self.last_update = 0.0  # largest vertex update (mm) of the last PCG iteration
        A = A.tocsr()
        self.A = A
        self.levels = []
        while A.shape[0] > self.coarse:
            n = A.shape[0]
            C = A.tocoo()
            dg = np.sqrt(np.abs(A.diagonal()))
            keep = (np.abs(C.data) >= self.theta * dg[C.row] * dg[C.col]) | (C.row == C.col)
            S = sp.csr_matrix((C.data[keep], (C.row[keep], C.col[keep])), shape=A.shape)
            agg, na = _aggregate(S)
            if na > 0.6 * n:  # no real coarsening left
                break
            T = sp.csr_matrix((np.ones(n), (np.arange(n), agg)), shape=(n, na))
            dinv = 1.0 / A.diagonal()
            x = np.random.default_rng(0).random(n)
            lam = 1.0
            for _ in range(15):  # power iteration for rho(D^-1 A)
                y = dinv * (A @ x)
                lam = float(np.linalg.norm(y))
                x = y / lam
            P = (T - sp.diags((4.0 / 3.0 / lam) * dinv) @ (A @ T)).tocsr() \
                if len(self.levels) < self.smooth_levels else T.tocsr()
            R = P.T.tocsr()
            self.levels.append((A, ((4.0 / 3.0 / lam) * dinv)[:, None], P, R))
            A = (R @ A @ P).tocsr()
        self.lu = _spd_splu(A.tocsc())
        mats = [lv[k] for lv in self.levels for k in (0, 2, 3)]
        self.bytes = sum(12 * M.nnz + 4 * M.shape[0] for M in mats) + 12 * (
            self.lu.L.nnz + self.lu.U.nnz)
        self.nnz = sum(M.nnz for M in mats)
        self.untracked_bytes = 12 * (self.lu.L.nnz + self.lu.U.nnz)  # coarsest-level SuperLU
        # the compiled iteration: a hierarchy with levels and a coarsest matrix small enough for
        # its dense inverse
        self._c = self._compiled(A) if (self.levels and A.shape[0] <= 2000
                                        and use_kernel()) else None

    def _compiled(self, Ac):
        """The hierarchy as the compiled amg_pcg's level structs (int32 CSR arrays kept alive
        here) and the dense inverse of the coarsest matrix (<= 2000 unknowns; its direct solve
        by SuperLU in the numpy V-cycle: the two agree to round-off)."""
        ffi, lib = _ckernel.load()
        keep = []

        def arr(a, dtype=np.float64, kind="double *"):
            a = np.ascontiguousarray(a, dtype=dtype)
            keep.append(a)
            return ffi.cast(kind, a.ctypes.data)

        def csr(M):
            return (arr(M.indptr, np.int32, "int *"), arr(M.indices, np.int32, "int *"),
                    arr(M.data))

        lv = ffi.new("amg_level[]", len(self.levels))
        for s, (A, dw, P, R) in zip(lv, self.levels):
            s.n = A.shape[0]
            s.Ap, s.Ai, s.Ax = csr(A)
            s.Pp, s.Pi, s.Px = csr(P)
            s.Rp, s.Ri, s.Rx = csr(R)
            s.dw = arr(dw.ravel())
        return {"ffi": ffi, "lib": lib, "lv": lv, "keep": keep, "nc": Ac.shape[0],
                "Ainv": arr(np.linalg.inv(Ac.toarray())), "scratch": {}}

    def _pcg_compiled(self, B, X, maxit, rtol, step_tol):
        c = self._c
        ffi, k = c["ffi"], B.shape[1]
        if k > 8:
            raise ValueError("compiled PCG: at most 8 right-hand sides")
        sc = c["scratch"].get(k)
        if sc is None:  # per-level scratch (x, r, b), PCG work and coarsest-level work
            bufs = [np.empty((3, lvl[0].shape[0] * k)) for lvl in self.levels]
            sc = c["scratch"][k] = (bufs, np.empty(4 * self.A.shape[0] * k),
                                    np.empty(2 * c["nc"] * k), ffi.new("double *"))
            for s, b in zip(c["lv"], bufs):
                s.x, s.r, s.b = (ffi.cast("double *", b[j].ctypes.data) for j in range(3))
        bufs, work, cwork, last = sc
        B = np.ascontiguousarray(B, dtype=np.float64)
        X = np.array(X, dtype=np.float64, order="C")
        n_it = c["lib"].amg_pcg(
            len(self.levels), c["lv"], c["nc"], c["Ainv"], k,
            ffi.cast("double *", B.ctypes.data), ffi.cast("double *", X.ctypes.data),
            maxit, rtol, step_tol, PCG_RTOL, self.iters,
            ffi.cast("double *", work.ctypes.data), ffi.cast("double *", cwork.ctypes.data), last)
        self.count[0] += 1
        self.count[1] += n_it
        self.last_update = float(last[0])
        return X

    def _vcycle(self, b, level=0):
        if level == len(self.levels):
            return self.lu.solve(np.asfortranarray(b))
        A, dw, P, R = self.levels[level]
        x = dw * b
        r = b - A @ x
        x += P @ self._vcycle(R @ r, level + 1)
        r = b - A @ x
        r *= dw
        x += r
        return x

    def _pcg(self, B, X, maxit, rtol, step_tol=0.0):
        if self._c is not None:
            return self._pcg_compiled(B, X, maxit, rtol, step_tol)
        A = self.A
        r = B - A @ X
        stop = rtol * np.sqrt(np.einsum("ij,ij->j", B, B))
        z = self._vcycle(r)
        p = z
        rz = np.einsum("ij,ij->j", r, z)
        for it in range(maxit):
            Ap = A @ p
            pAp = np.einsum("ij,ij->j", p, Ap)
            alpha = np.divide(rz, pAp, out=np.zeros_like(rz), where=pAp > 0)
            dx = alpha * p
            X += dx
            r -= alpha * Ap
            if it == maxit - 1 or np.all(np.sqrt(np.einsum("ij,ij->j", r, r)) <= stop):
                break
            if step_tol > 0:
                dmax = float(np.einsum("ij,ij->i", dx, dx).max(initial=0.0))
                if it == 0:
                    lim = max(step_tol ** 2, (PCG_RTOL ** 2) * dmax)
                if it + 1 >= self.iters and dmax <= lim:
                    break
            z = self._vcycle(r)
            rzn = np.einsum("ij,ij->j", r, z)
            beta = np.divide(rzn, rz, out=np.zeros_like(rz), where=rz > 0)
            p = z + beta * p
            rz = rzn
        self.count[0] += 1
        self.count[1] += it + 1
        self.last_update = float(np.sqrt(np.einsum("ij,ij->i", dx, dx).max(initial=0.0)))
        return X

    def solve(self, B):
        B = np.ascontiguousarray(B)
        return self._pcg(B, np.zeros_like(B), 500, 1e-12)

    def step(self, B, X0, tol_mm):
        """At least ``iters`` PCG iterations from X0, then until the largest vertex update is
        below tol_mm (mm) or PCG_RTOL times the first one (at most 25)."""
        return self._pcg(np.ascontiguousarray(B), np.array(X0, order="C"), 25, 0.0, tol_mm)


class _ComponentSolver:
    """Solves the reduced x-step system when it is block diagonal per displacement component:
    one scalar solver per distinct free-vertex set (SuperLU, or AMG-preconditioned CG from
    PCG_MIN free vertices on), the components sharing a set solved together as a multi-column
    right-hand side. ``step(rhs, q0)`` is the x-step (warm-started from q0 for CG)."""

    def __init__(self, Ls, plain_dofs, d):
        comp = plain_dofs % d
        groups = {}
        for c in range(d):
            pos = np.flatnonzero(comp == c)
            verts = plain_dofs[pos] // d
            groups.setdefault(verts.tobytes(), (verts, []))[1].append(pos)
        self.groups = []
        for verts, poss in groups.values():
            A = Ls[verts][:, verts]
            sol = _AmgPcg(A, PCG_ITERS) if len(verts) >= PCG_MIN else _Direct(A)
            self.groups.append((sol, np.stack(poss, axis=1)))
        self.nnz = sum(g.nnz for g, _ in self.groups)
        self.bytes = sum(g.bytes for g, _ in self.groups)
        self.untracked_bytes = sum(g.untracked_bytes for g, _ in self.groups)
        self.kind = "+".join(sorted({type(g).__name__.strip("_") for g, _ in self.groups}))
        # one group over all components in component-major order: no gather/scatter
        self.whole = None
        if len(self.groups) == 1:
            pos = self.groups[0][1]
            if pos.size == len(plain_dofs) and np.array_equal(
                    pos, np.arange(pos.size).reshape(pos.shape[1], -1).T):
                self.whole = pos.shape

    def solve(self, rhs, q0=None, tol_mm=0.0):
        if self.whole is not None:
            nv, nc = self.whole
            g = self.groups[0][0]
            B = rhs.reshape(nc, nv).T
            X = g.solve(B) if q0 is None else g.step(B, q0.reshape(nc, nv).T, tol_mm)
            return np.ascontiguousarray(X.T).reshape(-1)
        out = np.empty_like(rhs)
        for g, pos in self.groups:
            out[pos] = g.solve(rhs[pos]) if q0 is None else g.step(rhs[pos], q0[pos], tol_mm)
        return out

    def step(self, rhs, q0, tol_mm):
        """The ADMM x-step: exact (SuperLU) or warm-started from q0 to vertex updates below
        tol_mm (mm) (CG)."""
        return self.solve(rhs, q0, tol_mm)

    @property
    def inexactness(self):
        """Error proxy (mm) of the last x-step: the largest vertex update of the last CG
        iteration (0 for SuperLU)."""
        return max((getattr(g, "last_update", 0.0) for g, _ in self.groups), default=0.0)


class _CoupledSolver(_Direct):
    """SuperLU of the coupled reduced x-step matrix (oblique sliding)."""

    kind = "Direct"

    def solve(self, rhs, q0=None):
        return self.lu.solve(rhs)

    inexactness = 0.0

    def step(self, rhs, q0, tol_mm):
        return self.lu.solve(rhs)


def _vertex_rank(mesh):
    """Rank of every vertex in a reverse Cuthill-McKee ordering of the mesh graph (cached)."""
    rank = getattr(mesh, "_admm_rcm_rank", None)
    if rank is None or len(rank) != mesh.n_vertices:
        from scipy.sparse.csgraph import reverse_cuthill_mckee
        c = mesh.cells
        k = c.shape[1]
        A = sp.csr_matrix((np.ones(c.size * k, np.int8), (np.repeat(c, k, axis=1).ravel(),
                                                          np.tile(c, (1, k)).ravel())),
                          shape=(mesh.n_vertices, mesh.n_vertices))
        perm = reverse_cuthill_mckee(A, symmetric_mode=True)
        rank = np.empty(mesh.n_vertices, np.int64)
        rank[perm] = np.arange(mesh.n_vertices)
        try:
            object.__setattr__(mesh, "_admm_rcm_rank", rank)
        except (AttributeError, TypeError):
            pass
    return rank


def _reduction(case) -> _Reduction:
    n, d = case.mesh.n_vertices, case.mesh.gdim
    N = n * d
    c = case.constraints
    up = np.zeros(N)
    up[c.dofs] = c.values
    fixed = np.zeros(N, bool)
    fixed[c.dofs] = True
    rows_of: dict[int, list] = {}
    for verts, nrm, g in c.sliding:
        for v in np.asarray(verts).tolist():
            rows_of.setdefault(v, []).append((np.asarray(nrm, float), float(g)))
    # plain free dofs of vertices without oblique sliding
    slide_v = np.array(sorted(rows_of), dtype=np.int64)
    plain = ~fixed
    if len(slide_v):
        plain[(slide_v[:, None] * d + np.arange(d)).ravel()] = False
    plain_dofs = np.flatnonzero(plain)
    # component-major (all x dofs, then y, ...): the x-step's multi-column right-hand side
    # is then a view of the reduced vector; vertices in reverse Cuthill-McKee order (locality)
    plain_dofs = plain_dofs[np.lexsort((_vertex_rank(case.mesh)[plain_dofs // d], plain_dofs % d))]
    zr, zc, zv = [plain_dofs], [np.arange(len(plain_dofs))], [np.ones(len(plain_dofs))]
    col = len(plain_dofs)
    for v in slide_v.tolist():
        R, g = [], []
        for k in range(d):
            if fixed[d * v + k]:
                e = np.zeros(d)
                e[k] = 1.0
                R.append(e)
                g.append(up[d * v + k])
        for nrm, val in rows_of[v]:
            R.append(nrm)
            g.append(val)
        R, g = np.array(R), np.array(g)
        _, s, Vt = np.linalg.svd(R)
        rank = int(np.sum(s > 1e-10 * s[0]))
        upv = np.linalg.lstsq(R, g, rcond=None)[0]
        if np.linalg.norm(R @ upv - g) > 1e-8 * max(1.0, np.abs(g).max()):
            raise CaseError(f"vertex {v}: sliding and prescribed conditions conflict "
                            f"(no displacement satisfies them, residual "
                            f"{np.linalg.norm(R @ upv - g):.3g} mm)")
        up[d * v:d * v + d] = upv
        for b in Vt[rank:]:
            zr.append(d * v + np.arange(d))
            zc.append(np.full(d, col))
            zv.append(b)
            col += 1
    Z = sp.csr_matrix((np.concatenate(zv), (np.concatenate(zr), np.concatenate(zc))), shape=(N, col))
    return _Reduction(Z, up, separable=not len(slide_v), plain_dofs=plain_dofs,
                      ZT=Z.T.tocsr())


# =========================================================================== operators
@dataclass(frozen=True)
class ImplicitEuler:
    """Implicit-Euler dynamics (seed eq. 5): ``steps`` steps of ``dt`` (s), lumped mass
    density * V / (d+1) (kg), initial velocity ``velocity`` (mm/s, (n, gdim)) or zero.
    Boundary values are applied at full load from the first step."""

    dt: float
    steps: int = 1
    velocity: object = None

    def __post_init__(self):
        if not (np.isfinite(self.dt) and self.dt > 0):
            raise CaseError(f"ImplicitEuler dt must be > 0 s, got {self.dt!r}")
        if int(self.steps) < 1:
            raise CaseError(f"ImplicitEuler steps must be >= 1, got {self.steps!r}")


class AdmmOperators:
    """Everything precomputed once per Case structure (mesh, material, constrained dof set,
    rho, dt): D, the x-step matrix factorization, the reduction u = up + Z q."""

    def __init__(self, case, *, rho: float | None = None, dt: float | None = None):
        t0 = time.perf_counter()
        self.mesh = case.mesh
        kin, law = _case_parts(case)
        self.kin, self.law = kin, law
        n, d = case.mesh.n_vertices, kin.d
        self.n, self.d, self.N, self.m = n, d, n * d, len(kin.V)
        mat = case.material
        if rho is None:
            rho = mat.kappa + 4.0 * mat.mu / 3.0  # = lambda + 2 mu, the P-wave modulus
        if not (np.isfinite(rho) and rho > 0):
            raise CaseError(f"ADMM rho must be > 0 kPa, got {rho!r}")
        self.rho = float(rho)
        self.red = _reduction(case)
        Z = self.red.Z
        m = self.m
        # the ADMM loop's element order: by the reverse Cuthill-McKee rank of their first
        # vertex (memory locality of the products with D on large meshes); internal element k
        # is mesh element elem_order[k]
        self.elem_order = eo = np.argsort(_vertex_rank(case.mesh)[case.mesh.cells].min(axis=1),
                                          kind="stable")
        self.h = kin.V[eo] ** (1.0 / d)
        # D: (m*d*d, N) with H_flat = D u, rows in structure-of-arrays order (i, J, k): H_iJ of
        # (internal) element k at (d i + J) m + k
        rows = (np.arange(m)[:, None, None, None] + np.arange(d)[None, None, :, None] * d * m
                + np.arange(d)[None, None, None, :] * m)  # (m, a, i, J)
        rows = np.broadcast_to(rows, (m, d + 1, d, d))
        cols = np.broadcast_to(kin.dofs[eo].reshape(m, d + 1, d)[:, :, :, None],
                               (m, d + 1, d, d))
        vals = np.broadcast_to(kin.G[eo][:, :, None, :], (m, d + 1, d, d))
        D = sp.csr_matrix((vals.ravel(), (rows.ravel(), cols.ravel())), shape=(m * d * d, self.N))
        self.D = D
        w2 = self.rho * np.tile(kin.V[eo], d * d)
        self.w2 = w2
        self.DZ = (D @ Z).tocsr()
        self.eye_soa = np.repeat(np.eye(d).ravel(), m)  # I of every element, (d, d, m) flat
        self.DZtW = (self.DZ.T.multiply(w2[None, :])).tocsr()
        self.DZtW_I = self.DZtW @ self.eye_soa  # the identity's share of the x-step data
        L = (D.T.multiply(w2[None, :]) @ D).tocsr()
        self.L = L
        self.dt = dt
        self.mass = None
        Mx = L
        if dt is not None:
            mv = np.zeros(n)
            np.add.at(mv, case.mesh.cells.ravel(), np.repeat(mat.density * kin.V / (d + 1), d + 1))
            self.mass = np.repeat(mv, d)
            Mx = L + sp.diags(self.mass / dt ** 2)
        self.Mx = Mx.tocsr()
        if self.red.separable:
            # no oblique sliding: the x-step matrix is (rho scalar P1 Laplacian [+ M/dt^2]) x I_d;
            # factorize the scalar matrix once per distinct set of free vertices
            Ls = _scalar_laplacian(kin, self.rho, n)
            if dt is not None:
                Ls = Ls + sp.diags(mv / dt ** 2)
            self.lu = _ComponentSolver(Ls.tocsr(), self.red.plain_dofs, d)
        else:
            self.lu = _CoupledSolver(self.red.ZT @ self.Mx @ Z)
        self.nq = Z.shape[1]
        self._kpat = None  # reduced tangent's CSR pattern (built on first use)
        self._Dm = None  # gradient operator in mesh element order (built on first use)
        self.factor_cache = {}  # kept by ``factorize`` (e.g. a symbolic analysis)
        self.setup_s = time.perf_counter() - t0

    def reduced_tangent(self, u, diag=None):
        """(Z^T (K(u) + diag(diag)) Z as CSC, element matrices Ke): the tangent of the P1 energy
        on the reduced unknowns. Without oblique sliding it is assembled straight into a CSR
        pattern computed once (the matrix is symmetric, so its CSR arrays are its CSC)."""
        Ke = _element_K(self.kin, self.law.tangent(self.grad(u)))
        Z = self.red.Z
        if not self.red.separable:
            K = _assemble(self.kin, Ke, self.N)
            if diag is not None:
                K = K + sp.diags(diag)
            return (self.red.ZT @ K @ Z).tocsc(), Ke
        if self._kpat is None:
            nq = self.nq
            ridx = np.full(self.N, -1, np.int64)
            ridx[self.red.plain_dofs] = np.arange(nq)
            R = ridx[self.kin.dofs]
            nd = R.shape[1]
            rows = np.repeat(R, nd, axis=1).ravel()
            cols = np.tile(R, (1, nd)).ravel()
            valid = (rows >= 0) & (cols >= 0)
            ukey, pos = np.unique(rows[valid] * nq + cols[valid], return_inverse=True)
            indptr = np.concatenate([[0], np.cumsum(np.bincount(ukey // nq, minlength=nq))])
            dpos = np.searchsorted(ukey, np.arange(nq) * (nq + 1))
            self._kpat = (pos.astype(np.int32 if len(ukey) < 2 ** 31 else np.int64), valid,
                          indptr, (ukey % nq).astype(np.int32), len(ukey), dpos)
        pos, valid, indptr, indices, nnz, dpos = self._kpat
        data = np.bincount(pos, weights=Ke.reshape(-1)[valid], minlength=nnz)
        if diag is not None:
            data[dpos] += diag[self.red.plain_dofs]
        return sp.csc_matrix((data, indices, indptr), shape=(self.nq, self.nq)), Ke

    def _mesh_gradient(self):
        """(D_m, D_m^T): the gradient operator in mesh element order with rows (k, i, J) (H of
        element k at k d^2 + d i + J), CSR; built on first use."""
        if self._Dm is None:
            kin, m, d = self.kin, self.m, self.d
            rows = np.broadcast_to((np.arange(m)[:, None, None, None] * d * d
                                    + np.arange(d)[None, None, :, None] * d
                                    + np.arange(d)[None, None, None, :]), (m, d + 1, d, d))
            cols = np.broadcast_to(kin.dofs.reshape(m, d + 1, d)[:, :, :, None], (m, d + 1, d, d))
            vals = np.broadcast_to(kin.G[:, :, None, :], (m, d + 1, d, d))
            Dm = sp.csr_matrix((vals.ravel(), (rows.ravel(), cols.ravel())),
                               shape=(m * d * d, self.N))
            self._Dm = (Dm, Dm.T.tocsr())
        return self._Dm

    def grad(self, u):
        """H_e = grad u (m, d, d), mesh element order (as ``_grad``, one sparse product)."""
        return (self._mesh_gradient()[0] @ u.reshape(-1)).reshape(self.m, self.d, self.d)

    def scatter(self, Pv):
        """Nodal forces sum_e Pv_e : grad N_a (node-major, (N,)) of Pv (m, d, d) (as
        ``_scatter``, one sparse product)."""
        return self._mesh_gradient()[1] @ Pv.reshape(-1)

    def apply_elements(self, Ke, v):
        """K v (full dofs, mN) from element matrices Ke, without assembling K."""
        fe = np.einsum("mab,mb->ma", Ke, v[self.kin.dofs])
        return np.bincount(self.kin.dofs.ravel(), weights=fe.ravel(), minlength=self.N)

    def step_norm(self, dq):
        """Largest vertex displacement (mm) of the reduced increment dq."""
        whole = getattr(self.lu, "whole", None)
        if whole is not None:  # component-major plain dofs, every component on the same vertices
            dq = dq.reshape(whole[1], whole[0])
            return float(np.sqrt(np.einsum("ij,ij->j", dq, dq).max(initial=0.0)))
        return _vertex_norm_max(self.red.Z @ dq, self.d)


PCG_MIN = 4000  # free vertices from which the x-step is solved by AMG-preconditioned CG
PCG_ITERS = 1  # least warm-started PCG iterations per ADMM x-step
PCG_RTOL = 0.3  # PCG x-step: ... or below PCG_RTOL times its first update
XSTEP_TOL = 0.1  # PCG x-step: largest vertex update (mm) below XSTEP_TOL * tol_mm
ROUNDS = 4
CHUNK = 8192  # elements per cache block of the numpy ADMM loop
USE_CKERNEL = True  # compiled element loop when a C compiler is usable (see use_kernel)

_CACHE: OrderedDict[tuple, AdmmOperators] = OrderedDict()


def _structure_key(case, rho, dt):
    c = case.constraints
    sl = tuple((np.asarray(v).tobytes(), tuple(np.asarray(nr, float).round(14))) for v, nr, _ in
               c.sliding)
    return (id(case.mesh), c.dofs.tobytes(), sl, case.material, rho, dt)


def prepare(case, *, rho: float | None = None, dt: float | None = None) -> AdmmOperators:
    """The per-Case operators (x-step factorization included), cached for the last 4 Case
    structures: a Case differing only in prescribed values (e.g. other pushes) reuses them."""
    case.require_no_contact("the ADMM solver")
    key = _structure_key(case, rho, dt)
    ops = _CACHE.get(key)
    if ops is not None and ops.mesh is case.mesh:
        _CACHE.move_to_end(key)
        return ops
    ops = AdmmOperators(case, rho=rho, dt=dt)
    _CACHE[key] = ops
    while len(_CACHE) > 4:
        _CACHE.popitem(last=False)
    return ops


def _particular(case, ops: AdmmOperators) -> np.ndarray:
    """Prescribed part u_p (mm) of the displacement for this Case's boundary values."""
    c = case.constraints
    if c.sliding:
        return _reduction(case).up
    up = np.zeros(ops.N)
    up[c.dofs] = c.values
    return up


# =========================================================================== z-step
class _ZStep:
    """Per-element proximal step F = argmin psi(F) + rho/2 |F - Fhat|^2 (F = I + z) for all
    elements at once, on structure-of-arrays blocks (d, d, m): entry (i, J) of every element is
    one contiguous row. The ADMM loop keeps F = I + z in "extended" buffers E (5, 5, m) in 3D,
    F = E[:3, :3], whose last two rows/columns repeat the first two, so that every cofactor is a
    product of two shifted views (cof_ij = F[i+1, j+1] F[i+2, j+2] - F[i+1, j+2] F[i+2, j+1]).

    Neo-Hookean: one Newton-type step from the previous F (warm start) with the model Hessian
    M = (rho + mu J^(-2/3)) I + max(kappa (2 - 1/J), 0) cof (x) cof (the rho part and the
    volumetric part of the exact Hessian, which dominate it for rho of the order of the P-wave
    modulus), applied in closed form (Sherman-Morrison): no per-element matrices are formed,
    stored or inverted. Steps |D| <= s = ``small_step`` from states with
    J > s I1/sqrt(3) + s^2 sqrt(I1) + s^3 keep J > 0 (det(F + D) >= J - |cof||D| - |F||D|^2 -
    |D|^3, |cof| <= I1/sqrt(3)) and are taken as they are; the others get an Armijo backtracking
    on the local objective and further steps (up to ``rounds``). At a fixed point the local
    gradient vanishes, so the fixed point is exact whatever M."""

    small_step = 1e-2  # |dF| below which a step from a safe state is taken unchecked

    def __init__(self, ops: AdmmOperators, rho, rounds=None):
        rounds = ROUNDS if rounds is None else rounds
        self.law = ops.law
        self.d = ops.d
        self.rounds = rounds
        self._buf = {}
        self.set_rho(rho)

    def set_rho(self, rho):
        mat, d = self.law, self.d
        self.rho = rho
        if mat.model == "linear-elastic":
            self.f_dev = rho / (rho + 2 * mat.mu)
            self.f_vol = rho / (rho + 2 * mat.mu + d * mat.lmbda)

    def new_state(self, k):
        """An extended buffer for F (see the class docstring) and its F view."""
        d = self.d
        E = np.empty((5, 5, k)) if d == 3 else np.empty((d, d, k))
        return E, E[:d, :d]

    def _scratch(self, k):
        b = self._buf.get(k)
        if b is None:
            d = self.d
            b = (np.empty((d, d, k)), np.empty((d, d, k)), None)
            if len(self._buf) > 2:
                self._buf.clear()
            self._buf[k] = b  # the chunk sizes of the ADMM loop
        return b

    def _parts(self, E, cof, t):
        """cof (into ``cof``), J, I1 (plane strain: + 1) of F = E[:d, :d]."""
        d = self.d
        F = E[:d, :d]
        if d == 3:
            E[3:, :3] = E[:2, :3]
            E[:, 3:] = E[:, :2]
            np.multiply(E[1:4, 1:4], E[2:5, 2:5], out=cof)
            np.multiply(E[1:4, 2:5], E[2:5, 1:4], out=t)
            cof -= t
            J = np.einsum("jk,jk->k", F[0], cof[0])
            I1 = np.einsum("ijk,ijk->k", F, F)
        else:
            cof[0, 0], cof[1, 1] = F[1, 1], F[0, 0]
            np.negative(F[1, 0], out=cof[0, 1])
            np.negative(F[0, 1], out=cof[1, 0])
            J = F[0, 0] * F[1, 1] - F[0, 1] * F[1, 0]
            I1 = np.einsum("ijk,ijk->k", F, F)
            I1 += 1.0
        return J, I1

    def _phi(self, F, Fhat):
        """Local objective psi(F) + rho/2 |F - Fhat|^2 (inf where J <= 0) and J; F (d, d, k)."""
        mu, kappa, d = self.law.mu, self.law.kappa, self.d
        E, _ = self.new_state(F.shape[2])
        E[:d, :d] = F
        J, I1 = self._parts(E, np.empty_like(F), np.empty_like(F))
        with np.errstate(invalid="ignore", divide="ignore"):
            psi = 0.5 * mu * (np.abs(J) ** (-2.0 / 3.0) * I1 - 3.0) + 0.5 * kappa * (J - 1.0) ** 2
        psi[~(J > 0)] = np.inf
        r = F - Fhat
        return psi + 0.5 * self.rho * np.einsum("ijk,ijk->k", r, r), J

    def __call__(self, Fhat, E, Enew):
        """Writes the new F into Enew[:d, :d] (F = E[:d, :d] is the previous one) and returns
        |F_new - F|^2 per element; Fhat (d, d, m) contiguous."""
        d = self.d
        F, Fn = E[:d, :d], Enew[:d, :d]
        if self.law.model == "linear-elastic":
            # closed form on H = F - I: skew + f_dev dev(sym H) + f_vol tr(H)/d I
            np.add(Fhat, Fhat.transpose(1, 0, 2), out=Fn)
            Fn *= 0.5  # sym F
            skew = Fhat - Fn
            t = np.einsum("iik->k", Fn) / d - 1.0  # tr(sym H) / d
            Fn *= self.f_dev
            Fn += skew
            for i in range(d):
                Fn[i, i] += (self.f_vol - self.f_dev) * t + (1.0 - self.f_dev)
            dz = Fn - F
            return np.einsum("ijk,ijk->k", dz, dz)
        dsq, check, redo = self._step(Fhat, E, Fn, self._scratch(Fhat.shape[2]))
        for _ in range(self.rounds - 1):
            if not len(redo):
                break
            Es, _ = self.new_state(len(redo))
            Es[:d, :d] = Fn[:, :, redo]
            out = np.empty((d, d, len(redo)))
            _, _, r2 = self._step(Fhat[:, :, redo], Es, out,
                                  tuple(np.empty_like(out) for _ in range(3)))
            Fn[:, :, redo] = out
            redo = redo[r2]
        if len(check):
            dz = Fn[:, :, check] - F[:, :, check]
            dsq[check] = np.einsum("ijk,ijk->k", dz, dz)
        return dsq

    def _step(self, Fhat, E, Fn, scratch):
        """One safeguarded model-Newton step from F = E[:d, :d] into Fn; returns (|dF|^2 of the
        full model step, indices (into this block) of the elements checked by the line search,
        of those that backtracked and may step again).

        With P = a F + b cof (a = mu J^(-2/3), b = kappa (J - 1) - a I1 / (3 J)), the local
        gradient over rho is g = (1 + a/rho) F - Fhat + (b/rho) cof, and the model step
        F - M^-1 g / ... simplifies (the F terms cancel) to
        F_new = (Fhat + (s - b/rho) cof) / (1 + a/rho), s = beta (cof:g) / (alpha + beta |cof|^2),
        cof:g = alpha d J - cof:Fhat + (b/rho) |cof|^2 (cof:F = d J)."""
        mu, kappa, rho, d = self.law.mu / self.rho, self.law.kappa / self.rho, self.rho, self.d
        cof, t, _ = scratch
        F = E[:d, :d]
        J, I1 = self._parts(E, cof, t)
        iJ = 1.0 / J
        ar = np.cbrt(iJ)
        ar *= ar
        ar *= mu  # a / rho
        b = I1 * ar
        b *= iJ
        b *= -1.0 / 3.0
        b += kappa * J
        b -= kappa  # b / rho
        al = ar + 1.0  # alpha, the model's diagonal (over rho)
        beta = 2.0 - iJ
        beta *= kappa
        np.maximum(beta, 0.0, out=beta)  # the model's volumetric stiffness (over rho)
        cc = np.einsum("ijk,ijk->k", cof, cof)
        cg = al * J
        cg *= d
        cg -= np.einsum("ijk,ijk->k", cof, Fhat)
        cg += b * cc  # cof:g
        cg *= beta
        den = beta * cc
        den += al
        cg /= den
        cg -= b  # s - b / rho
        np.multiply(cof, cg, out=t)
        t += Fhat
        np.divide(t, al, out=Fn)
        np.subtract(Fn, F, out=t)  # the model step dF
        dz2 = np.einsum("ijk,ijk->k", t, t)
        # small steps from states with J > s I1/sqrt(3) + s^2 sqrt(I1) + s^3 keep J > 0: taken
        # as they are; the others are checked
        ds = self.small_step
        lim = np.sqrt(I1)
        lim *= ds * ds
        lim += (ds / np.sqrt(3.0)) * I1
        lim += ds ** 3
        bad = J <= lim
        bad |= dz2 > ds * ds
        check = np.flatnonzero(bad) if bad.any() else np.empty(0, np.int64)
        redo = check
        if len(check):
            dz = t[:, :, check]
            # g = -M dF, so g:dF = -(alpha |dF|^2 + beta (cof:dF)^2) (times rho: unscaled)
            cd = np.einsum("ijk,ijk->k", cof[:, :, check], dz)
            gd = -rho * (al[check] * dz2[check] + beta[check] * cd * cd)
            Fc = F[:, :, check]
            Fh = Fhat[:, :, check]
            phi0, _ = self._phi(Fc, Fh)
            tolr = 1e-13 * np.abs(phi0)
            idx = np.arange(len(check))
            alpha_ls = 1.0
            partial = np.zeros(len(check), bool)
            for _ in range(40):
                Ft = Fc[:, :, idx] + alpha_ls * dz[:, :, idx]
                ph, Jt = self._phi(Ft, Fh[:, :, idx])
                ok = (Jt > 0) & (ph <= phi0[idx] + 1e-4 * alpha_ls * gd[idx] + tolr[idx])
                Fn[:, :, check[idx[ok]]] = Ft[:, :, ok]
                if alpha_ls < 1.0:
                    partial[idx[ok]] = True
                idx = idx[~ok]
                if not len(idx):
                    break
                alpha_ls *= 0.5
            if len(idx):  # no decrease found: keep the old F of these elements
                Fn[:, :, check[idx]] = Fc[:, :, idx]
                partial[idx] = True
            redo = check[partial]
        return dz2, check, redo


# =========================================================================== helpers
def _diverged(msg, it, elem):
    return SolverDivergedError(f"ADMM diverged at iteration {it}: {msg} (element {elem})")


def _check_J(ops, H, it, what):
    if ops.law.model == "linear-elastic":
        if not np.all(np.isfinite(H)):
            e = int(np.flatnonzero(~np.isfinite(H.reshape(len(H), -1)).all(axis=1))[0])
            raise _diverged(f"non-finite displacement gradient in {what}", it, e)
        return
    J, _ = _det_cof(H + np.eye(ops.d))
    bad = ~(J > 0)
    if bad.any():
        e = int(np.argmin(np.where(np.isfinite(J), J, -np.inf)))
        raise _diverged(f"{int(bad.sum())} inverted element(s) in {what}, J = {J[e]:.3g} "
                        f"<= 0", it, e)


def _vertex_norm_max(du, d):
    du = du.reshape(-1, d)
    return float(np.sqrt(np.einsum("ij,ij->i", du, du).max(initial=0.0)))


def _aos(z):
    """(d, d, m) structure-of-arrays block -> (m, d, d) view."""
    return z.transpose(2, 0, 1)


def _soa(H):
    """(m, d, d) -> contiguous (d, d, m)."""
    return np.ascontiguousarray(H.transpose(1, 2, 0))


# =========================================================================== compiled element loop
def use_kernel() -> bool:
    """Whether the ADMM loop runs its element-local work (z-step, dual update, residuals) in the
    compiled kernel (``admm_kernel.c``, built on first use; see ``solvers._ckernel``). False
    (the numpy loop, same arithmetic) when no C compiler is usable, when USE_CKERNEL is False
    or with the environment variable TISSUE_NO_CKERNEL=1."""
    return USE_CKERNEL and _ckernel.load() is not None


class _NumpyElements:
    """The element work of one ADMM iteration (gather D u, z-step, dual update, residuals and the
    x-step data D^T W (z - lam)) in numpy, on (d, d, m) blocks in chunks of CHUNK elements.
    ``F``, ``lam``: the start state (F = I + z, scaled dual), (d, d, m)."""

    def __init__(self, ops, zstep, up, F, lam):
        d, m = ops.d, ops.m
        self.ops, self.zstep, self.d, self.m = ops, zstep, d, m
        self.DupI = ops.D @ up + ops.eye_soa  # D u_p + I
        self.E, self.F = zstep.new_state(m)
        self.Enew, self.Fnew = zstep.new_state(m)
        self.F[...] = F
        self.lam, self.lam_new = lam, np.empty_like(lam)
        self.w = F - lam  # x-step data z - lam (+ I)
        self.r, self.dsq = np.empty(m), np.empty(m)
        self.h2 = ops.h ** 2
        self.chunks = [(c, min(c + CHUNK, m)) for c in range(0, m, CHUNK)]
        self.scratch = {}

    def xdata(self):
        """Z^T D^T W (z - lam + I) (mN), the x-step's data term."""
        return self.ops.DZtW @ self.w.reshape(-1)

    def halve_dual(self):
        """lam *= 1/2 (rho doubled: lam = P / rho)."""
        self.lam *= 0.5
        np.subtract(self.F, self.lam, out=self.w)

    def update(self, q):
        """Element work after the x-step q (at the z-step's current rho); returns (r, dsq):
        h^2 |D u - z'|^2 and h^2 |z' - z|^2 per element (mm^2)."""
        d, m, zstep = self.d, self.m, self.zstep
        Hx = self.ops.DZ @ q
        Hx += self.DupI
        Hx = Hx.reshape(d, d, m)
        lam, lam_new, w, r, dsq = self.lam, self.lam_new, self.w, self.r, self.dsq
        for c0, c1 in self.chunks:
            sl = slice(c0, c1)
            Fhat, t = self.scratch.get(c1 - c0) or self.scratch.setdefault(
                c1 - c0, (np.empty((d, d, c1 - c0)), np.empty((d, d, c1 - c0))))
            np.add(Hx[:, :, sl], lam[:, :, sl], out=Fhat)
            dsq[sl] = zstep(Fhat, self.E[:, :, sl], self.Enew[:, :, sl])
            # dual update lam' = Fhat - F'; primal residual D u - z' = lam' - lam
            ln = lam_new[:, :, sl]
            np.subtract(Fhat, self.Fnew[:, :, sl], out=ln)
            np.subtract(ln, lam[:, :, sl], out=t)
            np.einsum("ijk,ijk->k", t, t, out=r[sl])
            np.subtract(self.Fnew[:, :, sl], ln, out=w[:, :, sl])  # next x-step's data
        r *= self.h2
        dsq *= self.h2
        self.lam, self.lam_new = lam_new, lam
        self.E, self.Enew, self.F, self.Fnew = self.Enew, self.E, self.Fnew, self.F
        return r, dsq


class _KernelElements:
    """The same element work in one call of the compiled ``admm_iteration`` (admm_kernel.c):
    gather of D u from the full displacement, z-step, dual update, residuals and the scatter of
    D^T W (z - lam + I) into a node vector, in one pass over the element arrays. F and lam live
    in the kernel's blocked layout (``_to_blocks``) and are updated in place; the ``F`` and
    ``lam`` properties give them back as (d, d, m)."""

    def __init__(self, ops, zstep, up, F, lam):
        self.ffi, self.lib = _ckernel.load()
        d, m = ops.d, ops.m
        self.ops, self.zstep, self.d, self.m, self.up = ops, zstep, d, m, up
        self.blk = int(self.lib.admm_block_size())
        kd = getattr(ops, "_kernel_data", None)
        if kd is None:
            # vertices renumbered by their reverse Cuthill-McKee rank (the elements are sorted by
            # it too), so that the gather of u and the scatter of f stay local in memory
            eo, rank = ops.elem_order, _vertex_rank(ops.mesh)
            plain = ops.red.plain_dofs
            kd = ops._kernel_data = (
                np.ascontiguousarray(rank[ops.mesh.cells[eo]], dtype=np.int32),
                np.ascontiguousarray(ops.kin.G[eo]), np.ascontiguousarray(ops.rho * ops.kin.V[eo]),
                np.ascontiguousarray(ops.h ** 2), rank, np.argsort(rank),
                d * rank[plain // d] + plain % d if ops.red.separable else None)
        self.cells, self.G, self.wv, self.h2, self.rank, self.order, self.idx = kd
        self.Fb, self.lamb = self._to_blocks(F), self._to_blocks(lam)
        self.r, self.dsq = np.empty(m), np.empty(m)
        self.u = np.ascontiguousarray(up.reshape(-1, d)[self.order]).reshape(-1)  # internal order
        self.f = np.zeros(ops.N)
        self.model = 0 if ops.law.model == "linear-elastic" else 1
        self._data = None
        p = self._ptr
        self._args = (p(self.cells, "int *"), p(self.G), p(self.wv), p(self.h2), p(self.u),
                      p(self.Fb), p(self.lamb), p(self.r), p(self.dsq), p(self.f))

    def _to_blocks(self, A):
        """(d, d, m) -> the kernel's (ceil(m / blk), d*d, blk) layout (padding never read)."""
        dd, m, blk = self.d * self.d, self.m, self.blk
        nb = -(-m // blk)
        out = np.zeros((dd, nb * blk))
        out[:, :m] = A.reshape(dd, m)
        return np.ascontiguousarray(out.reshape(dd, nb, blk).transpose(1, 0, 2))

    def _from_blocks(self, B):
        d, m = self.d, self.m
        return np.ascontiguousarray(B.transpose(1, 0, 2).reshape(d * d, -1)[:, :m]).reshape(d, d, m)

    @property
    def F(self):
        return self._from_blocks(self.Fb)

    @property
    def lam(self):
        return self._from_blocks(self.lamb)

    def _ptr(self, a, kind="double *"):
        if not a.flags.c_contiguous:
            raise TypeError("ADMM kernel: arrays must be C-contiguous")
        return self.ffi.cast(kind, a.ctypes.data)

    def xdata(self):
        if self._data is None:  # first iteration, or after a rho change
            self._data = self.ops.DZtW @ (self.F - self.lam).reshape(-1)
        return self._data

    def halve_dual(self):
        self.lamb *= 0.5
        self._data = None

    def update(self, q):
        ops, zs = self.ops, self.zstep
        d = self.d
        if self.idx is not None:  # u = up + Z q, Z a selection of plain dofs
            self.u[self.idx] = q
        else:
            self.u.reshape(-1, d)[...] = (self.up + ops.red.Z @ q).reshape(-1, d)[self.order]
        self.f[...] = 0.0
        self.lib.admm_iteration(
            self.model, self.d, self.m, ops.law.mu, ops.law.kappa, zs.rho,
            getattr(zs, "f_dev", 0.0), getattr(zs, "f_vol", 0.0), zs.rounds, zs.small_step,
            *self._args)
        if self.idx is not None:
            self._data = self.f[self.idx]
        else:
            self._data = ops.red.ZT @ self.f.reshape(-1, d)[self.rank].reshape(-1)
        return self.r, self.dsq


# =========================================================================== one static/step solve
def _admm(ops, up, rhs_extra, u0, *, tol_mm, max_iter, callback, it0, progress, hist):
    """ADMM iterations from u0. rhs_extra: f_ext (+ M u_tilde / dt^2), mN. Returns (u, iters,
    converged). The loop works with F = I + z and Fhat = I + D u + lam, (d, d, m) blocks."""
    Z, m, d = ops.red.Z, ops.m, ops.d
    # move the boundary from u0's values to up's and carry the interior along with the
    # harmonic (x-step matrix) extension of that change
    zu0 = ops.red.ZT @ u0
    delta = up - (u0 - Z @ zu0)
    q = zu0 - ops.lu.solve(ops.red.ZT @ (ops.Mx @ delta)) if np.any(delta) else zu0
    zstep = _ZStep(ops, ops.rho)
    F = (ops.DZ @ q + ops.D @ up + ops.eye_soa).reshape(d, d, m)  # I + D u
    if ops.law.model != "linear-elastic":
        # elements the prescribed values invert in the start state start from F = I
        J, _ = _det_cof(_aos(F))
        F[:, :, ~(J > 0.05)] = np.eye(d)[:, :, None]
    P, _ = ops.law.stress(_aos(F) - np.eye(d))
    lam = _soa(P) / ops.rho
    rhs_f = ops.red.ZT @ rhs_extra
    # x-step right-hand side constant: boundary values, and D^T W I (F = I + z)
    rhs_up = -(ops.red.ZT @ (ops.Mx @ up)) - ops.DZtW_I
    rho0 = rho = ops.rho
    adapt = ops.dt is None  # without a mass term the x-step matrix is rho * (fixed matrix)
    window_primal = np.inf
    big = 1e3 * float(np.ptp(ops.mesh.points, axis=0).max())
    rhs_c = rhs_f + rhs_up
    elements = (_KernelElements if use_kernel() else _NumpyElements)(ops, zstep, up, F, lam)
    converged = False
    k = 0
    for k in range(1, max_iter + 1):
        q_old = q
        # x-step for the current rho: (rho/rho0) Mx0 u = rho D^T V (z - lam) + f, scaled
        rhs = elements.xdata() + rhs_c
        q = ops.lu.step(rhs, q, XSTEP_TOL * tol_mm)
        r, dsq = elements.update(q)
        primal = float(np.sqrt(r.max()))
        # dual residual rho D^T (z^k - z^(k-1)) (Boyd et al. 2011, 3.3), in mm at rho0
        dual = (rho / rho0) * float(np.sqrt(dsq.max()))
        step = ops.step_norm(q - q_old)
        hist["primal"].append(primal)
        hist["dual"].append(dual)
        hist["max_step_mm"].append(step)
        hist["admm_clock_s"].append(time.perf_counter())
        if not (math.isfinite(primal) and math.isfinite(dual) and math.isfinite(step)):
            bad = ~(np.isfinite(r) & np.isfinite(dsq))
            raise _diverged("non-finite residual", it0 + k,
                            int(ops.elem_order[np.flatnonzero(bad)[0]]) if bad.any() else -1)
        if primal > big or step > big:
            raise _diverged(f"residual growth, primal {primal:.3g} mm", it0 + k,
                            int(ops.elem_order[np.argmax(r)]))
        if callback is not None:
            callback(it0 + k, (up + Z @ q).reshape(-1, d))
        if progress and k % 100 == 0:
            print(f"admm {it0 + k}: primal {primal:.3e} mm, dual {dual:.3e} mm, "
                  f"step {step:.3e} mm", flush=True)
        if primal < tol_mm and dual < tol_mm and ops.lu.inexactness < tol_mm:
            converged = True
            break
        if adapt and k % 25 == 0:
            # stagnation (e.g. a nonconvex element cycling between two local z minima): double
            # rho (more consensus, convex local problems); lam = P / rho is rescaled
            if primal > 0.9 * window_primal and rho < 64 * rho0:
                elements.halve_dual()
                rho *= 2.0
                zstep.set_rho(rho)
                rhs_c = (rho0 / rho) * rhs_f + rhs_up
                hist.setdefault("rho_changes", []).append((it0 + k, rho))
            window_primal = primal
    return up + Z @ q, k, converged


def _tangent_lift(ops, u, up, it, factorize=None):
    """u with its prescribed part moved to up's values and the interior moved by the linearized
    (tangent at u) response to that boundary change."""
    Z = ops.red.Z
    zu = ops.red.ZT @ u
    delta = up - (u - Z @ zu)
    if not np.any(delta):
        return u
    Kr, Ke = ops.reduced_tangent(u)
    try:
        rhs = -(ops.red.ZT @ ops.apply_elements(Ke, delta))
        s = _sym_splu(Kr, ops.factor_cache, factorize).solve(rhs)
    except RuntimeError as exc:
        raise _diverged(f"singular tangent in the boundary lift ({exc})", it, -1) from None
    cand = up + Z @ (zu + s)
    # keep elements valid: halve the interior part until no element inverts
    for _ in range(20):
        if ops.law.model == "linear-elastic":
            return cand
        J, _ = _det_cof(ops.grad(cand) + np.eye(ops.d))
        if np.all(J > 0):
            return cand
        s = 0.5 * s
        cand = up + Z @ (zu + s)
    return cand


def _energy(ops, u, fext, inertia):
    psi, J = ops.law.psi_J(ops.grad(u))
    e = float(ops.kin.V @ psi) - float(fext @ u)
    if inertia is not None:
        mdt, ut = inertia
        e += 0.5 * float((u - ut) @ (mdt * (u - ut)))
    return e, J


def _residual(ops, u, fext, inertia):
    P, _ = ops.law.stress(ops.grad(u))
    r = ops.scatter(ops.kin.V[:, None, None] * P) - fext
    if inertia is not None:
        mdt, ut = inertia
        r = r + mdt * (u - ut)
    return r


def _newton(ops, u, fext, inertia, *, tol_mm, max_iter, it0, hist, callback, factorize=None):
    """Newton on the same P1 energy (exact tangent, backtracking on the energy, J > 0)."""
    Z, d = ops.red.Z, ops.d
    k = 0
    for k in range(1, max_iter + 1):
        r = _residual(ops, u, fext, inertia)
        rr = ops.red.ZT @ r
        Kr, _ = ops.reduced_tangent(u, None if inertia is None else inertia[0])
        try:
            dq = -_sym_splu(Kr, ops.factor_cache, factorize).solve(rr)
        except RuntimeError as exc:
            raise _diverged(f"singular tangent in the Newton polish ({exc})", it0 + k, -1) from None
        du = Z @ dq
        e0, _ = _energy(ops, u, fext, inertia)
        r0 = float(np.linalg.norm(rr))
        alpha = 1.0
        for _ in range(40):
            e1, J1 = _energy(ops, u + alpha * du, fext, inertia)
            if J1 is None or np.all(J1 > 0):
                # merit: energy decrease, or (tangent indefinite) free residual decrease
                if e1 <= e0 + 1e-4 * alpha * float(rr @ dq) + 1e-12 * abs(e0):
                    break
                r1 = float(np.linalg.norm(
                    ops.red.ZT @ _residual(ops, u + alpha * du, fext, inertia)))
                if r1 < (1.0 - 1e-4 * alpha) * r0:
                    break
            alpha *= 0.5
        else:
            H = ops.grad(u + du)
            _check_J(ops, H, it0 + k, "the Newton polish")
            raise _diverged("Newton polish line search found no energy decrease", it0 + k,
                            int(np.argmax(np.abs(rr))) // d)
        u = u + alpha * du
        step = _vertex_norm_max(alpha * du, d)
        hist["max_step_mm"].append(step)
        hist["newton_step_mm"].append(step)
        if callback is not None:
            callback(it0 + k, u.reshape(-1, d))
        if step < tol_mm:
            break
    return u, k


# =========================================================================== public solve
def solve(case, *, pushes=None, initial=None, tol_mm: float = 1e-4, max_iter: int | None = None,
          rho: float | None = None, polish: bool = True, polish_tol_mm: float | None = None,
          polish_max_iter: int = 25, dynamics: ImplicitEuler | None = None, callback=None,
          load_steps: int | None = None, step_mm: float = 3.0,
          intermediate_tol_mm: float = 1e-2, lift="auto", handoff_mm: float = 1e-2,
          progress: bool = False, factorize=None) -> SolveResult:
    """ADMM solve of a Case (quasi-static equilibrium, or implicit-Euler dynamics).

    pushes: actuator name -> push (mm), applied with ``case.with_pushes``.
    initial: warm-start displacement (mm, (n_vertices, gdim)); its prescribed part is replaced by
        the Case's boundary values (exact), its stress initializes the ADMM dual.
    tol_mm: stopping tolerance (mm) on the primal and dual residuals (see module docstring).
    rho: ADMM penalty stiffness (kPa), w_e^2 = rho V_e; default see module docstring.
    max_iter: ADMM iterations per load step (per time step); default 20000 without polish, 20
        with it.
    polish: finish with Newton steps on the same P1 energy until the largest step is below
        ``polish_tol_mm`` (default tol_mm / 100). ADMM then only has to bring each step into
        Newton's basin: it stops at max(tol, ``handoff_mm``) (mm) or after ``max_iter``
        iterations, whichever comes first.
    dynamics: ImplicitEuler(dt, steps) for dynamics; None for quasi-static equilibrium.
    load_steps: quasi-static increments (default: the prescribed change from the start state
        divided in steps of at most ``step_mm``, mm); intermediate steps stop at
        ``intermediate_tol_mm`` (mm) (and, with ``polish``, are Newton-polished).
    lift: True: carry the interior along with each boundary increment by one linear solve with
        the tangent at the current state (K_ff du_f = -K_fc du_c); False: the x-step matrix's
        harmonic extension (free, already factorized); "auto" (default): the tangent lift when
        a load step moves the boundary by more than 1 mm. Counted in ``extra["lift_solves"]``.
    callback(it, u): called after every iteration (ADMM, then polish) with u (mm, (n, gdim)).
    factorize(A, cache): factorization of the polish's and lift's symmetric tangents with a
        ``solve(b)`` method, or None for SuperLU (the default); ``fem_reference.cholmod_factor``
        (CHOLMOD through PETSc, which this module does not import) is ~3x faster on the phantom
        and is what ``tissue solve`` / ``tissue verify`` pass.
    Raises SolverDivergedError (iteration and element named) on NaN, inverted elements or
    residual growth.
    """
    t0 = time.perf_counter()
    case.require_no_contact("the ADMM solver")
    case0 = case  # same mesh: its cached probe locations serve the pushed Case too
    if pushes:
        case = case.with_pushes(pushes)
    if not (np.isfinite(tol_mm) and tol_mm > 0):
        raise CaseError(f"tol_mm must be > 0 mm, got {tol_mm!r}")
    if max_iter is None:
        max_iter = 20 if polish else 20000
    if int(max_iter) < 1:
        raise CaseError(f"max_iter must be >= 1, got {max_iter!r}")
    if polish_tol_mm is None:
        polish_tol_mm = tol_mm / 100.0
    dt = dynamics.dt if dynamics is not None else None
    admm_iter = int(max_iter)

    def admm_tol(tol):
        return max(tol, handoff_mm) if polish else tol

    ops = prepare(case, rho=rho, dt=dt)
    up = _particular(case, ops)
    fext = case.external_forces(1.0)
    n, d = ops.n, ops.d
    if initial is None:
        u = np.zeros(ops.N)
    else:
        u = _as_u(case, initial).copy()
        _check_J(ops, ops.grad(u), 0, "the initial (warm-start) state")
    hist = {"primal": [], "dual": [], "max_step_mm": [], "newton_step_mm": [],
            "admm_clock_s": []}
    admm_it = newton_it = 0
    restarts = []
    lifts = 0
    converged = True
    if dynamics is None:
        # load steps: the prescribed change from the start state split in increments of at
        # most step_mm (mm); each step is an ADMM solve warm-started from the previous one
        uc = u - ops.red.Z @ (ops.red.ZT @ u)
        jump = _vertex_norm_max(up - uc, d)
        if not np.isfinite(jump):
            raise CaseError(f"{case.source or case.name}: the prescribed displacements are too "
                            f"large to be represented (|u| overflows)")
        if load_steps is None:
            load_steps = max(1, int(np.ceil(jump / step_mm)))
        for j in range(1, int(load_steps) + 1):
            s = j / load_steps
            last = j == load_steps
            tol_j = tol_mm if last else max(tol_mm, intermediate_tol_mm)
            up_j = uc + s * (up - uc)
            if lift is True or (lift == "auto" and jump / load_steps > 1.0):
                u = _tangent_lift(ops, u, up_j, admm_it + newton_it, factorize)
                lifts += 1
            u_start = u
            u, k, converged = _admm(ops, up_j, s * fext, u, tol_mm=admm_tol(tol_j),
                                    max_iter=admm_iter, callback=callback,
                                    it0=admm_it + newton_it,
                                    progress=progress, hist=hist)
            admm_it += k
            if polish:
                ptol = polish_tol_mm if last else max(polish_tol_mm, tol_j)
                try:
                    u, kn = _newton(ops, u, s * fext, None, tol_mm=ptol,
                                    max_iter=polish_max_iter, it0=admm_it + newton_it,
                                    hist=hist, callback=callback, factorize=factorize)
                except SolverDivergedError as exc:
                    # the unconverged ADMM state left Newton's basin: restart the polish
                    # from the step's start state (reported in extra["polish_restarts"]),
                    # carried to this step's boundary values first (without a lift it still
                    # has the previous step's, which Newton would keep: it moves free dofs only)
                    restarts.append(f"load step {j}: {exc}")
                    u_start = _tangent_lift(ops, u_start, up_j, admm_it + newton_it, factorize)
                    u, kn = _newton(ops, u_start, s * fext, None, tol_mm=ptol,
                                    max_iter=polish_max_iter, it0=admm_it + newton_it,
                                    hist=hist, callback=callback, factorize=factorize)
                newton_it += kn
                if last:
                    converged = hist["newton_step_mm"][-1] < polish_tol_mm
        inertia = None
    else:
        v = np.zeros(ops.N) if dynamics.velocity is None else _as_u(case, dynamics.velocity).copy()
        mdt = ops.mass / dt ** 2
        u = up + ops.red.Z @ (ops.red.ZT @ (u - up))
        traj = []
        for step in range(int(dynamics.steps)):
            ut = u + dt * v
            inertia = (mdt, ut)
            un, k, conv = _admm(ops, up, fext + mdt * ut, u, tol_mm=admm_tol(tol_mm),
                                max_iter=admm_iter, callback=callback,
                                it0=admm_it + newton_it,
                                progress=progress, hist=hist)
            admm_it += k
            if polish:
                un, kn = _newton(ops, un, fext, inertia, tol_mm=polish_tol_mm,
                                 max_iter=polish_max_iter, it0=admm_it + newton_it, hist=hist,
                                 callback=callback, factorize=factorize)
                newton_it += kn
                conv = hist["newton_step_mm"][-1] < polish_tol_mm
            converged = converged and conv
            v = (un - u) / dt
            u = un
            traj.append({k_: np.asarray(val).tolist() for k_, val in case.probe_values(u).items()})
        inertia = None
    H = ops.grad(u)
    _check_J(ops, H, admm_it + newton_it, "the final state")
    r = _residual(ops, u, fext, None)
    free_res = float(np.abs(ops.red.ZT @ r).max(initial=0.0)) if dynamics is None else \
        float(np.abs(ops.red.ZT @ _residual(ops, u, fext, inertia)).max(initial=0.0))
    reactions = _reactions(case, r)
    psi, _ = ops.law.psi_J(H)
    extra = {"admm_iterations": int(admm_it), "newton_iterations": int(newton_it),
             "load_steps": int(load_steps) if dynamics is None else 0,
             "rho_kPa": ops.rho, "setup_s": ops.setup_s, "tol_mm": tol_mm,
             "polish_restarts": restarts, "lift_solves": lifts,
             **deformation_state(case.mesh, u.reshape(n, d))}
    if dynamics is not None:
        extra.update({"dt_s": dt, "steps": int(dynamics.steps), "probe_trajectory": traj,
                      "velocity": v.reshape(n, d)})
    hist["admm_clock_s"] = [c - t0 for c in hist["admm_clock_s"]]
    u2 = u.reshape(n, d)
    return SolveResult(u=u2, converged=bool(converged), iterations=int(admm_it + newton_it),
                       residual=free_res, wall_time_s=time.perf_counter() - t0, solver="admm",
                       probes=case0.probe_values(u2), reactions=reactions,
                       strain_energy=float(ops.kin.V @ psi), case_name=case.name, n_vertices=n,
                       load_steps=int(load_steps) if dynamics is None else int(dynamics.steps),
                       n_cells=ops.m, history=hist, extra=extra)


def _reactions(case, r):
    """Region -> (gdim,) sum of r = f_int - f_ext (mN) over the region's prescribed dofs
    (oblique sliding regions: over all dofs of their vertices)."""
    d = case.mesh.gdim
    c = case.constraints
    out = case.prescribed_reactions(r)
    R = r.reshape(-1, d)
    for b in case.boundaries:
        if b.type == "sliding":
            for verts, nrm, _ in c.sliding:
                if np.array_equal(np.sort(verts), case.mesh.region_vertices(b.region)):
                    out[b.region] = out[b.region] + R[verts].sum(axis=0)
    return out
