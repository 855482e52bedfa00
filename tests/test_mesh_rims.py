"""``rim_size``: finer cells at the rims of the phantom's actuator patches, where a glued patch
is singular; ``base_rim_size``: at the base rim, where the fixed base meets the free dome. The
rims are computed here from the geometry (the patch's cylinder met with the dome; the base's
circle), not taken from the builder."""
import numpy as np
import pytest

from tissue_reference.errors import CaseError
from tissue_reference.meshes.builders import RIM_GRADING, build, estimate_cells
from tissue_reference.meshes.builders_curved import PHANTOM


def rim_points(azimuth_deg: float, n: int = 720) -> np.ndarray:
    """Points of one patch's rim: the cylinder of the patch radius around the inward radial axis
    through the site, met with the dome x^2/a^2 + y^2/a^2 + z^2/c^2 = 1 (solved per angle)."""
    g = PHANTOM
    site = g.side_point(azimuth_deg)
    d = -np.array([np.cos(np.radians(azimuth_deg)), np.sin(np.radians(azimuth_deg)), 0.0])
    e1, e2 = np.cross(d, [0.0, 0.0, 1.0]), np.array([0.0, 0.0, 1.0])
    scale = np.array([1 / g.radius ** 2, 1 / g.radius ** 2, 1 / g.height ** 2])
    out = []
    for th in np.linspace(0.0, 2 * np.pi, n, endpoint=False):
        p0 = site + g.patch_radius * (np.cos(th) * e1 + np.sin(th) * e2)
        # (p0 + t d) on the dome: a t^2 + b t + c = 0, the root nearest the site
        a, b, c = (d * d) @ scale, 2 * (p0 * d) @ scale, (p0 * p0) @ scale - 1.0
        t = (-b - np.sqrt(b * b - 4 * a * c)) / (2 * a)
        out.append(p0 + t * d)
    return np.array(out)


def cell_sizes_and_rim_distance(mesh, azimuths):
    pts = mesh.points[mesh.cells]
    centre = pts.mean(axis=1)
    h = np.linalg.norm(pts[:, [0, 0, 0, 1, 1, 2]] - pts[:, [1, 2, 3, 2, 3, 3]],
                       axis=2).mean(axis=1)
    rim = np.vstack([rim_points(az) for az in azimuths])
    dist = np.full(len(centre), np.inf)
    for k in range(0, len(rim), 120):
        dist = np.minimum(dist, np.linalg.norm(centre[:, None, :] - rim[None, k:k + 120],
                                               axis=2).min(axis=1))
    return h, dist


def test_rim_size_refines_the_patch_rims_and_nothing_else():
    size, rim = 8.0, 1.0
    refined = build("phantom-quarter", size, rim_size=rim)
    plain = build("phantom-quarter", size)
    # the quarter keeps the halves of A1 (azimuth 0) and A2 (90), cut along the mirror planes
    h, dist = cell_sizes_and_rim_distance(refined, (0.0, 90.0))
    at_rim = dist < 1.5 * rim
    assert at_rim.sum() > 100
    assert np.median(h[at_rim]) < 1.6 * rim                   # edge length about rim_size
    # cells grow by about RIM_GRADING per mm away from the rim
    ring = (dist > 4.0) & (dist < 5.0)
    assert np.median(h[ring]) > rim + 0.5 * RIM_GRADING * 4.0
    # far from every rim, the plain mesh's size
    far = dist > 1.2 * (size - rim) / RIM_GRADING
    hp, dp = cell_sizes_and_rim_distance(plain, (0.0, 90.0))
    assert np.median(h[far]) > 0.85 * np.median(hp[dp > 1.2 * (size - rim) / RIM_GRADING])
    # the cut along a mirror plane through the patch is not a rim: the patch's centre, 4-5 mm
    # from the rim and on the plane y = 0, keeps the graded size (about 2 mm), not rim_size
    c = PHANTOM.side_point(0.0)
    near_centre = np.linalg.norm(refined.points[refined.cells].mean(axis=1) - c, axis=1) < 1.5
    assert near_centre.any() and np.median(h[near_centre]) > 1.5 * rim
    est = estimate_cells("phantom-quarter", size, rim_size=rim)
    assert abs(est - refined.n_cells) <= 0.15 * refined.n_cells, (est, refined.n_cells)


def test_base_rim_size_refines_the_base_rim_and_nothing_else():
    size, rim = 8.0, 1.5
    refined = build("phantom-half", size, base_rim_size=rim)
    plain = build("phantom-half", size)

    def sizes_and_distance(mesh):
        pts = mesh.points[mesh.cells]
        c = pts.mean(axis=1)
        h = np.linalg.norm(pts[:, [0, 0, 0, 1, 1, 2]] - pts[:, [1, 2, 3, 2, 3, 3]],
                           axis=2).mean(axis=1)
        # distance to the circle x^2 + y^2 = radius^2, z = 0
        return h, np.hypot(np.hypot(c[:, 0], c[:, 1]) - PHANTOM.radius, c[:, 2])

    h, dist = sizes_and_distance(refined)
    hp, dp = sizes_and_distance(plain)
    at_rim = dist < 1.5 * rim
    assert at_rim.sum() > 100
    assert np.median(h[at_rim]) < 1.6 * rim < 0.5 * np.median(hp[dp < 1.5 * rim])
    far = dist > 1.2 * (size - rim) / RIM_GRADING     # beyond the grading: the plain size
    assert np.median(h[far]) > 0.85 * np.median(hp[dp > 1.2 * (size - rim) / RIM_GRADING])
    # the base's straight edge on the mirror plane y = 0 is not a rim: at the base's centre
    # the cells keep the plain size
    centre = (dist > 30.0) & (refined.points[refined.cells].mean(axis=1)[:, 2] < 3.0)
    assert np.median(h[centre]) > 3.0 * rim
    est = estimate_cells("phantom-half", size, base_rim_size=rim)
    assert abs(est - refined.n_cells) <= 0.15 * refined.n_cells, (est, refined.n_cells)


@pytest.mark.parametrize("name, kw, match", [
    ("phantom-half", {"base_rim_size": 0.0}, "base_rim_size must be a positive length"),
    ("box", {"base_rim_size": 1.0}, "base_rim_size applies to the builders"),
    ("phantom-half", {"site_size": 4.0, "path_reach": 8.0}, "path_reach 8.0 mm is the reach"),
    ("phantom-half", {"site_size": 4.0, "path_size": 2.0, "path_reach": -1.0},
     "path_reach must be a positive length"),
    ("phantom-quarter", {"rim_size": -1.0}, "rim_size must be a positive length"),
    ("phantom-quarter", {"rim_size": float("nan")}, "rim_size must be a positive length"),
    ("box", {"rim_size": 1.0}, "rim_size applies to the builders"),
])
def test_a_bad_rim_size_is_refused_with_its_value(name, kw, match):
    with pytest.raises(CaseError, match=match):
        build(name, 8.0, **kw)


def test_a_rim_size_in_a_case_file_reaches_the_builder(tmp_path):
    from pathlib import Path

    from tissue_reference.model.case import load_case

    text = Path("meshes/cases/phantom-quarter.toml").read_text()
    f = tmp_path / "rim.toml"
    f.write_text(text.replace("size = 6.0 ", "size = 8.0\nrim_size = 1.0 ", 1))
    assert load_case(f).mesh.n_cells == build("phantom-quarter", 8.0, rim_size=1.0).n_cells
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace("size = 6.0 ", "size = 8.0\nrim_size = 0 ", 1))
    with pytest.raises(CaseError, match="rim_size"):
        load_case(bad)
    base = tmp_path / "base.toml"
    base.write_text(text.replace("size = 6.0 ", "size = 8.0\nbase_rim_size = 2.0 ", 1))
    assert load_case(base).mesh.n_cells == build("phantom-quarter", 8.0,
                                                 base_rim_size=2.0).n_cells


def test_a_path_is_refined_when_the_site_size_is_the_mesh_size():
    """A site_size no finer than size refines nothing at the sites; the path inside them is
    refined all the same."""
    plain = build("phantom-quarter", 8.0, site_size=8.0)
    path = build("phantom-quarter", 8.0, site_size=8.0, path_size=3.0)
    assert path.n_cells > 1.5 * plain.n_cells


def test_path_reach_widens_the_refined_path():
    """Cells of path_size within path_reach of each tip's axis (from the site 20 mm inward):
    at 7-9 mm from A1's axis the default reach (6 mm) has graded up towards site_size, a
    reach of 10 mm has not. The axis is computed here from the geometry."""
    site, path = 4.0, 1.5
    site_pt = PHANTOM.side_point(0.0)              # A1's site; its axis runs along -x

    def ring_size(mesh):
        pts = mesh.points[mesh.cells]
        c = pts.mean(axis=1)
        h = np.linalg.norm(pts[:, [0, 0, 0, 1, 1, 2]] - pts[:, [1, 2, 3, 2, 3, 3]],
                           axis=2).mean(axis=1)
        along = site_pt[0] - c[:, 0]
        off = np.hypot(c[:, 1], c[:, 2] - site_pt[2])
        ring = (along > 3.0) & (along < 17.0) & (off > 7.0) & (off < 9.0)
        assert ring.sum() > 50
        return np.median(h[ring])

    default = build("phantom-half", 8.0, site_size=site, path_size=path)
    wide = build("phantom-half", 8.0, site_size=site, path_size=path, path_reach=10.0)
    assert ring_size(wide) < 1.4 * path < ring_size(default)
    assert wide.n_cells > default.n_cells
    est = estimate_cells("phantom-half", 8.0, site_size=site, path_size=path, path_reach=10.0)
    assert abs(est - wide.n_cells) <= 0.25 * wide.n_cells, (est, wide.n_cells)


@pytest.mark.slow
def test_refined_rims_move_the_glued_phantom_towards_the_independent_converged_value():
    """All four glued patches pushed 5 mm on the quarter phantom (P2): refining the patches'
    rims from 2.4 to 0.85 mm brings T1 u_z to within 2 % of the independent textbook solve's
    converged interval (tests/data/phantom_reference.json), less than half as far from it as
    before. The rim is singular: its smallest J falls as its cells shrink."""
    import json
    from pathlib import Path

    import tissue_reference.fem_reference as fr
    from tissue_reference.model.case import load_case

    ref = json.loads((Path(__file__).parent / "data/phantom_reference.json").read_text())
    lo, hi = ref["converged_T1_uz_mm"]["low"], ref["converged_T1_uz_mm"]["high"]
    case = load_case("meshes/cases/phantom-quarter.toml")
    out = {}
    for rim in (2.4, 0.85):
        c = case.with_mesh(build("phantom-quarter", 6.0, rim_size=rim))
        res = fr.solve(c, pushes={"A1": 5.0, "A2": 5.0}, degree=2)
        out[rim] = (res.probes["T1"][2], res.min_J)
    coarse, fine = out[2.4][0], out[0.85][0]
    assert coarse > fine > lo                           # from above, as the independent solve
    assert fine - hi < 0.02 * hi                        # within 2 % of the interval
    assert fine - hi < 0.5 * (coarse - hi)
    assert out[0.85][1] < out[2.4][1]
