"""Rigid indenters with contact (fem_reference/contact.py) against answers computed here
independently of the solver, on the quarter block ``indent-block`` (symmetry planes sliding,
bottom fixed, 240 mm deep, cells of h mm within 2.5 mm of the tip's axis):

- Hertz: a rigid sphere of radius R into a half-space, F = 4/3 E* sqrt(R) d^(3/2), contact
  radius a = sqrt(R d), E* = E / (1 - nu^2);
- a flat circular punch of radius A with its edge rounded by e: Sneddon's integrals for an
  axisymmetric frictionless indenter of profile f(r) (contact radius c):
  d = c int_0^c f'(r) / sqrt(c^2 - r^2) dr, F = 2 E* int_0^c r^2 f'(r) / sqrt(c^2 - r^2) dr,
  between Boussinesq's 2 (A - e) E* d and 2 A E* d (the flat face alone, the whole punch);
- a tied flat punch wider than a glued patch, pushed a little, against the glued patch;
- the penalty's effect: the force converges as O(1/beta) and the penetration falls as 1/beta.

Error budget of the half-space comparisons (linear-elastic material, nu = 0.45): the block's
bottom at depth D = 240 mm stiffens it by about a (1 + nu) (3 - 2 nu) / (pi (1 - nu^2) D)
(0.4 % at a = 1 mm); the contact's exact (finite-deformation) gap against Hertz's linearized one,
O((1 - 2 nu) a / R), about 0.1 %; the penalty (beta = 1e3) about -0.2 %; the rest is the mesh
(P2, h = 0.5 mm: 2 cells across the Hertz contact radius). Measured: Hertz +0.5 %, punch +1.0 %;
the tolerances are 2 % and 3 % (the punch's pressure is singular-like at its rounded edge).
Units: mm, kPa, mN.
"""
import itertools
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.optimize import brentq

import tissue_reference.fem_reference as fr
from tissue_reference.errors import CaseError
from tissue_reference.meshes.builders import indent_block
from tissue_reference.model.case import Actuator, Boundary, Case, Material

CASES = Path(__file__).resolve().parents[1] / "meshes" / "cases"

E, NU = 6.0, 0.45
E_STAR = E / (1 - NU ** 2)
DOWN = (0.0, 0.0, -1.0)
H = 0.5  # mm, cell size under the tip


@pytest.fixture(scope="module")
def block():
    return indent_block(H)


def quarter_case(mesh, actuator, model="linear-elastic"):
    return Case(mesh, Material(model, E, NU),
                boundaries=[Boundary("bottom", "fixed"),
                            Boundary("xsym", "sliding", normal=(1.0, 0.0, 0.0)),
                            Boundary("ysym", "sliding", normal=(0.0, 1.0, 0.0))],
                actuators=[actuator])


def sphere(R, **kw):
    return Actuator("I", "tip", DOWN, type="indenter", tip="sphere", radius=R,
                    point=(0.0, 0.0, 0.0), contact_region="top", **kw)


def indent(case, push, **kw):
    res = fr.solve(case, pushes={"I": push}, **kw)
    assert res.converged and res.valid
    return res, res.indenters["I"]


def sneddon_rounded_punch(A, e, d):
    """(F (mN), contact radius c (mm)) of a rigid flat punch of radius A whose edge is a quarter
    circle of radius e, pressed d mm into a half-space (Sneddon's integrals, r = c sin t)."""
    b = A - e

    def slope(r):
        x = max(r - b, 0.0)
        return x / math.sqrt(e * e - x * x)

    def integral(c, power):
        t0 = math.asin(b / c)
        return quad(lambda t: math.sin(t) ** power * slope(c * math.sin(t)), t0, math.pi / 2,
                    limit=200, epsabs=1e-13, epsrel=1e-10)[0]

    c = brentq(lambda c: c * integral(c, 0) - d, b * (1 + 1e-9), b + 0.9 * e, xtol=1e-14)
    return 2 * E_STAR * c * c * integral(c, 2), c


# --------------------------------------------------------------------------- half-space answers
@pytest.mark.slow
def test_sphere_into_a_half_space_gives_hertz_force_within_2_percent(block):
    R, d = 10.0, 0.1
    res, ind = indent(quarter_case(block, sphere(R)), d, degree=2)
    F_hertz = 4.0 / 3.0 * E_STAR * math.sqrt(R) * d ** 1.5
    F = 4 * ind["force"]  # a quarter of the body
    print(f"\nHertz: F = {F:.5f} mN vs {F_hertz:.5f} mN ({100 * (F / F_hertz - 1):+.2f} %), "
          f"contact area {4 * ind['contact_area']:.3f} vs {math.pi * R * d:.3f} mm^2, "
          f"penetration {ind['max_penetration']:.2e} mm, {res.iterations} Newton iterations")
    assert abs(F / F_hertz - 1) < 0.02
    # the contact area is the lumped area of the surface nodes in contact: radius within a cell
    a_fe = math.sqrt(4 * ind["contact_area"] / math.pi)
    assert abs(a_fe - math.sqrt(R * d)) < H
    # the actuator force is the reaction: the fixed bottom, the one support prescribing the
    # push direction (the symmetry planes slide along it), balances the tip
    assert abs(res.reactions["bottom"][2] + ind["force_vector"][2]) < 1e-6 * ind["force"]
    assert 0 < ind["max_penetration"] < 1e-2 * d


@pytest.mark.slow
def test_rounded_flat_punch_gives_sneddons_force_within_3_percent(block):
    A, e, d = 1.5, 0.3, 0.05
    punch = Actuator("I", "tip", DOWN, type="indenter", tip="punch", radius=A, edge_radius=e,
                     point=(0.0, 0.0, 0.0), contact_region="top")
    _, ind = indent(quarter_case(block, punch), d, degree=2)
    F_exact, c = sneddon_rounded_punch(A, e, d)
    F = 4 * ind["force"]
    print(f"\nrounded punch: F = {F:.5f} mN vs Sneddon {F_exact:.5f} mN "
          f"({100 * (F / F_exact - 1):+.2f} %, contact radius {c:.3f} mm); Boussinesq "
          f"{2 * (A - e) * E_STAR * d:.5f} (flat face) .. {2 * A * E_STAR * d:.5f} mN (radius A)")
    assert 2 * (A - e) * E_STAR * d < F_exact < 2 * A * E_STAR * d
    assert abs(F / F_exact - 1) < 0.03


def test_force_converges_as_the_penalty_grows_and_penetration_falls_as_its_inverse(block):
    """P1, Hertz geometry: |F(beta) - F(1e4)| falls about tenfold per decade of beta, and so does
    the penetration (the method's error, p h_c / (beta E) plus half the smoothing width)."""
    R, d = 10.0, 0.1
    case = quarter_case(block, sphere(R))
    out = {b: indent(case, d, degree=1, contact_penalty=b)[1] for b in (1e2, 1e3, 1e4)}
    F = {b: v["force"] for b, v in out.items()}
    pen = {b: v["max_penetration"] for b, v in out.items()}
    print("\n" + "\n".join(f"beta {b:g}: F = {4 * F[b]:.6f} mN, penetration {pen[b]:.3e} mm"
                           for b in out))
    e2, e3 = abs(F[1e2] - F[1e4]), abs(F[1e3] - F[1e4])
    assert e3 < 0.2 * e2 and e2 < 0.05 * F[1e4]
    assert 5 < pen[1e2] / pen[1e3] < 20 and 5 < pen[1e3] / pen[1e4] < 20


# --------------------------------------------------------------------------- tied = glued
def test_small_push_of_a_tied_punch_matches_the_glued_patch(block):
    """A tied flat punch wider than the patch ``tip`` (its contact surface) pushed 0.05 mm moves
    the patch like a glued plate: the same displacements and force, to the penalty's
    penetration (beta = 1e4 here: 0.1 % of the push); frictionless, the patch slides."""
    d = 0.05
    glued = quarter_case(block, Actuator("I", "tip", DOWN), model="neo-hookean")

    def punch(contact):
        return quarter_case(block, Actuator("I", "tip", DOWN, type="indenter", tip="punch",
                                            radius=2.5, edge_radius=0.25, contact=contact),
                            model="neo-hookean")

    rg = fr.solve(glued, pushes={"I": d})
    rt, ind = indent(punch("tied"), d, contact_penalty=1e4)
    rf, _ = indent(punch("frictionless"), d, contact_penalty=1e4)
    diff = np.abs(rg.u - rt.u).max()
    patch = block.region_vertices("tip")
    slide = {name: np.abs(r.u[patch, :2]).max() for name, r in (("tied", rt), ("free", rf))}
    print(f"\ntied punch vs glued patch: max |u difference| {diff:.2e} mm "
          f"({100 * diff / d:.2f} % of the push); force {ind['force']:.5f} vs "
          f"{rg.reactions['tip'] @ np.asarray(DOWN):.5f} mN; largest sideways displacement "
          f"on the patch: tied {slide['tied']:.1e}, frictionless {slide['free']:.1e} mm")
    assert diff < 0.005 * d
    # the force along the push (the patch's sideways reaction also carries its share of the
    # symmetry planes' support, which the punch leaves to them)
    assert abs(ind["force"] / (rg.reactions["tip"] @ np.asarray(DOWN)) - 1) < 0.005
    assert slide["tied"] < 0.1 * slide["free"]


# --------------------------------------------------------------------------- the Case
def test_with_pushes_records_an_indenter_position_and_adds_no_condition(block):
    case = quarter_case(block, sphere(10.0))
    pushed = case.with_pushes({"I": 0.3})
    assert pushed.boundaries == case.boundaries
    assert pushed.actuator("I").push == 0.3 and case.actuator("I").push == 0.0
    patch = quarter_case(block, Actuator("I", "tip", DOWN)).with_pushes({"I": 0.3})
    assert patch.boundaries[-1] == Boundary("tip", "displacement", value=(0.0, 0.0, -0.3))


def test_warm_start_moves_the_tip_from_where_the_initial_state_left_it(block):
    case = quarter_case(block, sphere(10.0))
    first, _ = indent(case, 0.05)
    warm, ind = indent(case, 0.1, initial=first)
    cold, ind0 = indent(case, 0.1)
    assert ind["push"] == 0.1 and abs(ind["force"] / ind0["force"] - 1) < 1e-6
    assert np.abs(warm.u - cold.u).max() < 1e-6


@pytest.mark.parametrize("degree", [1, 2])
def test_a_retracting_tip_releases_the_skin_to_rest(block, degree):
    """Pressed 1.5 mm, then pulled back to 0.5 mm above its start from that state: the tip has
    left the skin, which (no other load) returns to rest, with no force and no contact."""
    case = quarter_case(block, sphere(2.0), model="neo-hookean")
    pressed = fr.solve(case, pushes={"I": 1.5}, degree=degree)
    assert pressed.indenters["I"]["contact_area"] > 0 and pressed.indenters["I"]["force"] > 0
    back = fr.solve(case, pushes={"I": -0.5}, degree=degree, initial=pressed)
    ind = back.indenters["I"]
    assert back.converged and back.valid
    assert np.abs(back.u).max() < 1e-9
    assert ind["push"] == pytest.approx(-0.5, abs=1e-12)
    assert ind["force"] == 0.0 and ind["contact_area"] == 0.0


@pytest.mark.parametrize("kw,match", [
    ({"tip": "cone", "radius": 1.0}, "tip = one of"),
    ({"tip": "sphere", "radius": -1.0}, "radius > 0"),
    ({"tip": "punch", "radius": 1.0, "edge_radius": 1.0}, "0 < edge_radius < radius"),
    ({"tip": "sphere", "radius": 1.0, "edge_radius": 0.5}, "edge_radius only for tip = 'punch'"),
    ({"tip": "sphere", "radius": 1.0, "contact": "glued"}, "contact must be one of"),
    ({"tip": "sphere", "radius": 1.0, "contact": "tied"}, "contact = 'tied' needs tip = 'punch'"),
    ({"tip": "sphere", "radius": 1.0, "point": (0.0, 1.0)}, "point must be a list of 3"),
])
def test_bad_indenters_are_refused_naming_the_actuator(kw, match):
    with pytest.raises(CaseError, match=match) as err:
        Actuator("A1", "tip", DOWN, type="indenter", **kw)
    assert "actuator 'A1'" in str(err.value)


def test_a_patch_takes_no_tip_and_an_indenter_touches_facet_regions_only(block):
    with pytest.raises(CaseError, match="radius only for an indenter"):
        Actuator("A1", "tip", DOWN, radius=1.0)
    with pytest.raises(CaseError, match="'tissue' is not one"):
        quarter_case(block, sphere(10.0).__class__("I", "tissue", DOWN, type="indenter",
                                                   tip="sphere", radius=1.0))


def test_a_failed_push_keeps_the_last_converged_state_with_its_tip(block):
    """When Newton gives up, the last converged state is reported with the tip where that state
    was solved, converged as an answer: its push and force are those of a solve to that push,
    not of the failed try."""
    from tissue_reference.errors import ConvergenceError

    case = quarter_case(block, sphere(10.0))
    # few Newton iterations and few cut-backs: the first load steps converge (to their loose
    # tolerance, after the tip's predictor), the last fails (6 took 7, past 6 while converging)
    tight = fr.NewtonSettings(max_iterations=3, min_fraction=0.1, max_step_mm=0.1)
    with pytest.raises(ConvergenceError) as info:
        fr.solve(case, pushes={"I": 0.5}, settings=tight)
    last = info.value.last_converged
    reached = last.indenters["I"]["push"]
    assert reached == pytest.approx(info.value.load_fraction * 0.5, abs=1e-12)
    assert 0.0 < reached < 0.5
    _, again = indent(case, reached)
    # the reported state is converged to the final step's tolerances, as the solve to that push
    # is (as it was left, to the intermediate steps' tolerance, its force was off; the tip of
    # the failed try, pushed further, would give more force)
    assert last.indenters["I"]["force"] == pytest.approx(again["force"], rel=1e-6)


def test_newton_without_the_tips_curvature_reaches_the_same_answer(block):
    """Leaving the tip's curvature out of Newton's matrix (far from the answer, after a halved
    correction, or neither: the exact tangent throughout), the tips' first step length and
    line-search trials bent along the tip change the path, not the answer: a sphere pressed into the block gives the same force and
    field every way, and the exported tangent stays exact (its J_s is checked against finite
    differences in tests/test_indenter_jacobian.py)."""
    case = quarter_case(block, sphere(2.0), model="neo-hookean")
    out = {}
    for key, st in {"default": fr.NewtonSettings(),
                    "halved": fr.NewtonSettings(contact_curvature_below=math.inf),
                    "exact": fr.NewtonSettings(contact_curvature_below=math.inf,
                                               contact_curvature_after_halving="keep"),
                    "long": fr.NewtonSettings(tip_step=0.2),
                    # line-search trials also bent along the tip
                    "bent": fr.NewtonSettings(follow_tips=True),
                    # the same answer converged a thousand times tighter
                    "tight": fr.NewtonSettings(rtol=1e-13, atol=1e-14, atol_mm=1e-13)}.items():
        res = fr.solve(case, pushes={"I": 1.5}, settings=st)
        assert res.converged and res.valid
        out[key] = res
    a = out.pop("tight")
    for key, b in out.items():
        # the final load step's residual, down by rtol = 1e-10, leaves the contact force (a
        # penalty stiffness times the skin's penetration) to about 1e-8 of itself
        assert b.indenters["I"]["force"] == pytest.approx(
            a.indenters["I"]["force"], rel=1e-7), key
        assert np.abs(a.u - b.u).max() < 1e-8, key
    # each takes another path: the residual norms of their Newton iterates part (two paths
    # may take as many iterations: default and halved both 21 in 8 load steps, their residuals
    # apart by 0.6 % from the 17th iterate); round-off alone moves them by far less than 1e-3
    traces = {k: np.asarray(r.history["iterate_residual"]) for k, r in out.items()}
    for (k1, t1), (k2, t2) in itertools.combinations(traces.items(), 2):
        assert len(t1) != len(t2) or not np.allclose(t1, t2, rtol=1e-3, atol=1e-9), (k1, k2)
    with pytest.raises(ValueError, match="contact_curvature_after_halving"):
        fr.NewtonSettings(contact_curvature_after_halving="sometimes")
    for bad in (0.0, -1.0, float("nan"), "1e-4"):
        with pytest.raises(ValueError, match="contact_curvature_below"):
            fr.NewtonSettings(contact_curvature_below=bad)
    for bad in (0.0, float("inf")):
        with pytest.raises(ValueError, match="tip_step"):
            fr.NewtonSettings(tip_step=bad)


@pytest.mark.slow
def test_the_shifted_tangent_and_the_fitted_step_lengths_reach_the_same_answer():
    """The Levenberg-Marquardt shift of an indefinite tangent and the step lengths from the
    energy's quadratic fit change Newton's path, not the answer: all four tips pushed 5 mm into
    the quarter indenter phantom (P2, nodal contact rule, 2.7k cells), where the tissue crushed
    under the tips makes the tangent indefinite on the way (the shift is used), give the same
    forces and field as plain halving with the exact tangent."""

    from tissue_reference.meshes.builders import build
    from tissue_reference.model.case import load_case

    case = load_case(CASES / "phantom-indenter-quarter.toml",
                     mesh=build("phantom-quarter", 8.0, site_size=3.2))
    pushes = {a.name: 5.0 for a in case.actuators}
    # the exact tangent from each load step's start and tip steps of a whole radius, each
    # converged to 1e-6, where the crushed tissue makes it indefinite (Newton's matrix without
    # the tips' curvature far from the answer, the default, avoids that here, and so do the
    # default steps of 0.1 radius, each first correction tested on the energy)
    exact = {"contact_curvature_below": math.inf, "tip_step": 1.0, "intermediate_rtol": 1e-6}
    a = fr.solve(case, pushes=pushes, degree=2, contact_quadrature="nodal",
                 settings=fr.NewtonSettings(descent_shift=0.0, **exact))
    assert a.converged and a.valid
    assert a.extra["tangent_shifts"] == 0
    for st in (fr.NewtonSettings(**exact), fr.NewtonSettings(interpolate=True, **exact)):
        b = fr.solve(case, pushes=pushes, degree=2, contact_quadrature="nodal", settings=st)
        assert b.converged and b.valid
        assert b.extra["tangent_shifts"] > 0
        assert b.iterations != a.iterations  # another path
        for name in pushes:
            assert b.indenters[name]["force"] == pytest.approx(
                a.indenters[name]["force"], rel=1e-7)
        assert np.abs(a.u - b.u).max() < 1e-7
    for bad in (-1.0, float("nan")):
        with pytest.raises(ValueError, match="descent_shift"):
            fr.NewtonSettings(descent_shift=bad)


@pytest.mark.parametrize("package", ["mumps", "cholmod"])
def test_the_factorization_reports_the_tangents_negative_pivots(block, package):
    """The inertia the shift relies on: a tangent scaled by -1 after its Dirichlet rows are set
    has every free row negative; unscaled (at rest, positive definite) it has none. CHOLMOD
    refuses the indefinite one and hands it to MUMPS LDL^T, which counts them."""
    case = quarter_case(block, sphere(2.0), model="neo-hookean")
    s = fr.ReferenceSolver(case, degree=1, linear_solver="direct")
    s.linear.use_factor(package)
    bcs = [e[0] for e in s.boundary.dirichlet_bcs(case, 1.0, None)]
    s.newton.assemble_residual(bcs)
    s.newton.assemble_tangent(bcs)
    assert s.linear.solve(1e-8)
    assert s.linear.negative_pivots == 0
    s.newton.assemble_tangent(bcs)
    s.A.scale(-1.0)
    s.linear.refactor = True
    assert s.linear.solve(1e-8)
    assert s.linear.factor_package == "mumps"
    # the Dirichlet rows (E h on the diagonal) turn negative too: every row is
    assert s.linear.negative_pivots == s.A.getSize()[0]
