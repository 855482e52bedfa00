"""A loop's model on a case of its own (``build_loop(model_case=...)``, ``--model-case`` /
``--model-size``): the same body, actuators and probes meshed otherwise, in every mismatch
scenario, with rigid tips in both model and plant (Table I on tips in miniature)."""
import json
from dataclasses import replace

import numpy as np
import pytest
from test_contact_scenario import GOAL, block_case

from tissue_reference.control.fast_model import FastModel
from tissue_reference.control.loop import LoopSettings, run_closed_loop
from tissue_reference.control.mpc import MPCSettings
from tissue_reference.control.plants import PRESS_WIDTHS, build_loop, matching_case
from tissue_reference.control.scenarios import GRAVITY_MM_S2, indenter_plant_case, scenario_loop
from tissue_reference.errors import CaseError
from tissue_reference.model.case import Probe

TIP_MM = 3.0
COARSE = 1.6


def _t1(case, pushes):
    """T1's position by a cold reference solve of ``case`` at ``pushes``."""
    import tissue_reference.fem_reference as fr

    res = fr.solve(case, pushes=pushes)
    assert res.converged and res.valid
    return res.probes["T1"]


@pytest.fixture(scope="module")
def tips():
    """The block with 3 mm spherical tips (2.7k tets) and the same tips on a coarser block
    (box(COARSE): 1.5k tets, about half the cells)."""
    return (indenter_plant_case(block_case(), radius=TIP_MM),
            indenter_plant_case(block_case(COARSE), radius=TIP_MM))


def test_a_model_case_of_another_body_is_refused_naming_the_difference(tips):
    fine, coarse = tips
    renamed = replace(coarse, actuators=(replace(coarse.actuators[0], name="B1"),
                                         coarse.actuators[1]))
    with pytest.raises(CaseError, match=r"the model .* has actuators \['B1', 'A2'\], the case "
                                        r".* has \['A1', 'A2'\]"):
        build_loop(fine, plant="fem", model="admm", model_case=renamed)
    turned = replace(coarse, actuators=(replace(coarse.actuators[0], direction=(0.0, 0.0, -1.0)),
                                        coarse.actuators[1]))
    with pytest.raises(CaseError, match=r"actuator 'A1' pushes along \[0.0, 0.0, -1.0\] in the "
                                        r"model"):
        scenario_loop(fine, "gravity", model_case=turned)
    other = replace(coarse, probes=(Probe("T9", (5.0, 5.0, 5.5)),))
    with pytest.raises(CaseError, match=r"the model .* has probes \['T9'\], the case .* has "
                                        r"\['T1', 'T2'\]"):
        scenario_loop(fine, "nu", model_case=other)
    # the actuators come back in the case's order
    swapped = replace(coarse, actuators=coarse.actuators[::-1])
    assert [a.name for a in matching_case(fine, swapped, "case", "model").actuators] == \
        ["A1", "A2"]
    with pytest.raises(CaseError, match="the mesh scenario needs the model's case"):
        scenario_loop(fine, "mesh")


def test_every_scenario_runs_its_model_on_the_model_case_with_its_E(tips):
    """gravity, nu and mesh: the plant is the case changed as the scenario says, the model the
    model case (E scaled); the contact scenario's model must have glued patches."""
    fine, coarse = tips
    for name in ("gravity", "nu", "mesh"):
        loop = scenario_loop(fine, name, model_case=coarse, model_E_factor=1.2)
        m = loop.meta
        assert loop.model_case.mesh is coarse.mesh and loop.case.mesh is fine.mesh
        assert (m["plant_cells"], m["model_cells"]) == (fine.mesh.n_cells, coarse.mesh.n_cells)
        assert m["model_cells"] < 0.6 * m["plant_cells"]
        assert m["mismatch"]["mesh"] == "different" and m["mismatch"]["E_factor"] == 1.2
        assert loop.model_case.material.E == pytest.approx(1.2 * fine.material.E)
        assert (m["model_actuator_kind"], m["plant_actuator_kind"]) == ("indenter", "indenter")
        assert m["mismatch"]["gravity"] == ("different" if name == "gravity" else "same")
        assert m["plant_gravity_mm_s2"] == (list(GRAVITY_MM_S2) if name == "gravity" else None)
    with pytest.raises(CaseError, match="are indenters; the contact scenario's model is the "
                                        "glued-patch case"):
        scenario_loop(block_case(), "contact", model_case=coarse)


@pytest.mark.slow
def test_a_coarse_tip_model_steers_a_tip_plant_under_gravity_to_the_goal(tips):
    """Table I on tips in miniature: the plant the reference with 3 mm tips and gravity, the
    model ADMM (P1, the fast model) with the same tips on a mesh with half the cells and no
    gravity. The closed loop meets the goal with push-only steps, and the pushes it ended at,
    solved cold on the plant case, put T1 there (an independent solve, not the loop's)."""
    fine, coarse = tips
    loop = scenario_loop(fine, "gravity", model_case=coarse)
    assert loop.fast_model
    model = FastModel(loop.model_case, "T1", press_widths=PRESS_WIDTHS)
    res = run_closed_loop(loop.plant, loop.case, model, "T1", 1, goal=GOAL,
                          settings=LoopSettings(steps=15, mpc=MPCSettings(weights="gain")))
    assert res.steady_state_error_mm <= 0.05 and res.max_retraction_mm == 0.0
    assert not res.to_json_dict()["outside_range"]
    final = dict(zip(res.actuators, res.pushes[-1].tolist()))
    assert min(final.values()) > 0.1     # both tips press: the goal needs both
    plant = replace(fine, gravity=GRAVITY_MM_S2)
    moved = _t1(plant, final) - _t1(plant, dict.fromkeys(final, 0.0))
    assert np.hypot(moved[0] - GOAL[0], moved[1] - GOAL[1]) <= 0.05


@pytest.mark.slow
def test_table1_takes_the_model_case_in_its_scenarios(tmp_path, capsys, monkeypatch):
    """--model-case in a scenario run: read once, recorded in the tables and used (the model's
    cells); one of another body is refused before any solve, naming both files; --plant admm is
    refused with scenarios (their plant is the reference)."""
    from tissue_reference.meshes.writers import write_mesh
    from tissue_reference.tissue import loop_options
    from tissue_reference.tissue.cli import main
    from tissue_reference.tissue.output_schema import validate_file

    common = ('[material]\nE = 6.0\nnu = 0.3\n[[boundary]]\nregion = "base"\ntype = "fixed"\n'
              '[[probe]]\nname = "T1"\npoint = [5.0, 5.0, 5.5]\n')
    tip = f'type = "indenter"\ntip = "sphere"\nradius = {TIP_MM}\ncontact_region = "skin"\n'
    acts = ('[[actuator]]\nname = "A1"\nregion = "pX"\ndirection = [-1.0, 0.0, 0.0]\n' + tip
            + '[[actuator]]\nname = "A2"\nregion = "pY"\ndirection = [0.0, -1.0, 0.0]\n' + tip)
    for name, h in (("fine", 1.25), ("coarse", COARSE)):
        write_mesh(block_case(h).mesh, tmp_path / f"{name}.msh")
        (tmp_path / f"{name}.toml").write_text(f'name = "{name}"\n[mesh]\nfile = "{name}.msh"\n'
                                               + common + acts)
    (tmp_path / "other.toml").write_text(
        'name = "other"\n[mesh]\nfile = "coarse.msh"\n' + common
        + '[[actuator]]\nname = "B1"\nregion = "pX"\ndirection = [-1.0, 0.0, 0.0]\n' + tip)
    base = ["table1", tmp_path / "fine.toml", "--steps", "2", "--max-travel", "0.3", "-q",
            "--scenarios", "gravity"]
    assert main([str(a) for a in base + ["--model-case", tmp_path / "other.toml",
                                         "--out", tmp_path / "x"]]) == 2
    err = capsys.readouterr().err
    assert f"--model-case: the model {tmp_path / 'other.toml'} has actuators ['B1'], the case " \
           f"{tmp_path / 'fine.toml'} has ['A1', 'A2']" in err
    assert main([str(a) for a in base + ["--plant", "admm", "--out", tmp_path / "y"]]) == 2
    assert "--plant admm: the scenarios' plant is the reference" in capsys.readouterr().err
    assert not (tmp_path / "x" / "gravity").exists() and not (tmp_path / "y" / "gravity").exists()
    read = []
    real_read = loop_options.case_from_args

    def counted(args, **kw):
        read.append(str(args.case))
        return real_read(args, **kw)

    monkeypatch.setattr(loop_options, "case_from_args", counted)
    out = tmp_path / "t"
    assert main([str(a) for a in base + ["--model-case", tmp_path / "coarse.toml",
                                         "--model-E-factor", "1.2", "--out", out]]) == 0
    assert read == [str(tmp_path / "coarse.toml")]
    t = validate_file("table1", out / "gravity" / "table1.json")
    m = t["meta"]
    assert (m["model_case"], m["model_source"]) == ("coarse", str(tmp_path / "coarse.toml"))
    assert m["model_cells"] == block_case(COARSE).mesh.n_cells < m["plant_cells"]
    assert m["mismatch"]["E_factor"] == 1.2 and m["mismatch"]["gravity"] == "different"
    assert [r["status"] for r in t["rows"]] == ["ok", "ok", "unreachable"]
    assert json.loads((out / "table1_scenarios.json").read_text())["meta"]["gravity"][
        "model_source"] == str(tmp_path / "coarse.toml")
