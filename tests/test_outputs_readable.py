"""Every file the toolkit writes opens in the usual readers: pyvista (what ParaView's VTK
readers see) and meshio (``meshio.read``; ``meshio.xdmf.TimeSeriesReader`` for XDMF, which is
written as a time series of one step), and keeps the named regions: the integer cell field
``region`` with the names as field data (name -> [tag, dim]) in .vtu, gmsh physical groups in
.msh."""
from pathlib import Path

import meshio
import numpy as np
import pytest
import pyvista
from test_cli_fuzz import BOX as CLI_BOX  # the small box case of the CLI tests

from tissue_reference.meshes.builders import build
from tissue_reference.meshes.writers import (
    REGION,
    XDMF_TIME,
    region_tags,
    write_mesh,
    write_point_data,
)
from tissue_reference.tissue.cli import main
from tissue_reference.verification.scoring import load_field

BOX = CLI_BOX.format(model="linear-elastic")


@pytest.fixture(scope="module")
def meshes_():
    return {"box": build("box", 5.0), "rectangle": build("rectangle", 5.0)}


def read_xdmf_series(path):
    """(points, cells, [(t, point_data, cell_data)]) through meshio's TimeSeriesReader."""
    with meshio.xdmf.TimeSeriesReader(str(path)) as r:
        points, cells = r.read_points_cells()
        steps = [r.read_data(k) for k in range(r.num_steps)]
    return points, cells, steps


def expected_tags(mesh, blocks):
    """The region tags the writers give the cells, then (for the blocks asked for) the facets
    and the points, in order."""
    regions = region_tags(mesh)
    cells = np.zeros(mesh.n_cells, int)
    for _, tag, dim, ids in regions:
        if dim == mesh.gdim:
            cells[ids] = tag
    out = [cells]
    for want in blocks:
        out.append(np.concatenate([np.full(len(m), tag) for _, tag, dim, m in regions
                                   if dim == want]))
    return out


# --------------------------------------------------------------------------- write_mesh
@pytest.mark.parametrize("name", ["box", "rectangle"])
@pytest.mark.parametrize("all_regions", [False, True])
def test_vtu_keeps_the_regions_for_meshio_and_pyvista(meshes_, tmp_path, name, all_regions):
    mesh = meshes_[name]
    p = write_mesh(mesh, tmp_path / "m.vtu", all_regions=all_regions)
    extra = [d for d in (mesh.gdim - 1, 0) if all_regions and any(
        dim == d for _, _, dim, _ in region_tags(mesh))]
    want = expected_tags(mesh, extra)
    m = meshio.read(p)
    assert m.cells[0].type == ("tetra" if mesh.gdim == 3 else "triangle")
    assert len(m.cells) == 1 + len(extra)
    for got, exp in zip(m.cell_data[REGION], want):
        np.testing.assert_array_equal(got, exp)
    names = {n: [t, d] for n, t, d, _ in region_tags(mesh)}
    assert {k: v.tolist() for k, v in m.field_data.items()} == names
    assert set(names) >= set(mesh.region_names)
    g = pyvista.read(p)
    assert isinstance(g, pyvista.UnstructuredGrid) and g.n_points == mesh.n_vertices
    np.testing.assert_array_equal(g.cell_data[REGION], np.concatenate(want))
    assert {k: list(g.field_data[k]) for k in g.field_data} == names


@pytest.mark.parametrize("name", ["box", "rectangle"])
@pytest.mark.parametrize("all_regions", [False, True])
def test_xdmf_is_a_one_step_time_series_pyvista_and_meshio_read(meshes_, tmp_path, name,
                                                                  all_regions):
    mesh = meshes_[name]
    p = write_mesh(mesh, tmp_path / "m.xdmf", all_regions=all_regions)
    assert (tmp_path / "m.h5").is_file()
    facets = [mesh.gdim - 1] if all_regions else []   # XDMF holds no vertex cells
    want = expected_tags(mesh, facets)
    points, cells, steps = read_xdmf_series(p)
    assert len(steps) == 1 and steps[0][0] == XDMF_TIME
    np.testing.assert_allclose(points[:, :mesh.gdim], mesh.points)
    np.testing.assert_array_equal(cells[0].data, mesh.cells)
    for got, exp in zip(steps[0][2][REGION], want):
        np.testing.assert_array_equal(got, exp)
    g = pyvista.read(p)
    assert isinstance(g, pyvista.UnstructuredGrid)
    assert g.n_points == mesh.n_vertices and g.n_cells == sum(len(w) for w in want)
    np.testing.assert_array_equal(g.cell_data[REGION], np.concatenate(want))


def test_msh_written_by_meshes_io_keeps_the_groups_for_meshio_and_pyvista(meshes_, tmp_path):
    mesh = meshes_["box"]
    p = write_mesh(mesh, tmp_path / "m.msh")
    m = meshio.read(p)
    names = {n: [t, d] for n, t, d, _ in region_tags(mesh)}
    assert {k: v.tolist() for k, v in m.field_data.items()} == names
    g = pyvista.read(p)
    assert g.n_points == mesh.n_vertices
    assert g.n_cells == sum(len(c) for c in m.cells)


# --------------------------------------------------------------------------- tissue mesh
@pytest.mark.parametrize("builder, size, suffix", [
    ("box", 5.0, ".vtu"), ("box", 5.0, ".xdmf"), ("box", 5.0, ".msh"),
    ("phantom", 14.0, ".vtu"), ("phantom", 14.0, ".msh"),   # second order (curved) in .msh
])
def test_tissue_mesh_output_keeps_every_region(tmp_path, capsys, builder, size, suffix):
    out = tmp_path / f"{builder}{suffix}"
    assert main(["mesh", builder, "--size", str(size), "-o", str(out)]) == 0
    capsys.readouterr()
    mesh = build(builder, size)
    facet_names = set(mesh.facet_regions)
    if suffix == ".xdmf":
        _, cells, steps = read_xdmf_series(out)
        assert [c.type for c in cells] == ["tetra", "triangle"]
        tags = steps[0][2][REGION]
        assert len(np.unique(tags[1])) == len(facet_names)
    else:
        m = meshio.read(out)
        assert {c.type for c in m.cells} & {"tetra", "tetra10"}
        assert {c.type for c in m.cells} & {"triangle", "triangle6"}
        assert facet_names | set(mesh.cell_regions) <= set(m.field_data)
        if suffix == ".vtu":
            assert m.cell_data[REGION][0].min() >= 1
    g = pyvista.read(out)   # a kept .msh is gmsh 2.2, which pyvista opens through meshio
    if suffix == ".msh":    # a curved body's file holds its mid-edge nodes too
        assert g.n_points == len(m.points) >= mesh.n_vertices
    else:
        assert g.n_points == mesh.n_vertices
    assert (REGION if suffix != ".msh" else "gmsh:physical") in g.cell_data


# --------------------------------------------------------------------------- tissue solve
def test_solve_outputs_open_in_pyvista_and_meshio_with_the_same_fields(tmp_path, capsys):
    (tmp_path / "box.toml").write_text(BOX)
    out = tmp_path / "out"
    assert main(["solve", str(tmp_path / "box.toml"), "--solver", "mass-tensor", "--push",
                 "A1=1", "-q", "--out", str(out)]) == 0
    capsys.readouterr()
    vtu, xdmf = out / "displacement.vtu", out / "displacement.xdmf"
    m = meshio.read(vtu)
    u = m.point_data["displacement"]
    assert np.abs(u).max() > 0.1
    assert {"J", "inverted", REGION} <= set(m.cell_data) and "tissue" in m.field_data
    _, _, steps = read_xdmf_series(xdmf)
    np.testing.assert_array_equal(steps[-1][1]["displacement"], u)
    assert {"J", "inverted", REGION} <= set(steps[-1][2])
    for path in (vtu, xdmf):
        g = pyvista.read(path)
        assert isinstance(g, pyvista.UnstructuredGrid)
        np.testing.assert_array_equal(g.point_data["displacement"], u)
        np.testing.assert_array_equal(g.cell_data["J"], m.cell_data["J"][0])
        np.testing.assert_array_equal(g.cell_data[REGION], m.cell_data[REGION][0])
        # the field reader of `tissue verify --field` reads both
        np.testing.assert_array_equal(load_field(path, 3).u, u)


def test_write_point_data_2d_pads_vectors_for_the_readers(meshes_, tmp_path):
    mesh = meshes_["rectangle"]
    u = np.column_stack([mesh.points[:, 0] * 0.01, np.zeros(mesh.n_vertices)])
    paths = write_point_data(mesh, tmp_path, "u", {"displacement": u},
                             cell_data={"J": np.ones(mesh.n_cells)})
    assert [Path(p).suffix for p in paths] == [".xdmf", ".vtu"]
    for p in paths:
        g = pyvista.read(p)
        assert g.point_data["displacement"].shape == (mesh.n_vertices, 3)
        np.testing.assert_allclose(g.point_data["displacement"][:, :2], u)
        assert (g.cell_data["J"] == 1).all() and (g.cell_data[REGION] == 1).all()
