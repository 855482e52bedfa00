"""P1 mechanics of the ADMM solver: element kinematics (shape-function gradients, volumes), the
material laws (Neo-Hookean, seed eq. 14, linear elasticity, and the other laws of
``fem_reference.forms``: Mooney-Rivlin, Yeoh, stable Neo-Hookean, St Venant-Kirchhoff,
corotational, Ogden; 2D is plane strain), and the P1 strain energy, internal forces and exact tangent of a displacement
(mm, kPa, mN).

The laws besides Neo-Hookean and linear elasticity are written once, as an energy Phi(I1, I2, J)
of the invariants of C = F^T F (plane strain: C33 = 1) with its first and second partial
derivatives; the chain rule through

    dI1/dF = 2 F,   dI2/dF = 2 (I1 F - F C),   dJ/dF = cof F,
    d2I1 = 2 d_ik d_JL,
    d2I2 = 2 (2 F_iJ F_kL + I1 d_ik d_JL - d_ik C_LJ - F_iL F_kJ - (F F^T)_ik d_JL),
    d2J  = (cof_iJ cof_kL - cof_iL cof_kJ) / J

gives the stress P = dpsi/dF and its tangent A_iJkL = dP_iJ / dF_kL (``InvariantLaw``). The
Ogden law, a function of the principal stretches, takes its isochoric part from the spectral
formulas of ``fem_reference.ogden`` (which the reference uses too) and adds kappa/2 (J - 1)^2
(``OgdenLaw``).

Everything here is host (numpy/scipy) code: the Newton polish, the tangent lift and the final
checks use it whatever backend ran the ADMM iterations."""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp

from tissue_reference.errors import CaseError
from tissue_reference.fem_reference.invariants import principal_stretch_sum
from tissue_reference.fem_reference.ogden import OgdenIsochoric

KERNEL_LAWS = ("neo-hookean", "linear-elastic")
"""The laws of the compiled element pass (``kernel_c``) and of the closed-form z-steps
(``kernel_array.ZStep``); the others run the numpy element pass with ``kernel_array.LawZStep``."""
INVARIANT_LAWS = ("mooney-rivlin", "yeoh", "stable-neo-hookean", "saint-venant-kirchhoff",
                  "corotational")
"""The laws written as an energy of the invariants (I1, I2, J) (``InvariantLaw``)."""
SPECTRAL_LAWS = ("ogden",)
"""The laws written as a function of the principal stretches (``OgdenLaw``)."""
ADMM_LAWS = KERNEL_LAWS + INVARIANT_LAWS + SPECTRAL_LAWS
"""The strain-energy laws the ADMM solver implements; it refuses the others by name."""


class LawValues(NamedTuple):
    """What ``Law.evaluate`` returns at displacement gradients H (m, d, d): psi (m,) (kPa, inf
    where det F <= 0), J (m,) det F (None for linear elasticity), P (m, d, d) the first Piola
    stress (kPa), A (m, d*d, d*d) its tangent dP/dH (kPa); None for what was not asked for."""

    psi: np.ndarray | None
    J: np.ndarray | None
    P: np.ndarray | None
    A: np.ndarray | None


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


class _EvaluatedLaw:
    """The views of a law's ``evaluate`` (psi, J, P, A at displacement gradients H (m, d, d))
    that the local steps and the polish ask for one at a time."""

    def psi_J(self, H):
        """(psi, J) (``evaluate``)."""
        v = self.evaluate(H, stress=False, tangent=False)
        return v.psi, v.J

    def stress(self, H):
        """(P, J) (``evaluate``)."""
        v = self.evaluate(H, psi=False, tangent=False)
        return v.P, v.J

    def tangent(self, H):
        """A (m, d*d, d*d), rows (iJ), columns (kL): A_iJkL = d P_iJ / d H_kL (``evaluate``)."""
        return self.evaluate(H, psi=False, stress=False).A


class InvariantLaw(_EvaluatedLaw):
    """A law as an energy Phi(I1, I2, J) of the invariants of C (module docstring): ``phi`` gives
    Phi (m,), its gradient (m, 3) and Hessian (m, 3, 3) in (I1, I2, J); ``psi_J``, ``stress``
    and ``tangent`` follow by the chain rule, on displacement gradients H (m, d, d)."""

    def __init__(self, material, d):
        self.model = material.model
        self.mu, self.kappa, self.lmbda = material.mu, material.kappa, material.lmbda
        self.coefficients = material.coefficients
        self.d = d

    def _invariants(self, H):
        d = self.d
        F = H + np.eye(d)
        J, cof = det_cof(F)
        C = np.einsum("mki,mkj->mij", F, F)
        I1 = np.einsum("mii->m", C) + (3 - d)
        I2 = 0.5 * (I1 ** 2 - np.einsum("mij,mij->m", C, C) - (3 - d))
        return F, C, J, cof, I1, I2

    def phi(self, I1, I2, J):
        """(Phi, dPhi (m, 3), d2Phi (m, 3, 3)) in (I1, I2, J) of this law."""
        m = len(J)
        g = np.zeros((m, 3))
        h = np.zeros((m, 3, 3))
        mu, lam = self.mu, self.lmbda
        if self.model == "stable-neo-hookean":
            lp = lam + mu
            a = J - 1.0 - mu / lp
            g[:, 0], g[:, 2], h[:, 2, 2] = 0.5 * mu, lp * a, lp
            return 0.5 * mu * (I1 - 3.0) + 0.5 * lp * a ** 2 - mu ** 2 / (2.0 * lp), g, h
        if self.model == "saint-venant-kirchhoff":
            # tr Eg = (I1 - 3)/2, Eg:Eg = (I1^2 - 2 I2 - 2 I1 + 3)/4
            g[:, 0] = 0.25 * lam * (I1 - 3.0) + 0.5 * mu * (I1 - 1.0)
            g[:, 1] = -0.5 * mu
            h[:, 0, 0] = 0.25 * lam + 0.5 * mu
            return (0.125 * lam * (I1 - 3.0) ** 2
                    + 0.25 * mu * (I1 ** 2 - 2.0 * I2 - 2.0 * I1 + 3.0)), g, h
        if self.model == "corotational":
            return self._corotational(I1, I2, J, g, h)
        # uncoupled: W(x1, x2) + kappa/2 (J - 1)^2, x1 = J^(-2/3) I1, x2 = J^(-4/3) I2
        c = self.coefficients
        j23 = np.abs(J) ** (-2.0 / 3.0)
        x1, x2 = j23 * I1, j23 * j23 * I2
        if self.model == "mooney-rivlin":
            W = c["c1"] * (x1 - 3.0) + c["c2"] * (x2 - 3.0)
            W1, W2, W11 = np.full(m, c["c1"]), np.full(m, c["c2"]), np.zeros(m)
        elif self.model == "yeoh":
            x = x1 - 3.0
            W = c["c1"] * x + c["c2"] * x ** 2 + c["c3"] * x ** 3
            W1 = c["c1"] + 2.0 * c["c2"] * x + 3.0 * c["c3"] * x ** 2
            W2, W11 = np.zeros(m), 2.0 * c["c2"] + 6.0 * c["c3"] * x
        elif self.model == "neo-hookean":   # (the kernel's own closed forms serve it)
            W = 0.5 * mu * (x1 - 3.0)
            W1, W2, W11 = np.full(m, 0.5 * mu), np.zeros(m), np.zeros(m)
        else:
            raise ValueError(f"{self.model!r} is not an invariant law")
        iJ = 1.0 / J
        g1 = np.stack([j23, np.zeros(m), -2.0 / 3.0 * x1 * iJ], axis=1)
        g2 = np.stack([np.zeros(m), j23 * j23, -4.0 / 3.0 * x2 * iJ], axis=1)
        h[:, 0, 2] = h[:, 2, 0] = W1 * (-2.0 / 3.0) * j23 * iJ
        h[:, 1, 2] = h[:, 2, 1] = W2 * (-4.0 / 3.0) * j23 * j23 * iJ
        h[:, 2, 2] = (W1 * 10.0 / 9.0 * x1 + W2 * 28.0 / 9.0 * x2) * iJ * iJ + self.kappa
        h += W11[:, None, None] * np.einsum("ma,mb->mab", g1, g1)
        g = W1[:, None] * g1 + W2[:, None] * g2
        g[:, 2] += self.kappa * (J - 1.0)
        return W + 0.5 * self.kappa * (J - 1.0) ** 2, g, h

    def _corotational(self, I1, I2, J, g, h):
        """mu (I1 - 2 a + 3) + lambda/2 (a - 3)^2 with a = tr U the root of
        f(a) = (a^2 - I1)^2 / 4 - 2 J a - I2 (``fem_reference.forms``: the same iteration), its
        derivatives in (I1, I2, J) by implicit differentiation of f(a; I1, I2, J) = 0."""
        mu, lam = self.mu, self.lmbda
        a = principal_stretch_sum(I1, I2, J)
        fa = a * (a * a - I1) - 2.0 * J
        fx = np.stack([-(a * a - I1) / 2.0, -np.ones_like(a), -2.0 * a], axis=1)
        fax = np.stack([-a, np.zeros_like(a), -2.0 * np.ones_like(a)], axis=1)
        fxx = np.zeros_like(h)
        fxx[:, 0, 0] = 0.5
        ax = -fx / fa[:, None]
        axx = -(fxx + np.einsum("mi,mj->mij", fax, ax) + np.einsum("mi,mj->mij", ax, fax)
                + (3.0 * a * a - I1)[:, None, None] * np.einsum("mi,mj->mij", ax, ax)) \
            / fa[:, None, None]
        pa = -2.0 * mu + lam * (a - 3.0)
        g[:] = pa[:, None] * ax
        g[:, 0] += mu
        h[:] = lam * np.einsum("mi,mj->mij", ax, ax) + pa[:, None, None] * axx
        return mu * (I1 - 2.0 * a + 3.0) + 0.5 * lam * (a - 3.0) ** 2, g, h

    def _first(self, F, C, cof, I1):
        """dI/dF (m, 3, d, d) for (I1, I2, J)."""
        return np.stack([2.0 * F, 2.0 * (I1[:, None, None] * F - F @ C), cof], axis=1)

    def evaluate(self, H, psi=True, stress=True, tangent=True) -> LawValues:
        """``LawValues`` (psi, J, P, A) at H, each only where asked for, from one computation
        of the invariants, of Phi's derivatives and of the invariants' first derivatives."""
        F, C, J, cof, I1, I2 = self._invariants(H)
        if psi:
            with np.errstate(invalid="ignore", divide="ignore"):
                e, g, h = self.phi(I1, I2, J)
            e = np.where(J > 0, e, np.inf)
        else:
            e = None
            _, g, h = self.phi(I1, I2, J)
        if not (stress or tangent):
            return LawValues(e, J, None, None)
        dI = self._first(F, C, cof, I1)
        P = np.einsum("ma,maij->mij", g, dI) if stress else None
        A = self._tangent(F, C, J, cof, I1, g, h, dI) if tangent else None
        return LawValues(e, J, P, A)

    def _tangent(self, F, C, J, cof, I1, g, h, dI):
        """A (m, d*d, d*d) from the invariants, Phi's gradient g and Hessian h and dI/dF."""
        d = self.d
        m = len(F)
        dI = dI.reshape(m, 3, d * d)
        A = np.matmul(dI.transpose(0, 2, 1), np.matmul(h, dI))       # sum_ab h_ab dIa dIb
        eye = np.eye(d)
        B = F @ np.transpose(F, (0, 2, 1))

        def outer(X, Y):   # (m, i, J, k, L) = X_iJ Y_kL
            return X[:, :, :, None, None] * Y[:, None, None, :, :]

        FF = outer(F, F)
        cc = outer(cof, cof)
        # d2I2 = 2 (2 F_iJ F_kL + I1 d_ik d_JL - d_ik C_LJ - F_iL F_kJ - B_ik d_JL)
        d2I2 = 2.0 * (2.0 * FF - FF.transpose(0, 1, 4, 3, 2)
                      - B[:, :, None, :, None] * eye[None, None, :, None, :])
        for i in range(d):
            d2I2[:, i, :, i, :] += 2.0 * (I1[:, None, None] * eye - C)
        d2J = (cc - cc.transpose(0, 1, 4, 3, 2)) / J[:, None, None, None, None]
        A += (g[:, 1, None, None, None, None] * d2I2
              + g[:, 2, None, None, None, None] * d2J).reshape(m, d * d, d * d)
        A[:, np.arange(d * d), np.arange(d * d)] += 2.0 * g[:, 0, None]
        return A


class OgdenLaw(_EvaluatedLaw):
    """The Ogden law: the isochoric energy of ``fem_reference.ogden.OgdenIsochoric`` (from the
    eigen-decomposition of C, exact at equal principal stretches) plus seed 000's volumetric
    energy kappa/2 (J - 1)^2, kappa = k; the same interface as ``InvariantLaw`` on displacement
    gradients H (m, d, d)."""

    def __init__(self, material, d):
        self.model = material.model
        self.kappa = material.kappa
        self.iso = OgdenIsochoric(material.ogden_mu, material.ogden_alpha)
        self.d = d

    def evaluate(self, H, psi=True, stress=True, tangent=True) -> LawValues:
        """``LawValues`` (psi, J, P, A) at H, each only where asked for, from one
        eigen-decomposition per point; psi is inf where det F <= 0."""
        d, k = self.d, self.kappa
        F = H + np.eye(d)
        J, cof = det_cof(F)
        iso = self.iso.evaluate(F, psi, stress, tangent)
        e = P = A = None
        if psi:
            e = np.where(J > 0, iso.psi + 0.5 * k * (J - 1.0) ** 2, np.inf)
        if stress:
            P = iso.P + (k * (J - 1.0))[:, None, None] * cof
        if tangent:
            m = len(F)
            c = cof.reshape(m, d * d)
            with np.errstate(invalid="ignore", divide="ignore"):
                cc = cof[:, :, :, None, None] * cof[:, None, None, :, :]
                d2J = (cc - cc.transpose(0, 1, 4, 3, 2)) / J[:, None, None, None, None]
            A = iso.A + k * (c[:, :, None] * c[:, None, :]) \
                + (k * (J - 1.0))[:, None, None] * d2J.reshape(m, d * d, d * d)
        return LawValues(e, J, P, A)


class Law:
    """Energy density psi (kPa), first Piola stress P = dpsi/dH (kPa) and A = dP/dH (kPa) of the
    displacement gradient H (m, d, d): Neo-Hookean and linear elasticity in closed form, the
    other laws of ``ADMM_LAWS`` through ``InvariantLaw`` (Ogden: ``OgdenLaw``). ``kernel``: whether the compiled element
    pass and the closed-form z-steps implement this law (``KERNEL_LAWS``)."""

    def __init__(self, material, d):
        material.require_law(ADMM_LAWS, "the ADMM solver")
        material.require_compressible("the ADMM solver")
        material.require_seed_volumetric("the ADMM solver")
        self.model = material.model
        self.mu, self.kappa, self.lmbda = material.mu, material.kappa, material.lmbda
        self.d = d
        self.kernel = self.model in KERNEL_LAWS
        self._invariant = None if self.kernel else \
            (OgdenLaw if self.model in SPECTRAL_LAWS else InvariantLaw)(material, d)

    def evaluate(self, H, psi=True, stress=True, tangent=True) -> LawValues:
        """``LawValues`` (psi, J, P, A) at H, each only where asked for: the invariant laws
        compute their invariants and derivatives once for all three (``InvariantLaw.evaluate``);
        the closed forms of Neo-Hookean and linear elasticity are evaluated one by one."""
        if self._invariant is not None:
            return self._invariant.evaluate(H, psi, stress, tangent)
        e, J = self.psi_J(H) if psi else (None, None)
        P, J = self.stress(H) if stress else (None, J)
        A = self.tangent(H) if tangent else None
        if J is None and not (psi or stress) and self.model != "linear-elastic":
            J, _ = det_cof(H + np.eye(self.d))
        return LawValues(e, J, P, A)

    def psi_J(self, H):
        d = self.d
        if self._invariant is not None:
            return self._invariant.psi_J(H)
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
        if self._invariant is not None:
            return self._invariant.stress(H)
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
        if self._invariant is not None:
            return self._invariant.tangent(H)
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

