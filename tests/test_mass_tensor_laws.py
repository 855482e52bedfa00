"""The laws the Mass Tensor method takes: linear elasticity, and Neo-Hookean solved as linear
elasticity of the same E and nu (said in ``model_note``); every other law refused by name, and
left out with the reason where a command runs several solvers."""
import numpy as np
import pytest

from tissue_reference.errors import CaseError, NotModeledError
from tissue_reference.meshes.builders import box
from tissue_reference.model.case import Boundary, Case, Material, load_case
from tissue_reference.solvers import mass_tensor as mt
from tissue_reference.solvers.registry import solver
from tissue_reference.verification.suite import law_material, run_suite
from tissue_reference.verification.verify import verify

REFUSED = ("mooney-rivlin", "yeoh", "stable-neo-hookean", "saint-venant-kirchhoff",
           "corotational", "ogden")


@pytest.fixture(scope="module")
def cube():
    return box(5.0, lengths=(10.0, 10.0, 10.0))


def stretch(mesh, material):
    return Case(mesh=mesh, material=material,
                boundaries=[Boundary("xmin", "fixed"),
                            Boundary("xmax", "displacement", value=(0.5, 0.2, -0.1))])


def test_the_registry_declares_the_laws_it_takes():
    assert solver("mass-tensor").laws == ("linear-elastic", "neo-hookean")
    assert solver("admm").laws is None and solver("fem").laws is None


@pytest.mark.parametrize("law", REFUSED)
def test_each_nonlinear_law_but_neo_hookean_is_refused_by_name(cube, law):
    case = stretch(cube, law_material(law, 48.0, 0.45))
    with pytest.raises(NotModeledError) as exc:
        mt.solve(case)
    msg = str(exc.value)
    assert isinstance(exc.value, CaseError)
    assert f"the {law} law" in msg and "linear elasticity with the case's E and nu" in msg
    assert "--material linear-elastic" in msg and "admm" in msg
    with pytest.raises(NotModeledError, match=law):   # and through the registry
        solver("mass-tensor").solve(case)


def test_linear_elastic_solves_and_neo_hookean_is_its_linear_model_with_a_note(cube):
    lin = mt.solve(stretch(cube, Material("linear-elastic", E=48.0, nu=0.45)))
    assert lin.converged and lin.model == "linear-elastic" and lin.model_note is None
    nh = mt.solve(stretch(cube, Material("neo-hookean", E=48.0, nu=0.45)))
    assert nh.converged and nh.model == "linear-elastic"
    assert "not its neo-hookean material" in nh.model_note
    assert np.array_equal(nh.u, lin.u)


def test_cli_solve_refusal_names_the_law_with_the_error_exit_status(capsys):
    from tissue_reference.tissue.cli import main

    rc = main(["solve", "meshes/cases/phantom.toml", "--size", "14", "--solver", "mass-tensor",
               "--material", "yeoh:c1=5,c2=-0.5,c3=0.1,k=300"])
    err = capsys.readouterr().err
    assert rc == 2 and "tissue solve: error: solver 'mass-tensor'" in err
    assert "yeoh" in err and "--material linear-elastic" in err


def test_verify_lists_the_mass_tensor_as_not_applicable_and_scores_admm(capsys):
    case = load_case("meshes/cases/phantom.toml", size=14.0).with_law(
        "mooney-rivlin", {"c1": 5.0, "c2": 2.0, "k": 300.0})
    res = verify(case, {"A1": 1.0}, solvers=("mass-tensor", "admm"))
    assert "mass-tensor" not in res["solvers"] and "admm" in res["solvers"]
    why = res["skipped"]["mass-tensor"]
    assert "mooney-rivlin" in why and "--material linear-elastic" in why
    assert res["solvers"]["admm"]["model"] == "mooney-rivlin"
    assert list(res["reference"]["runs"]) == ["mooney-rivlin"]   # no linear run for it
    assert "mass-tensor" in capsys.readouterr().out


def test_a_suite_on_a_refused_law_lists_the_mass_tensor_as_refused_with_the_reason():
    out = run_suite(("admm", "mass-tensor"), ["shear-patch"], law="yeoh")
    r = out["problems"][0]["results"]
    assert r["admm"]["passed"] and "the yeoh law" in r["mass-tensor"]["refused"]
    assert out["summary"]["mass-tensor"] == {"passed": 0, "failed": 0, "refused": 1}
