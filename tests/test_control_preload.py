"""A control loop that starts from a preload: every actuator pushed in by some millimetres before
step 0, as seed 000's actuators start in contact with the phantom.

Independent answers: on a linear plant the preload shifts the state and nothing else (the loop's
increments and the open loop are those of a loop from rest); on phantom-seed, whose rigid heads
only touch the skin at rest (J_s = 0 there), the model's Jacobian at the preload is checked
against central differences of the reference plant's own nonlinear solves, and a 5 mm task is
driven to its goal measured from the target's preloaded position, which a separate reference
solve at the preload gives."""
import argparse
import json
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from test_control_support import LinearPlant, linear_p1_stiffness, linear_tangent, phantom

import tissue_reference.fem_reference as fr
from tissue_reference.control.fast_model import FastModel
from tissue_reference.control.jacobian import fd_jacobian
from tissue_reference.control.loop import LinearizedModel, LoopSettings, run_closed_loop
from tissue_reference.control.mpc import MPCSettings
from tissue_reference.control.plants import PRESS_WIDTHS, build_loop, plant_for
from tissue_reference.control.scenarios import GRAVITY_MM_S2
from tissue_reference.errors import CaseError
from tissue_reference.model.case import load_case
from tissue_reference.tissue.cli import main
from tissue_reference.tissue.loop_options import preload_from_args

SEED = Path(__file__).resolve().parents[1] / "meshes" / "cases" / "phantom-seed.toml"
PRELOAD = 3.0   # mm, every head


def seed_coarse(tmp_path, size=10.0, site_size=6.0):
    """phantom-seed meshed coarsely (size and site size in mm): 2-3k tets instead of 14k, at
    P1 (``degree = 1`` in place of the case's P2): what these tests check (a preload, the
    model's Jacobian against the plant's, a loop from the preload) needs no P2, and its P1
    answers are the ones the ADMM model solves on the same mesh."""
    text = SEED.read_text()
    text = re.sub(r"(?m)^size = 6\.0 .*$", f"size = {size}", text, count=1)
    text = re.sub(r"(?m)^site_size = 3\.0 .*$", f"site_size = {site_size}", text, count=1)
    text, n = re.subn(r"(?m)^degree = 2 .*$", "degree = 1", text, count=1)
    assert n == 1
    path = tmp_path / "phantom-seed-coarse.toml"
    path.write_text(text)
    return load_case(path)


@pytest.fixture(scope="module")
def linear():
    case = phantom().with_material(model="linear-elastic")
    K = linear_p1_stiffness(case)
    return case, K, LinearPlant(K)


def test_a_preload_must_be_a_push_of_known_actuators():
    with pytest.raises(CaseError, match="preload_mm must be a push >= 0"):
        LoopSettings(preload_mm=-1.0)
    with pytest.raises(CaseError, match=r"preload_mm\['A2'\] must be a push >= 0"):
        LoopSettings(preload_mm={"A1": 1.0, "A2": float("nan")})
    s = LoopSettings(preload_mm={"A2": 2})
    assert s.preload_mm == {"A2": 2.0}
    assert s.preload(["A1", "A2", "A3"]).tolist() == [0.0, 2.0, 0.0]
    assert LoopSettings(preload_mm=1.5).preload(["A1", "A2"]).tolist() == [1.5, 1.5]
    with pytest.raises(CaseError, match=r"preload of \['A9'\]: no such actuator"):
        LoopSettings(preload_mm={"A9": 1.0}).preload(["A1", "A2"])


def test_the_command_line_preload_names_every_actuator(linear):
    case = linear[0]
    names = [a.name for a in case.actuators]

    def parsed(*items, max_travel=None):
        return preload_from_args(argparse.Namespace(preload=list(items), max_travel=max_travel),
                                 case)

    assert parsed() == {n: 0.0 for n in names}
    assert parsed("2") == {n: 2.0 for n in names}
    assert parsed("2", "A1=4") == {n: 4.0 if n == "A1" else 2.0 for n in names}
    assert parsed("A3=1") == {n: 1.0 if n == "A3" else 0.0 for n in names}
    for items, msg in ((("A9=1",), "unknown actuator 'A9'"), (("1", "2"), "one bare MM"),
                       (("A1=-1",), "pushes >= 0"), (("x",), "MM or NAME=MM"),
                       (("A1=1", "A1=2"), "given twice")):
        with pytest.raises(CaseError, match=msg):
            parsed(*items)
    with pytest.raises(CaseError, match="beyond --max-travel 3"):
        parsed("4", max_travel=3.0)


def test_a_preloaded_linear_loop_is_the_loop_from_rest_shifted(linear):
    case, K, plant = linear
    settings = LoopSettings(steps=40, task_mm=0.5)
    pre = {a.name: 1.0 + i for i, a in enumerate(case.actuators)}
    p0 = np.array(list(pre.values()))
    rest = run_closed_loop(plant, case, LinearizedModel(case, plant, linear_tangent(K), "T1"),
                           "T1", 3, settings=settings)
    loaded = run_closed_loop(plant, case, LinearizedModel(case, plant, linear_tangent(K), "T1"),
                             "T1", 3, settings=replace(settings, preload_mm=pre))
    # the plant at the preload, solved on its own: the loop starts there, the goal from there
    x_pre = plant(case, pre).probes["T1"]
    np.testing.assert_allclose(loaded.target[0], x_pre, atol=1e-12)
    np.testing.assert_allclose(loaded.goal - loaded.target[0], rest.goal - rest.target[0],
                               atol=1e-12)
    np.testing.assert_allclose(loaded.pushes[0], p0)
    # linear: the same increments, the same errors, the same open loop beyond the preload
    np.testing.assert_allclose(loaded.pushes - p0, rest.pushes, atol=1e-9)
    np.testing.assert_allclose(loaded.error_mm, rest.error_mm, atol=1e-9)
    assert loaded.max_retraction_mm == 0.0 and np.all(loaded.pushes >= p0)
    np.testing.assert_allclose(loaded.open_loop["u_open"], rest.open_loop["u_open"], atol=1e-9)
    np.testing.assert_allclose(loaded.open_loop["pushes"] - p0, rest.open_loop["pushes"],
                               atol=1e-9)
    assert loaded.open_loop["steady_state_error_mm"] < 1e-9
    d = loaded.to_json_dict()
    assert d["preload_mm"] == p0.tolist() and d["actuator_positions_mm"][0] == p0.tolist()
    # a push limit counts from rest: the open loop's pushes beyond the preload are clamped to
    # what is left of it, and a preload past it is refused
    lim = replace(settings, preload_mm=pre, mpc=MPCSettings(max_travel=float(p0.max()) + 0.5))
    clamped = run_closed_loop(plant, case, LinearizedModel(case, plant, linear_tangent(K), "T1"),
                              "T1", 3, settings=lim)
    assert np.all(clamped.pushes <= p0.max() + 0.5 + 1e-9)
    assert np.all(clamped.open_loop["pushes"][-1] <= p0.max() + 0.5 + 1e-9)
    with pytest.raises(CaseError, match="beyond the push limit"):
        run_closed_loop(plant, case, LinearizedModel(case, plant, linear_tangent(K), "T1"), "T1",
                        3, settings=replace(lim, mpc=MPCSettings(max_travel=1.0)))


def test_a_loop_s_reference_is_solved_at_the_degree_given(capsys):
    """build_loop's degree (``tissue mpc`` / ``table1 --degree``) is the reference plant's,
    recorded in the loop's metadata; without it the case's (phantom-seed: P2). Refused, naming
    it, where neither the plant nor the model is the reference. Nothing is solved."""
    case = load_case(SEED, size=14.0)
    for degree, expected in ((None, 2), (1, 1)):
        meta = build_loop(case, plant="fem", model="admm", degree=degree).meta
        assert meta["plant_solver"]["discretization"]["degree"] == expected
        assert meta["model_solver"]["discretization"]["degree"] == 1     # ADMM: P1
    with pytest.raises(CaseError, match="neither the plant"):
        build_loop(case, plant="admm", degree=2)
    assert main(["mpc", "phantom-seed", "--size", "14", "--target", "T2", "--task", "1",
                 "--plant", "admm", "--degree", "1", "--preload", "3", "-q"]) == 2
    assert "--degree 1: the reference's degree" in capsys.readouterr().err


@pytest.mark.slow
def test_the_models_jacobian_at_the_preload_is_the_reference_plants(tmp_path):
    case = seed_coarse(tmp_path)
    pre = {a.name: PRELOAD for a in case.actuators}
    # the loops' ADMM model, started at the preload as a loop starts it
    J = FastModel(case, "T2", press_widths=PRESS_WIDTHS).jacobian(pre)
    fd = fd_jacobian(plant_for("fem"), case, pre, h=0.02, targets=["T2"]).J
    print(f"\nJ_s of T2 at the {PRELOAD:g} mm preload:\n{np.round(J, 4)}\nreference central "
          f"differences:\n{np.round(fd, 4)}")
    # the facing head (A1, along -x) moves T2 by tenths of a mm per mm, the others less
    assert fd[0, 0] < -0.1 and np.abs(fd).max() == -fd[0, 0]
    np.testing.assert_allclose(J, fd, atol=2e-3 * np.abs(fd).max())


@pytest.mark.slow
def test_a_5mm_task_reaches_its_goal_from_the_preload_with_the_open_loop_beside(tmp_path):
    model_case = seed_coarse(tmp_path)
    plant_case = replace(model_case, gravity=GRAVITY_MM_S2)   # the mismatch: the plant sags
    loop = build_loop(model_case, plant="fem", model="admm", plant_case=plant_case)
    settings = LoopSettings(steps=12, preload_mm=PRELOAD)
    res = loop.run("T2", 1, settings)
    # the goal: 5 mm along -x from where the preload put T2, by a reference solve of its own
    pre = {a.name: PRELOAD for a in plant_case.actuators}
    x_pre = np.asarray(fr.solve(plant_case, pushes=pre, degree=1).probes["T2"])
    np.testing.assert_allclose(res.target[0], x_pre, atol=1e-6)
    np.testing.assert_allclose(res.goal[0], x_pre[0] - 5.0, atol=1e-6)
    d = res.to_json_dict()
    print(f"\nT2 task 1 from the {PRELOAD:g} mm preload: closed SSE {d['steady_state_error_mm']:.2e}"
          f" mm, ITAE {d['itae']:.2f}; open loop {d['open_loop']['status']}, SSE "
          f"{d['open_loop']['steady_state_error_mm']}, ITAE {d['open_loop']['itae']:.2f}; "
          f"final pushes {np.round(res.pushes[-1], 2).tolist()} mm; {res.wall_time_s:.1f} s")
    assert res.settled and d["steady_state_error_mm"] <= 0.05
    assert res.pushes[0].tolist() == [PRELOAD] * 4 and np.all(np.diff(res.pushes, axis=0) >= 0)
    assert d["max_retraction_mm"] == 0.0
    assert res.target[-1][0] - res.target[0][0] == pytest.approx(-5.0, abs=0.05)
    # the open loop ran beside it, from the same preload, and ends farther from the goal
    ol = d["open_loop"]
    assert ol["status"] == "completed"
    assert ol["actuator_positions_mm"][0] == [PRELOAD] * 4
    assert ol["steady_state_error_mm"] > d["steady_state_error_mm"]
    assert ol["itae"] > d["itae"]


@pytest.mark.slow
def test_the_commands_record_the_preload(tmp_path, capsys):
    seed_coarse(tmp_path)
    js = tmp_path / "m.json"
    argv = ["mpc", str(tmp_path / "phantom-seed-coarse.toml"), "--target", "T2", "--task", "1",
            "--plant", "admm", "--steps", "2", "--preload", "3", "--preload", "A3=2", "-q",
            "--task-mm", "0.5", "--max-travel", "6", "--json", str(js)]
    assert main(argv) == 0
    d = json.loads(js.read_text())
    assert d["settings"]["preload_mm"] == {"A1": 3.0, "A2": 3.0, "A3": 2.0, "A4": 3.0}
    assert d["preload_mm"] == [3.0, 3.0, 2.0, 3.0] == d["actuator_positions_mm"][0]
    # a table resumed with another preload is refused, naming it
    out = tmp_path / "t"
    base = ["table1", str(tmp_path / "phantom-seed-coarse.toml"), "--plant", "admm",
            "--targets", "T2", "--steps", "1", "--task-mm", "0.5", "--max-travel", "6", "-q",
            "--out", str(out)]
    main(base + ["--preload", "3"])
    capsys.readouterr()
    table = json.loads((out / "table1.json").read_text())
    assert table["meta"]["settings"]["preload_mm"] == {a: 3.0 for a in ("A1", "A2", "A3", "A4")}
    assert next(r["preload_mm"] for r in table["rows"] if r["status"] == "ok") == [3.0] * 4
    assert main(base + ["--preload", "2"]) == 2
    assert "settings.preload_mm.A1 (3.0 there, 2.0 now)" in capsys.readouterr().err
