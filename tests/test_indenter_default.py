"""The indenter phantom's shipped default (meshes/cases/phantom-indenter.toml: 5 mm tips) with all
four tips pushed along one load path, against the finest level of a refinement study shipped as
test data (tests/data/phantom_indenter_reference.json: levels -2..1 of
bench/bench_indenter_convergence.py, P2 with the Gauss contact rule and refined paths on the
quarter phantom, every cell size divided by sqrt 2 per level; the finest has 160k unknowns on the
quarter): with the case's own Gauss rule (its tips started on the curved skin) at 5, 10 and
12.5 mm against ``four_gauss_surface``, and with the nodal rule (``--contact-quadrature nodal``,
its tips started on the skin's nodes) at 5 and 10 mm against ``four_gauss``.

The default's mesh is ``phantom-symmetric``: the quarter phantom's mesh and its mirror images.
Under all four pushed equally it is the same discrete problem as the quarter with its planes
sliding (tests/test_mirror.py checks that on a coarser mesh), so this test solves the quarter
meshed at the default's sizes, with the default's degree, at a quarter of the cost. The cut tip
A1 carries half its force.
"""
import dataclasses
import json
import tomllib
from pathlib import Path

import numpy as np
import pytest

import tissue_reference.fem_reference as fr
from tissue_reference.meshes.builders import build
from tissue_reference.model.case import load_case

ROOT = Path(__file__).resolve().parents[1]
CASES = ROOT / "meshes" / "cases"
DATA = ROOT / "tests" / "data" / "phantom_indenter_reference.json"


@pytest.mark.slow
@pytest.mark.parametrize("rule, study, pushes", [(None, "four_gauss_surface", (5.0, 10.0, 12.5)),
                                                 ("nodal", "four_gauss", (5.0, 10.0))])
def test_the_indenter_default_is_within_2_percent_of_the_finest_level(rule, study, pushes):
    whole = load_case(CASES / "phantom-indenter.toml")
    spec = tomllib.loads((CASES / "phantom-indenter.toml").read_text())["mesh"]
    assert spec["builtin"] == "phantom-symmetric"
    quarter = load_case(CASES / "phantom-indenter-quarter.toml")
    mesh = build("phantom-quarter", spec["size"], site_size=spec["site_size"],
                 path_size=spec["path_size"])
    assert {a.radius for a in whole.actuators} == {a.radius for a in quarter.actuators}
    assert whole.reference_tip_start is None and quarter.reference_tip_start is None
    case = dataclasses.replace(quarter, mesh=mesh)
    solver = fr.ReferenceSolver(case, degree=whole.reference_degree,
                                contact_quadrature=rule or whole.reference_contact_quadrature)
    data = json.loads(DATA.read_text())["loads"][study]
    assert data["tip_radius_mm"] == whole.actuators[0].radius
    assert data["levels"][-1]["cells"] > 4 * case.mesh.n_cells  # a far finer discretization
    prev = None
    for push in pushes:
        res = solver.solve({a.name: push for a in case.actuators}, initial=prev)
        prev = res
        assert res.valid is not False, res.invalid_reason
        entry = next(e for e in data["pushes"] if e["push_mm"] == push)
        # the finest level stands for the converged answer: its levels contract here
        f = entry["force_mN"]
        assert abs(f[-1] - f[-2]) < abs(f[-2] - f[-3]) < abs(f[-3] - f[-4])
        force = 2.0 * res.indenters["A1"]["force"]
        assert force == pytest.approx(f[-1], rel=0.02)
        for name, values in entry["probes_mm"].items():
            ref = np.asarray(values[-1])
            assert np.linalg.norm(res.probes[name] - ref) < 0.02 * np.linalg.norm(ref), name
