"""One actuator convention for every solve, the control Jacobians and the loop: a patch that is
not pushed is held where it is (glued) unless the case or --free-actuators frees it."""
import json
from pathlib import Path

import numpy as np
import pytest
from fem_checks import jacobian_column_error

import tissue_reference.fem_reference as fr
from tissue_reference.errors import CaseError
from tissue_reference.model.case import load_case

CASE = "meshes/cases/phantom.toml"
# the loops' task (mm): small enough that no push, open loop included, passes the glued
# patch's radius (5 mm), beyond which its answer converges to nothing (at size 14 the largest
# open-loop push is 4.6 mm: T2's task 3)
TASK_MM = 0.3
# the stated tolerance of two runs' table1 figures: relative, and absolute (mm, or mm s for
# ITAE); ten times the ADMM model's polish tolerance (1e-7 mm), a thousandth of a figure
ROWS_RTOL, ROWS_ATOL = 1e-6, 1e-6


@pytest.fixture(scope="module")
def case():
    return load_case(CASE, size=14.0)


def _region_dofs(case, name):
    v = case.mesh.region_vertices(case.actuator(name).region)
    return (3 * v[:, None] + np.arange(3)).ravel()


def test_unpushed_patches_are_held_unless_freed(case):
    pushed = case.with_pushes({"A1": 3.0})
    con = dict(zip(pushed.constraints.dofs.tolist(), pushed.constraints.values.tolist()))
    for name in ("A2", "A3", "A4"):
        dofs = _region_dofs(case, name)
        assert all(k in con and con[k] == 0.0 for k in dofs.tolist())
    free = case.with_free_actuators().with_pushes({"A1": 3.0})
    held = set(free.constraints.dofs.tolist())
    assert not held & set(_region_dofs(case, "A2").tolist())
    # "where it is": a later push of another actuator keeps A1 at its 3 mm
    again = pushed.with_pushes({"A2": 1.0})
    con = dict(zip(again.constraints.dofs.tolist(), again.constraints.values.tolist()))
    d = np.asarray(case.actuator("A1").direction)
    v = case.mesh.region_vertices(case.actuator("A1").region)[0]
    assert np.allclose([con[3 * v + c] for c in range(3)], 3.0 * d)


def test_the_jacobian_equals_central_differences_of_the_plain_solve(case):
    """J_s of A1 at a 5 mm pre-push against central differences of fem_reference.solve with
    only A1 named (what `tissue solve --push A1=...` runs): the same convention, 1e-4."""
    assert jacobian_column_error(case, "A1", 5.0) < 1e-4


def test_a_case_file_may_free_its_patches_and_indenters_take_no_idle(tmp_path):
    text = Path(CASE).read_text()
    free = tmp_path / "free.toml"
    free.write_text(text.replace('direction = [-1.0, 0.0, 0.0]',
                                 'direction = [-1.0, 0.0, 0.0]\nidle = "free"', 1)
                    .replace("size = 6.0", "size = 14.0", 1))
    c = load_case(free)
    assert c.actuator("A1").idle == "free"
    assert [a.idle for a in c.actuators][1:] == ["held"] * 3
    from tissue_reference.model.case import Actuator

    with pytest.raises(CaseError, match="idle only for a patch"):
        Actuator("I", "skin", (1, 0, 0), type="indenter", tip="sphere", radius=5.0, idle="free")


def test_cli_free_actuators_changes_the_answer(tmp_path, capsys):
    from tissue_reference.tissue.cli import main

    runs = {}
    for flag in ([], ["--free-actuators"]):
        js = tmp_path / f"s{len(flag)}.json"
        assert main(["solve", CASE, "--size", "14", "--push", "A1=4", "-q", "--json", str(js),
                     *flag]) == 0
        runs[bool(flag)] = json.loads(js.read_text())["probes"]["T1"]["displacement"]
    assert np.linalg.norm(np.subtract(runs[True], runs[False])) > 1e-3


def test_mpc_json_is_complete_and_an_infeasible_open_loop_is_named(tmp_path, capsys):
    from tissue_reference.tissue.cli import main

    js = tmp_path / "m.json"
    rc = main(["mpc", CASE, "--size", "14", "--target", "T1", "--task", "1", "--steps", "4",
               "--max-travel", "0.5", "--model-E-factor", "1.2", "--json", str(js)])
    out = capsys.readouterr().out
    assert rc == 0 and "open loop infeasible" in out
    d = json.loads(js.read_text())
    assert {"case", "target", "task", "plant", "model", "mismatch", "settings", "open_loop",
            "time_s", "actuator_positions_mm", "target_position_mm", "status"} <= set(d)
    assert d["mismatch"]["E_factor"] == 1.2 and d["settings"]["max_travel_mm"] == 0.5
    assert d["open_loop"]["status"] == "infeasible"
    assert max(d["open_loop"]["u_open_mm"]) <= 0.5 < max(d["open_loop"]["u_open_unclamped_mm"])


def test_table1_runs_mismatch_scenarios_with_trajectories(tmp_path, capsys):
    """Gravity on the plant only and a coarser model mesh: each scenario completes (or stops
    with a named reason), writes its table, trajectories and the combined summary and plot."""
    from tissue_reference.tissue.cli import main

    out = tmp_path / "t1"
    rc = main(["table1", CASE, "--size", "14", "--targets", "T1", "--steps", "3",
               "--task-mm", str(TASK_MM), "--scenarios", "gravity", "mesh", "--out", str(out)])
    assert rc == 0
    combined = json.loads((out / "table1_scenarios.json").read_text())
    assert set(combined["scenarios"]) == {"gravity", "mesh"}
    for name in ("gravity", "mesh"):
        t = json.loads((out / name / "table1.json").read_text())
        assert t["meta"]["scenario"] == name and len(t["rows"]) == 3
        assert t["meta"]["mismatch"]["gravity" if name == "gravity" else "mesh"] == "different"
        page = (out / name / "table1.html").read_text()
        for r in t["rows"]:
            if r["status"] == "ok":
                assert f"response_{r['target']}_task{r['task']}.png" in page
    assert (out / "table1_scenarios.png").read_bytes()[:4] == b"\x89PNG"
    # gravity moves the plant's targets before any push: the model (no gravity) cannot know
    g = json.loads((out / "gravity" / "table1.json").read_text())["meta"]
    assert g["plant_gravity_mm_s2"] == [0.0, 0.0, -9810.0] and g["model_gravity_mm_s2"] is None


def _rows_agree(a, b, path="rows"):
    """Whether two table1 row lists agree: the same keys, strings, flags and shapes; numbers
    within ROWS_RTOL relative or ROWS_ATOL absolute. A row's figures come from solves that
    stop at a tolerance (the reference's Newton at 1e-10 mm, the ADMM model's polish at 1e-7
    mm), so a worker process whose BLAS runs another number of threads may give other last
    bits; nothing that meets these tolerances changes a verdict of the table."""
    if isinstance(a, dict) and isinstance(b, dict):
        assert set(a) == set(b), f"{path}: keys {sorted(set(a) ^ set(b))} in one run only"
        for k in a:
            _rows_agree(a[k], b[k], f"{path}.{k}")
    elif isinstance(a, list) and isinstance(b, list):
        assert len(a) == len(b), f"{path}: {len(a)} against {len(b)} entries"
        for i, (x, y) in enumerate(zip(a, b)):
            _rows_agree(x, y, f"{path}[{i}]")
    elif isinstance(a, float) or isinstance(b, float):
        assert isinstance(a, (int, float)) and isinstance(b, (int, float)), f"{path}: {a!r} {b!r}"
        assert abs(a - b) <= ROWS_ATOL + ROWS_RTOL * max(abs(a), abs(b)), f"{path}: {a!r} {b!r}"
    else:
        assert a == b, f"{path}: {a!r} against {b!r}"


def test_table1_in_worker_processes_gives_the_serial_rows(tmp_path, capsys):
    """--jobs 2: every loop in a worker process that builds its own plant and model; the rows
    (verdicts, pushes, order; figures within the stated tolerance) are the serial run's, for a
    plain table and a scenario. The loops stay where a glued patch's answer converges: every
    push, closed loop and open loop, below the 10 mm patch's 5 mm radius."""
    from tissue_reference.tissue.cli import main

    timing = {"wall_time_s", "closed_loop_s", "model_time_s", "open_loop_s", "mpc_step_median_ms"}

    def rows(path):
        return [{k: v for k, v in r.items() if k not in timing}
                for r in json.loads(path.read_text())["rows"]]

    base = ["table1", CASE, "--size", "14", "--steps", "3", "-q", "--task-mm", str(TASK_MM)]
    for extra, sub in ((["--targets", "T1", "T2"], "."),
                       (["--targets", "T1", "--scenarios", "mesh"], "mesh")):
        serial, par = tmp_path / f"s{len(extra)}", tmp_path / f"p{len(extra)}"
        assert main(base + extra + ["--out", str(serial)]) == 0
        assert main(base + extra + ["--jobs", "2", "--out", str(par)]) == 0
        a, b = rows(serial / sub / "table1.json"), rows(par / sub / "table1.json")
        assert [(r["target"], r["task"]) for r in b] == [(t, k) for t in extra[1:3]
                                                          if t.startswith("T") for k in (1, 2, 3)]
        assert all(r["status"] == "ok" and r["open_loop_converged"] for r in a)
        pushes = [p for r in a for p in r["u_open_mm"] + r["final_pushes_mm"]]
        assert 0.5 < max(pushes) < 5.0
        _rows_agree(a, b)
        assert sorted(q.name for q in (par / sub).glob("response_*.png")) == \
            sorted(q.name for q in (serial / sub).glob("response_*.png"))


def test_rows_that_differ_past_the_tolerance_are_told_apart():
    """The comparison above can fail: a figure off by more than the tolerance, a verdict that
    differs, a key in one run only."""
    row = {"target": "T1", "open_loop_converged": True, "closed_loop_itae": 1.25,
           "final_pushes_mm": [0.5, 0.0]}
    _rows_agree([row], [dict(row, closed_loop_itae=1.25 * (1 + ROWS_RTOL / 2))])
    for other in (dict(row, closed_loop_itae=1.25 + 1e-3), dict(row, open_loop_converged=False),
                  dict(row, final_pushes_mm=[0.5, 1e-4]), {**row, "extra": 1}):
        with pytest.raises(AssertionError):
            _rows_agree([row], [other])


def test_a_glued_patch_that_crushes_its_rim_is_named():
    """All four patches at 15 mm on the default mesh: each is past the pushes at which a glued
    patch's answer converges, one line per patch, and A3's line says that it compresses rim
    cells below J = 0.2; 2 mm pushes are named by neither check."""
    c = load_case(CASE)
    far = fr.solve(c, pushes={a: 15.0 for a in ("A1", "A2", "A3", "A4")})
    lines = far.warnings
    assert sorted(w.split("'")[1] for w in lines) == ["A1", "A2", "A3", "A4"]
    assert any("'A3'" in w and "J = " in w for w in lines)
    near = fr.solve(c, pushes={"A1": 2.0})
    assert near.warnings == ()
