"""Answers that need no finite elements: the closed-form and semi-analytic values the
verification suite scores solvers against.

- ``neo_hookean_piola``: principal first Piola stresses of the toolkit's Neo-Hookean energy
  psi = mu/2 (J^(-2/3) I1 - 3) + kappa/2 (J - 1)^2 (seed 000 eq. 14) at stretches (l1, l2, l2);
- ``uniaxial_lateral_stretch``: the lateral stretch of a block stretched by ``stretch`` with
  traction-free lateral faces (a scalar root);
- ``thick_sphere``: the radial displacement of a thick spherical shell whose inner surface is
  pushed out radially, outer surface free: the radial equilibrium ODE
  dP_rR/dR + 2 (P_rR - P_tt)/R = 0 as a two-point boundary-value problem (scipy's solve_bvp);
  at nu = 0.5 the incompressible closed form r^3 = R^3 + a^3 - A^3;
- ``law_energy``, ``law_piola``, ``law_uniaxial_lateral_stretch``, ``law_thick_sphere``: the same
  for every strain-energy law of the toolkit (docs/laws.md), each energy written here in the
  principal stretches (l1, l2, l3) from its formula, the principal stresses its complex-step
  derivatives: the corotational law's tr U is l1 + l2 + l3, the invariants
  I1 = sum l_i^2, I2 = sum_(i<j) l_i^2 l_j^2, J = l1 l2 l3.
Units: mm, kPa.
"""
from __future__ import annotations

import numpy as np
from scipy.integrate import solve_bvp
from scipy.optimize import brentq

__all__ = ["incompressible_sphere_u", "law_energy", "law_piola", "law_thick_sphere",
           "law_uniaxial_lateral_stretch", "neo_hookean_piola", "thick_sphere",
           "uniaxial_lateral_stretch"]


def neo_hookean_piola(l1, l2, mu: float, kappa: float):
    """(P_11, P_22) at principal stretches (l1, l2, l2); works on complex and array input."""
    J = l1 * l2 * l2
    I1 = l1 * l1 + 2 * l2 * l2
    iso = mu * J ** (-2.0 / 3.0)
    vol = kappa * (J - 1) * J
    return iso * (l1 - I1 / (3 * l1)) + vol / l1, iso * (l2 - I1 / (3 * l2)) + vol / l2


def law_energy(material, l1, l2, l3):
    """psi (kPa) of ``material``'s law (a ``model.case.Material``) at principal stretches
    (l1, l2, l3), written from the law's formula (docs/laws.md); complex-safe."""
    model = material.model
    mu, lam, kappa = material.mu, material.lmbda, material.kappa
    J = l1 * l2 * l3
    I1 = l1 * l1 + l2 * l2 + l3 * l3
    if model == "linear-elastic":
        e = (l1 - 1, l2 - 1, l3 - 1)
        return mu * sum(x * x for x in e) + lam / 2 * sum(e) ** 2
    if model == "saint-venant-kirchhoff":
        e = ((l1 * l1 - 1) / 2, (l2 * l2 - 1) / 2, (l3 * l3 - 1) / 2)
        return lam / 2 * sum(e) ** 2 + mu * sum(x * x for x in e)
    if model == "stable-neo-hookean":
        lp = lam + mu
        return mu / 2 * (I1 - 3) + lp / 2 * (J - 1 - mu / lp) ** 2 - mu * mu / (2 * lp)
    if model == "corotational":
        a = l1 + l2 + l3
        return mu * (I1 - 2 * a + 3) + lam / 2 * (a - 3) ** 2
    I2 = l1 * l1 * l2 * l2 + l2 * l2 * l3 * l3 + l3 * l3 * l1 * l1
    x1 = J ** (-2.0 / 3.0) * I1 - 3
    G = J - 1 if material.volumetric == "quadratic" else np.log(J)
    c = material.coefficients
    if model == "neo-hookean":
        iso = mu / 2 * x1
    elif model == "mooney-rivlin":
        iso = c["c1"] * x1 + c["c2"] * (J ** (-4.0 / 3.0) * I2 - 3)
    elif model == "yeoh":
        iso = c["c1"] * x1 + c["c2"] * x1 ** 2 + c["c3"] * x1 ** 3
    elif model == "ogden":
        lb = [J ** (-1.0 / 3.0) * lam for lam in (l1, l2, l3)]
        iso = sum(2 * m / (a * a) * (sum(x ** a for x in lb) - 3)
                  for m, a in zip(material.ogden_mu, material.ogden_alpha))
    else:
        raise ValueError(f"no closed form for the law {model!r}")
    return iso + kappa / 2 * G ** 2


def law_piola(material, l1, l2):
    """(P_11, P_22) (kPa) of ``material``'s law at principal stretches (l1, l2, l2): complex-step
    derivatives of ``law_energy`` in l1 and in l2 alone (the third stretch held)."""
    h = 1e-30
    P1 = np.imag(law_energy(material, l1 + 1j * h, l2, l2)) / h
    P2 = np.imag(law_energy(material, l1, l2 + 1j * h, l2)) / h
    return P1, P2


def law_uniaxial_lateral_stretch(stretch: float, material) -> float:
    """``uniaxial_lateral_stretch`` for ``material``'s law."""
    return brentq(lambda t: law_piola(material, stretch, t)[1], 0.3, 2.0, xtol=1e-15,
                  rtol=1e-15)


def law_thick_sphere(inner: float, outer: float, push: float, material) -> dict:
    """``thick_sphere`` for ``material``'s law (nu = 0.5: the incompressible closed form, which
    holds for every incompressible law). RuntimeError where the boundary-value problem has no
    solution: St Venant-Kirchhoff at nu = 0.45 under the suite shell's inflation, where the radial
    compression the inner surface needs is more than the law carries (its radial stress has a
    least value, about -0.66 kPa at the hoop stretch 1.2, where its radial stiffness vanishes)."""
    if material.nu >= 0.5:
        return {"u_outer": incompressible_sphere_u(outer, inner, push), "P_inner": None}

    def piola(lr, lt):
        return law_piola(material, lr, lt)

    try:
        return _sphere_bvp(inner, outer, push, piola)
    except RuntimeError as exc:
        raise RuntimeError(f"no solution of the shell's radial equilibrium on the "
                           f"{material.model} law ({exc})") from None


def uniaxial_lateral_stretch(stretch: float, mu: float, kappa: float) -> float:
    """Lateral stretch t with P_22(stretch, t) = 0 (traction-free lateral faces)."""
    return brentq(lambda t: neo_hookean_piola(stretch, t, mu, kappa)[1], 0.3, 2.0, xtol=1e-15,
                  rtol=1e-15)


def _radial_stretch(P, lt, piola):
    """Solve P_11(l_r, l_t) = P for l_r (vectorized Newton; the slope by central differences,
    the root by the stress itself, so to round-off)."""
    lr = np.ones_like(lt)
    for _ in range(60):
        h = 1e-7
        f = piola(lr, lt)[0]
        slope = (piola(lr + h, lt)[0] - piola(lr - h, lt)[0]) / (2 * h)
        step = (f - P) / slope
        lr = lr - step
        if np.max(np.abs(step)) < 1e-14:
            break
    return lr


def thick_sphere(inner: float, outer: float, push: float, mu: float, kappa: float) -> dict:
    """Shell inner <= R <= outer, r(inner) = inner + push, P_rR(outer) = 0. Returns
    {"u_outer": radial displacement of the outer surface (mm), "P_inner": P_rR at the inner
    surface (kPa)}; kappa = inf gives the incompressible closed form.

    Parameters
    ----------
    inner, outer : float
        Inner and outer radii (mm).
    push : float
        Radial displacement of the inner surface (mm).
    mu : float
        Shear modulus (kPa).
    kappa : float
        Bulk modulus (kPa); math.inf: incompressible.

    Returns
    -------
    dict
        {"u_outer": mm, "P_inner": kPa}.
    """
    if not np.isfinite(kappa):
        return {"u_outer": incompressible_sphere_u(outer, inner, push), "P_inner": None}
    return _sphere_bvp(inner, outer, push, lambda lr, lt: neo_hookean_piola(lr, lt, mu, kappa))


def _sphere_bvp(inner, outer, push, piola) -> dict:
    """The shell's radial equilibrium as a boundary-value problem, principal stresses
    ``piola(l_r, l_t)`` -> (P_rR, P_tt) (``thick_sphere``)."""

    def rhs(R, y):
        r, P = y
        lt = r / R
        lr = _radial_stretch(P, lt, piola)
        P1, P2 = piola(lr, lt)
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
