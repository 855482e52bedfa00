"""Mesh I/O: gmsh ``.msh`` with named physical groups in; XDMF / VTU / ``.msh`` out (the
writers live in ``meshes.writers`` and are re-exported here).

Every output is written to a temporary file in the target folder and renamed (``atomic_path``),
so a file is written whole or not at all, and no temporary is left behind after an error or an
interrupt. ``check_output_file`` / ``check_output_dir`` refuse a path
that cannot be written before any work starts.
"""
from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from .errors import ReadError, WriteError
from .mesh import MeshData, check_tangles

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

_CELL = {3: "tetra", 2: "triangle"}
_FACET = {3: "triangle", 2: "line"}


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

    cell_blocks = tagged(_CELL[dim])
    cells = np.concatenate([d for d, _ in cell_blocks]).astype(np.int64)
    cell_tags = np.concatenate([t for _, t in cell_blocks])
    pts = np.asarray(m.points, dtype=np.float64)
    if dim == 2:
        if pts.shape[1] == 3 and np.ptp(pts[:, 2]) > 1e-12 * max(np.ptp(pts), 1.0):
            raise ReadError(f"{str(path)!r}: {_NO_VOLUME} (it holds surface triangles in 3D but "
                            f"no tetrahedra)")
        pts = pts[:, :2]
    curved = {}
    ho = [d for t, d in high_order if t == _CELL[dim]]
    if ho:
        from .curved import from_high_order_cells

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
    mesh = MeshData(pts, cells, facet_regions, point_regions, cell_regions, **curved)
    if curved:
        from .curved import validate

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


def _why(exc: OSError) -> str:
    return exc.strerror or str(exc)


def user_cache_root() -> Path:
    """The toolkit's folder in the user's cache (``$XDG_CACHE_HOME/tissue-reference``, else
    ``~/.cache/tissue-reference``): compiled kernels and built meshes are kept below it."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "tissue-reference"


class atomic_path:
    """Context manager yielding a temporary path beside ``path``, renamed onto it on success.

    The temporary is removed whatever ends the block (an error, KeyboardInterrupt, a failed
    rename); a failure to write raises WriteError naming ``path``."""

    def __init__(self, path, suffix=None):
        self.path = Path(path)
        self.suffix = suffix if suffix is not None else self.path.suffix
        self.tmp = None

    def __enter__(self):
        if self.path.is_dir():
            raise WriteError(f"cannot write {str(self.path)!r}: it is a directory, expected a "
                             "file path")
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=f".{self.path.stem}.", suffix=self.suffix,
                                       dir=self.path.parent)
        except OSError as exc:
            raise WriteError(f"cannot write {str(self.path)!r}: {_why(exc)}") from None
        try:
            os.close(fd)
        finally:
            self.tmp = Path(tmp)
        return self.tmp

    def _discard(self):
        if self.tmp is not None:
            try:
                self.tmp.unlink(missing_ok=True)
            except OSError:
                pass

    def __exit__(self, exc_type, exc, tb):
        if exc_type is not None:
            self._discard()
            return False
        try:
            # mkstemp makes the file 0600; give it the mode a plain open() would (umask applied)
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(self.tmp, 0o666 & ~umask)
            os.replace(self.tmp, self.path)
        except OSError as err:
            self._discard()
            raise WriteError(f"cannot write {str(self.path)!r}: {_why(err)}") from None
        except BaseException:
            self._discard()
            raise
        return False


def save_figure(fig, path, *, dpi: int = 100) -> Path:
    """Write a matplotlib figure as a PNG at ``path``, whole or not at all (``atomic_path``), and
    close it; returns the path."""
    import matplotlib.pyplot as plt

    path = Path(path)
    try:
        with atomic_path(path, suffix=".png") as tmp:
            fig.savefig(tmp, format="png", dpi=dpi)
    finally:
        plt.close(fig)
    return path


def _parent_folder(path: Path, what: str) -> Path:
    """The folder ``path`` goes into, made (with its missing parents) when it does not exist
    yet; WriteError when it, or the nearest of its parents that exists, is not a writable
    folder."""
    p = path.parent
    top = p
    while not top.exists() and top != top.parent:
        top = top.parent
    if not top.is_dir():
        raise WriteError(f"{what} {str(path)!r}: {str(top)!r} is not a folder")
    if top != p:
        _check_writable(top, path, what)
        try:
            p.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise WriteError(f"{what} {str(path)!r}: cannot make folder {str(p)!r}: "
                             f"{exc.strerror or exc}") from None
    return p


def _check_writable(folder: Path, path: Path, what: str):
    ok = os.access(folder, os.W_OK | os.X_OK)
    if ok:
        try:  # the real test (root, read-only file systems): create and drop a file there
            with tempfile.TemporaryFile(dir=folder):
                pass
        except OSError:
            ok = False
    if not ok:
        raise WriteError(f"{what} {str(path)!r}: folder {str(folder)!r} is not writable")


def check_output_file(path, what: str = "output file", *, suffixes=None) -> Path:
    """Refuse, before any work, a file path that cannot be written: an existing directory, a
    name ending in a path separator, a folder that is a file or is not writable, or a suffix not
    in ``suffixes``; missing folders on the way are made. Raises WriteError naming ``what``
    (e.g. the option) and the path."""
    text = os.fspath(path)
    path = Path(text)
    if not text or text.endswith(os.sep) or path.is_dir():
        raise WriteError(f"{what} {text!r}: is a directory, expected a file path")
    if suffixes is not None and path.suffix.lower() not in suffixes:
        raise WriteError(f"{what} {text!r}: unsupported suffix {path.suffix!r}; expected one of "
                         f"{sorted(suffixes)}")
    if path.exists() and not path.is_file():
        raise WriteError(f"{what} {text!r}: exists and is not a regular file")
    _check_writable(_parent_folder(path, what), path, what)
    return path


def check_output_dir(path, what: str = "output folder") -> Path:
    """Refuse, before any work, a folder path that cannot be written: an existing file or a
    folder that is not writable; a missing folder is created when writing (its missing parents
    now, under the nearest writable folder that exists). Raises WriteError naming ``what`` and
    the path."""
    text = os.fspath(path)
    path = Path(text)
    if not text:
        raise WriteError(f"{what} {text!r}: expected a folder path")
    if path.exists():
        if not path.is_dir():
            raise WriteError(f"{what} {text!r}: is a file, expected a folder")
        _check_writable(path, path, what)
    else:
        _check_writable(_parent_folder(path, what), path, what)
    return path


# the writers, re-exported (imported last: they use atomic_path and the cell names above)
from .writers import REGION, WRITERS, region_tags, write_mesh, write_point_data
