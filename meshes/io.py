"""Mesh I/O: gmsh ``.msh`` with named physical groups in; XDMF / VTU / ``.msh`` out. The readers
are here; the writers (``meshes.writers``) and the output-file helpers (``meshes.files``:
``atomic_path``, ``check_output_file``, ...) are re-exported, so that one module serves both
directions.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from tissue_reference.errors import ReadError

from .curved import from_high_order_cells, validate
from .files import (
    atomic_path,
    check_output_dir,
    check_output_file,
    save_figure,
    user_cache_root,
)
from .mesh import MeshData, check_tangles
from .writers import (
    MESHIO_CELL,
    MESHIO_FACET,
    REGION,
    WRITERS,
    region_tags,
    write_mesh,
    write_point_data,
)

__all__ = [
    "REGION",
    "WRITERS",
    "atomic_path",
    "check_output_dir",
    "check_output_file",
    "read_mesh",
    "read_msh",
    "region_tags",
    "save_figure",
    "user_cache_root",
    "write_mesh",
    "write_point_data",
]



_NO_VOLUME = ("add a Physical Volume (a Physical Surface for a 2D body) holding the body's "
              "cells: gmsh saves only the elements of physical groups when any is defined "
              "(.geo: Physical Volume(\"tissue\") = {1}; Python: gmsh.model.addPhysicalGroup(3, "
              "[1]) and setPhysicalName; or save everything with Mesh.SaveAll = 1)")


def read_msh(path, *, overlap_check: bool = True) -> MeshData:
    """Read a gmsh ``.msh`` (2.2 or 4.1) with named physical groups.

    The highest-dimensional simplices (tetra, else triangle) form the mesh; physical groups of
    dimension d-1 become facet regions, of dimension 0 point regions, of dimension d cell regions.
    Unused nodes are dropped. The cells are checked as they are in the file, before any
    re-orientation (``meshes.mesh.check_tangles``): a tangled, inverted or degenerate mesh raises
    MeshQualityError with the count and the worst cell; a body ordered left-handed throughout is
    re-oriented. overlap_check=False skips the vertex-in-cell overlap search (the builders' own
    gmsh output).
    """
    import meshio

    path = Path(path)
    if not path.is_file():
        raise ReadError(f"mesh file {str(path)!r} does not exist")
    try:
        m = meshio.read(str(path), file_format="gmsh")
    except (Exception, SystemExit) as exc:  # noqa: BLE001 (meshio raises many, even SystemExit)
        raise ReadError(f"cannot read mesh file {str(path)!r} as gmsh .msh: {exc}") from None
    blocks = [(c.type, c.data) for c in m.cells]
    # second-order meshes (gmsh order 2): corners form the linear mesh, the mid-edge nodes its
    # curved geometry (meshes.curved)
    high = {"tetra10": ("tetra", 4), "triangle6": ("triangle", 3), "line3": ("line", 2)}
    high_order = [(high[t][0], d) for t, d in blocks if t in ("tetra10", "triangle6")]
    blocks = [(high[t][0], d[:, :high[t][1]]) if t in high else (t, d) for t, d in blocks]
    types = {t for t, _ in blocks}
    if "tetra" in types:
        dim = 3
    elif "triangle" in types:
        dim = 2
    else:
        raise ReadError(f"{str(path)!r} holds no tetrahedra or triangles (found {sorted(types)})"
                        f": {_NO_VOLUME}")
    phys = m.cell_data.get("gmsh:physical")
    names = {}  # (dim, tag) -> name
    for name, (tag, d) in (m.field_data or {}).items():
        names[(int(d), int(tag))] = name

    def tagged(ctype):
        out = []
        for i, (t, data) in enumerate(blocks):
            if t == ctype:
                tags = phys[i] if phys is not None else np.zeros(len(data), int)
                out.append((data, np.asarray(tags)))
        return out

    cell_blocks = tagged(MESHIO_CELL[dim])
    cells = np.concatenate([d for d, _ in cell_blocks]).astype(np.int64)
    cell_tags = np.concatenate([t for _, t in cell_blocks])
    pts = np.asarray(m.points, dtype=np.float64)
    if dim == 2:
        if pts.shape[1] == 3 and np.ptp(pts[:, 2]) > 1e-12 * max(np.ptp(pts), 1.0):
            raise ReadError(f"{str(path)!r}: {_NO_VOLUME} (it holds surface triangles in 3D but "
                            f"no tetrahedra)")
        pts = pts[:, :2]
    curved = {}
    ho = [d for t, d in high_order if t == MESHIO_CELL[dim]]
    if ho:
        try:
            _, edges, xe = from_high_order_cells(pts, np.concatenate(ho).astype(np.int64), dim)
        except ValueError as exc:
            raise ReadError(f"{str(path)!r}: {exc}") from None
    used = np.unique(cells)
    remap = -np.ones(len(pts), dtype=np.int64)
    remap[used] = np.arange(len(used))
    if ho:
        curved = {"curved_edges": remap[edges], "curved_points": xe}
    pts = pts[used]
    cells = check_tangles(pts, remap[cells], source=str(path), overlap=overlap_check)

    def name_of(d, tag):
        return names.get((d, int(tag)), f"{d}d-{int(tag)}")

    cell_regions = {}
    if phys is not None:
        for tag in np.unique(cell_tags):
            cell_regions[name_of(dim, tag)] = np.flatnonzero(cell_tags == tag)
    facet_regions = {}
    for data, tags in tagged(MESHIO_FACET[dim]):
        for tag in np.unique(tags):
            f = remap[data[tags == tag]]
            if np.any(f < 0):
                raise ReadError(f"{str(path)!r}: facet group {name_of(dim - 1, tag)!r} uses nodes "
                                "that belong to no cell")
            key = name_of(dim - 1, tag)
            facet_regions[key] = np.concatenate([facet_regions[key], f]) if key in facet_regions else f
    point_regions = {}
    for data, tags in tagged("vertex"):
        for tag in np.unique(tags):
            v = remap[data[tags == tag].ravel()]
            if np.any(v < 0):
                raise ReadError(f"{str(path)!r}: point group {name_of(0, tag)!r} is not a mesh vertex")
            point_regions[name_of(0, tag)] = v
    mesh = MeshData(pts, cells, facet_regions, point_regions, cell_regions, **curved)
    if curved:
        mesh, _ = validate(mesh)
    return mesh


READERS = {".msh": read_msh}


def read_mesh(path) -> MeshData:
    """Read a mesh file by suffix (see ``READERS``)."""
    suffix = Path(path).suffix.lower()
    if suffix not in READERS:
        raise ReadError(f"{str(path)!r}: unsupported mesh format {suffix!r}; "
                        f"supported: {sorted(READERS)}")
    return READERS[suffix](path)


