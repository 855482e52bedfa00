"""A control loop that pushes an actuator past the range where its model's answers converge says
so, in its result and its exit status; ``--max-travel auto`` keeps it inside.

The independent fact: the phantom's patches are discs of 10 mm diameter (meshes/cases/
phantom.toml), so a glued patch's answers converge up to a push of about 5 mm (its radius; the
coarse mesh's polygon of a disc is a little smaller or larger). The seed's 5 mm task on the glued
phantom asks for pushes of 20-40 mm."""
import json
import math

import pytest

from tissue_reference.control.plant_step import outside_range
from tissue_reference.model.case import load_case
from tissue_reference.model.converged_range import converged_push_limit, converged_travel
from tissue_reference.tissue.cli import main

CASE = "meshes/cases/phantom.toml"
DISC_RADIUS = 5.0
BASE = ["mpc", CASE, "--size", "14", "--target", "T1", "--task", "1", "--steps", "6",
        "--weights", "gain", "-q"]


@pytest.fixture(scope="module")
def case():
    return load_case(CASE, size=14.0)


def test_the_range_is_the_patch_radius_and_linear_elastic_has_none(case):
    travel = converged_travel(case)
    assert set(travel) == {"A1", "A2", "A3", "A4"}
    for v in travel.values():
        assert v == pytest.approx(DISC_RADIUS, rel=0.1)
    assert converged_push_limit(case) == min(travel.values())
    lin = case.with_material(model="linear-elastic")
    assert converged_push_limit(lin) is None
    assert all(math.isinf(v) for v in converged_travel(lin).values())


def test_outside_range_names_each_side_at_its_deepest_push(case):
    acts = ("A1", "A2", "A3", "A4")
    inside = [[0, 0, 0, 0], [2.0, 1.0, 0, 0]]
    assert outside_range(case, case, acts, inside) == []
    deep = inside + [[7.5, 1.0, 0, 0], [6.0, 1.0, 0, 0]]
    lines = outside_range(case, case, acts, deep)
    assert len(lines) == 1 and lines[0].startswith("plant: glued patch 'A1' pushed 7.5 mm")
    model = load_case(CASE, size=14.0)   # another Case object: plant and model named apart
    lines = outside_range(case, model, acts, deep)
    assert [ln.split(":")[0] for ln in lines] == ["plant", "model"]


def test_a_loop_past_its_models_range_says_so_and_exits_1(tmp_path, capsys):
    js = tmp_path / "m.json"
    assert main(BASE + ["--json", str(js)]) == 1
    err = capsys.readouterr().err
    d = json.loads(js.read_text())
    deepest = max(p[0] for p in d["actuator_positions_mm"])
    assert deepest > 2 * DISC_RADIUS
    assert d["status"] == "outside range"
    assert len(d["outside_range"]) == 1 and f"'A1' pushed {deepest:g} mm" in d["outside_range"][0]
    assert d["open_loop"]["status"] == "outside range" and d["open_loop"]["outside_range"]
    assert "the closed loop left the range where answers converge" in err
    assert "the open loop left the range where answers converge" in err


def test_max_travel_auto_keeps_the_loop_in_range(tmp_path):
    js = tmp_path / "m.json"
    assert main(BASE + ["--max-travel", "auto", "--json", str(js)]) == 0
    d = json.loads(js.read_text())
    limit = d["settings"]["max_travel_mm"]
    assert 0.8 * DISC_RADIUS < limit < 1.1 * DISC_RADIUS
    assert max(max(p) for p in d["actuator_positions_mm"]) <= limit * (1 + 1e-9)
    assert d["status"] == "completed" and d["outside_range"] == []
    # the open loop's 41 mm pushes are clamped to the limit: infeasible, not outside the range
    assert d["open_loop"]["status"] == "infeasible" and d["open_loop"]["outside_range"] == []


def test_a_table_with_a_loop_past_its_range_exits_1_and_is_not_met(tmp_path, capsys):
    out = tmp_path / "t"
    assert main(["table1", CASE, "--size", "14", "--targets", "T1", "--steps", "2", "-q",
                 "--out", str(out)]) == 1
    assert "pushed past the range" in capsys.readouterr().err
    t = json.loads((out / "table1.json").read_text())
    assert t["summary"]["outside_range"] == 3 and t["summary"]["all_met"] is False
    assert all(r["open_loop_outside_range"] for r in t["rows"])
    assert "outside the range where answers converge" in (out / "table1.md").read_text()


def test_max_travel_auto_takes_each_scenarios_own_range(tmp_path):
    """The mesh scenario's model is a coarser mesh, whose patches' polygons differ: auto takes
    the smallest range of that scenario's plant and model, and no loop leaves it."""
    out = tmp_path / "t"
    assert main(["table1", CASE, "--size", "14", "--targets", "T1", "--steps", "2", "-q",
                 "--scenarios", "mesh", "--max-travel", "auto", "--out", str(out)]) == 0
    t = json.loads((out / "mesh" / "table1.json").read_text())
    limit = t["meta"]["settings"]["max_travel_mm"]
    assert 0.8 * DISC_RADIUS < limit < 1.1 * DISC_RADIUS
    assert t["summary"]["outside_range"] == 0
    assert all(max(r["final_pushes_mm"]) <= limit * (1 + 1e-9) for r in t["rows"])
