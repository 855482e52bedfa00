"""The phantom's symmetric parts (half: y >= 0; quarter: x >= 0, y >= 0) with sliding mirror
planes stand for the whole phantom under symmetric loads: geometry, regions, the refinement's
projection, and the answer of the whole phantom's own solve."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from tissue_reference.meshes.builders import PHANTOM, build
from tissue_reference.meshes.mesh import cell_volumes
from tissue_reference.meshes.refine import projector_for, refine_uniform
from tissue_reference.model.case import load_case

ROOT = Path(__file__).resolve().parents[1]
CASES = ROOT / "meshes" / "cases"


def _on_dome(x: np.ndarray) -> np.ndarray:
    """|f| of the dome's implicit surface (x^2 + y^2) / R^2 + z^2 / H^2 - 1."""
    g = PHANTOM
    return np.abs((x[:, 0] ** 2 + x[:, 1] ** 2) / g.radius ** 2 + x[:, 2] ** 2 / g.height ** 2 - 1)


@pytest.fixture(scope="module")
def parts():
    return {name: build(name, 8.0, site_size=4.0)
            for name in ("phantom-half", "phantom-quarter")}


@pytest.mark.parametrize("name, planes, patches, targets", [
    ("phantom-half", {"sym_y0": 1}, {"act_px", "act_py", "act_nx"}, ("T1", "T2", "T3", "T4")),
    ("phantom-quarter", {"sym_y0": 1, "sym_x0": 0}, {"act_px", "act_py"}, ("T1", "T2", "T3")),
])
def test_a_symmetric_part_keeps_its_side_with_the_planes_as_regions(parts, name, planes,
                                                                    patches, targets):
    m = parts[name]
    for region, axis in planes.items():
        assert m.points[:, axis].min() > -1e-9
        on = m.points[m.region_vertices(region)]
        assert len(on) > 10 and np.abs(on[:, axis]).max() < 1e-9
    assert set(m.facet_regions) == {"base", "skin", *patches, *planes}
    # the volume: half / a quarter of the dome's 2/3 pi R^2 H, to the P1 chords' deficit
    whole = 2.0 / 3.0 * math.pi * PHANTOM.radius ** 2 * PHANTOM.height
    vol = np.abs(cell_volumes(m.points, m.cells)).sum()
    assert vol == pytest.approx(whole / 2 ** len(planes), rel=0.02)
    for t in targets:  # each target is a vertex where the phantom puts it
        (v,) = m.point_regions[t]
        want = dict(PHANTOM.targets)[t]
        assert np.allclose(m.points[v], want, atol=1e-9)
    assert not set(m.point_regions) - set(targets)


def test_refining_a_part_keeps_the_planes_flat_and_the_skin_on_the_dome(parts):
    m = parts["phantom-quarter"]
    fine = refine_uniform(m, project=projector_for("phantom-quarter"))
    for region, axis in (("sym_y0", 1), ("sym_x0", 0)):
        on = fine.points[fine.region_vertices(region)]
        assert np.abs(on[:, axis]).max() < 1e-9
    skin = fine.points[fine.region_vertices("skin")]
    assert skin[:, 2].min() >= -1e-9
    assert _on_dome(skin).max() < 1e-6  # gmsh places its own vertices to ~1e-8; a chord
    # midpoint left unprojected would be off by ~h^2 / (8 R^2) ~ 1e-3
    # mirror-plane vertices inside the body stay put (no pull onto the dome)
    inner = fine.points[np.setdiff1d(fine.region_vertices("sym_y0"),
                                     fine.region_vertices("skin"))]
    assert _on_dome(inner).max() > 0.1


def test_the_half_phantom_answers_for_the_whole_under_a_symmetric_push():
    """A1 alone is symmetric about y = 0: the half phantom with its plane sliding gives the
    whole phantom's force (twice its half tip's) and targets, to the two meshes' discretization
    difference (P2, nodal contact rule, 4 mm sites, 1.5 mm push: 0.1-0.2 % measured; P1 differs
    by 5 %), and no motion across the plane."""
    import tissue_reference.fem_reference as fr

    out = {}
    for name, builder in (("phantom-indenter", "phantom"),
                          ("phantom-indenter-half", "phantom-half")):
        case = load_case(CASES / f"{name}.toml", mesh=build(builder, 8.0, site_size=4.0))
        res = fr.ReferenceSolver(case, degree=2, contact_quadrature="nodal").solve({"A1": 1.5})
        force = res.indenters["A1"]["force"]
        out[name] = (force * (2.0 if "half" in name else 1.0), res.probes)
    (f_whole, p_whole), (f_half, p_half) = out["phantom-indenter"], out["phantom-indenter-half"]
    assert f_half == pytest.approx(f_whole, rel=0.01)
    for t in ("T1", "T2", "T4"):  # on the plane: no motion across it
        assert abs(p_half[t][1]) < 1e-9
        assert abs(p_whole[t][1]) < 0.01 * np.linalg.norm(p_whole[t])
        assert np.linalg.norm(p_half[t] - p_whole[t]) < 0.01 * np.linalg.norm(p_whole[t])
