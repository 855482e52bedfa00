"""The toolkit works from a folder of the user's own, outside the repository: shipped cases by
name, output folders made as needed, a solver given as a Python file."""
import json

import pytest

from tissue_reference.errors import CaseReadError
from tissue_reference.model.case import load_case
from tissue_reference.model.case_file import SHIPPED_CASES, shipped_cases
from tissue_reference.tissue.cli import main

PLUGIN = '''
import numpy as np


def solve(case, pushes, **options):
    """Every vertex moved by the first push along x: not a tissue model, a solver to score."""
    u = np.zeros((case.mesh.n_vertices, case.mesh.gdim))
    u[:, 0] = -float(next(iter(pushes.values()), 0.0))
    return u
'''


@pytest.fixture
def elsewhere(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    return tmp_path


def test_a_shipped_case_loads_by_name_from_any_folder(elsewhere):
    names = shipped_cases()
    assert {"phantom", "phantom-indenter", "phantom-indenter-quarter"} <= set(names)
    assert not (elsewhere / "meshes").exists()
    for name in ("phantom", "phantom.toml"):
        c = load_case(name, size=14.0)
        assert c.name == "phantom" and c.source == str(SHIPPED_CASES / "phantom.toml")
    (elsewhere / "phantom.toml").write_text("not toml [")   # a file of the user's wins
    with pytest.raises(CaseReadError, match="invalid TOML"):
        load_case("phantom.toml")


def test_a_name_that_is_no_case_lists_the_shipped_ones(elsewhere, capsys):
    assert main(["solve", "phantom-indentr", "--push", "A1=1"]) == 2
    err = capsys.readouterr().err
    assert "phantom-indentr: does not exist" in err and "phantom-indenter-quarter" in err


def test_solve_by_name_writes_into_folders_it_makes(elsewhere, capsys):
    assert main(["solve", "phantom", "--size", "14", "--push", "A1=2", "-q", "--no-estimate",
                 "--json", "runs/today/a.json", "--out", "runs/today/fields"]) == 0
    d = json.loads((elsewhere / "runs" / "today" / "a.json").read_text())
    assert d["valid"] is True
    assert (elsewhere / "runs" / "today" / "fields").is_dir()


def test_a_solver_given_as_a_file_is_scored(elsewhere, capsys):
    (elsewhere / "my_solver.py").write_text(PLUGIN)
    assert main(["verify", "phantom", "--size", "14", "--push", "A1=1", "--solvers",
                 "my_solver.py:solve", "--json", "v/v.json"]) == 0
    d = json.loads((elsewhere / "v" / "v.json").read_text())
    assert list(d["solvers"]) == ["my_solver.py:solve"]
    assert d["solvers"]["my_solver.py:solve"]["max_vertex_error_mm"] > 0.1
    assert main(["verify", "phantom", "--size", "14", "--push", "A1=1", "--solvers",
                 "missing.py:solve"]) == 2
    assert "file 'missing.py' does not exist" in capsys.readouterr().err


def test_a_folder_of_a_cases_name_does_not_hide_it(elsewhere):
    (elsewhere / "phantom").mkdir()   # e.g. left by an earlier --out phantom
    assert load_case("phantom", size=14.0).source == str(SHIPPED_CASES / "phantom.toml")


def test_a_solver_file_loads_once_and_imports_its_neighbours(elsewhere):
    from tissue_reference.verification.plugins import resolve_solver

    (elsewhere / "helper.py").write_text("SCALE = 2.0\n")
    (elsewhere / "uses_helper.py").write_text(
        "import helper\nCALLS = []\n\n\ndef solve(case, pushes, **options):\n"
        "    CALLS.append(1)\n    return helper.SCALE\n")
    a = resolve_solver("uses_helper.py:solve")
    b = resolve_solver("uses_helper.py:solve")
    assert a.function is b.function and a.function(None, {}) == 2.0
