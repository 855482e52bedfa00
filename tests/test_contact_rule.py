"""Where the contact penalty is sampled (``contact_quadrature``): the nodal rule and Gauss rules
on the skin's facets, against answers computed here independently of the solver, on the
quarter block ``indent-block`` (symmetry planes sliding, bottom fixed):

- Hertz (shallow, linear elastic): a Gauss rule of degree 2 samples the gap more often than
  the P2 skin has nodes, which stiffens the contact a little (measured at h = 0.5 mm: +1.1 %
  against the nodal rule's +0.5 %, of which about 0.4 % is the block's fixed bottom); both stay
  within 2 % of Hertz;
- a deep push (Neo-Hookean, a ball-ended rod pushed three of its radii in, where the nodal rule
  stops): the work of the tip's force along the path, integrated here with Simpson's rule over
  the depths, equals the strain energy the tissue stores (frictionless contact and a
  hyperelastic body are conservative; the penalties store O(1/beta) of it). The force is the
  contact form's derivative, the energy the tissue's own integral: they agree only on an
  equilibrium path. Past 2.5 radii the answers warn that no mesh-converged value is known
  there (the indenter phantom's levels part at 3 radii).
Units: mm, kPa, mN, uJ.
"""
import json
import math
from pathlib import Path

import numpy as np
import pytest

import tissue_reference.fem_reference as fr
from tissue_reference.errors import CaseError
from tissue_reference.meshes.builders import indent_block
from tissue_reference.model.case import Actuator, Boundary, Case, Material, load_case

E, NU = 6.0, 0.45
E_STAR = E / (1 - NU ** 2)


def quarter_case(mesh, R, model):
    tip = Actuator("I", "tip", (0.0, 0.0, -1.0), type="indenter", tip="sphere", radius=R,
                   point=(0.0, 0.0, 0.0), contact_region="top")
    return Case(mesh, Material(model, E, NU),
                boundaries=[Boundary("bottom", "fixed"),
                            Boundary("xsym", "sliding", normal=(1.0, 0.0, 0.0)),
                            Boundary("ysym", "sliding", normal=(0.0, 1.0, 0.0))],
                actuators=[tip])


@pytest.mark.parametrize("rule", ["gauss", 0, 9, 2.0, True])
def test_a_bad_contact_quadrature_is_refused_naming_it(rule):
    case = quarter_case(indent_block(1.0), 10.0, "linear-elastic")
    with pytest.raises(CaseError, match="contact_quadrature"):
        fr.ReferenceSolver(case, degree=1, contact_quadrature=rule)


def test_a_gauss_rule_on_cells_wider_than_the_contact_is_off_hertz_and_says_so():
    """Cells of twice the Hertz contact radius (R = 10, d = 0.1 mm: a = 1 mm; h = 2 mm): the
    nodal rule stays within 2 % of Hertz's force, the degree-2 Gauss rule over-constrains the
    few facets in contact (measured +22 %) and its solve warns, naming the indenter; on cells of
    half the contact radius neither warns."""
    R, d = 10.0, 0.1
    F_hertz = 4.0 / 3.0 * E_STAR * math.sqrt(R) * d ** 1.5
    out = {}
    for h in (2.0, 0.5):
        case = quarter_case(indent_block(h), R, "linear-elastic")
        for rule in ("nodal", 2):
            res = fr.solve(case, pushes={"I": d}, degree=2, contact_quadrature=rule)
            assert res.converged
            out[h, rule] = (4 * res.indenters["I"]["force"] / F_hertz - 1,
                            [w for w in res.warnings if "indenter I" in w])
    assert abs(out[2.0, "nodal"][0]) < 0.02 and not out[2.0, "nodal"][1]
    assert out[2.0, 2][0] > 0.1
    assert len(out[2.0, 2][1]) == 1 and "Gauss contact rule over-constrains" in out[2.0, 2][1][0]
    assert not out[0.5, 2][1] and not out[0.5, "nodal"][1]


@pytest.mark.slow
def test_a_gauss_contact_rule_gives_hertz_force_within_2_percent_and_reports_its_rule():
    R, d = 10.0, 0.1
    case = quarter_case(indent_block(0.5), R, "linear-elastic")
    F_hertz = 4.0 / 3.0 * E_STAR * math.sqrt(R) * d ** 1.5
    forces = {}
    for rule in ("nodal", 2):
        res = fr.solve(case, pushes={"I": d}, degree=2, contact_quadrature=rule)
        ind = res.indenters["I"]
        assert res.converged and res.valid and ind["quadrature"] == rule
        forces[rule] = 4 * ind["force"]
    print(f"\nHertz {F_hertz:.5f} mN: nodal {forces['nodal']:.5f}, Gauss 2 {forces[2]:.5f}")
    assert abs(forces[2] / F_hertz - 1) < 0.02
    # the Gauss rule over-constrains the skin: stiffer than the nodal rule, not softer
    assert forces[2] > forces["nodal"]


@pytest.mark.slow
def test_a_deep_push_with_a_gauss_rule_does_the_work_the_tissue_stores():
    R, h = 1.0, 0.3
    case = quarter_case(indent_block(h), R, "neo-hookean")
    s = fr.ReferenceSolver(case, degree=2, contact_quadrature=2)
    depths = np.linspace(0.0, 3.0 * R, 13)
    forces, prev, deep = [0.0], None, []
    for d in depths[1:]:
        prev = s.solve({"I": float(d)}, initial=prev)
        assert prev.converged and prev.valid
        forces.append(4 * prev.indenters["I"]["force"])
        deep.append(any("radii deep" in w and "no error bar" in w
                        for w in prev.warnings))
    # the answers past 2.5 radii say they have no error bar (2.75 and 3 R), those before do not
    assert deep == [d > 2.5 * R + 1e-9 for d in depths[1:]]
    stored = 4 * prev.strain_energy
    hstep = depths[1] - depths[0]
    f = np.asarray(forces)
    work = hstep / 3 * (f[0] + f[-1] + 4 * f[1:-1:2].sum() + 2 * f[2:-1:2].sum())
    print(f"\nball-ended rod at 3 R: force {f[-1]:.3f} mN, work {work:.4f} uJ, strain energy "
          f"{stored:.4f} uJ ({100 * (work / stored - 1):+.2f} %)")
    assert np.all(np.diff(f) > 0)
    assert abs(work / stored - 1) < 0.01


CASES = Path(__file__).resolve().parents[1] / "meshes" / "cases"


def _quarter_file(tmp_path, line):
    """The shipped quarter case with its [reference] contact rule line replaced by ``line``
    ("" drops it)."""
    text = (CASES / "phantom-indenter-quarter.toml").read_text()
    old = "\ncontact_quadrature = 2 "
    assert text.count(old) == 1
    path = tmp_path / "quarter.toml"
    path.write_text(text.replace(old, f"\n{line} #" if line else "\n#"))
    return path


def test_a_case_file_chooses_its_contact_rule_and_a_solver_argument_overrides_it(tmp_path):
    shipped = load_case(CASES / "phantom-indenter-quarter.toml", size=14.0)
    assert shipped.reference_contact_quadrature == 2
    assert fr.ReferenceSolver(shipped, degree=1).contact.quadrature == 2
    assert fr.ReferenceSolver(shipped, degree=1,
                              contact_quadrature="nodal").contact.quadrature == "nodal"
    case = load_case(_quarter_file(tmp_path, 'contact_quadrature = "nodal"'), size=14.0)
    assert case.reference_contact_quadrature == "nodal"
    assert fr.ReferenceSolver(case, degree=1).contact.quadrature == "nodal"
    bare = load_case(_quarter_file(tmp_path, ""), size=14.0)     # a case that names no rule
    assert bare.reference_contact_quadrature is None
    assert fr.ReferenceSolver(bare, degree=1).contact.quadrature == "nodal"


def test_a_bad_contact_rule_in_a_case_file_is_refused_naming_file_and_key(tmp_path):
    path = _quarter_file(tmp_path, 'contact_quadrature = "gauss"')
    with pytest.raises(CaseError, match=r"quarter\.toml.*contact_quadrature"):
        load_case(path, size=14.0)


def test_a_stop_with_a_tip_two_radii_deep_names_the_nodal_rule():
    case = quarter_case(indent_block(1.0), 1.0, "neo-hookean")
    for rule, named in (("nodal", True), (2, False)):
        s = fr.ReferenceSolver(case, degree=1, contact_quadrature=rule)
        ind = s.contact.indenters[0]
        ind.q.value = ind.q0 + 1.5 * ind.d     # 1.5 radii: not deep
        assert s.contact.failure_hint() == ""
        ind.q.value = ind.q0 + 2.1 * ind.d
        hint = s.contact.failure_hint()
        assert ("I (2.10)" in hint and "contact_quadrature = 2" in hint) == named
        assert (hint == "") != named


def test_the_command_line_takes_the_contact_rule_and_reports_it(tmp_path, capsys):
    from tissue_reference.tissue.cli import main

    case = str(CASES / "phantom-indenter-quarter.toml")
    js = tmp_path / "s.json"
    assert main(["solve", case, "--size", "14", "--degree", "1", "--push", "A1=1", "-q",
                 "--json", str(js), "--contact-quadrature", "2"]) == 0
    doc = json.loads(js.read_text())
    assert doc["indenters"]["A1"]["quadrature"] == 2
    ind = doc["indenters"]["A1"]
    assert (f"indenter A1: push 1.00 mm, force {ind['force']:+.2f} mN, contact area "
            f"{ind['contact_area']:.1f} mm^2") in capsys.readouterr().out
    assert main(["solve", case, "--size", "14", "--contact-quadrature", "9"]) == 2
    assert "--contact-quadrature: 'nodal' or a Gauss degree 1-8, got '9'" in \
        capsys.readouterr().err
