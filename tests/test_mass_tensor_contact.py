"""Rigid tips on the Mass Tensor model (solvers/mass_tensor/contact.py) against independent
answers: the linear P1 reference's contact solve (fem_reference/contact.py: the same discrete
problem, linear elasticity with the same penalty, contact rule and tip start, written as UFL
forms and minimized by PETSc Newton), Hertz's closed form, the contactless answer once a tip has
left the skin, and the solver's own answer on other candidate sets and from a kept condensation.
Quarter block ``indent-block`` (cells of 0.5 mm under the tip), linear elasticity E = 6 kPa,
nu = 0.45; units mm, kPa, mN."""
import math
from dataclasses import replace

import numpy as np
import pytest

import tissue_reference.fem_reference as fr
from tissue_reference.errors import NotModeledError
from tissue_reference.meshes.builders import indent_block
from tissue_reference.model.case import Actuator, Boundary, Case, Material
from tissue_reference.solvers import mass_tensor as mt
from tissue_reference.solvers import registry
from tissue_reference.solvers.mass_tensor import contact as mt_contact
from tissue_reference.solvers.mass_tensor.driver import MODEL_CACHE

DOWN = (0.0, 0.0, -1.0)
SAME = 1e-8  # mm: the Mass Tensor answer against the linear P1 reference
# the reference's Newton to residuals well below what SAME resolves
TIGHT = fr.NewtonSettings(rtol=1e-12, atol=1e-12)


@pytest.fixture(scope="module")
def block():
    return indent_block(0.5)


def tip_case(mesh, tip="sphere", contact=None, radius=None, nu=0.45):
    kw = {"radius": radius or 2.0} if tip == "sphere" else {"radius": 1.5, "edge_radius": 0.5}
    if contact:
        kw["contact"] = contact
    a = Actuator("I", "tip", DOWN, type="indenter", tip=tip, point=(0.0, 0.0, 0.0),
                 contact_region="top", **kw)
    return Case(mesh, Material("linear-elastic", 6.0, nu),
                boundaries=[Boundary("bottom", "fixed"),
                            Boundary("xsym", "sliding", normal=(1.0, 0.0, 0.0)),
                            Boundary("ysym", "sliding", normal=(0.0, 1.0, 0.0))],
                actuators=[a])


@pytest.mark.parametrize("rule, tip, start", [("nodal", "sphere", None),
                                              (2, "sphere", None),
                                              (2, "sphere", "nodes"),
                                              (2, "punch", None)])
def test_the_mass_tensor_with_tips_equals_the_linear_p1_reference(block, rule, tip, start):
    """The nodal and the Gauss rule, a sphere and a rounded punch, the tip started where its
    rule starts it and (Gauss rule) on the nodes: the same discrete problem, the same
    answer."""
    case = tip_case(block, tip)
    push = {"I": 1.0 if tip == "sphere" else 0.75}
    opts = {"contact_quadrature": rule, **({"tip_start": start} if start else {})}
    ref = fr.solve(case, degree=1, pushes=push, settings=TIGHT, **opts)
    res = mt.solve(case, pushes=push, **opts)
    assert ref.converged and res.converged and res.valid
    a, b = res.indenters["I"], ref.indenters["I"]
    assert a["force"] > 0.5   # the tip presses
    assert np.abs(res.u - ref.u).max() < SAME
    assert a["force"] == pytest.approx(b["force"], rel=1e-7)
    assert np.asarray(a["tip_start"]) == pytest.approx(np.asarray(b["tip_start"]), abs=1e-12)
    assert a["contact_area"] == pytest.approx(b["contact_area"], rel=1e-9)
    assert a["max_penetration"] == pytest.approx(b["max_penetration"], abs=1e-9)
    assert res.strain_energy == pytest.approx(ref.strain_energy, rel=1e-7)
    assert res.reactions["bottom"] == pytest.approx(ref.reactions["bottom"], abs=1e-6)
    assert set(a) >= set(b) - {"contact_width_mm"}
    # the bottom's support balances the tip's push (the sliding sides take no z force)
    assert res.reactions["bottom"][2] == pytest.approx(-a["force_vector"][2], rel=1e-6)


def test_hertz_sphere_force_approaches_hertz_as_the_cells_shrink():
    """Hertz: a rigid sphere of radius R pressed d into a half-space, F = 4/3 E* sqrt(R) d^1.5
    (E* = E / (1 - nu^2)); nu = 0.45, R = 10 mm, d = 0.1 mm (contact radius 1 mm) on the quarter
    block, nodal rule. The linear P1 model locks at nu = 0.45: its force lies above Hertz's and
    falls towards it as the cells under the tip shrink (measured +13.1, +10.0, +8.5 % on cells of
    0.5, 0.35, 0.25 mm, ADMM's figures on the same discrete problem)."""
    E, nu, R, d = 6.0, 0.45, 10.0, 0.1
    hertz = 4.0 / 3.0 * E / (1 - nu ** 2) * math.sqrt(R) * d ** 1.5
    errors = []
    for h in (0.5, 0.35, 0.25):
        res = mt.solve(tip_case(indent_block(h), radius=R), pushes={"I": d})
        assert res.converged
        errors.append(4 * res.indenters["I"]["force"] / hertz - 1)
    print("\nMass Tensor P1 force against Hertz:", [f"{100 * e:+.2f} %" for e in errors])
    assert 0 < errors[2] < errors[1] < errors[0] < 0.15
    assert errors[2] < 0.10


@pytest.mark.parametrize("push", [0.0, -0.5])
def test_a_retracted_tip_releases_the_skin(block, push):
    """A tip at its start (touching, no force) or pulled back: no force, no contact, and the
    field is the contactless answer (the same case without the tip), after a solve that pressed
    (the kept condensation does not hold the skin)."""
    case = replace(tip_case(block), gravity=(0.0, 0.0, -9.81))   # a load without the tip
    pressed = mt.solve(case, pushes={"I": 1.0})
    assert pressed.indenters["I"]["force"] > 0.5
    res = mt.solve(case, pushes={"I": push})
    free = mt.solve(replace(case, actuators=()))
    assert res.converged and res.indenters["I"]["force"] == 0.0
    assert res.indenters["I"]["contact_area"] == 0.0
    assert res.indenters["I"]["force_vector"] == [0.0, 0.0, 0.0]
    assert np.abs(free.u).max() > 1e-3        # gravity moves the block
    assert np.array_equal(res.u, free.u)


def test_candidates_grown_in_rounds_give_the_same_answer(block, monkeypatch):
    """Candidates that start with only the deepest points (gap below -0.4 R at the contactless
    answer) grow by the points found pressing outside them, round by round, to the answer of
    the default candidates."""
    case = tip_case(block)
    mt.forget_factorizations()
    ref = mt.solve(case, pushes={"I": 1.2})
    assert ref.extra["contact_rounds"] == 1
    mt.forget_factorizations()
    monkeypatch.setattr(mt_contact, "REACH_RADII", -0.4)
    res = mt.solve(case, pushes={"I": 1.2})
    assert res.converged and res.extra["contact_rounds"] > 1
    assert res.extra["contact_candidate_vertices"] < ref.extra["contact_candidate_vertices"]
    assert np.abs(res.u - ref.u).max() < 1e-10
    assert res.indenters["I"]["force"] == pytest.approx(ref.indenters["I"]["force"], rel=1e-10)


def test_another_push_reuses_the_kept_condensation(block):
    """A cold solve makes the factorization and the compliance columns; the next push on the
    same point types makes no new column within the candidates' reach and gives the cold solve's
    answer; its tips' forces grow with the push."""
    case = tip_case(block)
    mt.forget_factorizations()
    first = mt.solve(case, pushes={"I": 1.0})
    assert first.extra["contact_columns"] == 3 * first.extra["contact_candidate_vertices"]
    warm = mt.solve(case, pushes={"I": 0.9})
    assert warm.extra["contact_columns"] == 0
    mt.forget_factorizations()
    cold = mt.solve(case, pushes={"I": 0.9})
    assert np.abs(warm.u - cold.u).max() < 1e-12
    assert 0 < warm.indenters["I"]["force"] < first.indenters["I"]["force"]


def test_contact_it_does_not_model_is_refused_by_name(block):
    """Tied tips (no slip) are the reference's; the tips' condensation needs the direct solve."""
    with pytest.raises(NotModeledError, match="the Mass Tensor solver models frictionless tips; "
                                              "indenter 'I' is 'tied'"):
        mt.solve(tip_case(block, "punch", contact="tied"), pushes={"I": 0.1})
    with pytest.raises(NotModeledError, match="with method 'direct' only.*not 'amg'"):
        mt.solve(tip_case(block), pushes={"I": 0.1}, method="amg")
    mt.require_modeled(tip_case(block))   # frictionless, direct: modeled


def test_the_registry_asks_each_solver_with_its_own_options(block):
    """A caller that scores any solver (``verify``) asks the registry whether it models a case
    with the options it will solve with: the Mass Tensor method's tips need its direct solve,
    and an option a solver's check does not take is not its concern."""
    entry, admm_entry = registry.solver("mass-tensor"), registry.solver("admm")
    with pytest.raises(NotModeledError, match="with method 'direct' only.*not 'amg'"):
        entry.require_modeled(tip_case(block), {"method": "amg", "tol_mm": 1e-3})
    entry.require_modeled(tip_case(block), {"method": "direct"})
    admm_entry.require_modeled(tip_case(block), {"method": "amg"})   # not ADMM's option
    with pytest.raises(NotModeledError, match="the ADMM solver models frictionless tips"):
        admm_entry.require_modeled(tip_case(block, "punch", contact="tied"))


def test_forgetting_what_a_solver_keeps_makes_its_next_solve_a_first_one(block):
    """``forget_kept`` drops the Mass Tensor method's kept factorizations (the next solve
    factorizes again: same answer) and is harmless for ADMM."""
    case = tip_case(block)
    first = mt.solve(case, pushes={"I": 0.1})
    kept = lambda: sum(len(m._factors) for m in MODEL_CACHE.values())
    assert kept() > 0
    registry.solver("mass-tensor").forget_kept()
    assert kept() == 0
    again = mt.solve(case, pushes={"I": 0.1})
    assert np.allclose(again.u, first.u, rtol=0, atol=1e-12)
    registry.solver("admm").forget_kept()
