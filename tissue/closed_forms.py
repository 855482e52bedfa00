"""Answers that need no finite elements: the closed-form and semi-analytic values the
verification suite scores solvers against.

- ``neo_hookean_piola``: principal first Piola stresses of the toolkit's Neo-Hookean energy
  psi = mu/2 (J^(-2/3) I1 - 3) + kappa/2 (J - 1)^2 (seed 000 eq. 14) at stretches (l1, l2, l2);
- ``uniaxial_lateral_stretch``: the lateral stretch of a block stretched by ``stretch`` with
  traction-free lateral faces (a scalar root);
- ``thick_sphere``: the radial displacement of a thick spherical shell whose inner surface is
  pushed out radially, outer surface free: the radial equilibrium ODE
  dP_rR/dR + 2 (P_rR - P_tt)/R = 0 as a two-point boundary-value problem (scipy's solve_bvp);
  at nu = 0.5 the incompressible closed form r^3 = R^3 + a^3 - A^3.
Units: mm, kPa.
"""
from __future__ import annotations

import numpy as np
from scipy.integrate import solve_bvp
from scipy.optimize import brentq

__all__ = ["incompressible_sphere_u", "neo_hookean_piola", "thick_sphere",
           "uniaxial_lateral_stretch"]


def neo_hookean_piola(l1, l2, mu: float, kappa: float):
    """(P_11, P_22) at principal stretches (l1, l2, l2); works on complex and array input."""
    J = l1 * l2 * l2
    I1 = l1 * l1 + 2 * l2 * l2
    iso = mu * J ** (-2.0 / 3.0)
    vol = kappa * (J - 1) * J
    return iso * (l1 - I1 / (3 * l1)) + vol / l1, iso * (l2 - I1 / (3 * l2)) + vol / l2


def uniaxial_lateral_stretch(stretch: float, mu: float, kappa: float) -> float:
    """Lateral stretch t with P_22(stretch, t) = 0 (traction-free lateral faces)."""
    return brentq(lambda t: neo_hookean_piola(stretch, t, mu, kappa)[1], 0.3, 2.0, xtol=1e-15,
                  rtol=1e-15)


def _radial_stretch(P, lt, mu, kappa):
    """Solve P_11(l_r, l_t) = P for l_r (vectorized Newton, complex-step derivative)."""
    lr = np.ones_like(lt)
    for _ in range(60):
        h = 1e-30
        f = neo_hookean_piola(lr + 1j * h, lt, mu, kappa)[0]
        step = (f.real - P) / (f.imag / h)
        lr = lr - step
        if np.max(np.abs(step)) < 1e-14:
            break
    return lr


def thick_sphere(inner: float, outer: float, push: float, mu: float, kappa: float) -> dict:
    """Shell inner <= R <= outer, r(inner) = inner + push, P_rR(outer) = 0. Returns
    {"u_outer": radial displacement of the outer surface (mm), "P_inner": P_rR at the inner
    surface (kPa)}; kappa = inf gives the incompressible closed form."""
    if not np.isfinite(kappa):
        return {"u_outer": incompressible_sphere_u(outer, inner, push), "P_inner": None}

    def rhs(R, y):
        r, P = y
        lt = r / R
        lr = _radial_stretch(P, lt, mu, kappa)
        P1, P2 = neo_hookean_piola(lr, lt, mu, kappa)
        return np.vstack([lr, 2.0 * (P2 - P1) / R])

    R = np.linspace(inner, outer, 400)
    r0 = R + push * (inner / R) ** 2
    sol = solve_bvp(rhs, lambda a, b: np.array([a[0] - inner - push, b[1]]), R,
                    np.vstack([r0, np.zeros_like(R)]), tol=1e-10, max_nodes=200000)
    if not sol.success:
        raise RuntimeError(f"thick-sphere ODE: {sol.message}")
    return {"u_outer": float(sol.sol(outer)[0] - outer), "P_inner": float(sol.sol(inner)[1])}


def incompressible_sphere_u(R, inner: float, push: float) -> float:
    """Radial displacement at reference radius R of the incompressible shell (mm)."""
    a = inner + push
    return float((R ** 3 + a ** 3 - inner ** 3) ** (1.0 / 3.0) - R)
