"""Closed loop of seed 000 section IV-B on a linear P1 plant (exact baseline) and with a model-plant
mismatch; unreachable goals and missing names reported as such."""
from dataclasses import replace

import numpy as np
import pytest

from control.controllability import UnreachableGoalError
from control.loop import LinearizedModel, LoopSettings, run_closed_loop, plot_response
from control.mpc import MPCSettings
from meshes.errors import CaseError
from test_control_support import LinearPlant, linear_p1_stiffness, linear_tangent, phantom


@pytest.fixture(scope="module")
def setup():
    case = phantom()
    K = linear_p1_stiffness(case)
    return case, K, LinearPlant(K)


def test_exact_linear_model_closed_loop_reaches_goal_and_open_loop_is_exact(setup, tmp_path):
    case, K, plant = setup
    model = LinearizedModel(case, plant, linear_tangent(K), "T1")
    res = run_closed_loop(plant, case, model, "T1", 3, settings=LoopSettings(steps=100))
    assert res.steady_state_error_mm < 1e-2
    assert res.max_retraction_mm == 0.0
    assert np.all(np.diff(res.pushes, axis=0) >= 0)
    # linear plant = linear model: the eq. 22 pushes reach the goal exactly
    assert res.open_loop["steady_state_error_mm"] < 1e-9
    d = res.to_json_dict()
    assert set(d) == {"steps", "itae", "steady_state_error_mm", "max_retraction_mm",
                      "mpc_step_median_ms", "open_loop", "time_s", "target_error_mm",
                      "actuator_positions_mm"}
    assert d["steps"] == 100 and len(d["actuator_positions_mm"]) == 101
    png = plot_response(res, tmp_path / "r.png")
    assert png.read_bytes()[:4] == b"\x89PNG"


def test_mismatched_model_closed_loop_beats_open_loop(setup):
    case, K, plant = setup
    Km = linear_p1_stiffness(case, nu=0.35)           # the controller's model is wrong
    model = LinearizedModel(case, LinearPlant(Km), linear_tangent(Km), "T2")
    res = run_closed_loop(plant, case, model, "T2", 1, settings=LoopSettings(steps=100))
    assert res.steady_state_error_mm < 0.05
    assert res.open_loop["steady_state_error_mm"] > 10 * res.steady_state_error_mm
    assert res.itae < res.open_loop["itae"]
    assert res.max_retraction_mm == 0.0


def test_noise_is_seeded(setup):
    case, K, plant = setup
    model = LinearizedModel(case, plant, linear_tangent(K), "T1")
    s = LoopSettings(steps=5, noise_mm=0.05, seed=3, open_loop=False)
    a = run_closed_loop(plant, case, model, "T1", 2, settings=s)
    b = run_closed_loop(plant, case, model, "T1", 2, settings=s)
    assert np.array_equal(a.pushes, b.pushes)


def test_unreachable_goal_is_reported_with_closest_point(setup):
    case, K, plant = setup
    one = replace(case, actuators=case.actuators[:1])      # A1 only: pushes along -x
    model = LinearizedModel(one, plant, linear_tangent(K), "T1")
    with pytest.raises(UnreachableGoalError, match="closest reachable") as exc:
        run_closed_loop(plant, one, model, "T1", 3, settings=LoopSettings(steps=3))
    assert exc.value.closest.shape == (3,) and np.all(exc.value.pushes >= 0)


def test_missing_target_is_named(setup):
    case, K, plant = setup
    with pytest.raises(CaseError, match="'T9'"):
        LinearizedModel(case, plant, linear_tangent(K), "T9")


@pytest.mark.parametrize("kw,name", [({"steps": 0}, "steps"), ({"noise_mm": -1.0}, "noise_mm"),
                                     ({"dt_s": 0.0}, "dt_s"), ({"mpc": 3}, "mpc")])
def test_bad_loop_settings_are_named(kw, name):
    with pytest.raises(CaseError, match=name):
        LoopSettings(**kw)


def test_travel_limit_is_respected_in_loop(setup):
    case, K, plant = setup
    model = LinearizedModel(case, plant, linear_tangent(K), "T1")
    s = LoopSettings(steps=30, open_loop=False, mpc=MPCSettings(max_travel=10.0))
    res = run_closed_loop(plant, case, model, "T1", 1, settings=s)
    assert res.pushes.max() <= 10.0 + 1e-9
