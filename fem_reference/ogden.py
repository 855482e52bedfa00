"""The isochoric part of the Ogden law as a spectral function, in numpy: its energy, first Piola
stress and exact tangent at deformation gradients F (m, d, d), batched over points. Shared by
the reference (which fills quadrature-point Functions with it: UFL has no eigen-decomposition)
and the fast solvers' numpy law (``solvers.admm.mechanics``); it imports no dolfinx.

With C = F^T F, its eigenvalues x_a = lambda_a^2 (the squared principal stretches) and unit
eigenvectors N_a, and D = det C = J^2, the isochoric energy (Abaqus' convention)

    W = sum_i 2 mu_i / alpha_i^2 (sum_a lb_a^alpha_i - 3),  lb_a = J^(-1/3) lambda_a,

is the symmetric function w(x) = sum_i c_i (s_i T_i - 3) of the eigenvalues, with c_i = 2 mu_i /
alpha_i^2, b_i = alpha_i / 2, e_ia = x_a^b_i, T_i = sum_a e_ia and s_i = D^(-b_i / 3). Its
derivatives (u_ia = e_ia - T_i / 3):

    w_a  = sum_i c_i b_i s_i u_ia / x_a,
    w_ab = sum_i c_i b_i s_i / (x_a x_b) (delta_ab (b_i e_ia - u_ia) - b_i (u_ia + e_ib) / 3),
    g_ab = (w_a - w_b) / (x_a - x_b) = sum_i c_i b_i s_i (dd(b_i - 1; x_a, x_b) + T_i / (3 x_a x_b)),

with dd(p; a, b) = (a^p - b^p) / (a - b), the divided difference of x^p, evaluated as
b^(p-1) expm1(p t) / expm1(t), t = ln(a / b) (its series p (1 + (p - 1) t / 2 + (p - 1) (2 p - 1)
t^2 / 12) for |t| < 1e-5): accurate to round-off for every a, b, and equal to its limit
p a^(p-1) = w_aa - w_ab where two eigenvalues coincide (rest, uniaxial, equibiaxial
deformations), so no branch of the formula divides by a vanishing difference. The second Piola
stress and its tangent follow from the theory of spectral functions (Lewis 1996, Sendov 2007):

    S = 2 dW/dC = sum_a 2 w_a N_a (x) N_a,
    CC = 4 d2W/dC2 = sum_ab 4 w_ab N_a N_a N_b N_b + sum_(a != b) 2 g_ab (N_a N_b N_a N_b + N_a N_b N_b N_a),

and P = F S, A_iJkL = dP_iJ / dF_kL = delta_ik S_JL + F_iM CC_MJNL F_kN. In the eigenbasis
(Fq = F Q, Q = [N_1 N_2 N_3]) the tangent reads

    Aq_iMkN = delta_MN (delta_ik 2 w_M + sum_(P != M) 2 g_PM Fq_iP Fq_kP) + 4 w_MN Fq_iM Fq_kN
              + (1 - delta_MN) 2 g_NM Fq_iN Fq_kM,

and A_iJkL = Q_JM Q_LN Aq_iMkN. Plane strain (d = 2) takes F33 = 1: the 3D law of the embedded
gradient, whose in-plane blocks are P and A. The sign of J is not seen (D = J^2): callers treat
det F <= 0 themselves.
"""
from __future__ import annotations

import numpy as np

__all__ = ["OgdenIsochoric", "OgdenValues", "divided_power"]

_SERIES_T = 1e-5
"""|ln(a/b)| under which ``divided_power`` takes its series (the error of its t^3 term, about
1e-16, is below round-off)."""


class OgdenValues:
    """What ``OgdenIsochoric.evaluate`` returns: psi (m,) (kPa), P (m, d, d) (kPa) and A (m, d*d,
    d*d) (kPa) with rows (iJ), columns (kL), A_iJkL = dP_iJ / dF_kL; None where not asked for."""

    __slots__ = ("A", "P", "psi")

    def __init__(self, psi, P, A):
        self.psi, self.P, self.A = psi, P, A


def divided_power(p, a, b):
    """(a^p - b^p) / (a - b) for positive a, b (arrays), and its limit p a^(p-1) at a = b,
    accurate to round-off for every a, b (module docstring).

    Parameters
    ----------
    p : float
        The exponent.
    a, b : numpy.ndarray
        Positive numbers of one shape.

    Returns
    -------
    numpy.ndarray
        The divided difference of x^p between a and b.
    """
    t = np.log(a) - np.log(b)
    small = np.abs(t) < _SERIES_T
    ts = np.where(small, 1.0, t)
    with np.errstate(invalid="ignore", divide="ignore"):
        far = np.expm1(p * ts) / np.expm1(ts)
    near = p * (1.0 + (p - 1.0) * t / 2.0 + (p - 1.0) * (2.0 * p - 1.0) * t * t / 12.0)
    return b ** (p - 1.0) * np.where(small, near, far)


class OgdenIsochoric:
    """The isochoric Ogden energy W = sum_i 2 mu_i / alpha_i^2 (sum_a lb_a^alpha_i - 3) of
    deformation gradients (module docstring).

    Parameters
    ----------
    mu : sequence of float
        The coefficients mu_i (kPa).
    alpha : sequence of float
        The exponents alpha_i (dimensionless, nonzero), as many as ``mu``.
    """

    def __init__(self, mu, alpha):
        self.mu = np.asarray(mu, dtype=np.float64).reshape(-1)
        self.alpha = np.asarray(alpha, dtype=np.float64).reshape(-1)
        if self.mu.shape != self.alpha.shape or not len(self.mu) or np.any(self.alpha == 0):
            raise ValueError(f"Ogden: mu {list(self.mu)} and alpha {list(self.alpha)} must be "
                             f"lists of one nonzero length, alpha_i != 0")

    def evaluate(self, F, psi=True, stress=True, tangent=True) -> OgdenValues:
        """W, P = dW/dF and A = dP/dF at deformation gradients F.

        Parameters
        ----------
        F : numpy.ndarray
            (m, d, d) deformation gradients, d = 2 (plane strain, F33 = 1) or 3.
        psi, stress, tangent : bool
            Which of W, P, A to compute.

        Returns
        -------
        OgdenValues
            psi (m,), P (m, d, d), A (m, d*d, d*d) (kPa); None for what was not asked for.
        """
        F = np.asarray(F, dtype=np.float64)
        m, d = F.shape[0], F.shape[1]
        F3 = F
        if d == 2:
            F3 = np.zeros((m, 3, 3))
            F3[:, :2, :2] = F
            F3[:, 2, 2] = 1.0
        C = np.einsum("mki,mkj->mij", F3, F3)
        x, Q = np.linalg.eigh(C)
        x = np.maximum(x, np.finfo(float).tiny)
        logx = np.log(x)
        logD = logx.sum(axis=1)
        W = np.zeros(m)
        w1 = np.zeros((m, 3))
        w2 = np.zeros((m, 3, 3))
        g = np.zeros((m, 3, 3))
        eye3 = np.eye(3)
        iu, ju = np.triu_indices(3, 1)
        for mu_i, al in zip(self.mu, self.alpha):
            c, b = 2.0 * mu_i / (al * al), al / 2.0
            e = np.exp(b * logx)                       # x_a^b
            T = e.sum(axis=1)
            s = np.exp(-b / 3.0 * logD)                # D^(-b/3)
            W += c * (s * T - 3.0)
            if not (stress or tangent):
                continue
            u = e - T[:, None] / 3.0
            cbs = c * b * s
            w1 += cbs[:, None] * u / x
            if tangent:
                xx = x[:, :, None] * x[:, None, :]
                w2 += (cbs[:, None, None] / xx) * (
                    eye3 * (b * e - u)[:, :, None] - b / 3.0 * (u[:, :, None] + e[:, None, :]))
                dd = divided_power(b - 1.0, x[:, iu], x[:, ju])
                gab = cbs[:, None] * (dd + T[:, None] / (3.0 * xx[:, iu, ju]))
                g[:, iu, ju] += gab
                g[:, ju, iu] += gab
        P = A = None
        Fq = np.matmul(F3, Q)
        if stress:
            # P = F S, S = Q diag(2 w_a) Q^T
            P3 = np.matmul(Fq * (2.0 * w1)[:, None, :], np.transpose(Q, (0, 2, 1)))
            P = P3[:, :d, :d]
        if tangent:
            A = self._tangent(Fq, Q, w1, w2, g)[:, :d, :d, :d, :d].reshape(m, d * d, d * d)
        return OgdenValues(W if psi else None, P, A)

    @staticmethod
    def _tangent(Fq, Q, w1, w2, g):
        """A (m, 3, 3, 3, 3), A_iJkL, from the eigenbasis form Aq (module docstring)."""
        m = len(Fq)
        eye3 = np.eye(3)
        Aq = np.zeros((m, 3, 3, 3, 3))   # (i, M, k, N)
        # 4 w_MN Fq_iM Fq_kN
        Aq += 4.0 * w2[:, None, :, None, :] * Fq[:, :, :, None, None] * Fq[:, None, None, :, :]
        # (1 - delta_MN) 2 g_NM Fq_iN Fq_kM   (g has a zero diagonal)
        Aq += 2.0 * np.transpose(g, (0, 2, 1))[:, None, :, None, :] \
            * Fq[:, :, None, None, :] * np.transpose(Fq, (0, 2, 1))[:, None, :, :, None]
        # delta_MN (delta_ik 2 w_M + sum_(P != M) 2 g_PM Fq_iP Fq_kP)
        diag = 2.0 * np.einsum("mpM,mip,mkp->miMk", g, Fq, Fq)
        diag += 2.0 * eye3[None, :, None, :] * w1[:, None, :, None]
        idx = np.arange(3)
        Aq[:, :, idx, :, idx] += np.transpose(diag, (2, 0, 1, 3))
        # A_iJkL = Q_JM Q_LN Aq_iMkN
        return np.einsum("mJM,mLN,miMkN->miJkL", Q, Q, Aq, optimize=True)
