"""Implant planning geometry: skin sheets, the RBF muscle estimate (seed 001 sec. 2.1, 4.2), the
gmsh tissue volume and the implant library."""
from __future__ import annotations

import numpy as np
import pytest

from tissue_reference.errors import CaseError, ReadError
from tissue_reference.implant.library import ImplantSpec, implant_mesh, mesh_volume
from tissue_reference.implant.rbf import ImplicitRBF, Thickness, breast_mask, muscle_surface
from tissue_reference.implant.surface import (
    TriSurface,
    check_single_sheet,
    closest_points,
    read_surface,
    vertex_normals,
)
from tissue_reference.implant.torso import SyntheticTorso, grid_triangles, tissue_mesh
from tissue_reference.meshes.mesh import cell_volumes


@pytest.fixture(scope="module")
def torso():
    return SyntheticTorso()


@pytest.fixture(scope="module")
def fit(torso):
    return muscle_surface(torso.skin(), torso.thickness_estimates())


def _flat_sheet(n=6, h=10.0, z=0.0):
    x, y = np.meshgrid(np.arange(n) * h, np.arange(n) * h, indexing="ij")
    p = np.column_stack([x.ravel(), y.ravel(), np.full(n * n, z)])
    return TriSurface(p, grid_triangles(n, n))


def test_rbf_interpolates_its_constraints_and_reproduces_linear_fields():
    rng = np.random.default_rng(1)
    x = rng.uniform(-50, 50, (60, 3))
    f = 0.3 + 0.01 * x[:, 0] - 0.02 * x[:, 2]  # linear: reproduced exactly by the polynomial
    rbf = ImplicitRBF.fit(x, f)
    q = rng.uniform(-50, 50, (20, 3))
    assert np.allclose(rbf(x), f, atol=1e-9)
    assert np.allclose(rbf(q), 0.3 + 0.01 * q[:, 0] - 0.02 * q[:, 2], atol=1e-8)
    assert np.allclose(rbf.gradient(q), [0.01, 0.0, -0.02], atol=1e-8)


def test_rbf_gradient_matches_central_differences():
    rng = np.random.default_rng(2)
    x = rng.uniform(-50, 50, (40, 3))
    rbf = ImplicitRBF.fit(x, rng.uniform(0, 1, 40))
    q = rng.uniform(-40, 40, (5, 3))
    h = 1e-5
    fd = np.column_stack([(rbf(q + h * e) - rbf(q - h * e)) / (2 * h) for e in np.eye(3)])
    assert np.allclose(rbf.gradient(q), fd, atol=1e-6)


def test_thickness_is_linear_between_the_three_planes_and_constant_outside():
    t = Thickness(10.0, 20.0, 30.0, -100.0, 0.0, 100.0)
    assert np.allclose(t([-200, -100, -50, 0, 50, 100, 300]), [10, 10, 15, 20, 25, 30, 30])


@pytest.mark.parametrize("bad", [0.0, -5.0, float("nan")])
def test_non_positive_thickness_estimate_is_rejected(bad):
    with pytest.raises(CaseError, match="thickness estimate A"):
        Thickness(bad, 20.0, 20.0, -100.0, 0.0, 100.0)


def test_thickness_larger_than_the_body_is_rejected(torso):
    t = torso.thickness_estimates()
    huge = Thickness(t.A, 400.0, t.C, t.x_A, t.x_B, t.x_C)
    with pytest.raises(CaseError, match="larger than the body"):
        muscle_surface(torso.skin(), huge)


def test_breast_mask_covers_the_synthetic_mounds_and_spares_the_chest(torso):
    m = breast_mask(torso.skin())
    mound = torso.breast(*torso.parameters()) > 0.5        # the mound stands out > 0.5 mm
    assert np.all(m[mound])
    assert not np.any(m[~torso.true_breast_mask(arc_margin=30.0)])  # nothing far outside


def test_rbf_muscle_within_5mm_and_3p5deg_of_the_true_one_in_the_implant_region(torso, fit):
    """Seed 001 section 4.2's figures, on a torso whose muscle is known exactly."""
    for side in ("left", "right"):
        c = torso.breast_centre(side)
        near = np.linalg.norm(fit.muscle.points - c, axis=1) < 70.0
        assert near.sum() > 20
        err = np.abs(torso.muscle_distance(fit.muscle.points[near]))
        assert err.max() < 5.0
        n = vertex_normals(fit.muscle.points, fit.muscle.triangles)[near]
        ang = np.degrees(np.arccos(np.clip(np.sum(n * torso.muscle_normal(fit.muscle.points[near]),
                                                  axis=1), -1, 1)))
        assert ang.max() < 3.5


def test_rbf_muscle_keeps_the_estimated_thickness_away_from_the_breasts(torso, fit):
    far = ~torso.true_breast_mask(arc_margin=25.0)
    err = np.abs(torso.muscle_distance(fit.muscle.points[far]))
    assert np.median(err) < 0.5


def test_disconnected_skin_is_rejected_before_any_solve():
    a, b = _flat_sheet(), _flat_sheet(z=100.0)
    two = TriSurface(np.vstack([a.points, b.points]),
                     np.vstack([a.triangles, b.triangles + a.n_points]))
    with pytest.raises(CaseError, match="not a single connected sheet: 2 separate pieces"):
        check_single_sheet(two)


def test_closed_surface_is_not_a_skin_sheet():
    p = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    t = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])
    with pytest.raises(CaseError, match="closed surface"):
        check_single_sheet(TriSurface(p, t))


@pytest.mark.parametrize("suffix", [".stl", ".ply", ".obj", ".vtk"])
def test_skin_surface_round_trips_through_meshio_formats(tmp_path, suffix):
    import meshio

    s = _flat_sheet()
    f = tmp_path / f"skin{suffix}"
    meshio.write(str(f), meshio.Mesh(s.points, [("triangle", s.triangles)]))
    r = read_surface(f)
    assert len(r.triangles) == len(s.triangles)
    assert np.isclose(r.area(), s.area())


def test_missing_skin_file_is_a_read_error(tmp_path):
    with pytest.raises(ReadError, match="does not exist"):
        read_surface(tmp_path / "none.stl")


def test_closest_points_on_a_plane_are_orthogonal_projections():
    s = _flat_sheet()
    q = np.array([[12.0, 17.0, 5.0], [33.0, 2.0, -7.0], [-10.0, 0.0, 0.0]])
    cp, d, _ = closest_points(q, s.points, s.triangles)
    assert np.allclose(cp, [[12, 17, 0], [33, 2, 0], [0, 0, 0]], atol=1e-12)
    assert np.allclose(d, [5.0, 7.0, 10.0])


def test_tissue_volume_has_named_regions_and_equals_the_layer_volume():
    """A flat 50 x 50 mm sheet over a parallel one 20 mm behind: a 50000 mm^3 slab."""
    skin = _flat_sheet(z=20.0)
    mus = _flat_sheet(z=0.0)
    m = tissue_mesh(skin, TriSurface(mus.points, skin.triangles))
    assert {"skin", "muscle", "sides"} <= set(m.facet_regions)
    assert np.isclose(cell_volumes(m.points, m.cells).sum(), 50.0 * 50.0 * 20.0, rtol=1e-9)
    assert np.allclose(m.points[m.region_vertices("muscle"), 2], 0.0)
    assert np.allclose(m.points[m.region_vertices("skin"), 2], 20.0)


def test_synthetic_tissue_mesh_is_about_3500_tetrahedra(torso, fit):
    m = tissue_mesh(torso.skin(), fit.muscle)
    assert 2500 <= m.n_cells <= 5000
    assert np.all(cell_volumes(m.points, m.cells) > 0)


@pytest.mark.parametrize("shape", ["round", "anatomical"])
@pytest.mark.parametrize("cc", [150.0, 245.0, 400.0])
def test_implant_mesh_volume_matches_its_label_within_1_percent(shape, cc):
    m = implant_mesh(ImplantSpec(shape, cc))
    assert abs(mesh_volume(m) / (cc * 1000.0) - 1.0) < 0.01
    assert np.allclose(m.points[m.region_vertices("base"), 2], 0.0)


def test_implant_keeps_a_given_width_and_sets_the_projection_from_the_volume():
    w, h, p = ImplantSpec("round", 245.0, width=120.0).dimensions()
    assert w == 120.0 and h == 120.0
    assert np.isclose(2 / 3 * np.pi * 60.0 * 60.0 * p, 245000.0)


def test_anatomical_implant_has_its_fuller_pole_below():
    m = implant_mesh(ImplantSpec("anatomical", 245.0))
    up, down = m.points[:, 1] > 10.0, m.points[:, 1] < -10.0
    assert m.points[down, 2].max() > m.points[up, 2].max()


@pytest.mark.parametrize("kw", [{"shape": "oval"}, {"volume_cc": -10.0}, {"width": 0.0}])
def test_bad_implant_specification_is_rejected(kw):
    with pytest.raises(CaseError):
        ImplantSpec(**kw)
