"""Implant placement, seed 001's two-step boundary conditions, the Mass Tensor plan, ICP and
surface distances, and the ``tissue implant`` command."""
from __future__ import annotations

import json

import numpy as np
import pytest

from tissue_reference.errors import CaseError
from tissue_reference.implant.library import ImplantSpec
from tissue_reference.implant.pipeline import (
    PlanSettings,
    patient_from_file,
    plan_implant,
    synthetic_patient,
)
from tissue_reference.implant.placement import place_implant
from tissue_reference.implant.registration import (
    RigidTransform,
    icp,
    kabsch,
    rotation_angle_deg,
    surface_distances,
)
from tissue_reference.implant.surface import closest_points
from tissue_reference.implant.torso import SyntheticTorso, grid_triangles


@pytest.fixture(scope="module")
def patient():
    return synthetic_patient()


@pytest.fixture(scope="module")
def plan(patient):
    return plan_implant(patient, PlanSettings(volume_cc=245.0, shape="round", side="left"))


@pytest.fixture(scope="module")
def sliding_plan(patient):
    return plan_implant(patient, PlanSettings(volume_cc=245.0, shape="anatomical", side="right",
                                              sliding=True))


# ------------------------------------------------------------------ registration / distances
def test_kabsch_recovers_an_exact_rigid_transform():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(30, 3)) * 50
    g = RigidTransform.from_axis_angle([1, 2, 3], 25.0, [4, -5, 6])
    e = kabsch(x, g.apply(x))
    assert np.allclose(e.R, g.R, atol=1e-12) and np.allclose(e.t, g.t, atol=1e-10)


@pytest.mark.parametrize("method", ["point-to-point", "point-to-plane"])
def test_icp_recovers_a_known_rigid_transform_within_0p1mm_and_0p1deg(method):
    skin = SyntheticTorso().skin()
    g = RigidTransform.from_axis_angle([0.3, 1.0, 0.2], 4.0, [5.0, -3.0, 7.0])
    r = icp(g.apply(skin.points), skin.points, skin.triangles, method=method)
    err = r.transform.compose(g)  # identity when g is undone
    assert r.converged
    assert rotation_angle_deg(err.R) < 0.1
    assert np.abs(err.apply(skin.points) - skin.points).max() < 0.1


def test_icp_uses_the_initial_transform_for_a_large_misalignment():
    skin = SyntheticTorso().skin()
    g = RigidTransform.from_axis_angle([0.0, 1.0, 0.0], 40.0, [30.0, 0.0, 0.0])
    init = RigidTransform.from_axis_angle([0.0, 1.0, 0.0], -38.0, [-28.0, 0.0, 0.0])
    r = icp(g.apply(skin.points), skin.points, skin.triangles, initial=init)
    err = r.transform.compose(g)
    assert rotation_angle_deg(err.R) < 0.1
    assert np.abs(err.apply(skin.points) - skin.points).max() < 0.1


def test_distance_between_parallel_sheets_is_their_offset():
    x, y = np.meshgrid(np.linspace(0, 100, 11), np.linspace(0, 100, 11), indexing="ij")
    p = np.column_stack([x.ravel(), y.ravel(), np.zeros(121)])
    tri = grid_triangles(11, 11)
    st = surface_distances(p + [0, 0, 3.0], p, tri)
    assert np.isclose(st.d_max_mm, 3.0) and np.isclose(st.mean_distance_mm, 3.0)
    st2 = surface_distances(p + [0, 0, 3.0], p, tri, region=np.flatnonzero(p[:, 0] < 50))
    assert st2.n_points == 55


# ------------------------------------------------------------------ placement / fit
def test_implant_on_the_wrong_side_is_rejected(plan):
    with pytest.raises(CaseError, match="not on the left side"):
        place_implant(plan.tissue, ImplantSpec(), side="left", at=(-80.0, -25.0), mid_x=0.0)


def test_implant_reaching_outside_the_muscle_patch_is_rejected(plan):
    with pytest.raises(CaseError, match="does not fit"):
        place_implant(plan.tissue, ImplantSpec(), side="left", at=(150.0, 100.0), mid_x=0.0)


def test_too_large_implant_is_rejected_before_any_solve(patient):
    with pytest.raises(CaseError, match="does not fit"):
        plan_implant(patient, PlanSettings(volume_cc=1500.0, side="left"))


def test_unknown_side_is_rejected(plan):
    with pytest.raises(CaseError, match="unknown side"):
        place_implant(plan.tissue, ImplantSpec(), side="middle")


# ------------------------------------------------------------------ two-step boundary conditions
def test_step1_ground_plane_lies_on_the_muscle(plan):
    base = plan.implant.base
    _, d, _ = closest_points(plan.implant_points[base], plan.tissue.points,
                             plan.tissue.facet_regions["muscle"])
    assert d.max() < 1e-6


def test_step2_interface_under_the_implant_reaches_its_upper_surface(plan):
    x = plan.predicted_points[plan.bc.target]
    _, d, _ = closest_points(x, plan.implant_points, plan.implant.shell)
    assert len(plan.bc.target) >= 20
    assert d.max() < 1e-6


def test_border_points_do_not_move_and_the_skin_is_pushed_out(plan):
    assert np.abs(plan.u[plan.bc.border]).max() < 1e-12
    skin = plan.tissue.region_vertices("skin")
    free_skin = np.setdiff1d(skin, plan.bc.border)
    # outward push of the skin over the implant: most of the projection (38.6 mm)
    outward = plan.u[free_skin] @ plan.placement.axis
    assert outward.max() > 20.0


def test_free_ring_points_lie_within_30mm_of_the_implant_and_move(plan):
    ring = plan.bc.free_ring
    assert ring.size > 0
    X = plan.tissue.points
    d = np.min(np.linalg.norm(X[ring][:, None] - X[plan.bc.target][None], axis=2), axis=1)
    assert d.max() <= 30.0
    assert np.abs(plan.u[ring]).max() > 0.1


def test_without_free_ring_every_other_interface_point_is_border(patient):
    p = plan_implant(patient, PlanSettings(volume_cc=245.0, side="left", free_ring=None))
    mv = p.tissue.region_vertices("muscle")
    assert p.bc.free_ring.size == 0
    assert np.array_equal(np.sort(np.concatenate([p.bc.target, np.intersect1d(p.bc.border, mv)])),
                          mv)


def test_target_to_sliding_switch_keeps_the_points_on_the_implant(sliding_plan):
    p = sliding_plan
    x = p.predicted_points[p.bc.target]
    _, d, _ = closest_points(x, p.implant_points, p.implant.shell)
    assert d.max() < 1e-3
    # released to slide, the points leave their projected targets
    assert np.abs(x - p.bc.target_positions).max() > 0.01


def test_mass_tensor_plan_matches_the_direct_linear_solve_with_the_same_bcs(plan):
    """The seed's 'exact FEM solution': the same linear system solved directly (scipy)."""
    import scipy.sparse.linalg as spla

    from tissue_reference.solvers.mass_tensor import MassTensorModel

    model = MassTensorModel(plan.tissue.points, plan.tissue.cells,
                            material=plan.settings.material)
    K = model.matrix().tocsr()
    dofs, vals = plan.dirichlet()
    n = 3 * plan.tissue.n_vertices
    free = np.setdiff1d(np.arange(n), dofs)
    u = np.zeros(n)
    u[dofs] = vals
    u[free] = spla.spsolve(K[free][:, free].tocsc(), -K[free][:, dofs] @ vals)
    u = u.reshape(-1, 3)
    skin_t = plan.skin_triangles
    st = surface_distances(plan.predicted_points, plan.tissue.points + u, skin_t,
                           region=plan.breast_region())
    assert st.mean_distance_mm <= 0.5 and st.d_max_mm <= 1.0


def test_plan_reports_the_muscle_thickness_error_on_synthetic_input(plan):
    e = plan.muscle_thickness_error_mm()
    assert e is not None and 0.0 <= e < 5.0


# ------------------------------------------------------------------ bad input, files, CLI
def test_disconnected_skin_file_is_rejected_before_any_solve(tmp_path):
    import meshio

    s = SyntheticTorso().skin()
    pts = np.vstack([s.points, s.points + [0, 0, 500.0]])
    tri = np.vstack([s.triangles, s.triangles + len(s.points)])
    f = tmp_path / "two.stl"
    meshio.write(str(f), meshio.Mesh(pts, [("triangle", tri)]))
    with pytest.raises(CaseError, match="not a single connected sheet"):
        patient_from_file(f, 16.0, 12.0, 16.0)


def test_user_skin_file_plans_like_the_synthetic_one(tmp_path):
    import meshio

    torso = SyntheticTorso()
    s = torso.skin()
    f = tmp_path / "skin.ply"
    meshio.write(str(f), meshio.Mesh(s.points, [("triangle", s.triangles)]))
    t = torso.thickness_estimates()
    p = patient_from_file(f, t.A, t.B, t.C, x_planes=(t.x_A, t.x_B, t.x_C))
    pl = plan_implant(p, PlanSettings(volume_cc=245.0, side="left"))
    assert pl.converged and pl.muscle_thickness_error_mm() is None
    assert len(pl.bc.target) >= 20


def _cli(argv):
    from tissue_reference.tissue.cli import main

    return main(argv)


def test_cli_rejects_a_negative_thickness_with_exit_code_2(tmp_path, capsys):
    import meshio

    s = SyntheticTorso().skin()
    f = tmp_path / "skin.stl"
    meshio.write(str(f), meshio.Mesh(s.points, [("triangle", s.triangles)]))
    rc = _cli(["implant", "--skin", str(f), "--thickness", "-3", "12", "16",
               "--json", str(tmp_path / "o.json")])
    assert rc == 2
    assert "thickness estimate A=-3.0" in capsys.readouterr().err
    assert not (tmp_path / "o.json").exists()


def test_cli_synthetic_mass_tensor_matches_the_linear_reference(tmp_path):
    """Seed 001's check against the exact FEM: skin mean distance <= 0.5 mm, max <= 1 mm."""
    pytest.importorskip("dolfinx")
    out = tmp_path / "r.json"
    rc = _cli(["implant", "--synthetic", "--volume", "245", "--shape", "round", "--side", "left",
               "--json", str(out), "--out", str(tmp_path / "o")])
    assert rc == 0
    r = json.loads(out.read_text())
    assert {"implant_volume_cc", "d_max_mm", "mean_distance_mm", "solver", "iterations",
            "wall_time_s", "muscle_thickness_error_mm"} <= set(r)
    assert r["solver"] == "mass-tensor" and r["implant_volume_cc"] == 245.0
    assert r["mean_distance_mm"] <= 0.5 and r["d_max_mm"] <= 1.0
    assert r["muscle_thickness_error_mm"] < 5.0
    for name in ("tissue.vtu", "skin_distance.vtu", "skin_distance.png"):
        assert (tmp_path / "o" / name).stat().st_size > 0
