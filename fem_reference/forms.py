"""UFL strain-energy densities (kPa = mN/mm^2) of the reference, as plain functions.

Neo-Hookean, seed 000 eq. 14:  psi = mu/2 (Ibar1 - 3) + kappa/2 (J - 1)^2,
Ibar1 = J^(-2/3) tr C,  C = F^T F,  J = det F,  mu = E / (2 (1 + nu)),  kappa = E / (3 (1 - 2 nu)).
Linear elasticity:  psi = mu eps:eps + lambda/2 (tr eps)^2,  eps = sym(grad u).
In 2D (plane strain) F is the 2x2 in-plane block and F33 = 1, so tr C gains + 1.
"""
from __future__ import annotations

import ufl

__all__ = ["first_piola", "linear_elastic_psi", "neo_hookean_psi", "strain_energy_density"]


def neo_hookean_psi(F, mu, kappa):
    gdim = F.ufl_shape[0]
    J = ufl.det(F)
    I1 = ufl.tr(F.T * F) + (3 - gdim)
    return mu / 2 * (J ** (-2.0 / 3.0) * I1 - 3) + kappa / 2 * (J - 1) ** 2


def linear_elastic_psi(F, mu, lmbda):
    gdim = F.ufl_shape[0]
    eps = ufl.sym(F - ufl.Identity(gdim))
    return mu * ufl.inner(eps, eps) + lmbda / 2 * ufl.tr(eps) ** 2


def strain_energy_density(u, model: str, mu, kappa, lmbda):
    """psi(F(u)) for ``model`` in {"neo-hookean", "linear-elastic"}; also returns F (a variable)."""
    gdim = u.ufl_shape[0]
    F = ufl.variable(ufl.Identity(gdim) + ufl.grad(u))
    if model == "neo-hookean":
        return neo_hookean_psi(F, mu, kappa), F
    return linear_elastic_psi(F, mu, lmbda), F


def first_piola(u, model: str, mu, kappa, lmbda):
    psi, F = strain_energy_density(u, model, mu, kappa, lmbda)
    return ufl.diff(psi, F)
