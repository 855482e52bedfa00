"""The control Jacobian of rigid indenters (fem_reference.contact_jacobian): mm of target per mm
of tip travel at a contact state, against central differences of the nonlinear contact solves
themselves (every other indenter held where it is)."""
import dataclasses

import numpy as np
import pytest

import tissue_reference.fem_reference as fr
from tissue_reference.control.plants import build_loop, jacobian_at
from tissue_reference.errors import CaseError
from tissue_reference.fem_reference.contact_jacobian import indenter_jacobian
from tissue_reference.fem_reference.newton_settings import NewtonSettings
from tissue_reference.meshes.builders import box
from tissue_reference.model.case import Actuator, Boundary, Case, Material, Probe

STATE = {"I": 1.0, "S": 0.5}   # mm


@pytest.fixture(scope="module")
def case():
    """A 10 mm block on its base, a sphere (R = 4 mm) pressing its top and another its side."""
    return Case(mesh=box(1.25), material=Material("neo-hookean", E=6.0, nu=0.3), name="tips",
                boundaries=(Boundary("zmin", "fixed"),),
                actuators=(Actuator("I", "zmax", (0.0, 0.0, -1.0), type="indenter",
                                    tip="sphere", radius=4.0, point=(5.0, 5.0, 10.0)),
                           Actuator("S", "xmax", (-1.0, 0.0, 0.0), type="indenter",
                                    tip="sphere", radius=4.0, point=(10.0, 5.0, 6.0))),
                probes=(Probe("T1", (5.0, 5.0, 6.0)), Probe("T2", (7.0, 5.0, 8.0))))


def test_indenter_jacobian_equals_central_differences_of_contact_solves(case):
    s = fr.ReferenceSolver(case, settings=NewtonSettings(rtol=1e-13, atol=1e-14))
    state = s.solve(STATE)
    assert state.converged and state.indenters["S"]["force"] > 0
    J = indenter_jacobian(s, case.with_pushes(STATE))
    d = 1e-3
    fd = []
    for name in ("I", "S"):
        sides = [s.solve({**STATE, name: STATE[name] + sign * d}, initial=state).probes
                 for sign in (1.0, -1.0)]
        fd.append(np.concatenate([(sides[0][t] - sides[1][t]) / (2 * d) for t in ("T1", "T2")]))
    fd = np.stack(fd, axis=1)
    assert np.abs(J).max() > 0.1
    assert np.abs(J - fd).max() < 1e-5 * np.abs(fd).max()
    # the solver is left at its state: a solve from it needs no Newton iteration
    again = s.solve(STATE, initial=state)
    assert np.abs(again.u - state.u).max() < 1e-9


def test_jacobian_at_gives_indenter_columns_checked_by_the_solves(case):
    out = jacobian_at(case, {"I": 1.0}, fd_h=0.02)
    assert out["actuators"] == ["I", "S"] and np.shape(out["J"]) == (6, 2)
    assert out["fd_max_rel_error"] < 1e-4
    assert out["actuator_kind"] == "indenter"


def test_the_jacobian_page_of_indenters_names_their_kind(case, tmp_path):
    from page_checks import check_page

    from tissue_reference.tissue.jacobian_report import write_jacobian_report

    out = jacobian_at(case, {"I": 1.0}, fd_h=0)
    check_page(write_jacobian_report(out, tmp_path))
    page = (tmp_path / "report.html").read_text()
    assert "Actuator kind: <b>indenter</b> (rigid indenters" in page
    assert "<th>I (mm/mm)</th><th>S (mm/mm)</th>" in page
    assert "Not checked against finite differences" in page


def steer_t2(case):
    """The push-only MPC, its model linearized with the indenter Jacobian at every step, moving
    T2 0.3 mm along -x on the contact plant (the same reference: no mismatch): (setup, result),
    the move checked."""
    from tissue_reference.control.loop import LinearizedModel, LoopSettings, run_closed_loop

    setup = build_loop(case, plant="fem")
    assert setup.model_sensitivity is not None
    model = LinearizedModel(setup.model_case, setup.model_solve, setup.model_tangent, "T2",
                            setup.model_sensitivity)
    res = run_closed_loop(setup.plant, setup.case, model, "T2", 1,
                          goal=[-0.3, np.nan, np.nan],
                          settings=LoopSettings(steps=12, open_loop=False))
    moved = res.target[-1] - res.target[0]
    assert abs(moved[0] + 0.3) <= 0.05 and res.steady_state_error_mm <= 0.05
    assert res.max_retraction_mm == 0.0 and res.pushes[-1].max() > 0.1
    return setup, res


@pytest.mark.slow
def test_a_closed_loop_steers_a_target_with_indenters(case):
    setup, res = steer_t2(case)
    # the plant's final state is a valid contact answer with the tips pressing
    final = setup.plant(setup.case, dict(zip(res.actuators, res.pushes[-1])), None)
    assert final.valid and max(r["force"] for r in final.indenters.values()) > 0


def test_mixing_indenters_and_patches_is_refused(case):
    mixed = Case(mesh=case.mesh, material=case.material, name="mixed",
                 boundaries=case.boundaries,
                 actuators=(case.actuators[0], Actuator("P", "xmin", (1.0, 0.0, 0.0))),
                 probes=case.probes)
    with pytest.raises(CaseError, match="mix indenters and glued patches"):
        jacobian_at(mixed, {"I": 1.0}, fd_h=0)
    with pytest.raises(CaseError, match="mixes indenters and glued patches"):
        build_loop(mixed, plant="fem")
    # an ADMM model presses the same frictionless tips (its fast update included)
    assert build_loop(case, plant="fem", model="admm", model_E_factor=0.9).fast_model


def test_the_model_linearizes_a_touching_tip_where_it_presses(case):
    """Tips started on the curved surface touch the skin without pressing: the Jacobian there
    is zero. The loop's model takes it a few smoothing widths in, where a push moves the
    targets, and leaves retracted and deeper tips where they are."""
    from tissue_reference.control.plants import PRESS_WIDTHS, pressing

    touching = dataclasses.replace(case, reference_contact_quadrature=2,
                                   reference_tip_start="surface")
    s = fr.ReferenceSolver(touching)
    s.solve({"I": 0.0, "S": 0.0})
    assert np.abs(indenter_jacobian(s, touching.with_pushes({"I": 0.0, "S": 0.0}))).max() == 0.0
    width = {i.name: i.smoothing_width for i in s.contact.indenters}
    assert 0.0 < width["S"] < 0.01
    at = pressing(s, {"I": -0.5, "S": 0.0})
    assert at == {"I": -0.5, "S": PRESS_WIDTHS * width["S"]}
    assert pressing(s, {"I": 1.0, "S": 0.2}) == {"I": 1.0, "S": 0.2}
    s.solve(at)
    J = indenter_jacobian(s, touching.with_pushes(at))
    # S pushes along -x: T2 (7, 5, 8) moves along -x, by most of a millimetre per millimetre
    assert J[3, 1] < -0.3 and J[3, 0] == 0.0


@pytest.mark.slow
def test_a_closed_loop_from_rest_steers_with_tips_started_on_the_surface(case):
    steer_t2(dataclasses.replace(case, reference_contact_quadrature=2,
                                 reference_tip_start="surface"))
