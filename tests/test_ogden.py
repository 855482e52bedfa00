"""The Ogden law (Abaqus' convention) against answers written here from its formula, not from the
code: the closed-form Cauchy stresses of uniaxial stretch and of simple shear (principal
stretches by hand), Ogden with alpha = 2 against the Neo-Hookean law's own code, alpha = [2, -2]
against Mooney-Rivlin's, the tangent against central differences of the stress at random F and
at equal stretches (rest, uniaxial, equibiaxial), the small-strain limit (linear elasticity with
mu0 = sum mu_i, kappa = k), its case-file table and its stability checks, ADMM and the
reference (quadrature-point Functions, P1 displacement and P2/P1 mixed) on the stretched block
against the closed-form uniaxial answer, the reference's exported tangent against differences
of its residual, and ADMM + polish against the reference on the phantom, under a rigid sphere
and in plane strain. Units: mm, kPa, mN."""
import math

import numpy as np
import pytest
from scipy.optimize import brentq

from tissue_reference.errors import CaseError
from tissue_reference.model.case import Material
from tissue_reference.solvers.admm.mechanics import Law

MU, ALPHA, K = (1.2, 0.25, 0.03), (2.5, -2.0, 6.0), 40.0
OGDEN = Material("ogden", ogden_mu=MU, ogden_alpha=ALPHA, k=K)


def law(material=OGDEN, d=3):
    return Law(material, d)


def piola(F, material=OGDEN):
    return law(material, F.shape[0]).stress((F - np.eye(F.shape[0]))[None])[0][0]


def cauchy(F, material=OGDEN):
    return piola(F, material) @ F.T / np.linalg.det(F)


def random_F(seed, n=20, scale=0.25, d=3):
    F = np.eye(d) + np.random.default_rng(seed).normal(scale=scale, size=(n, d, d))
    return F[np.linalg.det(F) > 0.3]


# ------------------------------------------------------------------ closed forms by hand
@pytest.mark.parametrize("lam", [0.7, 1.0, 1.3, 2.0])
def test_uniaxial_isochoric_stretch_meets_the_closed_form(lam):
    """F = diag(lam, lam^-1/2, lam^-1/2) (J = 1): the isochoric stretches are the stretches,
    sigma_aa = sum_i 2 mu_i / alpha_i lam_a^alpha_i - p with p = 0 (J = 1, G = 0), so
    sigma_11 - sigma_22 = sum_i 2 mu_i / alpha_i (lam^alpha_i - lam^(-alpha_i / 2)) and
    sigma_11 + 2 sigma_22 = 0 (the isochoric stress is deviatoric)."""
    t = lam ** -0.5
    s = cauchy(np.diag([lam, t, t]))
    diff = sum(2 * m / a * (lam ** a - lam ** (-a / 2)) for m, a in zip(MU, ALPHA))
    scale = max(1.0, abs(diff))
    assert s[0, 0] - s[1, 1] == pytest.approx(diff, abs=1e-12 * scale)
    assert s[0, 0] + 2 * s[1, 1] == pytest.approx(0.0, abs=1e-12 * scale)
    assert s[1, 1] == pytest.approx(s[2, 2], abs=1e-12 * scale)
    assert np.abs(s - np.diag(np.diag(s))).max() < 1e-12 * scale


def test_stretched_with_volume_change_meets_the_closed_form():
    """F = diag(l1, l2, l3), J != 1: sigma_aa = 1/J sum_i 2 mu_i / alpha_i (lb_a^alpha_i - 1/3
    sum_b lb_b^alpha_i) + k (J - 1), lb = J^(-1/3) l (the Kirchhoff stress of each term, plus the
    pressure of k/2 (J - 1)^2)."""
    ls = np.array([1.3, 0.85, 0.95])
    J = ls.prod()
    lb = J ** (-1 / 3) * ls
    expected = np.zeros(3)
    for m, a in zip(MU, ALPHA):
        expected += 2 * m / a * (lb ** a - (lb ** a).sum() / 3)
    expected = expected / J + K * (J - 1)
    s = cauchy(np.diag(ls))
    np.testing.assert_allclose(np.diag(s), expected, rtol=0, atol=1e-12 * K)


@pytest.mark.parametrize("g", [0.1, 0.4, 1.0])
def test_simple_shear_meets_the_closed_form(g):
    """Simple shear F = I + g e1 e2 (J = 1): principal stretches l = g/2 + sqrt(1 + g^2/4), 1/l,
    1; b = F F^T has its principal directions at angle theta, tan 2 theta = 2 / g, so sigma =
    sum_a s_a n_a n_a with s_a = sum_i 2 mu_i / alpha_i (l_a^alpha_i - 1/3 sum_b l_b^alpha_i):
    sigma_12 = (s_1 - s_2) sin(theta) cos(theta) = (s_1 - s_2) / 2 sin 2 theta."""
    F = np.eye(3)
    F[0, 1] = g
    lam = g / 2 + math.sqrt(1 + g * g / 4)
    ls = (lam, 1 / lam, 1.0)
    s = [sum(2 * m / a * (la ** a - sum(lb ** a for lb in ls) / 3) for m, a in zip(MU, ALPHA))
         for la in ls]
    theta = 0.5 * math.atan2(2.0, g)
    sig = cauchy(F)
    assert sig[0, 1] == pytest.approx((s[0] - s[1]) / 2 * math.sin(2 * theta), rel=1e-11)
    # normal stresses: s_1 cos^2 + s_2 sin^2, s_1 sin^2 + s_2 cos^2, s_3
    c2, s2 = math.cos(theta) ** 2, math.sin(theta) ** 2
    np.testing.assert_allclose([sig[0, 0], sig[1, 1], sig[2, 2]],
                               [s[0] * c2 + s[1] * s2, s[0] * s2 + s[1] * c2, s[2]],
                               rtol=0, atol=1e-12 * max(map(abs, s)))


# ------------------------------------------------------------------ against other laws' code
def _gradients():
    Fs = list(random_F(7))
    Fs += [np.eye(3), np.diag([1.3, 1 / math.sqrt(1.3), 1 / math.sqrt(1.3)]),
           np.diag([1.2, 1.2, 0.8]), np.diag([0.9, 1.1, 1.1])]
    return np.array(Fs)


@pytest.mark.parametrize("d", [2, 3])
def test_alpha_two_is_the_neo_hookean_law(d):
    """mu = [mu0], alpha = [2]: sum lb^2 - 3 = Ibar1 - 3, so psi = mu0/2 (Ibar1 - 3) + k/2 (J -
    1)^2, the Neo-Hookean law of E and nu from mu0 and k, whose closed-form code is separate."""
    mu0, k = 2.0, 30.0
    og = Law(Material("ogden", ogden_mu=(mu0,), ogden_alpha=(2.0,), k=k), d)
    E = 9 * k * mu0 / (3 * k + mu0)
    nh = Law(Material("neo-hookean", E=E, nu=(3 * k - 2 * mu0) / (2 * (3 * k + mu0))), d)
    H = _gradients()[:, :d, :d] - np.eye(d)
    a, b = og.evaluate(H), nh.evaluate(H)
    np.testing.assert_allclose(a.psi, b.psi, rtol=0, atol=1e-10)
    np.testing.assert_allclose(a.P, b.P, rtol=0, atol=1e-10)
    np.testing.assert_allclose(a.A, b.A, rtol=0, atol=1e-10)


def test_alpha_two_and_minus_two_is_the_mooney_rivlin_law():
    """alpha = [2, -2]: sum lb^-2 = Ibar2 (lb1 lb2 lb3 = 1), so mu = [2 c1, 2 c2] is
    c1 (Ibar1 - 3) + c2 (Ibar2 - 3): Mooney-Rivlin's invariant code."""
    c1, c2, k = 1.0, 0.4, 30.0
    og = Law(Material("ogden", ogden_mu=(2 * c1, 2 * c2), ogden_alpha=(2.0, -2.0), k=k), 3)
    mr = Law(Material("mooney-rivlin", c1=c1, c2=c2, k=k), 3)
    H = _gradients() - np.eye(3)
    a, b = og.evaluate(H), mr.evaluate(H)
    for x, y in ((a.psi, b.psi), (a.P, b.P), (a.A, b.A)):
        np.testing.assert_allclose(x, y, rtol=0, atol=1e-10 * np.abs(y).max())


# ------------------------------------------------------------------ tangent, small strain
@pytest.mark.parametrize("d", [2, 3])
def test_tangent_is_the_derivative_of_the_stress_also_at_equal_stretches(d):
    """A against central differences of P (and P against those of psi) at random F and where
    two or three principal stretches coincide: rest, uniaxial, equibiaxial."""
    Fs = list(random_F(11, n=6, d=d))
    Fs += [np.eye(d), np.diag([1.25, 0.9, 0.9][:d]), np.diag([1.1, 1.1, 0.8][:d])]
    if d == 3:
        Fs.append(np.diag([1.2, 1 / math.sqrt(1.2), 1 / math.sqrt(1.2)]))
    lw = law(d=d)
    h = 1e-6
    for F in Fs:
        H = (F - np.eye(d))[None]
        v = lw.evaluate(H)
        assert np.all(np.isfinite(v.A))
        fdA = np.zeros((d * d, d * d))
        fdP = np.zeros(d * d)
        for k in range(d * d):
            dH = np.zeros(d * d)
            dH[k] = h
            dH = dH.reshape(1, d, d)
            fdA[:, k] = ((lw.stress(H + dH)[0] - lw.stress(H - dH)[0]) / (2 * h)).reshape(-1)
            fdP[k] = (lw.psi_J(H + dH)[0][0] - lw.psi_J(H - dH)[0][0]) / (2 * h)
        np.testing.assert_allclose(v.A[0], fdA, rtol=0, atol=1e-7 * np.abs(fdA).max())
        np.testing.assert_allclose(v.A[0], v.A[0].T, rtol=0, atol=1e-12 * np.abs(fdA).max())
        np.testing.assert_allclose(v.P[0].reshape(-1), fdP, rtol=0,
                                   atol=1e-7 * max(1.0, np.abs(fdP).max()))


def test_small_strain_limit_is_linear_elasticity():
    """At F = I + t H: P / t -> 2 mu0 dev sym H + k tr H I with mu0 = sum mu_i; the tangent at
    rest is exactly linear elasticity's (no eigenvalue gap there)."""
    mu0 = sum(MU)
    H = np.array([[0.1, 0.2, -0.1], [0.05, -0.05, 0.15], [-0.1, 0.1, 0.05]])
    eps = (H + H.T) / 2
    expected = 2 * mu0 * (eps - np.trace(eps) / 3 * np.eye(3)) + K * np.trace(eps) * np.eye(3)
    t = 1e-7
    got = piola(np.eye(3) + t * H) / t
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-5 * np.abs(expected).max())
    A0 = law().tangent(np.zeros((1, 3, 3)))[0]
    np.testing.assert_allclose((A0 @ H.reshape(-1)).reshape(3, 3), expected, rtol=0,
                               atol=1e-12 * np.abs(expected).max())
    assert OGDEN.mu == pytest.approx(mu0) and OGDEN.kappa == pytest.approx(K)


# ------------------------------------------------------------------ the material, the case file
def test_stability_checks_refuse_by_name():
    with pytest.raises(CaseError, match="one nonzero length"):
        Material("ogden", ogden_mu=(1.0, 0.5), ogden_alpha=(2.0,), k=10.0)
    with pytest.raises(CaseError, match="one nonzero length"):
        Material("ogden", ogden_mu=(), ogden_alpha=(), k=10.0)
    with pytest.raises(CaseError, match="term\\(s\\) 2 unstable.*mu_i > 0"):
        Material("ogden", ogden_mu=(1.0, -0.5), ogden_alpha=(2.0, -2.0), k=10.0)
    with pytest.raises(CaseError, match="alpha_i != 0"):
        Material("ogden", ogden_mu=(1.0,), ogden_alpha=(0.0,), k=10.0)
    with pytest.raises(CaseError, match="bulk modulus k must be > 0"):
        Material("ogden", ogden_mu=(1.0,), ogden_alpha=(2.0,), k=0.0)
    with pytest.raises(CaseError, match="needs mu, alpha, k"):
        Material("ogden", ogden_mu=(1.0,), k=10.0)
    with pytest.raises(CaseError, match="belong to other laws"):
        Material("neo-hookean", E=6.0, nu=0.45, ogden_mu=(1.0,))
    with pytest.raises(CaseError, match="list of finite numbers"):
        Material("ogden", ogden_mu=(1.0, math.inf), ogden_alpha=(2.0, 3.0), k=10.0)
    # a negative exponent with a positive mu_i is a stable term (Mooney-Rivlin's c2 at -2)
    Material("ogden", ogden_mu=(1.0, 0.5), ogden_alpha=(2.0, -2.0), k=10.0)


def test_case_file_table_and_scaling(tmp_path):
    from tissue_reference.model.case import load_case
    from tissue_reference.model.results import material_json

    text = ('name = "og"\n[mesh]\nbuiltin = "box"\nsize = 5.0\n[material]\n'
            'model = "ogden"\nmu = [1.5, 0.25]\nalpha = [4.0, -2.0]\nk = 30.0\n'
            'volumetric = "log"\n[[boundary]]\nregion = "xmin"\ntype = "fixed"\n')
    (tmp_path / "og.toml").write_text(text)
    case = load_case(tmp_path / "og.toml")
    m = case.material
    mu0, k = 1.75, 30.0
    assert (m.ogden_mu, m.ogden_alpha, m.volumetric) == ((1.5, 0.25), (4.0, -2.0), "log")
    assert m.E == pytest.approx(9 * k * mu0 / (3 * k + mu0))
    assert m.nu == pytest.approx((3 * k - 2 * mu0) / (2 * (3 * k + mu0)))
    js = material_json(m)
    assert js["coefficients_kPa"] == {"mu_1": 1.5, "mu_2": 0.25, "k": 30.0}
    assert js["alpha"] == [4.0, -2.0]
    stiffer = case.with_material(E=2 * m.E).material
    assert (stiffer.ogden_mu, stiffer.ogden_alpha, stiffer.k) == ((3.0, 0.5), (4.0, -2.0), 60.0)
    for old, new, words in (("mu = [1.5, 0.25]", "mu = [1.5, -0.25]", "term(s) 2 unstable"),
                            ("alpha = [4.0, -2.0]", "alpha = [4.0]", "one nonzero length"),
                            ("k = 30.0\n", "k = 30.0\nE = 6.0\n", "E follows from them")):
        (tmp_path / "bad.toml").write_text(text.replace(old, new))
        with pytest.raises(CaseError) as info:
            load_case(tmp_path / "bad.toml")
        assert words in str(info.value) and "bad.toml" in str(info.value)
    other = case.with_law("ogden", {"mu": [2.0], "alpha": [3.0], "k": 20.0})
    assert other.material.ogden_mu == (2.0,) and other.material.volumetric == "log"
    with pytest.raises(CaseError, match="missing: alpha, k"):
        case.with_law("ogden", {"mu": [2.0]})


def test_material_option_takes_lists():
    from tissue_reference.tissue.common import material_spec

    assert material_spec("ogden:mu=1.5/0.2,alpha=4/-2,k=30") == \
        ("ogden", {"mu": [1.5, 0.2], "alpha": [4.0, -2.0], "k": 30.0})


# ------------------------------------------------------------------ ADMM
def test_admm_stretches_the_block_to_the_closed_form_uniaxial_answer():
    """The 10 mm block stretched 20 % between sliding faces (homogeneous answer, in the P1
    space): the lateral stretch t is the root of the closed-form lateral Cauchy stress
    s_2 = 1/J sum_i 2 mu_i / alpha_i (lb_2^alpha_i - 1/3 sum lb^alpha_i) + k (J - 1)."""
    from test_laws import _stretched_block

    from tissue_reference.solvers import admm

    def lateral(t):
        ls = np.array([1.2, t, t])
        J = ls.prod()
        lb = J ** (-1 / 3) * ls
        return sum(2 * m / a * (lb[1] ** a - (lb ** a).sum() / 3) for m, a in zip(MU, ALPHA)) \
            / J + K * (J - 1)

    t = brentq(lateral, 0.5, 1.2, xtol=1e-14)
    res = admm.solve(_stretched_block(OGDEN))
    assert res.converged
    np.testing.assert_allclose(res.probes["corner"][1:], 10.0 * (t - 1.0), rtol=0, atol=1e-9)


# ------------------------------------------------------------------ the reference
def _lateral_stress(t, stretch=1.2, k=K, volumetric="quadratic"):
    """The closed-form lateral Cauchy stress of diag(stretch, t, t) (the isochoric Kirchhoff
    stress of each term over J, plus the pressure dpsi_vol/dJ of k/2 G(J)^2)."""
    ls = np.array([stretch, t, t])
    J = ls.prod()
    lb = J ** (-1 / 3) * ls
    iso = sum(2 * m / a * (lb[1] ** a - (lb ** a).sum() / 3) for m, a in zip(MU, ALPHA)) / J
    return iso + (k * (J - 1) if volumetric == "quadratic" else k * math.log(J) / J)


def _axial_piola(t, stretch=1.2, k=K, volumetric="quadratic"):
    """P_11 = J sigma_11 / stretch of diag(stretch, t, t), closed form."""
    ls = np.array([stretch, t, t])
    J = ls.prod()
    lb = J ** (-1 / 3) * ls
    iso = sum(2 * m / a * (lb[0] ** a - (lb ** a).sum() / 3) for m, a in zip(MU, ALPHA)) / J
    vol = k * (J - 1) if volumetric == "quadratic" else k * math.log(J) / J
    return J * (iso + vol) / stretch


@pytest.mark.parametrize("k,volumetric", [(K, "quadratic"), (1500.0, "log")])
def test_reference_stretches_the_block_to_the_closed_form_uniaxial_answer(k, volumetric):
    """The reference's block stretched 20 %: P1 displacement at k = 40 kPa, and the mixed u-p
    formulation (P2/P1, picked for nu = 0.4995) at k = 1500 kPa with G = ln J: the corner's
    lateral motion and the face force against the closed form's traction-free root."""
    from test_laws import _stretched_block

    from tissue_reference.fem_reference import solve

    material = Material("ogden", ogden_mu=MU, ogden_alpha=ALPHA, k=k, volumetric=volumetric)
    t = brentq(lambda s: _lateral_stress(s, k=k, volumetric=volumetric), 0.5, 1.2, xtol=1e-15)
    res = solve(_stretched_block(material))
    assert res.converged
    assert res.discretization["formulation"] == ("mixed" if material.nu >= 0.49
                                                 else "displacement")
    np.testing.assert_allclose(res.probes["corner"][1:], 10.0 * (t - 1.0), rtol=0, atol=1e-9)
    force = _axial_piola(t, k=k, volumetric=volumetric) * 100.0
    assert res.reactions["xmax"][0] == pytest.approx(force, rel=1e-8)


def test_reference_tangent_is_the_derivative_of_its_residual():
    """The reference's exported tangent (outputs read the quadrature Functions after refreshing
    them) against central differences of its exported residual at a stretched, sheared state."""
    from test_laws import _stretched_block

    from tissue_reference.fem_reference.outputs_tangent import internal_forces, tangent
    from tissue_reference.fem_reference.solver import ReferenceSolver

    case = _stretched_block(OGDEN)
    solver = ReferenceSolver(case, degree=1, formulation="displacement")
    X = case.mesh.points
    u = 0.1 * X @ np.array([[0.2, 0.05, 0.0], [0.1, -0.05, 0.02], [0.0, 0.03, -0.04]])
    K_ = tangent(solver, u).K
    du = np.random.default_rng(5).normal(size=u.shape)
    h = 1e-6
    fd = (internal_forces(solver, u + h * du) - internal_forces(solver, u - h * du)) / (2 * h)
    got = K_ @ du.reshape(-1)
    np.testing.assert_allclose(got, fd, rtol=0, atol=1e-6 * np.abs(fd).max())
    solver.close()


def test_admm_with_its_polish_equals_the_reference_on_the_phantom():
    """A1 pushed 2 mm on the coarse phantom: ADMM + Newton polish (numpy law) against the
    reference's P1 displacement solve (quadrature Functions of the same spectral law, PETSc
    Newton): 1e-8 mm."""
    import dataclasses

    from tissue_reference.fem_reference import solve
    from tissue_reference.meshes.builders import build
    from tissue_reference.model.case import load_case
    from tissue_reference.model.case_file import case_path
    from tissue_reference.solvers import admm

    phantom = load_case(case_path("phantom"), mesh=build("phantom", 10.0))
    case = dataclasses.replace(phantom, material=Material("ogden", ogden_mu=(0.7, 0.3),
                                                          ogden_alpha=(4.0, -2.0), k=20.0))
    ref = solve(case, degree=1, formulation="displacement", pushes={"A1": 2.0})
    res = admm.solve(case, pushes={"A1": 2.0})
    assert ref.converged and res.converged
    assert np.abs(np.asarray(res.u) - np.asarray(ref.u)).max() < 1e-8


def test_admm_with_its_polish_equals_the_reference_under_a_rigid_sphere():
    """A sphere pressed 1 mm into the quarter block (cells of 0.5 mm under the tip): the
    reference's Newton with its energy line search (the total energy reads the refreshed
    quadrature Functions) and ADMM + polish reach the same P1 answer, 1e-8 mm, the same force
    and strain energy."""
    from test_admm_contact import TIGHT, same_contact, tip_case

    import tissue_reference.fem_reference as fr
    from tissue_reference.meshes.builders import indent_block
    from tissue_reference.solvers import admm

    case = tip_case(indent_block(0.5)).with_law("ogden", {"mu": [1.5, 0.5], "alpha": [4.0, -2.0],
                                                          "k": 20.0})
    ref = fr.solve(case, degree=1, pushes={"I": 1.0}, settings=TIGHT)
    res = admm.solve(case, pushes={"I": 1.0})
    assert ref.converged and res.converged and res.valid
    assert res.indenters["I"]["force"] > 0.5
    same_contact(res, ref)


def test_plane_strain_reference_equals_admm():
    """2D (plane strain, F33 = 1: the third stretch 1 in the spectral law) on the rectangle
    stretched and sheared by its right edge: the reference and ADMM + polish, 1e-8 mm."""
    from tissue_reference.fem_reference import solve
    from tissue_reference.meshes.builders import rectangle
    from tissue_reference.model.case import Boundary, Case
    from tissue_reference.solvers import admm

    case = Case(mesh=rectangle(2.0), material=OGDEN,
                boundaries=(Boundary("xmin", "fixed"),
                            Boundary("xmax", "displacement", value=[1.5, 0.8])))
    ref = solve(case, degree=1, formulation="displacement")
    res = admm.solve(case)
    assert ref.converged and res.converged
    assert np.abs(np.asarray(res.u) - np.asarray(ref.u)).max() < 1e-8
