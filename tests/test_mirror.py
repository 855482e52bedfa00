"""A whole body's mesh as a symmetric part and its mirror image (meshes.mirror): the joined mesh
is symmetric, keeps every region and its curved edges, refuses a plane that is not one, and the
whole phantom meshed so gives the quarter's answer (with its planes sliding) under all four
pushed equally: a second formulation of the quarter's mirror planes."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from tissue_reference.errors import CaseError
from tissue_reference.meshes.builders import PHANTOM, build, structured_box
from tissue_reference.meshes.io import read_msh
from tissue_reference.meshes.mesh import boundary_facets, cell_volumes
from tissue_reference.meshes.mirror import mirror
from tissue_reference.meshes.writers import write_mesh
from tissue_reference.model.case import load_case

CASES = Path(__file__).resolve().parents[1] / "meshes" / "cases"


def _rows(a: np.ndarray) -> set:
    return {tuple(r) for r in np.sort(a, axis=1).tolist()}


def test_a_mirrored_box_is_the_doubled_box_with_its_regions_joined_and_renamed():
    box = structured_box((2, 3, 2), lengths=(1.0, 3.0, 2.0))
    whole = mirror(box, "xmin", 0, {"xmax": "xmin_far"})
    on_plane = np.unique(box.facet_regions["xmin"]).size
    assert whole.n_vertices == 2 * box.n_vertices - on_plane
    assert whole.n_cells == 2 * box.n_cells
    vol = cell_volumes(whole.points, whole.cells)
    assert vol.min() > 0                                  # the image keeps its orientation
    assert vol.sum() == pytest.approx(2 * 1.0 * 3.0 * 2.0, rel=1e-12)
    assert np.allclose(whole.points.min(axis=0), [-1, 0, 0])
    assert np.allclose(whole.points.max(axis=0), [1, 3, 2])
    assert "xmin" not in whole.facet_regions              # the plane is inside now
    far = whole.points[whole.region_vertices("xmin_far")]
    assert np.allclose(far[:, 0], -1.0)
    assert np.allclose(whole.points[whole.region_vertices("xmax")][:, 0], 1.0)
    # regions that keep their name join with their image: the block's outer faces, exactly
    assert _rows(whole.facet_regions["ymin"]) | _rows(whole.facet_regions["xmax"]) \
        | _rows(whole.facet_regions["xmin_far"]) | _rows(whole.facet_regions["ymax"]) \
        | _rows(whole.facet_regions["zmin"]) | _rows(whole.facet_regions["zmax"]) \
        == _rows(boundary_facets(whole.cells))
    assert np.array_equal(np.sort(whole.cell_regions["tissue"]), np.arange(whole.n_cells))


@pytest.mark.parametrize("plane, axis, why", [
    ("nowhere", 0, "is not a facet region"),
    ("xmax", 0, "off the plane"),
    ("ymin", 0, "off the plane"),
])
def test_mirroring_across_a_plane_that_is_not_one_is_refused(plane, axis, why):
    box = structured_box(2, lengths=(1.0, 1.0, 1.0))
    with pytest.raises(CaseError, match=why):
        mirror(box, plane, axis)


def test_a_mesh_reaching_across_the_plane_is_refused():
    box = structured_box(2, lengths=(1.0, 1.0, 1.0))
    shifted = type(box)(box.points - [0.5, 0.0, 0.0], box.cells, box.facet_regions)
    with pytest.raises(CaseError, match="reaches across|off the plane"):
        mirror(shifted, "xmin", 0)


@pytest.fixture(scope="module")
def symmetric():
    return build("phantom-symmetric", 10.0, site_size=5.0)


def test_the_symmetric_phantom_is_its_own_mirror_image_about_both_planes(symmetric):
    m = symmetric
    tree = cKDTree(m.points)
    for axis in (0, 1):
        image = m.points * np.where(np.arange(3) == axis, -1.0, 1.0)
        dist, idx = tree.query(image)
        assert dist.max() == 0.0
        # cells map onto cells, so the mesh (not only its vertices) is symmetric
        assert _rows(idx[m.cells]) == _rows(m.cells)
    assert sorted(m.facet_regions) == ["act_nx", "act_ny", "act_px", "act_py", "base", "skin"]
    for name, xyz in PHANTOM.targets:
        assert m.points[m.point_regions[name]].tolist() == [list(xyz)]
    # the patches are where the whole phantom's are: centred on their sites
    for name, az in (("act_px", 0), ("act_py", 90), ("act_nx", 180), ("act_ny", 270)):
        c = m.points[m.region_vertices(name)].mean(axis=0)
        assert np.linalg.norm(c - PHANTOM.side_point(az)) < 1.0
    # closed: its boundary is exactly the union of its facet regions
    assert set().union(*(_rows(f) for f in m.facet_regions.values())) \
        == _rows(boundary_facets(m.cells))
    vol = cell_volumes(m.points, m.cells)
    exact = 2.0 / 3.0 * math.pi * PHANTOM.radius ** 2 * PHANTOM.height
    assert vol.min() > 0 and 0.99 * exact < vol.sum() < exact       # inscribed in the dome
    assert m.geometry_order == 2        # curved nodes (skin, plug cylinders) have images too
    nodes = cKDTree(m.curved_points)
    for axis in (0, 1):
        image = m.curved_points * np.where(np.arange(3) == axis, -1.0, 1.0)
        assert nodes.query(image)[0].max() == 0.0


def test_a_curved_mesh_written_to_msh_reads_back_curved(symmetric, tmp_path):
    m = symmetric
    back = read_msh(write_mesh(m, tmp_path / "whole.msh", all_regions=True))
    assert np.array_equal(back.points, m.points)
    assert np.array_equal(back.cells, m.cells)
    assert sorted(back.facet_regions) == sorted(m.facet_regions)
    for name, f in m.facet_regions.items():
        assert _rows(back.facet_regions[name]) == _rows(f)
    key = {tuple(e): x for e, x in zip(np.sort(back.curved_edges, axis=1).tolist(),
                                       back.curved_points)}
    assert len(key) == len(m.curved_edges)
    for e, x in zip(np.sort(m.curved_edges, axis=1).tolist(), m.curved_points):
        assert np.array_equal(key[tuple(e)], x)


def test_the_symmetric_whole_phantom_gives_the_quarters_answer_under_four_equal_pushes(
        symmetric):
    """The quarter with its planes sliding and the whole meshed as the quarter mirrored are the
    same discrete problem under all four pushed equally: same targets (the images of the
    quarter's for T4, T5), forces four (patches: two) times the quarter's cut ones, nothing
    across the planes."""
    import tissue_reference.fem_reference as fr

    quarter = build("phantom-quarter", 10.0, site_size=5.0)   # the one ``symmetric`` mirrors
    out = {}
    for name, mesh in (("phantom", symmetric), ("phantom-quarter", quarter)):
        case = load_case(CASES / f"{name}.toml", mesh=mesh)
        res = fr.solve(case, pushes={a.name: 3.0 for a in case.actuators}, degree=2,
                       symmetry=False)   # the whole mesh solved, not reduced to the quarter
        out[name] = res
    w, q = out["phantom"], out["phantom-quarter"]
    scale = np.linalg.norm(q.probes["T1"])
    for t in ("T1", "T2", "T3"):
        assert np.linalg.norm(w.probes[t] - q.probes[t]) < 1e-6 * scale
    assert np.linalg.norm(w.probes["T4"] - q.probes["T2"] * [-1, 1, 1]) < 1e-6 * scale
    assert np.linalg.norm(w.probes["T5"] - q.probes["T3"] * [1, -1, 1]) < 1e-6 * scale
    assert abs(w.probes["T1"][0]) < 1e-9 * scale and abs(w.probes["T1"][1]) < 1e-9 * scale
    fw, fq = w.reactions["act_px"], q.reactions["act_px"]
    assert abs(fw[0]) > 1.0                                      # mN
    assert fw[0] == pytest.approx(2.0 * fq[0], rel=1e-6)    # the quarter holds half of act_px
    assert w.reactions["base"][2] == pytest.approx(4.0 * q.reactions["base"][2], rel=1e-6)


def test_the_shipped_indenter_phantom_gives_the_quarter_cases_answer_on_its_mesh():
    """phantom-indenter.toml on ``phantom-symmetric`` and phantom-indenter-quarter.toml on the
    quarter it mirrors, all four tips pushed 2 mm (P2, nodal contact rule): the same tips at the
    same sites, so the same answer; the cut tip A1 carries half the force."""
    import tissue_reference.fem_reference as fr

    out = {}
    for name, builder in (("phantom-indenter", "phantom-symmetric"),
                          ("phantom-indenter-quarter", "phantom-quarter")):
        case = load_case(CASES / f"{name}.toml", mesh=build(builder, 16.0, site_size=8.0))
        out[name] = fr.ReferenceSolver(case, degree=2, contact_quadrature="nodal").solve(
            {a.name: 2.0 for a in case.actuators})
    w, q = out["phantom-indenter"], out["phantom-indenter-quarter"]
    fw, fq = (r.indenters["A1"]["force"] for r in (w, q))
    assert fw > 10.0                                             # mN: the tips press
    assert fw == pytest.approx(2.0 * fq, rel=1e-7)
    scale = np.linalg.norm(q.probes["T1"])
    for t in ("T1", "T2", "T3"):
        assert np.linalg.norm(w.probes[t] - q.probes[t]) < 1e-7 * scale
