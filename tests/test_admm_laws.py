"""The ADMM solver on every law of the reference: its P1 law code (``solvers.admm.mechanics``)
against the formulas written in tests/test_laws.py (the stress by complex steps of the energy as
the formula reads, the tangent by central differences of that stress), the invariant form of the
Neo-Hookean law against its closed form (two formulations of one energy), ADMM on the stretched
block against the formula's uniaxial answer, and ADMM with its Newton polish against the
reference's P1 solve of the phantom (a second discretization code: UFL). Units: mm, kPa, mN."""
import dataclasses

import numpy as np
import pytest
from scipy.optimize import brentq
from test_laws import GRADIENTS, LAWS, _stretched_block, piola_formula

from tissue_reference.errors import CaseError, NotModeledError
from tissue_reference.model.case import Material
from tissue_reference.solvers.admm.mechanics import ADMM_LAWS, InvariantLaw, Law

NEW_LAWS = [m for m in LAWS if m not in ("neo-hookean", "linear-elastic")]


def test_admm_implements_every_law_of_the_reference():
    assert set(LAWS) <= set(ADMM_LAWS)


@pytest.mark.parametrize("model", list(LAWS))
@pytest.mark.parametrize("which", list(GRADIENTS))
def test_stress_and_tangent_of_each_law_meet_the_formula(model, which):
    F = GRADIENTS[which]
    law = Law(Material(model, **LAWS[model]), 3)
    P, _ = law.stress((F - np.eye(3))[None])
    expected = piola_formula(F, model, LAWS[model])
    np.testing.assert_allclose(P[0], expected, rtol=0, atol=1e-12 * np.abs(expected).max())
    A = law.tangent((F - np.eye(3))[None])[0]
    h = 1e-6
    fd = np.zeros((9, 9))
    for k in range(9):
        dF = np.zeros(9)
        dF[k] = h
        dF = dF.reshape(3, 3)
        fd[:, k] = ((piola_formula(F + dF, model, LAWS[model])
                     - piola_formula(F - dF, model, LAWS[model])) / (2 * h)).reshape(9)
    np.testing.assert_allclose(A, fd, rtol=0, atol=1e-7 * np.abs(fd).max())
    np.testing.assert_allclose(A, A.T, rtol=0, atol=1e-12 * np.abs(A).max())


@pytest.mark.parametrize("d", [2, 3])
def test_invariant_form_of_neo_hookean_equals_its_closed_form(d):
    material = Material("neo-hookean", E=6.0, nu=0.45)
    H = np.random.default_rng(3).normal(scale=0.2, size=(40, 3, 3))[:, :d, :d]
    closed, invariant = Law(material, d), InvariantLaw(material, d)
    for a, b in ((closed.psi_J(H)[0], invariant.psi_J(H)[0]),
                 (closed.stress(H)[0], invariant.stress(H)[0]),
                 (closed.tangent(H), invariant.tangent(H))):
        np.testing.assert_allclose(b, a, rtol=1e-12, atol=1e-12 * np.abs(a).max())


@pytest.mark.parametrize("model", NEW_LAWS)
def test_admm_stretches_the_block_to_the_formulas_uniaxial_answer(model):
    """The 10 mm block stretched 20 % between sliding faces (exact answer homogeneous, in the P1
    space): the corner's lateral motion 10 (t - 1) mm with t the root of the formula's lateral
    stress, with the polish to round-off and without it within the ADMM tolerance."""
    from tissue_reference.solvers import admm

    params = LAWS[model]
    t = brentq(lambda s: piola_formula(np.diag([1.2, s, s]), model, params)[1, 1], 0.5, 1.2,
               xtol=1e-14)
    case = _stretched_block(Material(model, **params))
    for polish, tol in ((True, 1e-9), (False, 1e-3)):
        res = admm.solve(case, polish=polish)
        assert res.converged
        np.testing.assert_allclose(res.probes["corner"][1:], 10.0 * (t - 1.0), rtol=0, atol=tol)


@pytest.fixture(scope="module")
def phantom():
    from tissue_reference.meshes.builders import build
    from tissue_reference.model.case import load_case
    from tissue_reference.model.case_file import case_path

    return load_case(case_path("phantom"), mesh=build("phantom", 10.0))


@pytest.mark.parametrize("model", NEW_LAWS)
def test_admm_with_its_polish_equals_the_reference_on_the_phantom(phantom, model):
    """A1 pushed 2 mm on the coarse phantom: ADMM + Newton polish (numpy law code) against the
    reference's P1 displacement solve (UFL energy, PETSc Newton) of the same law: 1e-8 mm."""
    from tissue_reference.fem_reference import solve
    from tissue_reference.solvers import admm

    case = dataclasses.replace(phantom, material=Material(model, **LAWS[model]))
    ref = solve(case, degree=1, formulation="displacement", pushes={"A1": 2.0})
    res = admm.solve(case, pushes={"A1": 2.0})
    assert ref.converged and res.converged
    assert np.abs(np.asarray(res.u) - np.asarray(ref.u)).max() < 1e-8


def test_admm_refuses_what_it_does_not_implement():
    with pytest.raises(CaseError, match="volumetric"):
        Law(Material("mooney-rivlin", c1=1.0, c2=0.5, k=30.0, volumetric="log"), 3)
    from tissue_reference.solvers.admm.kernel_array import LawZStep

    class Ops:
        law = Law(Material("yeoh", **LAWS["yeoh"]), 3)
        d = 3

    with pytest.raises(NotModeledError, match="GPU element pass implements the laws"):
        LawZStep(Ops(), 10.0, xp=object())


def test_with_law_keeps_what_the_new_law_shares_and_names_what_does_not_fit(phantom):
    mr = phantom.with_law("mooney-rivlin", {"c1": 1.0, "c2": 0.5, "k": 30.0})
    assert mr.material.coefficients == {"c1": 1.0, "c2": 0.5, "k": 30.0}
    assert mr.material.density == phantom.material.density
    snh = mr.with_law("stable-neo-hookean")   # E and nu follow from the coefficients
    assert (snh.material.E, snh.material.nu) == (mr.material.E, mr.material.nu)
    assert snh.material.coefficients == {}
    with pytest.raises(CaseError, match="missing: c2, k"):
        phantom.with_law("mooney-rivlin", {"c1": 1.0})
    with pytest.raises(CaseError, match="takes c1, c2, c3, k, volumetric, density; not E"):
        phantom.with_law("yeoh", {"E": 3.0})
    with pytest.raises(CaseError, match="unknown material law 'arruda-boyce'"):
        phantom.with_law("arruda-boyce")


def test_tissue_verify_scores_admm_on_the_law_given_on_the_command_line(tmp_path, capsys):
    """--material swaps the case's law: the reference and ADMM both solve St Venant-Kirchhoff,
    and agree to round-off (the scores are the JSON's); a bad parameter exits 2 naming it."""
    import json

    from tissue_reference.tissue.cli import main

    out = tmp_path / "v.json"
    rc = main(["verify", "phantom", "--size", "10", "--material", "saint-venant-kirchhoff",
               "--push", "A1=2", "--solvers", "admm", "--json", str(out), "-q"])
    assert rc == 0
    data = json.loads(out.read_text())
    assert data["reference"]["material"]["model"] == "saint-venant-kirchhoff"
    score = data["solvers"]["admm"]
    assert score["model"] == score["reference_model"] == "saint-venant-kirchhoff"
    assert score["max_vertex_error_mm"] < 1e-8
    rc = main(["solve", "phantom", "--size", "10", "--material", "yeoh:c1=x", "--solver", "admm"])
    assert rc == 2
    assert "c1 must be a number, got 'x'" in capsys.readouterr().err
