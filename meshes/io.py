"""Mesh I/O: gmsh ``.msh`` with named physical groups in, XDMF / VTU / ``.msh`` out.

Writers are registered by suffix in ``WRITERS``; every writer writes to a temporary file in the
target folder and renames it, so a file is written whole or not at all.
"""
from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from .errors import ReadError, WriteError
from .mesh import MeshData, orient_cells

__all__ = ["WRITERS", "atomic_path", "read_mesh", "read_msh", "write_mesh", "write_point_data"]

_CELL = {3: "tetra", 2: "triangle"}
_FACET = {3: "triangle", 2: "line"}


def read_msh(path) -> MeshData:
    """Read a gmsh ``.msh`` (2.2 or 4.1) with named physical groups.

    The highest-dimensional simplices (tetra, else triangle) form the mesh; physical groups of
    dimension d-1 become facet regions, of dimension 0 point regions, of dimension d cell regions.
    Unused nodes are dropped and cells oriented positively.
    """
    import meshio

    path = Path(path)
    if not path.is_file():
        raise ReadError(f"mesh file {str(path)!r} does not exist")
    try:
        m = meshio.read(str(path), file_format="gmsh")
    except (Exception, SystemExit) as exc:  # meshio raises many types, even SystemExit
        raise ReadError(f"cannot read mesh file {str(path)!r} as gmsh .msh: {exc}") from None
    blocks = [(c.type, c.data) for c in m.cells]
    types = {t for t, _ in blocks}
    if "tetra" in types:
        dim = 3
    elif "triangle" in types:
        dim = 2
    else:
        raise ReadError(f"{str(path)!r} holds no tetrahedra or triangles (found {sorted(types)})")
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

    cell_blocks = tagged(_CELL[dim])
    cells = np.concatenate([d for d, _ in cell_blocks]).astype(np.int64)
    cell_tags = np.concatenate([t for _, t in cell_blocks])
    pts = np.asarray(m.points, dtype=np.float64)
    if dim == 2:
        if pts.shape[1] == 3 and np.ptp(pts[:, 2]) > 1e-12 * max(np.ptp(pts), 1.0):
            raise ReadError(f"{str(path)!r}: triangles only but the mesh is not planar (z varies)")
        pts = pts[:, :2]
    used = np.unique(cells)
    remap = -np.ones(len(pts), dtype=np.int64)
    remap[used] = np.arange(len(used))
    pts = pts[used]
    cells = orient_cells(pts, remap[cells])

    def name_of(d, tag):
        return names.get((d, int(tag)), f"{d}d-{int(tag)}")

    cell_regions = {}
    if phys is not None:
        for tag in np.unique(cell_tags):
            cell_regions[name_of(dim, tag)] = np.flatnonzero(cell_tags == tag)
    facet_regions = {}
    for data, tags in tagged(_FACET[dim]):
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
    return MeshData(pts, cells, facet_regions, point_regions, cell_regions)


READERS = {".msh": read_msh}


def read_mesh(path) -> MeshData:
    """Read a mesh file by suffix (see ``READERS``)."""
    suffix = Path(path).suffix.lower()
    if suffix not in READERS:
        raise ReadError(f"{str(path)!r}: unsupported mesh format {suffix!r}; "
                        f"supported: {sorted(READERS)}")
    return READERS[suffix](path)


class atomic_path:
    """Context manager yielding a temporary path beside ``path``, renamed onto it on success."""

    def __init__(self, path, suffix=None):
        self.path = Path(path)
        self.suffix = suffix if suffix is not None else self.path.suffix

    def __enter__(self):
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=f".{self.path.stem}.", suffix=self.suffix,
                                       dir=self.path.parent)
        except OSError as exc:
            raise WriteError(f"cannot write {str(self.path)!r}: {exc}") from exc
        os.close(fd)
        self.tmp = Path(tmp)
        return self.tmp

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            # mkstemp makes the file 0600; give it the mode a plain open() would (umask applied)
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(self.tmp, 0o666 & ~umask)
            os.replace(self.tmp, self.path)
        else:
            self.tmp.unlink(missing_ok=True)
        return False


def _meshio_mesh(mesh: MeshData, point_data=None, cell_data=None):
    import meshio

    pts = mesh.points if mesh.gdim == 3 else np.column_stack([mesh.points, np.zeros(mesh.n_vertices)])
    pd = {}
    for k, v in (point_data or {}).items():
        v = np.asarray(v, dtype=np.float64)
        if v.ndim == 2 and v.shape[1] == 2:
            v = np.column_stack([v, np.zeros(len(v))])
        pd[k] = v
    cd = {k: [np.asarray(v)] for k, v in (cell_data or {}).items()}
    return meshio.Mesh(pts, [(_CELL[mesh.gdim], mesh.cells)], point_data=pd, cell_data=cd)


def _write_vtu(mesh, path, point_data=None, cell_data=None):
    import meshio

    with atomic_path(path) as tmp:
        meshio.write(str(tmp), _meshio_mesh(mesh, point_data, cell_data), file_format="vtu")


def _write_xdmf(mesh, path, point_data=None, cell_data=None):
    """XDMF + HDF5 pair (ParaView). Both files are written to temporaries and then renamed."""
    import meshio

    path = Path(path)
    h5 = path.with_suffix(".h5")
    tmpdir = Path(tempfile.mkdtemp(prefix=".xdmf-", dir=path.parent if path.parent.exists() else None))
    try:
        tmp_x = tmpdir / path.name
        meshio.write(str(tmp_x), _meshio_mesh(mesh, point_data, cell_data), file_format="xdmf")
        path.parent.mkdir(parents=True, exist_ok=True)
        os.replace(tmp_x.with_suffix(".h5"), h5)
        os.replace(tmp_x, path)
    except Exception as exc:
        raise WriteError(f"cannot write {str(path)!r}: {exc}") from exc
    finally:
        for f in tmpdir.glob("*"):
            f.unlink()
        tmpdir.rmdir()


def _write_msh(mesh, path, point_data=None, cell_data=None):
    """gmsh 2.2 ASCII with the named regions as physical groups."""
    import meshio

    d = mesh.gdim
    blocks, phys, field = [], [], {}
    tag = 1
    regions = mesh.cell_regions or {"volume": np.arange(mesh.n_cells)}
    for name, ids in regions.items():
        blocks.append((_CELL[d], mesh.cells[ids]))
        phys.append(np.full(len(ids), tag))
        field[name] = np.array([tag, d])
        tag += 1
    for name, f in mesh.facet_regions.items():
        blocks.append((_FACET[d], f))
        phys.append(np.full(len(f), tag))
        field[name] = np.array([tag, d - 1])
        tag += 1
    for name, v in mesh.point_regions.items():
        blocks.append(("vertex", np.asarray(v).reshape(-1, 1)))
        phys.append(np.full(len(v), tag))
        field[name] = np.array([tag, 0])
        tag += 1
    pts = mesh.points if d == 3 else np.column_stack([mesh.points, np.zeros(mesh.n_vertices)])
    m = meshio.Mesh(pts, blocks, cell_data={"gmsh:physical": phys, "gmsh:geometrical": phys},
                    field_data=field)
    with atomic_path(path) as tmp:
        meshio.write(str(tmp), m, file_format="gmsh22", binary=False)


WRITERS = {".vtu": _write_vtu, ".xdmf": _write_xdmf, ".msh": _write_msh}


def write_mesh(mesh: MeshData, path, *, point_data=None, cell_data=None) -> Path:
    """Write a mesh (and optional point / cell fields) by suffix: .vtu, .xdmf (+ .h5), .msh."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in WRITERS:
        raise WriteError(f"{str(path)!r}: unsupported output format {suffix!r}; "
                         f"supported: {sorted(WRITERS)}")
    try:
        WRITERS[suffix](mesh, path, point_data, cell_data)
    except WriteError:
        raise
    except Exception as exc:
        raise WriteError(f"cannot write {str(path)!r}: {exc}") from exc
    return path


def write_point_data(mesh: MeshData, out_dir, stem: str, point_data: dict) -> list[Path]:
    """Write ``stem.xdmf`` and ``stem.vtu`` with the given vertex fields (ParaView-readable)."""
    out_dir = Path(out_dir)
    return [write_mesh(mesh, out_dir / f"{stem}{s}", point_data=point_data) for s in (".xdmf", ".vtu")]
