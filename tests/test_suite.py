"""The verification suite: its known answers checked against independent limits, the reference
passing it, and the scorecard's handling of solvers that fail or refuse."""
import json

import numpy as np
import pytest
from test_laws import LAWS, piola_formula

from tissue_reference.errors import CaseError
from tissue_reference.model.case import Material
from tissue_reference.tissue.suite_report import write_scorecard
from tissue_reference.verification import closed_forms as cf
from tissue_reference.verification.suite import run_suite


def lame_sphere_u_outer(a, b, push, E, nu):
    """Small-strain thick sphere: u = A r + B / r^2, u(a) = push, sigma_rr(b) = 0."""
    lam, mu = E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))
    k = 4 * mu / ((3 * lam + 2 * mu) * b ** 3)      # A = k B
    B = push / (k * a + 1 / a ** 2)
    return k * B * b + B / b ** 2


def test_the_sphere_ode_tends_to_the_linear_closed_form_at_small_pushes():
    m = Material("neo-hookean", E=6.0, nu=0.45)
    push = 1e-4
    u = cf.thick_sphere(10.0, 20.0, push, m.mu, m.kappa)["u_outer"]
    assert u == pytest.approx(lame_sphere_u_outer(10.0, 20.0, push, 6.0, 0.45), rel=1e-3)


def test_the_sphere_ode_tends_to_the_incompressible_closed_form():
    m = Material("neo-hookean", E=6.0, nu=0.49999)
    u = cf.thick_sphere(10.0, 20.0, 2.0, m.mu, m.kappa)["u_outer"]
    a = 12.0
    r = (20.0 ** 3 + a ** 3 - 10.0 ** 3) ** (1 / 3)     # volume conservation, written here
    assert u == pytest.approx(r - 20.0, rel=1e-4)


def test_the_lateral_stretch_has_poissons_ratio_as_its_small_strain_limit():
    m = Material("neo-hookean", E=6.0, nu=0.3)
    eps = 1e-5
    t = cf.uniaxial_lateral_stretch(1 + eps, m.mu, m.kappa)
    assert -(t - 1) / eps == pytest.approx(0.3, rel=1e-3)


@pytest.fixture(scope="module")
def scorecard(tmp_path_factory):
    d = tmp_path_factory.mktemp("suite")

    def raises(case, pushes):
        raise RuntimeError("no convergence")

    def refuses(case, pushes):
        raise CaseError("this solver takes 3D cases only")

    def zero(case, pushes):
        return np.zeros((case.mesh.n_vertices, case.mesh.gdim))

    out = run_suite(("fem", "mass-tensor", raises, refuses, zero), json_file=d / "suite.json")
    write_scorecard(out, d)
    return out, d


def test_the_reference_passes_every_problem(scorecard):
    out, _ = scorecard
    assert out["summary"]["fem"] == {"passed": len(out["problems"]), "failed": 0, "refused": 0}
    names = {p["name"] for p in out["problems"]}
    assert {"uniaxial-stretch", "shear-patch", "thick-sphere",
            "thick-sphere-nearly-incompressible", "cook-membrane"} <= names


def test_failures_refusals_and_wrong_answers_are_scored_as_such(scorecard):
    out, d = scorecard
    s = out["summary"]
    raises = next(n for n in s if n.endswith("raises"))
    refuses = next(n for n in s if n.endswith("refuses"))
    zero = next(n for n in s if n.endswith("zero"))
    assert s[raises]["failed"] == len(out["problems"])
    assert s[refuses]["refused"] == len(out["problems"])
    assert s[zero]["failed"] == len(out["problems"])          # a zero field passes nothing
    row = out["problems"][0]["results"]
    assert "no convergence" in row[raises]["error"]
    assert row[zero]["error_rel"] == pytest.approx(1.0)
    # the linear model passes the patch test (any homogeneous material does) but not the
    # finite-strain stretch
    by = {p["name"]: p["results"]["mass-tensor"] for p in out["problems"]}
    assert by["shear-patch"]["passed"] and not by["uniaxial-stretch"]["passed"]
    on_disk = json.loads((d / "suite.json").read_text())
    assert on_disk["summary"] == json.loads(json.dumps(s))
    page = (d / "suite.html").read_text()
    assert page.count("class='pass'") >= len(out["problems"]) and "refused" in page


def test_cli_suite_exit_status(tmp_path, capsys):
    from tissue_reference.tissue.cli import main

    rc = main(["suite", "-q", "--solvers", "fem", "--problems", "shear-patch", "uniaxial-stretch",
               "--json", str(tmp_path / "s.json")])
    assert rc == 0 and "fem: 2 passed, 0 failed" in capsys.readouterr().out
    rc = main(["suite", "-q", "--solvers", "fem", "mass-tensor", "--problems", "uniaxial-stretch",
               "--strict"])
    assert rc == 1 and "failed: ['mass-tensor']" in capsys.readouterr().err




@pytest.mark.parametrize("model", list(LAWS))
def test_the_principal_stresses_of_each_law_meet_its_formula_in_F(model):
    """closed_forms writes each energy in the principal stretches; tests/test_laws.py writes it
    in F (and the corotational stress by the SVD): the two agree at diag(1.2, 0.9, 0.9)."""
    m = Material(model, **LAWS[model])
    P = piola_formula(np.diag([1.2, 0.9, 0.9]), model, LAWS[model])
    np.testing.assert_allclose(cf.law_piola(m, 1.2, 0.9), (P[0, 0], P[1, 1]), rtol=1e-12,
                               atol=1e-12 * np.abs(P).max())


def test_the_law_forms_reproduce_the_neo_hookean_ones_and_the_linear_limits():
    nh = Material("neo-hookean", E=6.0, nu=0.45)
    assert cf.law_uniaxial_lateral_stretch(1.2, nh) == pytest.approx(
        cf.uniaxial_lateral_stretch(1.2, nh.mu, nh.kappa), rel=1e-13)
    assert cf.law_thick_sphere(10.0, 20.0, 2.0, nh)["u_outer"] == pytest.approx(
        cf.thick_sphere(10.0, 20.0, 2.0, nh.mu, nh.kappa)["u_outer"], rel=1e-8)
    # without rotation the corotational law is linear elasticity in the stretches: the lateral
    # stretch is 1 - nu eps exactly
    for model in ("corotational", "linear-elastic"):
        m = Material(model, E=6.0, nu=0.45)
        assert cf.law_uniaxial_lateral_stretch(1.2, m) == pytest.approx(1 - 0.45 * 0.2,
                                                                        rel=1e-13)
    m = Material("stable-neo-hookean", E=6.0, nu=0.45)
    assert cf.law_thick_sphere(10.0, 20.0, 1e-4, m)["u_outer"] == pytest.approx(
        lame_sphere_u_outer(10.0, 20.0, 1e-4, 6.0, 0.45), rel=1e-3)


def test_the_suite_on_another_law_scores_it_and_says_what_it_leaves_out(tmp_path):
    out = run_suite(("fem", "admm"), ["uniaxial-stretch", "shear-patch", "cook-membrane"],
                    law="mooney-rivlin", json_file=tmp_path / "s.json")
    assert out["law"] == "mooney-rivlin"
    assert [p["name"] for p in out["problems"]] == ["uniaxial-stretch", "shear-patch"]
    for p in out["problems"]:
        assert p["material"]["model"] == "mooney-rivlin"
        assert all(r["passed"] for r in p["results"].values())
    assert "published linear-elastic value" in out["not_applicable"]["cook-membrane"]
    svk = run_suite(("fem",), ["thick-sphere-nearly-incompressible", "thick-sphere"],
                    law="saint-venant-kirchhoff")
    assert svk["problems"] == []
    assert "does not split" in svk["not_applicable"]["thick-sphere-nearly-incompressible"]
    assert "no solution of the shell's radial equilibrium" in svk["not_applicable"][
        "thick-sphere"]
    with pytest.raises(CaseError, match="unknown law 'arruda-boyce'"):
        run_suite(("fem",), ["shear-patch"], law="arruda-boyce")
