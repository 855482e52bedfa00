"""The Python API speaks up: an answer that is not valid, one past the loads where answers
converge, or one whose estimated error is above 2 % warns with TissueWarning; a trustworthy one
is silent; the command line prints its own lines instead of Python's."""
import warnings

import numpy as np
import pytest

import tissue_reference.fem_reference as fr
from tissue_reference.errors import TissueWarning
from tissue_reference.model.answer_warnings import (
    FOLDED_ADVICE,
    answer_concerns,
    estimate_warning,
)
from tissue_reference.model.case import load_case
from tissue_reference.model.results import SolveResult
from tissue_reference.tissue.cli import main


@pytest.fixture(scope="module")
def case():
    return load_case("meshes/cases/phantom.toml", size=14.0)


def _result(fields, probes=None):
    n = 4
    return SolveResult(u=np.zeros((n, 3)), converged=True, iterations=1, residual=0.0,
                       wall_time_s=0.0, solver="x", probes=probes or {}, **fields)


def test_each_concern_is_one_line():
    assert answer_concerns(_result({"valid": True})) == []
    assert answer_concerns(_result({"valid": False, "invalid_reason": "3 inverted cells"})) == \
        [f"the answer is not valid: 3 inverted cells; {FOLDED_ADVICE}"]
    assert answer_concerns(_result({"valid": False, "invalid_reason": "runaway"})) == \
        ["the answer is not valid: runaway"]
    big = _result({"probe_error_estimates": {"T1": 0.05}}, {"T1": np.array([1.0, 0.0, 0.0])})
    assert answer_concerns(big)[0].startswith("estimated discretization error up to 5.0%")
    small = _result({"probe_error_estimates": {"T1": 0.01}}, {"T1": np.array([1.0, 0.0, 0.0])})
    assert answer_concerns(small) == []


def test_a_solve_past_the_converged_range_warns_and_a_small_push_does_not(case):
    with pytest.warns(TissueWarning, match="pushed 10 mm"):
        fr.solve(case, pushes={"A1": 10.0})
    with warnings.catch_warnings():
        warnings.simplefilter("error", TissueWarning)
        r = fr.solve(case, pushes={"A1": 2.0})
    assert r.valid


def test_an_invalid_answer_warns(case):
    """Nearly incompressible tissue (mixed P2/P1) with all four glued patches pushed 15 mm
    folds rim cells on this coarse mesh: the answer comes back converged, not valid, and says
    so (27 inverted cells when this test was written)."""
    with pytest.warns(TissueWarning) as caught:
        r = fr.solve(case.with_material(nu=0.4999), pushes={a: 15.0 for a in
                                                            ("A1", "A2", "A3", "A4")})
    assert r.converged and r.valid is False
    assert any(str(w.message).startswith("the answer is not valid: ") for w in caught)


def test_the_command_line_prints_its_own_lines_not_pythons(capsys):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rc = main(["solve", "meshes/cases/phantom.toml", "--size", "14", "--push", "A1=10",
                   "-q", "--no-estimate"])
    assert rc == 1
    assert not [w for w in caught if issubclass(w.category, TissueWarning)]
    err = capsys.readouterr().err
    assert "tissue solve: warning: glued patch 'A1' pushed 10 mm" in err


def test_the_estimates_conclusion_is_the_librarys():
    """An estimate above 2 % of a probe's displacement warns, one below does not; at a load with
    no mesh-converged answer any estimate is a difference between degrees, said as such."""
    u = {"T1": np.array([0.0, 2.0, 0.0])}
    big = _result({"probe_error_estimates": {"T1": 0.1}}, u)
    assert estimate_warning(big) == (
        "estimated discretization error up to 5.0% of a probe's displacement (above 2%): "
        "raise --degree, or refine until it is within a tolerance (--accuracy 0.01)")
    assert answer_concerns(big) == [estimate_warning(big)]
    assert estimate_warning(_result({"probe_error_estimates": {"T1": 0.02}}, u)) is None
    assert estimate_warning(_result({}, u)) is None
    why = "glued patch 'A1' pushed 10 mm"
    small = _result({"probe_error_estimates": {"T1": 0.02}, "no_converged_value": why,
                     "degree": 2}, u)
    assert estimate_warning(small).startswith("the degree-3 answer differs from this one by up "
                                              "to 1.0% of a probe's displacement")
    assert answer_concerns(small) == [estimate_warning(small),
                                      f"no mesh-converged answer is known at this load: {why}"]


def test_a_probe_that_did_not_move_with_no_error_is_no_concern():
    still = _result({"probe_error_estimates": {"T1": 0.0}}, {"T1": np.zeros(3)})
    assert answer_concerns(still) == []


def test_the_first_use_of_the_reference_leaves_warnings_shown_as_warnings():
    """Importing dolfinx imports FFCx, which routes Python's warnings to logging; the reference's
    public names load it without that, so a first solve's TissueWarning is a warning."""
    import subprocess
    import sys

    code = ("import warnings; shown = warnings.showwarning; "
            "import tissue_reference.fem_reference as fr; fr.ReferenceSolver; "
            "import sys; print('ffcx' in sys.modules, warnings.showwarning is shown)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.split()
    assert out == ["True", "True"]
