"""Flat-sided gmsh bodies, meshed at first order. Lengths in mm.

``box``: the block [0, Lx] x [0, Ly] x [0, Lz] with faces ``xmin`` .. ``zmax``; ``rectangle``:
its 2D (plane strain) analogue with edges ``xmin`` .. ``ymax``; ``structured_box``: the same
block cut into n_x x n_y x n_z cubes of six tetrahedra each, built with numpy alone (no gmsh:
for machines without it, and meshes of a known count); ``cook_membrane``: Cook's
tapered panel (2D); ``indent_block``: a large quarter block, graded from fine cells at the
indentation point (``IndentBlock``), for indentation against half-space answers.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import builders_gmsh
from .builders_gmsh import finish
from .mesh import MeshData

__all__ = ["INDENT_BLOCK", "IndentBlock", "box", "cook_membrane", "indent_block", "rectangle",
           "structured_box"]


def _axis_block(kind: str, size: float, lengths, out) -> MeshData:
    """Axis-aligned block (3D) or rectangle (2D) from the origin, with the cell group ``tissue``
    and one facet group per side: xmin, xmax, ymin, ymax (, zmin, zmax)."""
    d = len(lengths)
    with builders_gmsh.gmsh_session(kind, size) as gmsh:
        occ = gmsh.model.occ
        tag = occ.addBox(0, 0, 0, *lengths) if d == 3 else occ.addRectangle(0, 0, 0, *lengths)
        occ.synchronize()
        gmsh.model.addPhysicalGroup(d, [tag], 1)
        gmsh.model.setPhysicalName(d, 1, "tissue")
        sides = [(f"{'xyz'[k]}{end}", k, val) for k in range(d)
                 for end, val in (("min", 0.0), ("max", lengths[k]))]
        facets = gmsh.model.getBoundary([(d, tag)], oriented=False)
        for i, (name, axis, val) in enumerate(sides):
            for _, f in facets:
                c = occ.getCenterOfMass(d - 1, f)
                if abs(c[axis] - val) < 1e-9 * max(lengths):
                    gmsh.model.addPhysicalGroup(d - 1, [f], 10 + i)
                    gmsh.model.setPhysicalName(d - 1, 10 + i, name)
        return finish(gmsh, d, out)


def box(size: float = 5.0, *, lengths=(10.0, 10.0, 10.0), out=None) -> MeshData:
    """Block [0, Lx] x [0, Ly] x [0, Lz] (mm) with faces xmin .. zmax."""
    return _axis_block("box", size, tuple(lengths), out)


# the six tetrahedra of a unit cube around its diagonal 0-7 (corner k at bits x, y, z of k)
_KUHN = np.array([(0, 1, 3, 7), (0, 1, 5, 7), (0, 2, 3, 7), (0, 2, 6, 7), (0, 4, 5, 7),
                  (0, 4, 6, 7)])


def structured_box(n, *, lengths=(10.0, 10.0, 10.0)) -> MeshData:
    """Block [0, Lx] x [0, Ly] x [0, Lz] (mm) cut into ``n`` cubes per side (an int, or one per
    axis), each into six tetrahedra sharing its main diagonal (Kuhn's subdivision: conforming,
    6 n_x n_y n_z cells); faces xmin .. zmax as in ``box``, cell group ``tissue``."""
    nx, ny, nz = (int(n),) * 3 if np.ndim(n) == 0 else (int(k) for k in n)
    if min(nx, ny, nz) < 1:
        raise ValueError(f"structured_box: need at least one cube per side, got {(nx, ny, nz)}")
    axes = [np.linspace(0.0, float(L), k + 1) for L, k in zip(lengths, (nx, ny, nz))]
    X, Y, Z = np.meshgrid(*axes, indexing="ij")
    points = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])
    vid = np.arange(points.shape[0]).reshape(nx + 1, ny + 1, nz + 1)
    i, j, k = (a.ravel() for a in np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz),
                                              indexing="ij"))
    corners = np.stack([vid[i + (c & 1), j + ((c >> 1) & 1), k + ((c >> 2) & 1)]
                        for c in range(8)], axis=1)
    cells = corners[:, _KUHN].reshape(-1, 4)
    a, b, c, d = (points[cells[:, q]] for q in range(4))
    flip = np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a) < 0
    cells[flip] = cells[flip][:, [0, 2, 1, 3]]
    faces = {}
    for axis, m in enumerate((nx, ny, nz)):
        for end, idx in (("min", 0), ("max", m)):
            grid = np.take(vid, idx, axis=axis)
            q = np.stack([grid[:-1, :-1], grid[1:, :-1], grid[1:, 1:], grid[:-1, 1:]],
                         axis=-1).reshape(-1, 4)
            faces[f"{'xyz'[axis]}{end}"] = _split_quads(q, points)
    return MeshData(points, cells, facet_regions=faces,
                    cell_regions={"tissue": np.arange(cells.shape[0])})


def _split_quads(q, points):
    """Boundary triangles of the quads ``q`` (4 vertex ids in cycle order) that are faces of the
    Kuhn tetrahedra: each quad is cut along the diagonal through its corner of smallest
    coordinates (all of a cube's faces meet the cube's diagonal 0-7 there or at corner 7)."""
    s = points[q].sum(axis=2)                       # x + y + z of each corner
    lo = np.argmin(s, axis=1)
    q = np.take_along_axis(q, (lo[:, None] + np.arange(4)) % 4, axis=1)
    return np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])


def rectangle(size: float = 2.0, *, lengths=(10.0, 10.0), out=None) -> MeshData:
    """2D plane-strain rectangle [0, Lx] x [0, Ly] (mm) with edges xmin, xmax, ymin, ymax."""
    return _axis_block("rectangle", size, tuple(lengths), out)


def cook_membrane(size: float = 4.0, *, out=None) -> MeshData:
    """Cook's membrane (R. D. Cook 1974; Simo & Rifai 1990): the tapered panel with corners
    (0, 0), (48, 44), (48, 60), (0, 44) mm, in 2D (the reference's plane strain). Edges ``left``
    (x = 0, clamped in the benchmark), ``right`` (x = 48, 16 mm long, carrying the shear load),
    ``top`` and ``bottom`` (free); point groups ``mid_edge`` (48, 52), the midpoint of the loaded
    edge, and ``corner`` (48, 60), both mesh vertices; cell group ``tissue``. size: element
    edge length (mm).

    The benchmark (linear elasticity, E = 1, nu = 1/3, plane stress, unit total shear load on
    ``right``): the vertical displacement at ``mid_edge`` converges to 23.96 (the value quoted
    for Cook's membrane; e.g. 23.97 in P. Krysl's FinEtools plane-stress tutorial, tracked at
    (48, 52)). Plane stress (E, nu) is plane strain with E* = E (1 + 2 nu) / (1 + nu)^2,
    nu* = nu / (1 + nu): E* = 15/16, nu* = 1/4 here."""
    corners = [(0.0, 0.0), (48.0, 44.0), (48.0, 52.0), (48.0, 60.0), (0.0, 44.0)]
    with builders_gmsh.gmsh_session("cook-membrane", size) as gmsh:
        occ = gmsh.model.occ
        pts = [occ.addPoint(x, y, 0.0) for x, y in corners]
        lines = [occ.addLine(pts[k], pts[(k + 1) % 5]) for k in range(5)]
        surf = occ.addPlaneSurface([occ.addCurveLoop(lines)])
        occ.synchronize()
        gmsh.model.addPhysicalGroup(2, [surf], 1)
        gmsh.model.setPhysicalName(2, 1, "tissue")
        groups = {"bottom": [lines[0]], "right": [lines[1], lines[2]], "top": [lines[3]],
                  "left": [lines[4]]}
        for k, (name, ls) in enumerate(groups.items()):
            gmsh.model.addPhysicalGroup(1, ls, 10 + k)
            gmsh.model.setPhysicalName(1, 10 + k, name)
        for k, (name, p) in enumerate((("mid_edge", pts[2]), ("corner", pts[3]))):
            gmsh.model.addPhysicalGroup(0, [p], 20 + k)
            gmsh.model.setPhysicalName(0, 20 + k, name)
        return finish(gmsh, 2, out)


@dataclass(frozen=True)
class IndentBlock:
    """The ``indent-block`` quarter block (mm): [0, half_width]^2 x [-depth, 0], indented at the
    origin, a corner of its top face; cells of ``size`` within ``core`` of the origin, growing by
    ``growth`` per mm of distance beyond it up to ``max_size``."""

    half_width: float = 240.0
    depth: float = 240.0
    patch_radius: float = 2.0
    core: float = 2.5
    growth: float = 0.3
    max_size: float = 40.0

    def cell_size(self, r, size: float):
        """Target cell size (mm) at distance ``r`` (mm) from the origin."""
        return np.minimum(max(self.max_size, size),
                          size + self.growth * np.maximum(np.asarray(r, float) - self.core, 0.0))


INDENT_BLOCK = IndentBlock()


def indent_block(size: float = 0.25, *, out=None, geometry: IndentBlock = INDENT_BLOCK) -> MeshData:
    """A large quarter block for indentation against half-space answers (Hertz, Boussinesq):
    [0, W] x [0, W] x [-D, 0] mm (W = D = 240), the indenter's axis along the edge x = y = 0.
    Facet regions: ``tip``, the quarter disc of radius 2 mm around the origin on the top face
    (z = 0), ``top`` the rest of the top face, ``xsym`` (x = 0) and ``ysym`` (y = 0), the
    symmetry planes, ``xmax``, ``ymax`` and ``bottom`` (z = -D); cell group ``tissue``.
    size: the cell size (mm) within 2.5 mm of the origin; beyond, it grows by 0.3 mm per mm of
    distance up to 40 mm (``IndentBlock``), so the block costs little more than its core.

    The block stands for a half-space: fixing its bottom at depth D removes about the half-space
    settlement there, F (1 + nu) (3 - 2 nu) / (2 pi E D) (mm, Boussinesq's point load F), from
    the indentation: for a contact radius a, a relative stiffening of about
    a (1 + nu) (3 - 2 nu) / (pi (1 - nu^2) D) (0.4 % for a = 1 mm, nu = 0.45)."""
    g = geometry
    W, D, rp = g.half_width, g.depth, g.patch_radius
    with builders_gmsh.gmsh_session("indent-block", size) as gmsh:
        occ = gmsh.model.occ
        blk = occ.addBox(0, 0, -D, W, W, D)
        o = occ.addPoint(0, 0, 0)
        a, b = occ.addPoint(rp, 0, 0), occ.addPoint(0, rp, 0)
        loop = occ.addCurveLoop([occ.addLine(o, a), occ.addCircleArc(a, o, b),
                                 occ.addLine(b, o)])
        disc = occ.addPlaneSurface([loop])
        occ.fragment([(3, blk)], [(2, disc)])
        occ.synchronize()
        vols = [t for _, t in gmsh.model.getEntities(3)]
        gmsh.model.addPhysicalGroup(3, vols, 1)
        gmsh.model.setPhysicalName(3, 1, "tissue")
        groups = {"tip": [], "top": [], "xsym": [], "ysym": [], "xmax": [], "ymax": [],
                  "bottom": []}
        for _, f in gmsh.model.getBoundary([(3, v) for v in vols], oriented=False):
            c = np.array(occ.getCenterOfMass(2, f))
            tol = 1e-9 * W
            if abs(c[2]) < tol:
                groups["tip" if np.hypot(c[0], c[1]) < rp else "top"].append(f)
            elif abs(c[2] + D) < tol:
                groups["bottom"].append(f)
            else:
                k = 0 if abs(c[0]) < tol or abs(c[0] - W) < tol else 1
                groups[("xy"[k]) + ("sym" if abs(c[k]) < tol else "max")].append(f)
        for i, (name, fs) in enumerate(groups.items()):
            gmsh.model.addPhysicalGroup(2, fs, 10 + i)
            gmsh.model.setPhysicalName(2, 10 + i, name)
        hmax = max(g.max_size, size)
        gmsh.option.setNumber("Mesh.CharacteristicLengthMax", hmax)
        field = gmsh.model.mesh.field.add("MathEval")
        gmsh.model.mesh.field.setString(
            field, "F", f"Min({hmax!r}, {size!r} + {g.growth!r} * "
                        f"Max(0, Sqrt(x*x + y*y + z*z) - {g.core!r}))")
        gmsh.model.mesh.field.setAsBackgroundMesh(field)
        return finish(gmsh, 3, out)

