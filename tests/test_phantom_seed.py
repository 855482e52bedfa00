"""The seed-000 experiment case (meshes/cases/phantom-seed.toml): one actuator's broad punch
pushed in steps on a coarse P1 mesh, checked against properties that hold whatever the numbers:
the work the punch does equals the strain energy the tissue stores (a conservative,
frictionless, quasi-static problem; the idle heads and the fixed base do no work), the force
grows with the push, the targets move along the push and less than it, the more the nearer the
punch, and the layout's mirror symmetry about the push's plane y = 0 (T3 and T5)."""
from pathlib import Path

import numpy as np
import pytest

import tissue_reference.fem_reference as fr
from tissue_reference.model.case import load_case

CASE = Path(__file__).resolve().parents[1] / "meshes" / "cases" / "phantom-seed.toml"


def test_the_seed_case_is_the_seeds_experiment_within_the_converged_range():
    case = load_case(CASE, size=14.0)
    assert case.material.model == "neo-hookean" and case.material.E == 6.0
    assert [a.name for a in case.actuators] == ["A1", "A2", "A3", "A4"]
    assert [p.name for p in case.probes] == ["T1", "T2", "T3", "T4", "T5"]
    # rigid heads whose 15 mm pushes stay within 2.5 tip radii, where answers converge
    assert all(a.type == "indenter" and 2.5 * a.radius >= 15.0 for a in case.actuators)


@pytest.mark.slow
def test_a_push_does_the_work_the_tissue_stores_and_moves_the_targets_along_it():
    case = load_case(CASE, size=10.0)
    solver = fr.ReferenceSolver(case, degree=1)
    d = np.array([-1.0, 0.0, 0.0])                       # A1's push direction
    pushes = np.linspace(0.0, 10.0, 9)
    forces, res = [0.0], None
    for p in pushes[1:]:
        res = solver.solve({"A1": float(p)}, initial=res)
        assert res.converged and res.valid
        forces.append(res.indenters["A1"]["force"])
    f = np.asarray(forces)
    assert np.all(np.diff(f) > 0)
    h = pushes[1] - pushes[0]
    work = h / 3 * (f[0] + f[-1] + 4 * f[1:-1:2].sum() + 2 * f[2:-1:2].sum())   # Simpson, uJ
    stored = res.strain_energy
    print(f"\nA1 = 10 mm: force {f[-1]:.1f} mN, work {work:.1f} uJ, strain energy {stored:.1f} "
          f"uJ ({100 * (work / stored - 1):+.2f} %)")
    assert abs(work / stored - 1) < 0.03
    u = {t: np.asarray(v) for t, v in res.probes.items()}
    along = {t: float(v @ d) for t, v in u.items()}
    # every target moves along the push and less than the head; the nearer it, the more
    assert all(0.0 < a < 10.0 for a in along.values())
    assert along["T2"] > along["T1"] > along["T4"]
    assert along["T2"] >= 2.0                            # the case's aim: millimetres, not tenths
    # mirror symmetry of the layout about y = 0 (on an unsymmetric mesh: to a tenth)
    mirror = u["T5"] * [1.0, -1.0, 1.0]
    assert np.linalg.norm(u["T3"] - mirror) < 0.1 * np.linalg.norm(u["T3"])
    assert abs(u["T3"][1]) > 0.0 and u["T3"][1] * u["T5"][1] < 0.0
