"""Mesh output: XDMF / VTU / ``.msh`` files that ParaView, pyvista and meshio open, with the
named regions kept (``write_mesh``).

An XDMF output is a time series of one step (pyvista's XDMF reader needs a time; meshio reads
it with ``meshio.xdmf.TimeSeriesReader``, and the VTU written beside field outputs with
``meshio.read``). Cells carry their region's integer tag as the cell field ``region``
(``region_tags`` is the numbering, the same as the ``.msh`` physical groups); the region names
are stored as field data, name -> [tag, dim].

Writers are registered by suffix in ``WRITERS``; each writes to a temporary file in the target
folder and renames it (``meshes.files.atomic_path``), so a file is written whole or not at all.
"""
from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from tissue_reference.errors import WriteError

from .curved import EDGES, FACET_EDGES, MESHIO_EDGES, p2_cells, p2_facets
from .files import atomic_path, os_reason
from .mesh import MeshData

__all__ = ["REGION", "WRITERS", "region_tags", "write_mesh", "write_point_data"]

REGION = "region"  # the integer cell field holding each cell's region tag
XDMF_TIME = 0.0  # the time of the one step an XDMF file holds
MESHIO_CELL = {3: "tetra", 2: "triangle"}  # meshio's names of the cells and facets by dimension
MESHIO_FACET = {3: "triangle", 2: "line"}


def region_tags(mesh: MeshData) -> list[tuple[str, int, int, np.ndarray]]:
    """The mesh's regions as (name, tag, dimension, members), numbered as every writer numbers
    them: cell regions 1, 2, ... (a mesh without any has one, "volume", of every cell), then
    facet regions, then point regions. Members: cell ids, facets ((k, gdim) vertex ids) or
    vertex ids."""
    d = mesh.gdim
    groups = [(d, mesh.cell_regions or {"volume": np.arange(mesh.n_cells)}),
              (d - 1, mesh.facet_regions), (0, mesh.point_regions)]
    out = []
    for dim, regions in groups:
        for name, members in regions.items():
            out.append((name, len(out) + 1, dim, np.asarray(members)))
    return out


def _cell_tags(mesh: MeshData, regions) -> np.ndarray:
    """Each cell's region tag (0 where it is in none; the last region listed wins)."""
    tags = np.zeros(mesh.n_cells, dtype=np.int32)
    for _, tag, dim, ids in regions:
        if dim == mesh.gdim:
            tags[ids.astype(np.int64)] = tag
    return tags


def _meshio_mesh(mesh: MeshData, point_data=None, cell_data=None, all_regions=False,
                 vertex_cells=True):
    """The meshio Mesh of ``mesh``: its cells with the cell data and the integer cell field
    ``region`` (the tags of ``region_tags``, whose names and dimensions are the field data:
    name -> [tag, dim]); with ``all_regions`` the facet regions follow as a block of triangles
    (lines in 2D) and (with ``vertex_cells``) the point regions as a block of vertices, tagged
    in ``region`` the same way (the other cell fields are NaN, or 0 for integer ones, there)."""
    import meshio

    pts = mesh.points if mesh.gdim == 3 else np.column_stack([mesh.points, np.zeros(mesh.n_vertices)])
    pd = {}
    for k, v in (point_data or {}).items():
        v = np.asarray(v, dtype=np.float64)
        if v.ndim == 2 and v.shape[1] == 2:
            v = np.column_stack([v, np.zeros(len(v))])
        pd[k] = v
    regions = region_tags(mesh)
    blocks = [(MESHIO_CELL[mesh.gdim], mesh.cells)]
    tags = [_cell_tags(mesh, regions)]
    if all_regions:
        facets = [(f.reshape(-1, mesh.gdim), tag) for _, tag, dim, f in regions
                  if dim == mesh.gdim - 1 and dim > 0]
        points = [(v.reshape(-1, 1), tag) for _, tag, dim, v in regions
                  if dim == 0 and vertex_cells]
        for ctype, group in ((MESHIO_FACET[mesh.gdim], facets), ("vertex", points)):
            if group:
                blocks.append((ctype, np.concatenate([c for c, _ in group]).astype(np.int64)))
                tags.append(np.concatenate([np.full(len(c), t, np.int32) for c, t in group]))
    cd = {}
    for k, v in (cell_data or {}).items():
        v = np.asarray(v)
        fill = np.nan if v.dtype.kind in "fc" else 0
        cd[k] = [v] + [np.full((len(b),) + v.shape[1:], fill, dtype=v.dtype if fill == 0
                               else np.result_type(v.dtype, np.float64)) for _, b in blocks[1:]]
    cd.setdefault(REGION, tags)
    field = {name: np.array([tag, dim], dtype=np.int32) for name, tag, dim, _ in regions}
    return meshio.Mesh(pts, blocks, point_data=pd, cell_data=cd, field_data=field)


def _vtu_field_data(field_data: dict) -> bytes:
    """The VTU ``<FieldData>`` element of name -> integer array (meshio's VTU writer leaves
    field data out; its reader, VTK and pyvista read it)."""
    from xml.sax.saxutils import quoteattr

    arrays = "".join(
        f'<DataArray type="Int32" Name={quoteattr(name)} NumberOfTuples="{len(v)}" '
        f'format="ascii">{" ".join(str(int(x)) for x in v)}</DataArray>\n'
        for name, v in field_data.items())
    return f"<FieldData>\n{arrays}</FieldData>\n".encode()


def _write_vtu(mesh, path, point_data=None, cell_data=None, all_regions=False):
    """VTU (ParaView, pyvista, meshio) with the region tags as the cell field ``region`` and
    their names as field data (name -> [tag, dim])."""
    import meshio

    m = _meshio_mesh(mesh, point_data, cell_data, all_regions)
    with atomic_path(path) as tmp:
        meshio.write(str(tmp), m, file_format="vtu")
        if m.field_data:
            text = tmp.read_bytes()
            at = text.find(b"<Piece")
            if at < 0:
                raise WriteError(f"cannot write {str(path)!r}: unexpected VTU layout")
            tmp.write_bytes(text[:at] + _vtu_field_data(m.field_data) + text[at:])


def _as_time_series(xdmf: Path, field_data: dict):
    """Rewrite the one-grid XDMF that meshio writes as a time series of one step at XDMF_TIME:
    a temporal collection holding that grid, with a ``Time`` and the region names
    (an ``Information`` in meshio's own form: name -> tag and dimension).

    This is the layout every XDMF reader around here agrees on: ParaView, pyvista (whose
    XdmfReader needs time values, and fails on a grid without any) and
    ``meshio.xdmf.TimeSeriesReader``; ``meshio.read`` reads only a lone grid without a time
    (the ``.vtu`` beside it is that for meshio.read)."""
    import xml.etree.ElementTree as ET

    tree = ET.parse(xdmf)
    domain = tree.getroot().find("Domain")
    grid = domain.find("Grid") if domain is not None else None
    if grid is None:
        raise WriteError(f"unexpected XDMF layout in {str(xdmf)!r}")
    domain.remove(grid)
    series = ET.SubElement(domain, "Grid", Name="TimeSeries", GridType="Collection",
                           CollectionType="Temporal")
    grid.set("Name", "mesh")
    grid.set("GridType", "Uniform")
    grid.insert(0, ET.Element("Time", Value=f"{XDMF_TIME:g}"))
    if field_data:
        info = ET.SubElement(grid, "Information", Name="Information",
                             Value=str(len(field_data)))
        main = ET.Element("main")
        for name, (tag, dim) in field_data.items():
            ET.SubElement(main, "map", key=name, dim=str(int(dim))).text = str(int(tag))
        info.text = ET.tostring(main, encoding="unicode")
    series.append(grid)
    tree.write(xdmf, encoding="utf-8", xml_declaration=True)


def _write_xdmf(mesh, path, point_data=None, cell_data=None, all_regions=False):
    """XDMF + HDF5 pair: a time series of one step (see ``_as_time_series``) with the region
    tags as the cell field ``region``. No vertex cells for the point regions (meshio reads
    XDMF vertex cells back wrong); their names are listed all the same. Both files are written
    to temporaries and then renamed."""
    import meshio

    path = Path(path)
    h5 = path.with_suffix(".h5")
    if path.is_dir() or h5.is_dir():
        raise WriteError(f"cannot write {str(path)!r}: it or its .h5 is a directory")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmpdir = Path(tempfile.mkdtemp(prefix=".xdmf-", dir=path.parent))
    except OSError as exc:
        raise WriteError(f"cannot write {str(path)!r}: {os_reason(exc)}") from None
    try:
        tmp_x = tmpdir / path.name
        m = _meshio_mesh(mesh, point_data, cell_data, all_regions, vertex_cells=False)
        meshio.write(str(tmp_x), m, file_format="xdmf")
        _as_time_series(tmp_x, m.field_data)
        os.replace(tmp_x.with_suffix(".h5"), h5)
        os.replace(tmp_x, path)
    except Exception as exc:  # noqa: BLE001 (any writer failure is a WriteError naming the file)
        raise WriteError(f"cannot write {str(path)!r}: {exc}") from None
    finally:
        shutil.rmtree(tmpdir, ignore_errors=True)


def _second_order(mesh):
    """(nodes, cells, facets_of): a curved mesh's nodes (vertices first) and cells in meshio's
    second-order node order (tetra10 / triangle6), and a function giving a facet region's
    second-order facets (triangle6 / line3)."""
    d = mesh.gdim
    x, cells, edges = p2_cells(mesh)
    order = [d + 1 + EDGES[d].index(e) for e in MESHIO_EDGES[d]]
    cells = cells[:, list(range(d + 1)) + order]
    if d == 3:  # triangle6: its mid-edge nodes in meshio's order of a triangle's edges
        f_order = [0, 1, 2] + [3 + FACET_EDGES[3].index(e) for e in MESHIO_EDGES[2]]
    else:
        f_order = [0, 1, 2]
    return x, cells, lambda facets: p2_facets(mesh, facets, edges)[:, f_order]


def _write_msh(mesh, path, point_data=None, cell_data=None, all_regions=True):
    """gmsh 2.2 ASCII with the named regions as physical groups (tags of ``region_tags``); a
    curved mesh (``geometry_order`` 2) as second-order cells and facets, which ``read_msh``
    reads back curved."""
    import meshio

    d = mesh.gdim
    pts, cells, facets_of = mesh.points, mesh.cells, (lambda f: f)
    types = (MESHIO_CELL[d], MESHIO_FACET[d])
    if mesh.geometry_order == 2:
        pts, cells, facets_of = _second_order(mesh)
        types = ({3: "tetra10", 2: "triangle6"}[d], {3: "triangle6", 2: "line3"}[d])
    blocks, phys, field = [], [], {}
    for name, tag, dim, members in region_tags(mesh):
        if dim == d:
            blocks.append((types[0], cells[members]))
        elif dim == 0:
            blocks.append(("vertex", members.reshape(-1, 1)))
        else:
            blocks.append((types[1], facets_of(members)))
        phys.append(np.full(len(members), tag))
        field[name] = np.array([tag, dim])
    if d == 2:
        pts = np.column_stack([pts, np.zeros(len(pts))])
    m = meshio.Mesh(pts, blocks, cell_data={"gmsh:physical": phys, "gmsh:geometrical": phys},
                    field_data=field)
    with atomic_path(path) as tmp:
        meshio.write(str(tmp), m, file_format="gmsh22", binary=False)


WRITERS = {".vtu": _write_vtu, ".xdmf": _write_xdmf, ".msh": _write_msh}


def write_mesh(mesh: MeshData, path, *, point_data=None, cell_data=None,
               all_regions: bool = False) -> Path:
    """Write a mesh (and optional point / cell fields) by suffix: .vtu, .xdmf (+ .h5), .msh.

    Every format keeps the regions: .msh as named physical groups; .vtu and .xdmf as the integer
    cell field ``region`` with the names as field data (name -> [tag, dim], see
    ``region_tags``), and with ``all_regions`` the facet and point regions too, as blocks of
    facets and vertices after the cells (a mesh file; field outputs keep to the cells; XDMF
    holds no vertex cells)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in WRITERS:
        raise WriteError(f"{str(path)!r}: unsupported output format {suffix!r}; "
                         f"supported: {sorted(WRITERS)}")
    try:
        WRITERS[suffix](mesh, path, point_data, cell_data, all_regions)
    except WriteError:
        raise
    except Exception as exc:
        raise WriteError(f"cannot write {str(path)!r}: {exc}") from exc
    return path


def write_point_data(mesh: MeshData, out_dir, stem: str, point_data: dict,
                     cell_data: dict | None = None) -> list[Path]:
    """Write ``stem.xdmf`` and ``stem.vtu`` with the given vertex (and cell) fields and the
    cell regions (``region``): both open in ParaView and pyvista; ``meshio.read`` reads the
    .vtu, ``meshio.xdmf.TimeSeriesReader`` the .xdmf."""
    out_dir = Path(out_dir)
    return [write_mesh(mesh, out_dir / f"{stem}{s}", point_data=point_data, cell_data=cell_data)
            for s in (".xdmf", ".vtu")]
