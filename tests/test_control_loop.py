"""Closed loop of seed 000 section IV-B on a linear P1 plant (exact baseline) and with a model-plant
mismatch; unreachable goals and missing names reported as such."""
from dataclasses import replace

import numpy as np
import pytest
from test_control_support import LinearPlant, linear_p1_stiffness, linear_tangent, phantom

from tissue_reference.control.controllability import UnreachableGoalError
from tissue_reference.control.loop import (
    LinearizedModel,
    LoopSettings,
    itae,
    plot_response,
    run_closed_loop,
)
from tissue_reference.control.mpc import MPCSettings
from tissue_reference.control.plant_step import PUSH_MATCH_MM
from tissue_reference.errors import CaseError, ConvergenceError


@pytest.fixture(scope="module")
def setup():
    # the plant here is linear elastic: so is its Case (whose answers then have no push range)
    case = phantom().with_material(model="linear-elastic")
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
    assert set(d) >= {"steps", "itae", "steady_state_error_mm", "max_retraction_mm",
                      "mpc_step_median_ms", "open_loop", "time_s", "target_error_mm",
                      "actuator_positions_mm", "target", "task", "goal_mm",
                      "target_position_mm", "mpc_step_ms"}
    assert d["open_loop"]["status"] == "completed" and not d["open_loop"]["clamped"]
    assert d["target"] == "T1" and d["task"] == 3
    assert d["steps"] == 100 and len(d["actuator_positions_mm"]) == 101
    png = plot_response(res, tmp_path / "r.png")
    assert png.read_bytes()[:4] == b"\x89PNG"


def test_a_shorter_task_moves_the_target_by_that_distance(setup):
    case, K, plant = setup
    model = LinearizedModel(case, plant, linear_tangent(K), "T1")
    lines = []
    res = run_closed_loop(plant, case, model, "T1", 1,
                          settings=LoopSettings(steps=60, task_mm=0.5), progress=lines.append)
    assert len(lines) == 60 + 61    # a line per closed-loop step, and per open-loop step
    assert lines[0].startswith("closed loop step 1/60: pushes [")
    assert lines[-1].startswith("open loop step 60/60: ")
    moved = res.target[-1] - res.target[0]
    assert moved[0] == pytest.approx(-0.5, abs=1e-2)
    with pytest.raises(CaseError, match="task_mm"):
        LoopSettings(task_mm=0.0)


def test_mismatched_model_closed_loop_beats_open_loop(setup):
    case, _K, plant = setup
    Km = linear_p1_stiffness(case, nu=0.35)           # the controller's model is wrong
    model = LinearizedModel(case, LinearPlant(Km), linear_tangent(Km), "T2")
    res = run_closed_loop(plant, case, model, "T2", 1, settings=LoopSettings(steps=100))
    assert res.steady_state_error_mm < 0.05
    assert res.open_loop["steady_state_error_mm"] > 10 * res.steady_state_error_mm
    assert res.itae < res.open_loop["itae"]
    assert res.max_retraction_mm == 0.0


def test_gain_relative_weights_close_a_small_task_within_the_loop(setup):
    """T1 moves a fraction of a mm per mm of push: the seed's absolute weights close a
    0.3 mm task slowly; R relative to the model's gain closes it in a few steps, pushing only."""
    case, _, plant = setup
    Km = linear_p1_stiffness(case, nu=0.35)
    res = {}
    for weights in ("absolute", "gain"):
        model = LinearizedModel(case, LinearPlant(Km), linear_tangent(Km), "T1")
        res[weights] = run_closed_loop(plant, case, model, "T1", 3, settings=LoopSettings(
            steps=60, task_mm=0.3, mpc=MPCSettings(weights=weights)))
    fast, slow = res["gain"], res["absolute"]
    assert fast.steady_state_error_mm < 1e-6 < slow.steady_state_error_mm
    assert fast.itae < slow.itae / 10 and fast.itae < fast.open_loop["itae"]
    assert fast.error_mm[5] < 0.01 * fast.error_mm[0]
    assert fast.max_retraction_mm == 0.0


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


def test_unreachable_goal_closest_point_is_the_projection_on_the_push_cone(setup):
    # A3 alone pushes T1 along ~+x: the goal (+5, +5) of task 3 is outside its (one-ray) cone;
    # the closest reachable point is the projection of the goal on that ray
    case, K, plant = setup
    one = replace(case, actuators=case.actuators[2:3])
    model = LinearizedModel(one, plant, linear_tangent(K), "T1")
    with pytest.raises(UnreachableGoalError, match="outside the positive span") as exc:
        run_closed_loop(plant, one, model, "T1", 3, settings=LoopSettings(steps=3))
    assert not isinstance(exc.value, ConvergenceError)        # reported as such, not a failure
    j = model.jacobian({"A3": 0.0})[:2, 0]
    goal = np.array([5.0, 5.0])
    t = goal @ j / (j @ j)
    assert t > 0
    np.testing.assert_allclose(exc.value.closest[:2], t * j, rtol=1e-6)
    assert exc.value.closest[2] == 0.0                         # z is free in every task
    np.testing.assert_allclose(exc.value.pushes, [t], rtol=1e-6)


def test_model_and_plant_with_other_actuators_are_named(setup):
    case, K, plant = setup
    other = replace(case, actuators=case.actuators[:3])
    model = LinearizedModel(other, plant, linear_tangent(K), "T1")
    with pytest.raises(CaseError, match="A4"):
        run_closed_loop(plant, case, model, "T1", 1, settings=LoopSettings(steps=2))


class FailingAfter:
    """The linear plant, raising ConvergenceError from call ``n`` on (a plant that cannot take the
    open loop's pushes)."""

    def __init__(self, plant, n):
        self.plant, self.n, self.calls = plant, n, 0

    def __call__(self, case, pushes, initial=None):
        self.calls += 1
        if self.calls > self.n:
            raise ConvergenceError(f"test plant: no convergence at pushes {pushes}")
        return self.plant(case, pushes, initial)


def test_open_loop_plant_failure_is_reported_with_a_lower_bound_itae(setup, tmp_path):
    case, K, plant = setup
    steps = 10
    model = LinearizedModel(case, plant, linear_tangent(K), "T1")
    full = run_closed_loop(plant, case, model, "T1", 2, settings=LoopSettings(steps=steps))
    # closed loop: 1 + steps solves; the open loop's step 0 is the closed loop's first load
    # (given back), then it solves steps 1..3 and fails at step 4
    fp = FailingAfter(plant, 1 + steps + 3)
    res = run_closed_loop(fp, case, model, "T1", 2, settings=LoopSettings(steps=steps))
    ol = res.open_loop
    assert not ol["converged"] and ol["failed_at_step"] == 4
    assert ol["steady_state_error_mm"] is None and len(ol["error_mm"]) == 4
    np.testing.assert_allclose(ol["error_mm"], full.open_loop["error_mm"][:4])
    assert ol["itae"] <= full.open_loop["itae"]                # a lower bound
    np.testing.assert_allclose(ol["itae"], itae(res.time_s[:4], ol["error_mm"], 1.0))
    d = res.to_json_dict()["open_loop"]
    assert d["itae_is_lower_bound"] and d["failed_at_step"] == 4 and "test plant" in d["failure"]
    np.testing.assert_array_equal(res.pushes, full.pushes)    # the closed loop is unaffected
    assert plot_response(res, tmp_path / "f.png").read_bytes()[:4] == b"\x89PNG"


def test_a_plant_that_fails_mid_loop_stops_it_with_the_history_so_far(setup, tmp_path):
    """The plant cannot be solved at the pushes of step 7 (warm, then cold): the loop stops with
    LoopStopped naming the step and the pushes asked, and carries the steps it reached, equal
    to those of the same loop on a plant that does not fail; Table I's row and the mpc page keep
    them."""
    import json

    from page_checks import check_page

    from tissue_reference.control.loop import LoopStopped
    from tissue_reference.control.table1 import run_table1
    from tissue_reference.tissue.mpc_report import write_mpc_report
    from tissue_reference.tissue.output_schema import schema

    case, K, plant = setup
    steps = 10
    model = LinearizedModel(case, plant, linear_tangent(K), "T1")
    full = run_closed_loop(plant, case, model, "T1", 2, settings=LoopSettings(steps=steps))
    with pytest.raises(LoopStopped) as info:
        run_closed_loop(FailingAfter(plant, 1 + 6), case, model, "T1", 2,
                        settings=LoopSettings(steps=steps))
    stop = info.value
    assert isinstance(stop, ConvergenceError) and stop.step == 7
    assert "stopped at step 7/10" in str(stop) and "test plant" in str(stop)
    np.testing.assert_allclose(stop.pushes_mm, full.pushes[7], atol=1e-12)
    d = stop.to_json_dict()
    np.testing.assert_allclose(d["target_error_mm"], full.error_mm[:7], atol=1e-12)
    np.testing.assert_allclose(d["actuator_positions_mm"], full.pushes[:7], atol=1e-12)
    assert d["last_error_mm"] == pytest.approx(full.error_mm[6], abs=1e-12)
    assert d["itae_so_far"] == pytest.approx(sum(k * full.error_mm[k] for k in range(7)))

    class Loop:   # what run_table1 needs of control.plants.LoopSetup
        def run(self, target, task, settings, progress=None):
            return run_closed_loop(FailingAfter(plant, 1 + 6), case, model, target, task,
                                   settings=settings)

    lines = []
    summ = run_table1(case, ["T1"], Loop(), LoopSettings(steps=steps), tmp_path, plots=False,
                      progress=lines.append)
    assert summ["failed"] == 3 and not summ["all_met"]
    row = json.loads((tmp_path / "table1.json").read_text())["rows"][1]
    assert set(row) <= set(schema("table1")["$defs"]["row"]["properties"])   # each described
    assert row["status"] == "failed" and row["failed_at_step"] == 7
    assert len(row["target_error_mm"]) == 7 and len(row["failed_pushes_mm"]) == 4
    assert "stopped at step 7/10" in (tmp_path / "table1.md").read_text()
    assert "closed loop failed: closed loop stopped at step 7/10" in lines[1]
    page = write_mpc_report({"case": "phantom", "target": "T1", "task": 2, "status": "failed",
                             "error": str(stop), **d}, tmp_path)
    assert set(d) <= set(schema("mpc")["properties"])
    text = page.read_text()
    assert "Up to the stop" in text and "7 of 10" in text
    assert "mpc_T1_task2_error.png" in check_page(page)["images"]   # well formed, units named
    assert (tmp_path / "mpc_T1_task2_error.png").read_bytes()[:4] == b"\x89PNG"


def test_table1_files_and_summary(setup, tmp_path):
    import json

    from tissue_reference.control.table1 import table1_row, write_table1

    case, K, plant = setup
    model = LinearizedModel(case, plant, linear_tangent(K), "T1")
    ok = run_closed_loop(plant, case, model, "T1", 3, settings=LoopSettings(steps=100))
    # 101 closed-loop solves, the open loop's first load given back: it fails at step 5
    cut = run_closed_loop(FailingAfter(plant, 101 + 4), case, model, "T1", 3,
                          settings=LoopSettings(steps=100))
    rows = [table1_row("T1", 3, ok), table1_row("T1", 3, cut),
            {"target": "T2", "task": 1, "status": "unreachable", "error": "goal outside"}]
    summ = write_table1(tmp_path, {"case": "phantom"}, rows, 3)
    assert summ["ran"] == 2 and summ["unreachable"] == 1 and not summ["all_met"]
    assert summ["sse_le_0.05mm"] == 2 and summ["zero_retraction"] == 2
    assert summ["open_loop_plant_failures"] == 1
    data = json.loads((tmp_path / "table1.json").read_text())
    assert data["summary"] == summ and len(data["rows"]) == 3
    md = (tmp_path / "table1.md").read_text()
    assert md.count("\n| T1 | 3 |") == 2 and ">= " in md and "plant failed at step 5" in md
    assert "unreachable: goal outside" in md
    html = (tmp_path / "table1.html").read_text()
    table, settings = html.split("<h2>Settings</h2>")
    assert table.count("<tr>") == 4 and "&gt;= " in table
    # the settings as a key/value table, not JSON
    assert "<th scope='row'>case</th><td>phantom</td>" in settings and "<pre>" not in html


def test_table1_passes_on_a_long_loops_steps_at_most_once_a_minute(setup, tmp_path,
                                                                   monkeypatch):
    """The real loop on the linear plant, each plant solve taking 25 s of a fake clock: its
    step lines reach ``progress`` prefixed by target and task, the first STEP_LINE_S after the
    loop starts at the earliest, then at most one per STEP_LINE_S; with step_lines=False only
    each scenario's own line."""
    from tissue_reference.control import table1

    case, K, plant = setup
    clock = [0.0]
    monkeypatch.setattr(table1.time, "monotonic", lambda: clock[0])
    starts = {}

    def slow(case_, pushes, initial=None):
        clock[0] += 25.0
        return plant(case_, pushes, initial)

    class Loop:   # what run_table1 needs of control.plants.LoopSetup
        def run(self, target, task, settings, progress=None):
            starts[f"{target} task {task}"] = clock[0]
            model = LinearizedModel(case, plant, linear_tangent(K), target)
            return run_closed_loop(slow, case, model, target, task, settings=settings,
                                   progress=progress)

    lines = []
    table1.run_table1(case, ["T1"], Loop(), LoopSettings(steps=12), tmp_path, plots=False,
                      progress=lambda line: lines.append((clock[0], line)))
    assert sum("itae closed" in line for _, line in lines) == 3
    steps = [(t, line) for t, line in lines if "itae closed" not in line]
    assert any("closed loop step" in line for _, line in steps)
    assert any("open loop step" in line for _, line in steps)
    for name, t0 in starts.items():
        times = [t for t, line in steps if line.startswith(name + ": ")]
        assert times, name
        assert np.all(np.diff([t0, *times]) >= table1.STEP_LINE_S)
    assert all(any(line.startswith(n + ": ") for n in starts) for _, line in steps)
    quiet = []
    table1.run_table1(case, ["T1"], Loop(), LoopSettings(steps=12), tmp_path / "q",
                      plots=False, progress=quiet.append, step_lines=False)
    assert len(quiet) == 3 and all("itae closed" in line for line in quiet)


def test_table1_killed_after_its_first_row_resumes_to_the_same_table(setup, tmp_path):
    """A run stopped (KeyboardInterrupt) after its first loop leaves that row in table1.json;
    the same run resumed runs only the two loops it lacks, and its table is the table of a run
    never stopped (rows equal but for wall and step times). A folder of other settings is refused,
    naming the setting; a row of a target not asked for too; restarting ignores the table."""
    import json

    from tissue_reference.control.table1 import run_table1

    case, K, plant = setup
    ran = []

    class Loop:   # what run_table1 needs of control.plants.LoopSetup
        def __init__(self, stop_after=None):
            self.stop_after = stop_after

        def run(self, target, task, settings, progress=None):
            if self.stop_after is not None and len(ran) >= self.stop_after:
                raise KeyboardInterrupt
            ran.append((target, task))
            model = LinearizedModel(case, plant, linear_tangent(K), target)
            return run_closed_loop(plant, case, model, target, task, settings=settings)

    meta = {"case": "phantom", "settings": {"steps": 6}}
    settings = LoopSettings(steps=6)
    whole = run_table1(case, ["T1"], Loop(), settings, tmp_path / "whole", meta=meta,
                       plots=False, progress=lambda line: None)
    assert len(ran) == 3
    ran.clear()
    out = tmp_path / "stopped"
    with pytest.raises(KeyboardInterrupt):
        run_table1(case, ["T1"], Loop(stop_after=1), settings, out, meta=meta, plots=False,
                   progress=lambda line: None)
    assert [r["task"] for r in json.loads((out / "table1.json").read_text())["rows"]] == [1]
    ran.clear()
    lines = []
    summ = run_table1(case, ["T1"], Loop(), settings, out, meta=meta, plots=False,
                      progress=lines.append, resume=True)
    assert ran == [("T1", 2), ("T1", 3)]
    assert "1 of 3 loops finished there, 2 to run" in lines[0]
    assert summ == whole

    def rows(folder):
        return [{k: v for k, v in r.items() if not k.endswith(("_s", "_ms"))}
                for r in json.loads((folder / "table1.json").read_text())["rows"]]

    assert rows(out) == rows(tmp_path / "whole")
    ran.clear()
    run_table1(case, ["T1"], Loop(), settings, out, meta=meta, plots=False,
               progress=lambda line: None, resume=True)
    assert ran == []   # nothing left to run
    other = {"case": "phantom", "settings": {"steps": 8}}
    with pytest.raises(CaseError, match=r"other settings: settings\.steps \(6 there, 8 now\)"):
        run_table1(case, ["T1"], Loop(), LoopSettings(steps=8), out, meta=other, plots=False,
                   progress=lambda line: None, resume=True)
    with pytest.raises(CaseError, match="rows this run does not ask for"):
        run_table1(case, ["T2"], Loop(), settings, out, meta=meta, plots=False,
                   progress=lambda line: None, resume=True)
    run_table1(case, ["T1"], Loop(), settings, out, meta=other, plots=False,
               progress=lambda line: None)   # not resumed: starts over
    assert ran == [("T1", 1), ("T1", 2), ("T1", 3)]
    (out / "table1.json").write_text("{")
    with pytest.raises(CaseError, match="not a Table I table to resume from"):
        run_table1(case, ["T1"], Loop(), settings, out, meta=meta, plots=False,
                   progress=lambda line: None, resume=True)


@pytest.mark.slow
def test_tissue_table1_resumes_its_folder_and_restarts_on_request(tmp_path, capsys):
    """The same ``tissue table1`` command run again in its folder resumes it (nothing left to
    run here); other settings are refused with exit status 2, naming the setting; --restart
    runs every loop again."""
    import json

    from tissue_reference.tissue.cli import main

    out = tmp_path / "t"
    cmd = ["table1", "phantom", "--size", "14", "--targets", "T1", "--steps", "2", "--out",
           str(out)]
    main(cmd + ["-q"])
    first = json.loads((out / "table1.json").read_text())["rows"]
    assert [r["task"] for r in first] == [1, 2, 3]
    capsys.readouterr()
    main(cmd)
    assert "3 of 3 loops finished there, 0 to run" in capsys.readouterr().out
    assert json.loads((out / "table1.json").read_text())["rows"] == first
    assert main(cmd[:-3] + ["3", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "settings.steps (2 there, 3 now)" in err and "--restart" in err
    main(cmd + ["--restart"])
    assert "finished there" not in capsys.readouterr().out
    again = json.loads((out / "table1.json").read_text())["rows"]
    assert [r["wall_time_s"] for r in again] != [r["wall_time_s"] for r in first]   # rerun


class StaleBoundary:
    """A plant that reports success but returns the previous call's state from call ``n`` on (the
    failure mode of a solver whose restart keeps the old boundary values)."""

    def __init__(self, plant, n):
        self.plant, self.n, self.calls, self.last = plant, n, 0, None

    def __call__(self, case, pushes, initial=None):
        self.calls += 1
        r = self.plant(case, pushes, initial)
        if self.calls >= self.n and self.last is not None:
            r = self.last
        self.last = r
        return r


def test_a_converged_state_that_misses_the_pushes_is_refused(setup):
    case, K, plant = setup
    model = LinearizedModel(case, plant, linear_tangent(K), "T1")
    with pytest.raises(ConvergenceError, match="misses the prescribed displacements"):
        run_closed_loop(StaleBoundary(plant, 3), case, model, "T1", 1,
                        settings=LoopSettings(steps=5, open_loop=False))
    bad_model = LinearizedModel(case, StaleBoundary(plant, 3), linear_tangent(K), "T1")
    with pytest.raises(ConvergenceError, match="controller model.* solve reported success"):
        run_closed_loop(plant, case, bad_model, "T1", 1,
                        settings=LoopSettings(steps=5, open_loop=False))


class WarmFails:
    """The linear plant, raising ConvergenceError on warm-started calls from call ``n`` on."""

    def __init__(self, plant, n):
        self.plant, self.n, self.calls = plant, n, 0

    def __call__(self, case, pushes, initial=None):
        self.calls += 1
        if self.calls >= self.n and initial is not None:
            raise ConvergenceError("test plant: warm start left the basin")
        return self.plant(case, pushes, initial)


def test_a_failed_warm_start_is_retried_cold_and_recorded(setup):
    case, K, plant = setup
    model = LinearizedModel(case, plant, linear_tangent(K), "T1")
    ref = run_closed_loop(plant, case, model, "T1", 1, settings=LoopSettings(steps=6))
    res = run_closed_loop(WarmFails(plant, 4), case, model, "T1", 1, settings=LoopSettings(steps=6))
    np.testing.assert_allclose(res.pushes, ref.pushes, rtol=0, atol=1e-12)
    np.testing.assert_allclose(res.open_loop["error_mm"], ref.open_loop["error_mm"], atol=1e-12)
    assert len(res.extra["plant_retries"]) == 6 - 2         # closed-loop calls 4..7 (1-based)
    assert all("warm start left the basin" in m for m in res.extra["plant_retries"])
    assert len(res.open_loop["retries"]) == 6               # open-loop steps 1..6 (step 0 cold)


def test_a_converged_but_folded_plant_state_is_not_measured():
    """A plant answer marked invalid (inverted cells) fails the step instead of being measured."""
    from tissue_reference.control.loop import check_prescribed
    from tissue_reference.errors import ConvergenceError
    from tissue_reference.meshes.builders import box
    from tissue_reference.model.case import Boundary, Case
    from tissue_reference.model.results import SolveResult

    mesh = box(5.0)
    case = Case(mesh=mesh, boundaries=[Boundary("zmin", "fixed")], name="folded")
    r = SolveResult(u=np.zeros((mesh.n_vertices, 3)), converged=True, iterations=1, residual=0.0,
                    wall_time_s=0.0, solver="test",
                    valid=False, invalid_reason="3 inverted cells")
    with pytest.raises(ConvergenceError, match="not valid: 3 inverted cells"):
        check_prescribed(case, {}, r, "plant")
    ok = SolveResult(u=np.zeros((mesh.n_vertices, 3)), converged=True, iterations=1,
                     residual=0.0, wall_time_s=0.0, solver="test", valid=True)
    check_prescribed(case, {}, ok, "plant")


def test_kept_answers_match_a_load_to_round_off_and_no_further():
    """A load asked again within PUSH_MATCH_MM of one solved gets that answer back, whichever
    solve it was; one a micrometre away, another case or another set of actuators is solved."""
    from tissue_reference.control.plant_step import KeptAnswers

    solved = []

    def solve(case, pushes, initial):
        solved.append(dict(pushes))
        return object()

    case, other = object(), object()
    kept = KeptAnswers(solve)
    a = kept(case, {"A1": 1.0, "A2": 0.5}, None)
    b = kept(case, {"A1": 2.0, "A2": 0.5}, None)
    assert kept(case, {"A2": 0.5 + 1e-12, "A1": 1.0 - 1e-12}, None) is a   # the earlier one
    assert kept(case, {"A1": 2.0, "A2": 0.5}, None) is b
    assert kept.kept == 2 and len(solved) == 2
    assert kept(case, {"A1": 1.0 + 1e-6, "A2": 0.5}, None) not in (a, b)
    assert kept(other, {"A1": 1.0, "A2": 0.5}, None) is not a
    assert kept(case, {"A1": 1.0}, None) is not a
    assert len(solved) == 5 and kept.kept == 2


class _Counting:
    """A plant that counts its solves and records their pushes."""

    def __init__(self, plant):
        self.plant, self.pushes = plant, []

    def __call__(self, case, pushes, initial=None):
        self.pushes.append(tuple(sorted(pushes.items())))
        return self.plant(case, pushes, initial)


def test_a_plant_answer_is_kept_where_the_pushes_repeat(setup):
    """A loop whose pushes stop at the push limit solves the plant once per load: the closed
    loop's and the open loop's held steps, and the preload both loops start from, give back the
    answer solved before, and the loop is the same as with every step solved (the linear
    plant's answer does not depend on its start)."""
    case, K, plant = setup
    model = LinearizedModel(case, plant, linear_tangent(K), "T1")
    settings = LoopSettings(steps=40, task_mm=5.0,
                            mpc=MPCSettings(max_travel=1.0))   # the goal lies beyond the limit
    counted = _Counting(plant)
    res = run_closed_loop(counted, case, model, "T1", 1, settings=settings)
    closed = [tuple(sorted(zip(res.actuators, p))) for p in res.pushes.tolist()]
    opened = [tuple(sorted(zip(res.actuators, p))) for p in res.open_loop["pushes"].tolist()]
    assert len(set(closed)) < len(closed) and closed[-1] == closed[-2]   # held at the limit
    asked = closed + opened   # every step's pushes, in the order the loop asks for them
    assert opened[0] == closed[0]   # both loops start at the preload (here rest)
    loads = [p for i, p in enumerate(asked) if not any(
        all(abs(a[1] - b[1]) <= PUSH_MATCH_MM for a, b in zip(p, q)) for q in asked[:i])]
    assert counted.pushes == loads   # solved at each load the first time, nowhere else
    assert res.extra["plant_kept_steps"] == len(asked) - len(loads)
    assert res.to_json_dict()["plant_kept_steps"] == res.extra["plant_kept_steps"] > 0
    every = run_closed_loop(plant, case, LinearizedModel(case, plant, linear_tangent(K), "T1"),
                            "T1", 1, settings=settings)
    assert np.allclose(every.target, res.target, rtol=0, atol=1e-12)
    assert np.allclose(every.open_loop["target"], res.open_loop["target"], rtol=0, atol=1e-12)
