"""UFL strain-energy densities (kPa = mN/mm^2) of the reference, as plain functions.

Neo-Hookean:  psi = mu/2 (Ibar1 - 3) + kappa/2 G(J)^2,  with the volume-change measure
G(J) = J - 1 (``volumetric = "quadratic"``, seed 000 eq. 14) or G(J) = ln J (``"log"``),
Ibar1 = J^(-2/3) tr C,  C = F^T F,  J = det F,  mu = E / (2 (1 + nu)),  kappa = E / (3 (1 - 2 nu)).
Both laws agree to first order at J = 1; under strong compression the quadratic one's pressure
is bounded by kappa (``model.case_parts.Material``), the log one's is not.
Mooney-Rivlin:  psi = c1 (Ibar1 - 3) + c2 (Ibar2 - 3) + kappa/2 G(J)^2,
Yeoh:           psi = c1 (Ibar1 - 3) + c2 (Ibar1 - 3)^2 + c3 (Ibar1 - 3)^3 + kappa/2 G(J)^2,
with Ibar2 = J^(-4/3) ((tr C)^2 - tr C^2) / 2 and kappa = k (``model.case_parts.Material``).
Stable Neo-Hookean (Smith et al. 2018):  psi = mu/2 (tr C - 3) + lambda'/2 (J - 1 - mu/lambda')^2
- mu^2 / (2 lambda'),  lambda' = lambda + mu.
St Venant-Kirchhoff:  psi = lambda/2 (tr Eg)^2 + mu Eg:Eg,  Eg = (C - I) / 2.
Corotational:  psi = mu |F - R|^2 + lambda/2 tr(R^T F - I)^2 = mu (tr C - 2 a + 3) + lambda/2 (a - 3)^2,
with F = R U the polar decomposition and a = tr U, the sum of the principal stretches. The
invariants of U and C are tied by a^2 - 2 b = I1, b^2 - 2 J a = I2 (b the second invariant of
U), so a is the largest root of (a^2 - I1)^2 / 4 - 2 J a - I2 = 0: Newton's iteration on it
from an upper bound (``principal_stretch_sum``) converges monotonically and reaches round-off in
four steps for principal stretches from 1/4 to 4; a smooth function of C, exact at equal
stretches (at rest too), whose UFL derivatives are the exact ones to round-off.
Linear elasticity:  psi = mu eps:eps + lambda/2 (tr eps)^2,  eps = sym(grad u).
In 2D (plane strain) F is the 2x2 in-plane block and F33 = 1, so tr C gains + 1 (and tr C^2 too;
Eg33 = 0).
The coefficients c1, c2, c3 reach the forms as ``coefficients`` (UFL values by name).
Ogden:  psi = sum_i 2 mu_i / alpha_i^2 (sum_a lb_a^alpha_i - 3) + kappa/2 G(J)^2 is a function
of the principal stretches, which UFL cannot give: its isochoric part lives on quadrature-point
Functions (``ogden_fields``), its volumetric part is ``volume_change`` here.

Mixed (u-p, perturbed Lagrangian) form of the uncoupled energies (Neo-Hookean, Mooney-Rivlin,
Yeoh: an isochoric part W(Ibar1, Ibar2) and kappa/2 G(J)^2) and of linear elasticity, with p the
pressure (kPa, positive in compression):
    uncoupled:      psi(u, p) = W(Ibar1, Ibar2) - p G(J) - p^2 / (2 kappa)
    linear-elastic: psi(u, p) = mu dev(eps):dev(eps) - p tr(eps) - p^2 / (2 kappa)
Stationarity in p gives p = -kappa G(J) (resp. -kappa tr eps), and substituting it back gives
the displacement energy exactly: the mixed form changes the discretization, not the model. With
1/kappa = 0 (nu = 0.5) p is the Lagrange multiplier of J = 1 (tr eps = 0): the incompressible
limit, the same for both volume-change measures. dev is taken in 3D (plane strain keeps eps33 = 0).
"""
from __future__ import annotations

import ufl

from .invariants import principal_stretch_sum

__all__ = [
    "corotational_psi",
    "first_piola",
    "isochoric_energy",
    "linear_elastic_psi",
    "mixed_energy_density",
    "neo_hookean_psi",
    "saint_venant_kirchhoff_psi",
    "stable_neo_hookean_psi",
    "strain_energy_density",
    "volume_change",
    "volume_measure",
]


def _invariants(F):
    """(I1, I2, J) of C = F^T F; in 2D (plane strain) with C33 = 1."""
    gdim = F.ufl_shape[0]
    C = F.T * F
    I1 = ufl.tr(C) + (3 - gdim)
    I2 = (I1 ** 2 - (ufl.inner(C, C) + (3 - gdim))) / 2
    return I1, I2, ufl.det(F)


def isochoric_energy(F, model: str, mu, coefficients=None):
    """(W, J): the isochoric energy of an uncoupled law (``model.case_parts.UNCOUPLED_LAWS``)
    of Ibar1 = J^(-2/3) I1 and Ibar2 = J^(-4/3) I2 (module docstring); ``mu`` serves the
    Neo-Hookean law, ``coefficients`` (c1, c2, c3 by name) the others."""
    I1, I2, J = _invariants(F)
    x = J ** (-2.0 / 3.0) * I1 - 3
    if model == "neo-hookean":
        return mu / 2 * x, J
    c = coefficients or {}
    if model == "mooney-rivlin":
        return c["c1"] * x + c["c2"] * (J ** (-4.0 / 3.0) * I2 - 3), J
    if model == "yeoh":
        return c["c1"] * x + c["c2"] * x ** 2 + c["c3"] * x ** 3, J
    if model == "ogden":
        raise ValueError("the Ogden law's isochoric energy is no UFL expression: it lives on "
                         "quadrature-point Functions (fem_reference.ogden_fields)")
    raise ValueError(f"{model!r} is not an uncoupled law")


def volume_change(J, volumetric: str = "quadratic"):
    """G(J): J - 1 (``"quadratic"``) or ln J (``"log"``), the measure the volumetric energy
    kappa/2 G^2 penalizes (module docstring)."""
    if volumetric == "quadratic":
        return J - 1
    if volumetric == "log":
        return ufl.ln(J)
    raise ValueError(f"unknown volumetric law {volumetric!r}")


def neo_hookean_psi(F, mu, kappa, volumetric: str = "quadratic"):
    iso, J = isochoric_energy(F, "neo-hookean", mu)
    return iso + kappa / 2 * volume_change(J, volumetric) ** 2


def stable_neo_hookean_psi(F, mu, lmbda):
    """Smith, de Goes and Kim's (2018) stable Neo-Hookean energy with lambda' = lambda + mu, less
    its rest value, so that it vanishes at F = I and its small-strain limit is linear
    elasticity's with the same mu and lambda (module docstring)."""
    I1, _, J = _invariants(F)
    lp = lmbda + mu
    return mu / 2 * (I1 - 3) + lp / 2 * (J - 1 - mu / lp) ** 2 - mu ** 2 / (2 * lp)


def saint_venant_kirchhoff_psi(F, mu, lmbda):
    """lambda/2 (tr Eg)^2 + mu Eg:Eg with the Green-Lagrange strain Eg = (F^T F - I) / 2."""
    gdim = F.ufl_shape[0]
    Eg = (F.T * F - ufl.Identity(gdim)) / 2
    return lmbda / 2 * ufl.tr(Eg) ** 2 + mu * ufl.inner(Eg, Eg)


def corotational_psi(F, mu, lmbda):
    """mu |F - R|^2 + lambda/2 tr(R^T F - I)^2 (F = R U), written as mu (I1 - 2 tr U + 3) +
    lambda/2 (tr U - 3)^2 with tr U from ``principal_stretch_sum`` (module docstring)."""
    I1, I2, J = _invariants(F)
    a = principal_stretch_sum(I1, I2, J)
    return mu * (I1 - 2 * a + 3) + lmbda / 2 * (a - 3) ** 2


def linear_elastic_psi(F, mu, lmbda):
    gdim = F.ufl_shape[0]
    eps = ufl.sym(F - ufl.Identity(gdim))
    return mu * ufl.inner(eps, eps) + lmbda / 2 * ufl.tr(eps) ** 2


def strain_energy_density(u, model: str, mu, kappa, lmbda, volumetric: str = "quadratic",
                          coefficients=None):
    """psi(F(u)) for ``model`` (``model.case_parts.MATERIAL_MODELS``; the uncoupled laws with
    the ``volumetric`` law, Mooney-Rivlin and Yeoh with ``coefficients``: module docstring);
    also returns F (a variable)."""
    gdim = u.ufl_shape[0]
    F = ufl.variable(ufl.Identity(gdim) + ufl.grad(u))
    if model == "linear-elastic":
        return linear_elastic_psi(F, mu, lmbda), F
    if model == "stable-neo-hookean":
        return stable_neo_hookean_psi(F, mu, lmbda), F
    if model == "saint-venant-kirchhoff":
        return saint_venant_kirchhoff_psi(F, mu, lmbda), F
    if model == "corotational":
        return corotational_psi(F, mu, lmbda), F
    iso, J = isochoric_energy(F, model, mu, coefficients)
    return iso + kappa / 2 * volume_change(J, volumetric) ** 2, F


def volume_measure(u, model: str, volumetric: str = "quadratic"):
    """What the mixed formulation's pressure multiplies: G(J) of the uncoupled laws (the
    ``volumetric`` measure), tr eps of linear elasticity (module docstring)."""
    if model == "linear-elastic":
        return ufl.tr(ufl.sym(ufl.grad(u)))
    return volume_change(ufl.det(ufl.Identity(u.ufl_shape[0]) + ufl.grad(u)), volumetric)


def mixed_energy_density(u, p, model: str, mu, inv_kappa, volumetric: str = "quadratic",
                         coefficients=None):
    """psi(u, p) of the mixed formulation (module docstring) of an uncoupled law or linear
    elasticity; ``inv_kappa`` = 1/kappa (1/kPa), 0 for an incompressible material. Returns (psi,
    the volume-change measure G(J) or tr eps)."""
    gdim = u.ufl_shape[0]
    F = ufl.Identity(gdim) + ufl.grad(u)
    if model != "linear-elastic":
        iso, J = isochoric_energy(F, model, mu, coefficients)
        vol = volume_change(J, volumetric)
    else:
        eps = ufl.sym(ufl.grad(u))
        vol = ufl.tr(eps)
        iso = mu * (ufl.inner(eps, eps) - vol ** 2 / 3)
    return iso - p * vol - inv_kappa / 2 * p ** 2, vol


def first_piola(u, model: str, mu, kappa, lmbda, volumetric: str = "quadratic",
                coefficients=None):
    """P = dpsi/dF (kPa) of ``strain_energy_density``."""
    psi, F = strain_energy_density(u, model, mu, kappa, lmbda, volumetric, coefficients)
    return ufl.diff(psi, F)
