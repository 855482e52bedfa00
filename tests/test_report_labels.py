"""Reports say what was computed and nothing else: a figure a solver did not report is named
as such (not "None"), a comparison that needs no registration says so (not a blank cell), a
solver that is not ours is labelled with the model it states (not the case's), and a verify
report with --estimate shows the reference's own error beside the scores."""
from functools import partial

import numpy as np
import pytest

from tissue_reference.meshes.builders import box
from tissue_reference.model.case import Boundary, Case, Material, Probe
from tissue_reference.tissue.implant_report import distance_rows
from tissue_reference.tissue.suite_report import result_cell
from tissue_reference.tissue.verify_report import write_report
from tissue_reference.verification.verify import verify


@pytest.fixture(scope="module")
def pulled():
    """A 10 mm box, bottom fixed, its top pulled 0.2 mm up (a glued patch), two targets."""
    from tissue_reference.model.case import Actuator

    return Case(mesh=box(5.0), material=Material("neo-hookean", E=6.0, nu=0.3), name="pulled",
                boundaries=(Boundary("zmin", "fixed"),),
                actuators=(Actuator("A", "zmax", (0.0, 0.0, 1.0)),),
                probes=(Probe("P", (5.0, 5.0, 5.0)), Probe("Q", (2.5, 7.5, 8.0))))


def test_a_scorecard_cell_names_iterations_that_were_not_reported():
    row = {"passed": True, "value_mm": 1.0, "error_rel": 1e-3, "wall_time_s": 0.5,
           "iterations": None}
    assert "None" not in result_cell(row) and "iterations not reported" in result_cell(row)
    assert "12 its" in result_cell({**row, "iterations": 12})


def test_distance_rows_on_one_mesh_say_no_registration_was_needed():
    rows = distance_rows({"d_max_mm": 0.0314, "mean_distance_mm": 0.01,
                          "neo_hookean": {"d_max_mm": 0.2, "mean_distance_mm": 0.1}})
    assert len(rows) == 2 and all(c != "" for r in rows for c in r)
    assert all("same mesh" in str(r[3]) for r in rows)


def linear_solver(case, pushes, **_):
    """A solver that is not ours, of linear elasticity, and says so."""
    from tissue_reference.fem_reference import solve
    r = solve(case.with_material(model="linear-elastic"), pushes=pushes, degree=1)
    return {"u": r.u, "extra": {"model": "linear-elastic"}}


def silent_solver(case, pushes, **_):
    """A solver that states no model."""
    return np.zeros((case.mesh.n_vertices, 3))


def test_a_plugin_is_labelled_with_the_model_it_states_and_the_report_shows_the_refs_error(
        pulled, tmp_path):
    out = verify(pulled, {"A": 0.2}, solvers=[linear_solver, silent_solver],
                 report=partial(write_report, tmp_path), estimate=True)
    scores = {name.rpartition(":")[2]: e for name, e in out["solvers"].items()}
    assert scores["linear_solver"]["model"] == "linear-elastic"
    assert scores["silent_solver"]["model"].startswith("not stated")
    est = scores["linear_solver"]["discretization_error_estimate_mm"]
    assert set(est) == {"P", "Q"}
    page = (tmp_path / "report.html").read_text()
    assert "own error (estimate)" in page   # the label is HTML-escaped
