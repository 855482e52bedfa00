"""The "contact" mismatch scenario: the controller's model is the fast solver on glued patches,
the plant the reference on the same body with each patch replaced by a rigid spherical indenter
in frictionless contact (control.scenarios.indenter_plant_case, scenario_loop)."""
import json
import math
from dataclasses import replace

import numpy as np
import pytest

from tissue_reference.control.loop import LinearizedModel, LoopSettings, run_closed_loop
from tissue_reference.control.scenarios import (
    check_contact_plant,
    indenter_plant_case,
    scenario_loop,
    skin_region,
)
from tissue_reference.errors import CaseError
from tissue_reference.meshes.builders import box
from tissue_reference.meshes.mesh import MeshData
from tissue_reference.model.case import Actuator, Boundary, Case, Material, Probe

DISC_MM = 3.0                                   # radius of the patches carved in the block
SITES = {"pX": (10.0, 5.0, 5.5), "pY": (5.0, 10.0, 5.5)}
GOAL = [-0.3, -0.2, np.nan]                     # T1 moved 0.3 mm along -x, 0.2 mm along -y


def _block_mesh(h: float = 1.25):
    """A 10 mm block (box(h); 1.25: 2.7k tets) standing on ``base`` (z = 0), with a disc patch
    of about DISC_MM (the facets whose centroids lie within it) on the +x face (``pX``) and on
    the +y face (``pY``), and every other boundary facet in ``skin``."""
    m = box(h)
    fr, X = m.facet_regions, m.points
    regions = {"base": fr["zmin"]}
    rest = [fr["xmin"], fr["ymin"], fr["zmax"]]
    for name, face in (("pX", "xmax"), ("pY", "ymax")):
        f = fr[face]
        inside = np.linalg.norm(X[f].mean(axis=1) - SITES[name], axis=1) < DISC_MM
        regions[name] = f[inside]
        rest.append(f[~inside])
    regions["skin"] = np.concatenate(rest)
    return MeshData(m.points, m.cells, facet_regions=regions, cell_regions=m.cell_regions)


def block_case(h: float = 1.25):
    """The glued-patch case on the block (``_block_mesh(h)``): A1 pushes the +x disc along -x, A2
    the +y disc along -y; targets T1 (the centre at z = 5.5 mm) and T2 (nearer both discs).
    Also the case of bench/bench_contact_scenario.py."""
    return Case(mesh=_block_mesh(h), material=Material("neo-hookean", E=6.0, nu=0.3),
                name="discs", boundaries=(Boundary("base", "fixed"),),
                actuators=(Actuator("A1", "pX", (-1.0, 0.0, 0.0)),
                           Actuator("A2", "pY", (0.0, -1.0, 0.0))),
                probes=(Probe("T1", (5.0, 5.0, 5.5)), Probe("T2", (7.0, 7.0, 5.5))))


@pytest.fixture(scope="module")
def block():
    return block_case()


def _disc_radius(points, facets):
    """sqrt(area / pi) of triangles, their areas by Heron's formula."""
    x = points[facets]
    a, b, c = (np.linalg.norm(x[:, i] - x[:, j], axis=1) for i, j in ((0, 1), (1, 2), (2, 0)))
    s = (a + b + c) / 2
    area = np.sqrt(np.maximum(s * (s - a) * (s - b) * (s - c), 0.0)).sum()
    return math.sqrt(area / math.pi)


# --------------------------------------------------------------------------- the plant case
def test_the_derived_plant_replaces_each_patch_by_a_sphere_of_the_patch_area(block):
    plant = indenter_plant_case(block)
    assert [a.name for a in plant.actuators] == ["A1", "A2"]
    for a, p in zip(block.actuators, plant.actuators):
        assert (p.type, p.tip, p.contact, p.idle) == ("indenter", "sphere", "frictionless", "held")
        assert p.region == a.region and p.direction == a.direction
        assert p.contact_regions == (a.region, "skin") and p.point is None
        r = _disc_radius(block.mesh.points, block.mesh.facet_regions[a.region])
        assert p.radius == pytest.approx(r, rel=1e-12)
        assert abs(r - DISC_MM) < 0.1 * DISC_MM     # the carved disc's own radius, roughly
    # the same body: mesh, material, supports and probes untouched; the model keeps its patches
    assert plant.mesh is block.mesh and plant.material == block.material
    assert plant.boundaries == block.boundaries and plant.probes == block.probes
    assert {a.type for a in block.actuators} == {"patch"}
    assert [a.radius for a in indenter_plant_case(block, radius=2.0).actuators] == [2.0, 2.0]
    assert [a.radius for a in indenter_plant_case(block, radius={"A2": 2.5}).actuators][1] == 2.5


def test_the_phantoms_skin_is_found_without_naming_it():
    from tissue_reference.model.case import load_case

    phantom = load_case("meshes/cases/phantom.toml", size=14)
    assert skin_region(phantom) == "skin"
    assert {a.contact_regions[1] for a in indenter_plant_case(phantom).actuators} == {"skin"}


# --------------------------------------------------------------------------- bad input
def test_a_skin_that_cannot_be_told_is_refused_naming_the_case_and_the_candidates(block):
    faces = box(1.25)
    plain = Case(mesh=faces, material=block.material, name="faces",
                 boundaries=(Boundary("zmin", "fixed"),),
                 actuators=(Actuator("A1", "xmax", (-1.0, 0.0, 0.0)),), probes=block.probes)
    with pytest.raises(CaseError, match=r"faces: cannot tell the skin .* 4 facet regions are "
                                        r"free .*\(\['xmin', 'ymax', 'ymin', 'zmax'\]"):
        indenter_plant_case(plain)
    with pytest.raises(CaseError, match="faces: cannot tell the skin"):
        scenario_loop(plain, "contact")
    # named, it is used
    assert indenter_plant_case(plain, skin="zmax").actuators[0].contact_regions == \
        ("xmax", "zmax")
    with pytest.raises(CaseError, match="skin region 'nope' is not a facet region"):
        indenter_plant_case(plain, skin="nope")
    with pytest.raises(CaseError, match=r"tip radii for \['A9'\], which are not actuators"):
        indenter_plant_case(block, radius={"A9": 2.0})


def test_a_plant_whose_actuators_differ_from_the_models_is_refused(block):
    plant = indenter_plant_case(block)
    renamed = replace(plant, actuators=(replace(plant.actuators[0], name="B1"),
                                        plant.actuators[1]))
    with pytest.raises(CaseError, match=r"has actuators \['B1', 'A2'\], the model discs has "
                                        r"\['A1', 'A2'\]"):
        scenario_loop(block, "contact", plant_case=renamed)
    fewer = replace(plant, actuators=plant.actuators[:1])
    with pytest.raises(CaseError, match=r"actuators \['A1'\], the model discs has"):
        scenario_loop(block, "contact", plant_case=fewer)
    with pytest.raises(CaseError, match=r"actuators \['A1', 'A2'\] are not indenters"):
        scenario_loop(block, "contact", plant_case=block)
    turned = replace(plant, actuators=(replace(plant.actuators[0], direction=(0.0, 0.0, -1.0)),
                                       plant.actuators[1]))
    with pytest.raises(CaseError, match="actuator 'A1' pushes along"):
        scenario_loop(block, "contact", plant_case=turned)
    # the model must be the glued-patch case; a plant case is the contact scenario's alone
    with pytest.raises(CaseError, match="are indenters; the contact scenario's model is the "
                                        "glued-patch case"):
        scenario_loop(plant, "contact")
    with pytest.raises(CaseError, match="only the contact scenario takes one"):
        scenario_loop(block, "gravity", plant_case=plant)
    with pytest.raises(CaseError, match="only the contact scenario takes one"):
        scenario_loop(block, "gravity", contact_rule=2)


def test_an_explicit_plant_in_another_actuator_order_is_taken_in_the_models(block):
    plant = indenter_plant_case(block, radius=2.5)
    swapped = replace(plant, actuators=plant.actuators[::-1])
    assert [a.name for a in check_contact_plant(block, swapped).actuators] == ["A1", "A2"]
    loop = scenario_loop(block, "contact", plant_case=swapped)
    assert [a.name for a in loop.case.actuators] == ["A1", "A2"]
    assert loop.meta["plant_indenters"]["A1"]["radius_mm"] == 2.5


# --------------------------------------------------------------------------- the closed loop
def _steer(loop, steps, open_loop):
    model = LinearizedModel(loop.model_case, loop.model_solve, loop.model_tangent, "T1",
                            loop.model_sensitivity)
    return run_closed_loop(loop.plant, loop.case, model, "T1", 1, goal=GOAL,
                           settings=LoopSettings(steps=steps, open_loop=open_loop))


def _target_moved(case, pushes):
    """T1's displacement by a cold reference solve of ``case`` at ``pushes``."""
    import tissue_reference.fem_reference as fr

    res = fr.solve(case, pushes=pushes)
    assert res.converged and res.valid
    return res


@pytest.mark.slow
def test_the_patch_model_steers_the_contact_plant_to_the_goal(block):
    """ADMM on the glued patches linearizes the loop; the reference with the tips is the
    tissue. The open loop (eq. 22 pushes of the patch model) misses by more than the 0.05 mm
    goal; the closed loop meets it with push-only steps."""
    loop = scenario_loop(block, "contact")
    assert (loop.meta["plant"], loop.meta["model"]) == ("fem", "admm")
    assert loop.meta["plant_actuator_kind"] == "indenter"
    assert loop.meta["model_actuator_kind"] == "patch"
    assert loop.meta["mismatch"]["actuator_kind"] == "different"
    assert loop.meta["mismatch"]["mesh"] == "same"
    assert (loop.meta["plant_case"], loop.meta["plant_source"]) == ("discs-indenters", None)
    res = _steer(loop, 15, True)
    assert res.steady_state_error_mm <= 0.05 and res.max_retraction_mm == 0.0
    assert res.open_loop["converged"] and res.open_loop["steady_state_error_mm"] > 0.05
    assert res.itae < res.open_loop["itae"]
    # the pushes the loop ended at, solved cold on the contact plant, put T1 at the goal and
    # press both tips into the skin
    final = dict(zip(res.actuators, res.pushes[-1].tolist()))
    r = _target_moved(loop.case, final)
    moved = r.probes["T1"] - _target_moved(loop.case, {"A1": 0.0, "A2": 0.0}).probes["T1"]
    assert np.hypot(moved[0] - GOAL[0], moved[1] - GOAL[1]) <= 0.05
    assert min(t["force"] for t in r.indenters.values()) > 0


@pytest.mark.slow
def test_an_explicit_plant_with_smaller_tips_is_steered_too(block):
    """Tips of 2.5 mm, given as the plant case (actuators in another order): the loop pushes
    further than with the patch-sized tips and still meets the goal."""
    plant = indenter_plant_case(block, radius=2.5)
    loop = scenario_loop(block, "contact",
                         plant_case=replace(plant, actuators=plant.actuators[::-1]))
    res = _steer(loop, 15, False)
    assert res.steady_state_error_mm <= 0.05 and res.max_retraction_mm == 0.0


# --------------------------------------------------------------------------- the command line
@pytest.mark.slow
def test_table1_runs_the_contact_scenario_and_its_outputs_match_the_schemas(block, tmp_path,
                                                                           capsys):
    from tissue_reference.meshes.writers import write_mesh
    from tissue_reference.tissue.cli import main
    from tissue_reference.tissue.output_schema import validate_file

    write_mesh(block.mesh, tmp_path / "block.msh")
    common = ('[mesh]\nfile = "block.msh"\n[material]\nE = 6.0\nnu = 0.3\n'
              '[[boundary]]\nregion = "base"\ntype = "fixed"\n'
              '[[probe]]\nname = "T1"\npoint = [5.0, 5.0, 5.5]\n')
    (tmp_path / "discs.toml").write_text(
        'name = "discs"\n' + common
        + '[[actuator]]\nname = "A1"\nregion = "pX"\ndirection = [-1.0, 0.0, 0.0]\n'
        + '[[actuator]]\nname = "A2"\nregion = "pY"\ndirection = [0.0, -1.0, 0.0]\n')
    tip = 'type = "indenter"\ntip = "sphere"\nradius = 2.5\ncontact_region = "skin"\n'
    (tmp_path / "tips.toml").write_text(
        'name = "tips"\n' + common
        + '[[actuator]]\nname = "A1"\nregion = "pX"\ndirection = [-1.0, 0.0, 0.0]\n' + tip
        + '[[actuator]]\nname = "A2"\nregion = "pY"\ndirection = [0.0, -1.0, 0.0]\n' + tip)
    (tmp_path / "other.toml").write_text(
        'name = "other"\n' + common
        + '[[actuator]]\nname = "B1"\nregion = "pX"\ndirection = [-1.0, 0.0, 0.0]\n' + tip)
    base = ["table1", tmp_path / "discs.toml", "--steps", "2", "--max-travel", "0.3", "-q"]
    # refused before any solve: another plant's actuators, a plant without the scenario
    assert main([str(a) for a in base + ["--scenarios", "gravity", "contact", "--contact-plant",
                                         tmp_path / "other.toml", "--out", tmp_path / "x"]]) == 2
    err = capsys.readouterr().err
    assert f"the contact plant {tmp_path / 'other.toml'} has actuators ['B1']" in err
    assert f"the model {tmp_path / 'discs.toml'} has ['A1', 'A2']" in err
    assert main([str(a) for a in base + ["--scenarios", "gravity", "--contact-plant",
                                         tmp_path / "tips.toml", "--out", tmp_path / "y"]]) == 2
    assert "--contact-plant: only with --scenarios contact" in capsys.readouterr().err
    assert main([str(a) for a in base + ["--scenarios", "gravity", "--contact-quadrature", "2",
                                         "--out", tmp_path / "y"]]) == 2
    assert "--contact-quadrature: only with --scenarios contact" in capsys.readouterr().err
    assert main([str(a) for a in base + ["--scenarios", "contact", "--contact-plant",
                                         tmp_path / "nope.toml", "--out", tmp_path / "z"]]) == 2
    assert "--contact-plant: " in capsys.readouterr().err
    assert not (tmp_path / "x" / "gravity").exists()
    out = tmp_path / "t"
    assert main([str(a) for a in base + ["--scenarios", "contact", "--contact-plant",
                                         tmp_path / "tips.toml", "--out", out]]) == 0
    both = validate_file("table1_scenarios", out / "table1_scenarios.json")
    t = validate_file("table1", out / "contact" / "table1.json")
    assert both["meta"]["contact"]["plant_actuator_kind"] == "indenter"
    assert t["meta"]["plant_actuator_kind"] == "indenter"
    assert t["meta"]["model_actuator_kind"] == "patch"
    assert t["meta"]["plant_source"] == str(tmp_path / "tips.toml")
    assert t["meta"]["plant_contact_rule"] == "nodal"      # the plant case's own
    assert t["meta"]["plant_indenters"]["A2"] == {"tip": "sphere", "radius_mm": 2.5,
                                                  "contact": "frictionless",
                                                  "contact_regions": ["pY", "skin"]}
    assert [r["status"] for r in t["rows"]] == ["ok", "ok", "unreachable"]
    assert "table1 contact:" in capsys.readouterr().out
    assert json.loads((out / "table1_scenarios.json").read_text())["scenarios"]["contact"]
    from page_checks import check_page

    check_page(out / "table1_scenarios.html")
    check_page(out / "contact" / "table1.html")
    page = (out / "contact" / "table1.html").read_text()
    assert "<th scope='row'>plant actuator kind</th><td>indenter</td>" in page
    assert "<th scope='row'>model actuator kind</th><td>patch</td>" in page
    assert "<th scope='row'>plant indenters: A1: radius (mm)</th><td>2.5</td>" in page
    # the plant's contact rule set from the command line, and recorded
    gauss = tmp_path / "g"
    assert main([str(a) for a in base + ["--scenarios", "contact", "--contact-plant",
                                         tmp_path / "tips.toml", "--contact-quadrature", "2",
                                         "--targets", "T1", "--out", gauss]]) == 0
    assert validate_file("table1", gauss / "contact" / "table1.json")["meta"][
        "plant_contact_rule"] == 2


def test_a_contact_plant_too_coarse_for_its_tips_is_refused_before_any_loop():
    """The glued phantom at its default size: tips of the patches' area start between the skin's
    nodes (the dome's facets lie inside them), so the derived plant is invalid at rest; the
    scenario says so once, with the remedy, instead of failing every loop on its first step."""
    from pathlib import Path

    from tissue_reference.model.case import load_case

    case = load_case(Path(__file__).resolve().parents[1] / "meshes" / "cases" / "phantom.toml")
    with pytest.raises(CaseError, match=r"plant .*cannot start.*between the nodes.*--contact-plant"):
        scenario_loop(case, "contact")


@pytest.mark.slow
def test_the_shipped_control_plant_starts_valid_and_fits_the_phantom():
    """meshes/cases/phantom-indenter-control.toml, the contact scenario's shipped plant for the
    phantom: the same actuators, directions and targets as the glued phantom, and valid at rest
    (its skin fine enough at the sites that no tip lies between the nodes), where the plant
    derived from the glued phantom is not (the test above)."""
    from pathlib import Path

    from tissue_reference.model.case import load_case

    cases = Path(__file__).resolve().parents[1] / "meshes" / "cases"
    model = load_case(cases / "phantom.toml", size=10)
    plant = load_case(cases / "phantom-indenter-control.toml")
    assert all(a.type == "indenter" for a in check_contact_plant(model, plant).actuators)
    loop = scenario_loop(model, "contact", plant_case=plant)   # solves the plant at rest
    assert loop.meta["plant_case"] == "phantom-indenter-control"
