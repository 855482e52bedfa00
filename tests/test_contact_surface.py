"""A tip narrower than the skin's cells can pass between the surface's nodes (the contact acts
at the nodes): the solve must say so (an invalid state), never report it as a contact answer.
Checked on a coarse box with a sphere placed so that the facet under its axis is inside it,
against a fine-enough mesh where the same check stays quiet."""
import numpy as np
import pytest

import tissue_reference.fem_reference as fr
from tissue_reference.errors import CaseError
from tissue_reference.meshes.builders import box, estimate_cells
from tissue_reference.model.case import Actuator, Boundary, Case, Material

R = 1.0


def tip_case(mesh, point):
    return Case(mesh=mesh, material=Material("neo-hookean", E=6.0, nu=0.3), name="tip",
                boundaries=(Boundary("zmin", "fixed"),),
                actuators=(Actuator("I", "zmax", (0.0, 0.0, -1.0), type="indenter",
                                    tip="sphere", radius=R, point=tuple(point)),))


def lonely_axis(mesh):
    """A point of the top face whose nearest top node is 0.9 R from it, every other node
    farther than R: the sphere touches that one node and its front sits inside the facet."""
    top = np.unique(mesh.facet_regions["zmax"])
    xy = mesh.points[top, :2]
    for p in xy:
        for ang in np.linspace(0, 2 * np.pi, 24, endpoint=False):
            q = p + 0.9 * R * np.array([np.cos(ang), np.sin(ang)])
            if not (1.5 < q[0] < 8.5 and 1.5 < q[1] < 8.5):
                continue
            d = np.sort(np.linalg.norm(xy - q, axis=1))
            if d[0] > 0.89 * R and d[1] > 1.2 * R:
                return (q[0], q[1], 10.0)
    pytest.skip("no such point on this mesh")


def test_a_tip_between_coarse_nodes_gives_an_invalid_state():
    mesh = box(5.0)
    res = fr.solve(tip_case(mesh, lonely_axis(mesh)), pushes={"I": 0.1})
    rep = res.indenters["I"]
    # the sphere's front sits R (1 - sqrt(1 - 0.81)) = 0.56 R below the node it touches
    assert rep["surface_penetration"] > 0.4 * R and rep["tip_through_surface"]
    assert res.valid is False
    assert "passed between the nodes of its contact surface" in res.invalid_reason


def test_the_check_is_quiet_where_the_surface_resolves_the_tip():
    mesh = box(0.35)
    top = np.unique(mesh.facet_regions["zmax"])
    node = mesh.points[top][np.argmin(np.linalg.norm(mesh.points[top, :2] - 5.0, axis=1))]
    res = fr.solve(tip_case(mesh, node), pushes={"I": 0.3})
    rep = res.indenters["I"]
    assert rep["force"] > 0 and not rep["tip_through_surface"] and res.valid
    assert rep["surface_penetration"] < 0.05 * R


def test_site_size_refines_only_the_phantom_builders():
    assert estimate_cells("phantom", 6.0, site_size=1.6) > 5 * estimate_cells("phantom", 6.0)
    from tissue_reference.meshes.builders import build

    with pytest.raises(CaseError, match="site_size applies to the builders"):
        build("box", 5.0, site_size=1.0)


def test_path_size_refines_along_each_actuators_path_into_the_tissue():
    # quarter phantom: the paths run from the sites of A1 (azimuth 0) and A2 (90) inward; the
    # cells within PATH_REACH of them shrink towards path_size, those of the site's ball farther
    # than 1.5 PATH_REACH from both paths keep site_size (compared with the same mesh built
    # without a path)
    from tissue_reference.meshes.builders import PATH_DEPTH, PATH_REACH, SITE_REACH, build
    from tissue_reference.meshes.builders_curved import PHANTOM

    site, path = 4.0, 2.0

    def sizes(mesh):
        pts = mesh.points[mesh.cells]
        c = pts.mean(axis=1)
        h = np.linalg.norm(pts[:, [0, 0, 0, 1, 1, 2]] - pts[:, [1, 2, 3, 2, 3, 3]],
                           axis=2).mean(axis=1)
        d, r = [], []
        for az in (0.0, 90.0):
            s0 = PHANTOM.side_point(az)
            n = -np.array([np.cos(np.radians(az)), np.sin(np.radians(az)), 0.0])
            t = np.clip((c - s0) @ n, 0.0, PATH_DEPTH)
            d.append(np.linalg.norm(c - s0 - t[:, None] * n, axis=1))
            r.append(np.linalg.norm(c - s0, axis=1))
        d, r = np.min(d, axis=0), np.min(r, axis=0)
        on_path = d < PATH_REACH - path
        in_ball = (r < SITE_REACH - 1.0) & (d > 1.5 * PATH_REACH + 1.0)
        assert on_path.sum() > 100 and in_ball.sum() > 50
        return np.median(h[on_path]), np.median(h[in_ball])

    refined = build("phantom-quarter", 8.0, site_size=site, path_size=path)
    plain = build("phantom-quarter", 8.0, site_size=site)
    (p_on, p_ball), (q_on, q_ball) = sizes(refined), sizes(plain)
    assert q_on > 0.9 * site                  # without a path: site_size there too
    assert p_on < 1.3 * path and p_on < 0.7 * q_on
    assert p_ball > 0.85 * q_ball             # the rest of the site's ball is as it was
    assert refined.n_cells > 2 * plain.n_cells
    est = estimate_cells("phantom-quarter", 8.0, site_size=site, path_size=path)
    assert abs(est - refined.n_cells) <= 0.15 * refined.n_cells, (est, refined.n_cells)


@pytest.mark.parametrize("kw, match", [({"path_size": 1.0}, "give a site_size too"),
                                       ({"site_size": 2.0, "path_size": 3.0},
                                        "needs a site_size at least as large"),
                                       ({"site_size": 2.0, "path_size": -1.0},
                                        "path_size must be a positive length")])
def test_a_path_size_without_a_coarser_site_is_refused(kw, match):
    from tissue_reference.meshes.builders import build

    with pytest.raises(CaseError, match=match):
        build("phantom-quarter", 8.0, **kw)


def test_a_degree_2_surface_is_checked_where_it_bulges_between_its_vertices():
    """A P2 field bends a facet between its vertices: the check samples that curved surface.
    The field is quadratic (P2 holds it exactly): a paraboloid bulge rising towards the tip,
    highest under its axis, between the top face's vertices. The expected depth is computed
    here from the formula of the field and of the sphere at points spread over each facet."""
    mesh = box(5.0)
    axis = lonely_axis(mesh)
    case = tip_case(mesh, axis)
    solver = fr.ReferenceSolver(case, degree=2)
    ind = solver.contact.indenters[0]
    centre = np.asarray(ind.q.value, float) + np.array([0.0, 0.0, R])   # tip's front + R up
    a, b = 1.0, 0.01   # apex rise (mm) and fall-off (1/mm)

    def bulge(x):
        return a - b * ((x[0] - axis[0]) ** 2 + (x[1] - axis[1]) ** 2)

    solver.u.interpolate(lambda x: np.stack([0 * x[0], 0 * x[0], bulge(x)]))
    top = mesh.facet_regions["zmax"]
    n = 4
    bary = np.array([(1 - (i + j) / n, i / n, j / n) for i in range(n + 1)
                     for j in range(n + 1 - i)])
    X = np.einsum("sk,fkd->fsd", bary, mesh.points[top]).reshape(-1, 3)
    def depth(y):   # inside the ball-ended rod along +z from the centre (mm)
        w = y - centre
        rho = np.linalg.norm(w[:, :2], axis=1)
        return np.where(w[:, 2] <= 0, R - np.linalg.norm(w, axis=1), R - rho)

    Y = X + np.stack([0 * X[:, 0], 0 * X[:, 0], bulge(X.T)], axis=1)
    expected = max(0.0, float(np.max(depth(Y))))
    vertices = mesh.points[np.unique(top)]
    chord = float(np.max(depth(
        vertices + np.stack([0 * vertices[:, 0], 0 * vertices[:, 0], bulge(vertices.T)], 1))))
    assert expected > 0.2 * R and chord < expected - 0.1 * R   # the bulge is between vertices
    assert ind.surface_penetration() == pytest.approx(expected, abs=1e-9)
