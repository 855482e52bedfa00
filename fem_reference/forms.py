"""UFL strain-energy densities (kPa = mN/mm^2) of the reference, as plain functions.

Neo-Hookean:  psi = mu/2 (Ibar1 - 3) + kappa/2 G(J)^2,  with the volume-change measure
G(J) = J - 1 (``volumetric = "quadratic"``, seed 000 eq. 14) or G(J) = ln J (``"log"``),
Ibar1 = J^(-2/3) tr C,  C = F^T F,  J = det F,  mu = E / (2 (1 + nu)),  kappa = E / (3 (1 - 2 nu)).
Both laws agree to first order at J = 1; under strong compression the quadratic one's pressure
is bounded by kappa (``meshes.case_parts.Material``), the log one's is not.
Linear elasticity:  psi = mu eps:eps + lambda/2 (tr eps)^2,  eps = sym(grad u).
In 2D (plane strain) F is the 2x2 in-plane block and F33 = 1, so tr C gains + 1.

Mixed (u-p, perturbed Lagrangian) form of the same energies, with p the pressure (kPa, positive
in compression):
    Neo-Hookean:    psi(u, p) = mu/2 (Ibar1 - 3) - p G(J) - p^2 / (2 kappa)
    linear-elastic: psi(u, p) = mu dev(eps):dev(eps) - p tr(eps) - p^2 / (2 kappa)
Stationarity in p gives p = -kappa G(J) (resp. -kappa tr eps), and substituting it back gives
the displacement energy exactly: the mixed form changes the discretization, not the model. With
1/kappa = 0 (nu = 0.5) p is the Lagrange multiplier of J = 1 (tr eps = 0): the incompressible
limit, the same for both volume-change measures. dev is taken in 3D (plane strain keeps eps33 = 0).
"""
from __future__ import annotations

import ufl

__all__ = [
    "first_piola",
    "linear_elastic_psi",
    "mixed_energy_density",
    "neo_hookean_psi",
    "strain_energy_density",
    "volume_change",
]


def _isochoric_neo_hookean(F, mu):
    gdim = F.ufl_shape[0]
    J = ufl.det(F)
    I1 = ufl.tr(F.T * F) + (3 - gdim)
    return mu / 2 * (J ** (-2.0 / 3.0) * I1 - 3), J


def volume_change(J, volumetric: str = "quadratic"):
    """G(J): J - 1 (``"quadratic"``) or ln J (``"log"``), the measure the volumetric energy
    kappa/2 G^2 penalizes (module docstring)."""
    if volumetric == "quadratic":
        return J - 1
    if volumetric == "log":
        return ufl.ln(J)
    raise ValueError(f"unknown volumetric law {volumetric!r}")


def neo_hookean_psi(F, mu, kappa, volumetric: str = "quadratic"):
    iso, J = _isochoric_neo_hookean(F, mu)
    return iso + kappa / 2 * volume_change(J, volumetric) ** 2


def linear_elastic_psi(F, mu, lmbda):
    gdim = F.ufl_shape[0]
    eps = ufl.sym(F - ufl.Identity(gdim))
    return mu * ufl.inner(eps, eps) + lmbda / 2 * ufl.tr(eps) ** 2


def strain_energy_density(u, model: str, mu, kappa, lmbda, volumetric: str = "quadratic"):
    """psi(F(u)) for ``model`` in {"neo-hookean", "linear-elastic"} (Neo-Hookean with the
    ``volumetric`` law); also returns F (a variable)."""
    gdim = u.ufl_shape[0]
    F = ufl.variable(ufl.Identity(gdim) + ufl.grad(u))
    if model == "neo-hookean":
        return neo_hookean_psi(F, mu, kappa, volumetric), F
    return linear_elastic_psi(F, mu, lmbda), F


def mixed_energy_density(u, p, model: str, mu, inv_kappa, volumetric: str = "quadratic"):
    """psi(u, p) of the mixed formulation (module docstring); ``inv_kappa`` = 1/kappa (1/kPa),
    0 for an incompressible material. Returns (psi, the volume-change measure G(J) or tr eps)."""
    gdim = u.ufl_shape[0]
    F = ufl.Identity(gdim) + ufl.grad(u)
    if model == "neo-hookean":
        iso, J = _isochoric_neo_hookean(F, mu)
        vol = volume_change(J, volumetric)
    else:
        eps = ufl.sym(ufl.grad(u))
        vol = ufl.tr(eps)
        iso = mu * (ufl.inner(eps, eps) - vol ** 2 / 3)
    return iso - p * vol - inv_kappa / 2 * p ** 2, vol


def first_piola(u, model: str, mu, kappa, lmbda):
    psi, F = strain_energy_density(u, model, mu, kappa, lmbda)
    return ufl.diff(psi, F)
