"""The Neo-Hookean volumetric laws against their closed forms.

A cube compressed uniformly (u = (s - 1) X on every face) deforms homogeneously, F = s I,
J = s^3, so the isochoric part carries no stress and the first Piola stress is
P = U'(J) J F^-T = U'(J) s^2 I, with U = kappa/2 G(J)^2: U'(J) = kappa (J - 1) for the seed's
quadratic law (G = J - 1) and kappa ln J / J for the log law (G = ln J). The support's force on
the face x = 10 is then P_xx times its reference area. The expected values below are these
formulas, evaluated here."""
import dataclasses
import math

import numpy as np
import pytest

import tissue_reference.fem_reference as fr
from tissue_reference.errors import CaseError
from tissue_reference.meshes.builders import box
from tissue_reference.model.case import Boundary, Case, Material

E, NU = 6.0, 0.45
KAPPA = E / (3 * (1 - 2 * NU))
AREA = 100.0                       # mm^2: the face x = 10 of the 10 mm cube
FACES = ("xmin", "xmax", "ymin", "ymax", "zmin", "zmax")


def squeezed(mesh, s, volumetric):
    G = ((s - 1.0) * np.eye(3)).tolist()
    return Case(mesh, Material("neo-hookean", E, NU, volumetric=volumetric),
                boundaries=[Boundary(f, "affine", gradient=G, offset=[0.0, 0.0, 0.0])
                            for f in FACES])


def closed_form_force(J, volumetric):
    du = KAPPA * (J - 1.0) if volumetric == "quadratic" else KAPPA * math.log(J) / J
    return du * J ** (2.0 / 3.0) * AREA


JS = (0.9, 0.6, 0.4, 0.25)


@pytest.mark.parametrize("volumetric", ["quadratic", "log"])
@pytest.mark.parametrize("formulation, degree, size", [("displacement", 1, 2.5),
                                                       ("mixed", 2, 5.0)])
def test_hydrostatic_compression_follows_the_volumetric_law(volumetric, formulation, degree,
                                                            size):
    mesh = box(size)
    forces = []
    for J in JS:
        res = fr.solve(squeezed(mesh, J ** (1 / 3), volumetric), degree=degree,
                       formulation=formulation)
        fx = res.reactions["xmax"][0]
        assert fx == pytest.approx(closed_form_force(J, volumetric), rel=1e-6), (J, fx)
        forces.append(-fx)
    if volumetric == "quadratic":
        # the seed's law resists hydrostatic compression with a force that peaks at J = 0.4
        # (d/dJ [(1 - J) J^(2/3)] = 0) and then falls: pressed harder, the tissue collapses
        assert forces[2] > forces[1] and forces[2] > forces[3]
    else:
        assert np.all(np.diff(forces) > 0)             # the log law's grows without bound


def test_the_laws_agree_at_small_strain():
    mesh = box(5.0)
    J = 0.999
    f = {v: fr.solve(squeezed(mesh, J ** (1 / 3), v)).reactions["xmax"][0]
         for v in ("quadratic", "log")}
    assert f["log"] == pytest.approx(f["quadratic"], rel=2e-3)     # (1 - J) relative
    assert f["log"] != pytest.approx(f["quadratic"], rel=1e-4)


def test_the_fast_solvers_refuse_the_log_law_by_name():
    from tissue_reference.solvers import admm

    case = squeezed(box(5.0), 0.95, "log")
    with pytest.raises(CaseError, match="volumetric = 'log'"):
        admm.solve(case)


def test_a_solver_refuses_a_case_of_another_law():
    mesh = box(5.0)
    s = fr.ReferenceSolver(squeezed(mesh, 0.95, "quadratic"))
    with pytest.raises(CaseError, match="material law"):
        s.solve({}, case=squeezed(mesh, 0.95, "log"))


@pytest.mark.parametrize("material, match", [
    ({"volumetric": "cubic"}, "unknown material volumetric law 'cubic'"),
    ({"model": "linear-elastic", "volumetric": "log"}, "applies to the laws"),
])
def test_a_bad_volumetric_law_is_refused(material, match):
    with pytest.raises(CaseError, match=match):
        Material(**material)


def test_a_case_file_chooses_the_law(tmp_path):
    from pathlib import Path

    from tissue_reference.model.case import load_case

    text = Path("meshes/cases/phantom.toml").read_text()
    f = tmp_path / "log.toml"
    f.write_text(text.replace('model = "neo-hookean"', 'model = "neo-hookean"\nvolumetric = "log"'))
    case = load_case(f, size=14)
    assert case.material.volumetric == "log"
    assert dataclasses.replace(case.material, volumetric="quadratic") == load_case(
        "meshes/cases/phantom.toml", size=14).material
