"""The Case and mesh layer: builders, regions, I/O round trips, and bad input named clearly."""
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tissue_reference.errors import CaseError, ConvergenceError, MeshQualityError, ReadError
from tissue_reference.meshes.builders import box, phantom
from tissue_reference.meshes.io import read_msh, write_mesh
from tissue_reference.meshes.mesh import MeshData
from tissue_reference.model.case import Boundary, Case, Material, load_case

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def ph():
    return phantom(12.0)


def test_phantom_has_named_regions_and_targets_are_vertices(ph):
    for r in ("base", "skin", "act_px", "act_py", "act_nx", "act_ny"):
        assert len(ph.facet_regions[r]) > 0
    for k, xyz in {"T1": (0, 0, 15), "T2": (12, 0, 15), "T4": (-12, 0, 15)}.items():
        np.testing.assert_allclose(ph.points[ph.point_regions[k][0]], xyz, atol=1e-9)
    assert np.all(np.abs(ph.points[ph.region_vertices("base")][:, 2]) < 1e-9)
    # actuator patches are about 10 mm across, centred at the actuator height
    p = ph.points[ph.region_vertices("act_px")]
    assert np.ptp(p[:, 1]) <= 10.0 + 1e-6 and abs(p[:, 2].mean() - 15.0) < 2.0


def test_msh_round_trip_keeps_regions(ph, tmp_path):
    write_mesh(ph, tmp_path / "p.msh")
    back = read_msh(tmp_path / "p.msh")
    np.testing.assert_allclose(back.points, ph.points)
    assert {k: len(v) for k, v in back.facet_regions.items()} == \
        {k: len(v) for k, v in ph.facet_regions.items()}
    assert set(back.point_regions) == set(ph.point_regions)


def test_case_file_with_mesh_file_relative_to_case(tmp_path):
    box(5.0, out=tmp_path / "part.msh")
    (tmp_path / "c.toml").write_text(
        '[mesh]\nfile = "part.msh"\n[material]\nE = 3.0\nnu = 0.3\n'
        '[[boundary]]\nregion = "zmin"\ntype = "fixed"\n'
        '[[probe]]\nname = "P"\npoint = [5.0, 5.0, 10.000005]\n')
    case = load_case(tmp_path / "c.toml")
    assert case.material.E == 3.0
    loc = case.probe_locations[0]
    # a point just outside the mesh (within 1e-6 of its diagonal) snaps to the nearest cell
    assert loc.snap_distance == pytest.approx(5e-6, abs=1e-7)


def test_shipped_cases_load():
    for name in ("phantom", "phantom-3"):
        c = load_case(ROOT / "meshes/cases" / f"{name}.toml", size=14)
        assert len(c.probes) == 5 and len(c.actuators) == (4 if name == "phantom" else 3)


@pytest.mark.parametrize("kw,msg", [
    ({"E": 0.0}, "E must be > 0"),
    ({"E": -1.0}, "E must be > 0"),
    ({"nu": 0.51}, "nu must lie in"),
    ({"nu": -1.2}, "nu must lie in"),
    ({"model": "mooney"}, "unknown material model"),
])
def test_bad_material_is_named(kw, msg):
    with pytest.raises(CaseError, match=msg):
        Material(**kw)


def test_unknown_region_lists_existing_ones():
    m = box(5.0)
    with pytest.raises(CaseError, match=r"unknown region 'bottom'.*xmin"):
        Case(mesh=m, boundaries=[Boundary("bottom", "fixed")])


def test_unknown_boundary_type_is_named():
    with pytest.raises(CaseError, match="unknown type 'glued'"):
        Boundary("zmin", "glued")


def test_missing_mesh_file_is_named(tmp_path):
    (tmp_path / "c.toml").write_text('[mesh]\nfile = "nowhere.msh"\n')
    with pytest.raises(ReadError, match="nowhere.msh"):
        load_case(tmp_path / "c.toml")


def test_unreadable_mesh_file_is_named(tmp_path):
    (tmp_path / "bad.msh").write_text("this is not a mesh")
    with pytest.raises(ReadError, match="bad.msh"):
        read_msh(tmp_path / "bad.msh")


def test_inverted_cells_are_counted_with_first_ids():
    m = box(5.0)
    cells = m.cells.copy()
    cells[[3, 7]] = cells[[3, 7]][:, [1, 0, 2, 3]]
    bad = MeshData(m.points, cells, m.facet_regions)
    with pytest.raises(MeshQualityError, match=r"2 inverted or zero-volume cells.*\[3, 7\]"):
        Case(mesh=bad, boundaries=[Boundary("zmin", "fixed")])


def test_rigid_body_freedom_is_reported_before_solving():
    m = box(5.0)
    with pytest.raises(CaseError, match="rigid-body mode"):
        Case(mesh=m, boundaries=[Boundary("zmin", "sliding", normal=[0, 0, 1])])


def test_conflicting_prescriptions_on_one_vertex_are_rejected():
    m = box(5.0)
    with pytest.raises(CaseError, match="conflicting prescriptions on vertex"):
        Case(mesh=m, boundaries=[Boundary("zmin", "fixed"),
                                 Boundary("xmin", "displacement", value=[1.0, 0, 0])])


def test_oblique_sliding_that_contradicts_a_fixed_edge_is_rejected_when_built():
    m = box(5.0)
    n = [1.0, 1.0, 0.0]
    # the edge shared by zmin (fixed) and the oblique sliding face xmin: u = 0 there, so u.n = 0
    ok = Case(mesh=m, boundaries=[Boundary("zmin", "fixed"),
                                  Boundary("xmin", "sliding", normal=n, value=0.0)])
    assert len(ok.constraints.sliding) == 1
    with pytest.raises(CaseError, match="conflicting prescriptions on vertex .* sliding region "
                                        "'xmin' sets u.n = 0.5 mm"):
        Case(mesh=m, boundaries=[Boundary("zmin", "fixed"),
                                 Boundary("xmin", "sliding", normal=n, value=0.5)])


def test_unknown_actuator_push_is_named():
    c = load_case(ROOT / "meshes/cases/phantom.toml", size=14)
    with pytest.raises(CaseError, match="unknown actuator 'A9'"):
        c.with_pushes({"A9": 1.0})


def test_the_same_pushes_give_the_same_case_and_other_pushes_another():
    c = load_case(ROOT / "meshes/cases/phantom.toml", size=14)
    a = c.with_pushes({"A1": 2.0, "A2": 1.0})
    assert c.with_pushes({"A2": 1, "A1": 2.0}) is a       # validated once, whatever the order
    b = c.with_pushes({"A1": 2.5, "A2": 1.0})
    assert b is not a and b.actuator("A1").push == 2.5 and a.actuator("A1").push == 2.0
    disp = {bc.region: bc.value for bc in b.boundaries if bc.type == "displacement"}
    assert disp[c.actuator("A1").region] == pytest.approx(
        tuple(2.5 * np.asarray(c.actuator("A1").direction)))


def test_diverging_load_step_keeps_last_converged_state(tmp_path):
    """A push that crushes the phantom fails after cut-backs; the CLI writes the last converged
    state and names the load fraction reached."""
    import tissue_reference.fem_reference as fr
    from tissue_reference.fem_reference.solver import NewtonSettings

    c = load_case(ROOT / "meshes/cases/phantom.toml", size=14)
    s = fr.ReferenceSolver(c, settings=NewtonSettings(max_iterations=8, min_fraction=1 / 16,
                                                       max_step_mm=40.0))
    with pytest.raises(ConvergenceError) as err:
        s.solve({"A1": 160.0, "A3": 160.0})
    e = err.value
    assert 0.0 <= e.load_fraction < 1.0
    assert "load fraction" in str(e)
    assert e.last_converged is not None and np.all(np.isfinite(e.last_converged.u))


def test_cli_reports_bad_case_without_traceback(tmp_path):
    (tmp_path / "c.toml").write_text('[mesh]\nbuiltin = "box"\nsize = 5.0\n'
                                     '[[boundary]]\nregion = "floor"\ntype = "fixed"\n')
    tissue = str(Path(sys.executable).with_name("tissue"))
    p = subprocess.run([tissue, "solve", str(tmp_path / "c.toml")], capture_output=True, text=True,
                       check=False)
    assert p.returncode == 2
    assert "unknown region 'floor'" in p.stderr and "Traceback" not in p.stderr


def test_written_files_get_the_umask_mode_not_the_private_temporary_mode(tmp_path):
    """Outputs are written to a temporary and renamed; the temporary's 0600 must not leak into
    the result (ParaView on another account could not open it)."""
    import os

    old = os.umask(0o022)
    try:
        out = tmp_path / "m.vtu"
        write_mesh(box(size=1.0, lengths=(1.0, 1.0, 1.0)), out)
    finally:
        os.umask(old)
    assert out.stat().st_mode & 0o777 == 0o644


BOX_CASE = ('[mesh]\nbuiltin = "box"\nsize = 5.0\n{reference}'
            '[[boundary]]\nregion = "zmin"\ntype = "fixed"\n'
            '[[boundary]]\nregion = "zmax"\ntype = "displacement"\nvalue = [0.0, 0.0, -0.5]\n'
            '[[probe]]\nname = "c"\npoint = [5.0, 5.0, 5.0]\n')


def test_the_case_names_the_reference_degree_a_solve_gets_by_default(tmp_path):
    import tissue_reference.fem_reference as fr

    (tmp_path / "p2.toml").write_text(BOX_CASE.format(reference="[reference]\ndegree = 2\n"))
    (tmp_path / "plain.toml").write_text(BOX_CASE.format(reference=""))
    p2, plain = load_case(tmp_path / "p2.toml"), load_case(tmp_path / "plain.toml")
    assert p2.reference_degree == 2 and plain.reference_degree is None
    assert fr.solve(p2).discretization["degree"] == 2
    assert fr.solve(plain).discretization["degree"] == 1
    assert fr.solve(p2, degree=1).discretization["degree"] == 1  # an explicit one wins


def test_a_bad_reference_degree_is_named(tmp_path):
    (tmp_path / "c.toml").write_text(BOX_CASE.format(reference="[reference]\ndegree = 4\n"))
    with pytest.raises(CaseError, match=r"c\.toml: \[reference\]\.degree"):
        load_case(tmp_path / "c.toml")
    with pytest.raises(CaseError, match="reference degree must be 1, 2 or 3"):
        Case(mesh=box(5.0), reference_degree=0,
             boundaries=[Boundary(region="zmin", type="fixed")])
