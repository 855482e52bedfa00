"""Rigid tips in the ADMM solver (solvers/admm/contact.py) against independent answers: the P1
reference's contact solve (fem_reference/contact.py: the same discrete energy written as UFL
forms, minimized by PETSc Newton), the state at rest once a tip has left the skin, and the
reference's implicit-Euler dynamics. Quarter block ``indent-block`` (cells of 0.5 mm under the
tip), Neo-Hookean E = 6 kPa, nu = 0.45; units mm, kPa, mN."""
from dataclasses import replace

import numpy as np
import pytest

import tissue_reference.fem_reference as fr
from tissue_reference.control.fast_model import FastModel
from tissue_reference.control.jacobian import admm_indenter_jacobian, fd_jacobian, max_rel_error
from tissue_reference.control.loop import LoopSettings, run_closed_loop
from tissue_reference.control.plants import PRESS_WIDTHS, build_loop
from tissue_reference.errors import CaseError
from tissue_reference.fem_reference.dynamics import simulate
from tissue_reference.meshes.builders import indent_block
from tissue_reference.meshes.facet_quadrature import gauss_rule, nodal_rule
from tissue_reference.model.case import Actuator, Boundary, Case, Material, Probe
from tissue_reference.solvers import admm
from tissue_reference.solvers.admm import ImplicitEuler

DOWN = (0.0, 0.0, -1.0)
SAME = 1e-8  # mm: ADMM + polish against the P1 reference
# the reference's Newton to residuals well below what SAME resolves (its defaults stop near
# 3e-8 mN here, about 1e-8 mm; the polish goes to steps of 1e-6 mm, quadratically converging)
TIGHT = fr.NewtonSettings(rtol=1e-12, atol=1e-12)


@pytest.fixture(scope="module")
def block():
    return indent_block(0.5)


def tip_case(mesh, tip="sphere", contact=None, density=1e-6):
    kw = {"radius": 2.0} if tip == "sphere" else {"radius": 1.5, "edge_radius": 0.5}
    if contact:
        kw["contact"] = contact
    a = Actuator("I", "tip", DOWN, type="indenter", tip=tip, point=(0.0, 0.0, 0.0),
                 contact_region="top", **kw)
    return Case(mesh, Material("neo-hookean", 6.0, 0.45, density=density),
                boundaries=[Boundary("bottom", "fixed"),
                            Boundary("xsym", "sliding", normal=(1.0, 0.0, 0.0)),
                            Boundary("ysym", "sliding", normal=(0.0, 1.0, 0.0))],
                actuators=[a])


def same_contact(res, ref, tol=SAME):
    a, b = res.indenters["I"], ref.indenters["I"]
    assert np.abs(res.u - ref.u).max() < tol
    assert a["force"] == pytest.approx(b["force"], rel=1e-7)
    assert np.asarray(a["tip_start"]) == pytest.approx(np.asarray(b["tip_start"]), abs=1e-12)
    assert a["contact_area"] == pytest.approx(b["contact_area"], rel=1e-9)
    assert a["surface_penetration"] == pytest.approx(b["surface_penetration"], abs=1e-8)
    assert res.strain_energy == pytest.approx(ref.strain_energy, rel=1e-7)


@pytest.mark.parametrize("rule, tip, device", [("nodal", "sphere", "cpu"),
                                               (2, "sphere", "cpu"),
                                               (2, "punch", "cpu"),
                                               (2, "sphere", "array-cpu")])
def test_admm_with_polish_equals_the_p1_reference_with_contact(block, rule, tip, device):
    """The nodal and the Gauss rule, a sphere and a rounded punch, the compiled element pass and
    the GPU's array code (on numpy)."""
    case = tip_case(block, tip)
    push = {"I": 1.0 if tip == "sphere" else 0.75}
    ref = fr.solve(case, degree=1, pushes=push, contact_quadrature=rule, settings=TIGHT)
    res = admm.solve(case, pushes=push, contact_quadrature=rule, device=device)
    assert ref.converged and res.converged and res.valid
    assert res.indenters["I"]["force"] > 0.5   # the tip presses
    same_contact(res, ref)
    assert set(res.indenters["I"]) >= set(ref.indenters["I"]) - {
        "contact_width_mm"}


@pytest.mark.parametrize("rule, tip", [("nodal", "sphere"), (2, "sphere"), (2, "punch")])
def test_plain_admm_reaches_the_p1_reference_with_contact_within_1e_3_mm(block, rule, tip):
    case = tip_case(block, tip)
    ref = fr.solve(case, degree=1, pushes={"I": 1.0}, contact_quadrature=rule)
    res = admm.solve(case, pushes={"I": 1.0}, contact_quadrature=rule, polish=False,
                     tol_mm=1e-5, max_iter=5000)
    assert res.converged and res.extra["newton_iterations"] == 0
    assert np.abs(res.u - ref.u).max() < 1e-3


def test_a_retracting_tip_releases_the_skin_to_rest(block):
    """Pushed 1 mm, then pulled back 0.5 mm above its start from that state: the tip has left
    the skin, which (no other load) returns to rest exactly, with no force and no contact."""
    case = tip_case(block)
    pressed = admm.solve(case, pushes={"I": 1.0})
    assert pressed.indenters["I"]["contact_area"] > 0
    back = admm.solve(case, pushes={"I": -0.5}, initial=pressed)
    ind = back.indenters["I"]
    assert back.converged and back.load_steps >= 1
    assert np.abs(back.u).max() < 1e-9
    assert ind["push"] == -0.5 and ind["force"] == 0.0 and ind["contact_area"] == 0.0


@pytest.mark.parametrize("start, push", [("rest", 0.5), ("pressed", -0.5)])
def test_implicit_euler_with_a_tip_equals_the_reference_dynamics(block, start, push):
    """A tip that presses from rest, and one that jumps back 0.5 mm above its start from the
    pressed state (the skin springs up after it and leaves it): three time steps of the same
    lumped-mass implicit Euler, ADMM + polish against the reference's
    (fem_reference.dynamics)."""
    case = tip_case(block, density=1e-3)   # heavy enough that the skin lags the tip
    initial = fr.solve(case, degree=1, pushes={"I": 1.0}) if start == "pressed" else None
    dt, steps = 0.05, 3
    ref = simulate(case, dt=dt, steps=steps, pushes={"I": push}, initial=initial)
    res = admm.solve(case, pushes={"I": push}, initial=None if initial is None else initial.u,
                     dynamics=ImplicitEuler(dt, steps))
    assert res.converged
    assert ref.converged.all() and len(ref.u) == steps + 1   # the start and each step
    assert np.abs(res.u - ref.u[-1]).max() < SAME
    # the skin still moves: the dynamics matter here
    assert np.abs(res.extra["velocity"]).max() > 0.1
    force = res.indenters["I"]["force"]
    assert force == 0.0 if push < 0 else force > 0.5


def test_the_contact_rules_are_the_references_own():
    """The Gauss rules on a facet are basix's defaults (what the reference's forms use); the
    nodal rule weights a P1 facet's vertices equally."""
    basix = pytest.importorskip("basix")
    for degree in range(1, 9):
        for cell, fdim in ((basix.CellType.interval, 1), (basix.CellType.triangle, 2)):
            p, w = basix.make_quadrature(cell, degree)
            P, W = gauss_rule(fdim, degree)
            assert np.abs(P - p).max() < 1e-15 and np.abs(W - w).max() < 1e-15
    p, w = nodal_rule(2, 1)
    assert w == pytest.approx([1 / 6] * 3) and p.tolist() == [[0, 0], [1, 0], [0, 1]]


def test_admm_refuses_what_it_does_not_model_naming_it(block):
    """ADMM models frictionless tips, not tied ones (the Mass Tensor method's refusals:
    tests/test_mass_tensor_contact.py)."""
    with pytest.raises(CaseError, match="the ADMM solver models frictionless tips; indenter "
                                        "'I' is 'tied'"):
        admm.solve(tip_case(block, "punch", contact="tied"), pushes={"I": 0.1})


def test_hertz_sphere_force_by_admm_approaches_hertz_as_the_cells_shrink():
    """Hertz: a rigid sphere of radius R pressed d into a half-space, F = 4/3 E* sqrt(R) d^1.5
    (E* = E / (1 - nu^2)); linear elasticity, nu = 0.45, R = 10 mm, d = 0.1 mm (contact radius
    1 mm) on the quarter block. P1 tetrahedra are too stiff at nu = 0.45 (locking; the
    reference's P2 is within 0.5 %, tests/test_contact.py): the force lies above Hertz's and
    falls towards it as the cells under the tip shrink (measured +13.1, +10.0, +8.5 % on cells
    of 0.5, 0.35, 0.25 mm; +6.2 % at 0.15 mm)."""
    import math

    E, nu, R, d = 6.0, 0.45, 10.0, 0.1
    hertz = 4.0 / 3.0 * E / (1 - nu ** 2) * math.sqrt(R) * d ** 1.5
    errors = []
    for h in (0.5, 0.35, 0.25):
        a = Actuator("I", "tip", DOWN, type="indenter", tip="sphere", radius=R,
                     point=(0.0, 0.0, 0.0), contact_region="top")
        case = Case(indent_block(h), Material("linear-elastic", E, nu),
                    boundaries=[Boundary("bottom", "fixed"),
                                Boundary("xsym", "sliding", normal=(1.0, 0.0, 0.0)),
                                Boundary("ysym", "sliding", normal=(0.0, 1.0, 0.0))],
                    actuators=[a])
        res = admm.solve(case, pushes={"I": d})
        assert res.converged
        errors.append(4 * res.indenters["I"]["force"] / hertz - 1)
    print("\nADMM P1 force against Hertz:", [f"{100 * e:+.2f} %" for e in errors])
    assert 0 < errors[2] < errors[1] < errors[0] < 0.15
    assert errors[2] < 0.10


def test_verify_scores_admm_its_chord_polish_and_the_mass_tensor_on_tips(
        block, tmp_path):
    """ADMM with the Newton and the chord polish against the P1 reference; the Mass Tensor method
    against the linear reference of the same E and nu (the same contact), its iterative methods
    skipped: its tips need the direct solve."""
    from tissue_reference.verification.verify import verify

    out = verify(tip_case(block), {"I": 1.0},
                 solvers=["admm", "mass-tensor", "mass-tensor-amg", "admm-chord"])
    assert out["solvers"]["admm"]["max_vertex_error_mm"] < SAME
    assert out["solvers"]["mass-tensor"]["max_vertex_error_mm"] < 1e-6
    assert out["solvers"]["mass-tensor"]["reference_model"] == "linear-elastic"
    assert "mass-tensor-amg" not in out["solvers"]
    assert "with method 'direct' only" in out["skipped"]["mass-tensor-amg"]
    assert out["solvers"]["admm-chord"]["max_vertex_error_mm"] < SAME


# --------------------------------------------------------------------------- the contact Jacobian
def probed(case, rule):
    """The tip case with two targets under and beside the tip, and its contact rule named."""
    return replace(case, probes=(Probe("T", (0.5, 0.5, -2.0)), Probe("U", (2.0, 1.0, -1.0))),
                   reference_contact_quadrature=None if rule == "nodal" else rule)


@pytest.mark.parametrize("rule", ["nodal", 2])
def test_the_admm_contact_jacobian_equals_central_differences_of_admm_solves(block, rule):
    """Targets per mm of tip travel at a pressed state (the active contact set's), against
    central differences (+-1e-3 mm) of ADMM solves polished to 1e-10 mm."""
    case = probed(tip_case(block), rule)
    state = {"I": 1.0}
    res = admm.solve(case, pushes=state, polish_tol_mm=1e-10)
    jac = admm_indenter_jacobian(case.with_pushes(state), res.u)

    def plant(c, pushes, initial):
        return admm.solve(c, pushes=pushes, initial=res, polish_tol_mm=1e-10)

    fd = fd_jacobian(plant, case, state, h=1e-3)
    assert np.abs(jac.J).max() > 0.3          # the targets follow the tip
    assert max_rel_error(jac.J, fd.J) < 1e-4


def test_the_fast_model_follows_a_tip_with_the_exact_jacobian(block):
    """The controller's fast ADMM model moved along a tip's path (chord iterations with a line
    search, refactorized as the contact set grows): its state and Jacobian at each push are the
    polished ADMM solve's and the exact contact Jacobian there."""
    case = probed(tip_case(block), "nodal")
    model = FastModel(case, "T")
    for push in (0.2, 0.5, 0.8, 1.0):
        J = model.jacobian({"I": push})
        ref = admm.solve(case, pushes={"I": push}, polish_tol_mm=1e-10)
        exact = admm_indenter_jacobian(case.with_pushes({"I": push}), ref.u, targets=["T"]).J
        assert np.abs(model.u - ref.u).max() < 1e-6
        assert max_rel_error(J, exact) < 1e-5


def test_a_push_only_loop_steers_a_target_with_a_tip_model_and_a_tip_plant(block):
    """The reference P1 as the plant, the ADMM fast model (E 20 % off: no body force, so the
    same answers) as the controller's model, one tip: the target under it is driven 0.3 mm down
    and held, without retracting the tip, closed loop at least as close as open loop."""
    case = probed(tip_case(block), "nodal")
    loop = build_loop(case, plant="fem", model="admm", model_E_factor=0.8)
    assert loop.fast_model and loop.meta["model_actuator_kind"] == "indenter"
    model = FastModel(loop.model_case, "T", press_widths=PRESS_WIDTHS)
    res = run_closed_loop(loop.plant, loop.case, model, "T", 1,
                          settings=LoopSettings(steps=8), goal=(np.nan, np.nan, -0.3))
    assert res.steady_state_error_mm <= 0.05 * 0.3
    assert res.max_retraction_mm == 0.0 and res.pushes.min() >= 0.0
    assert res.steady_state_error_mm <= res.open_loop["steady_state_error_mm"] + 1e-9


@pytest.mark.parametrize("device", ["cpu", "array-cpu"])
def test_anderson_accelerated_admm_reaches_the_p1_reference_with_contact(block, device):
    """Anderson acceleration over the elements' and the contact blocks' variables: the same
    answer as the reference (within 1e-3 mm, as plain ADMM), in fewer iterations, on the
    compiled element pass and the array code."""
    case = tip_case(block, "punch")
    ref = fr.solve(case, degree=1, pushes={"I": 1.0}, contact_quadrature=2)
    runs = [admm.solve(case, pushes={"I": 1.0}, contact_quadrature=2, polish=False,
                       tol_mm=1e-5, max_iter=20000, anderson=m, device=device) for m in (0, 5)]
    for res in runs:
        assert res.converged and np.abs(res.u - ref.u).max() < 1e-3
    assert runs[1].extra["admm_iterations"] < runs[0].extra["admm_iterations"]
