"""gmsh geometry builders with named physical groups. Lengths in mm.

``phantom`` is the breast phantom of seed 000: a half-ellipsoid dome on a fixed flat base.

    base radius R = 50 mm, height H = 45 mm, base at z = 0 (physical group ``base``)
    actuator patches: discs of radius 5 mm (10 mm across) on the side at height z_a = 15 mm,
        centred at azimuths 0, 90, 180, 270 deg: ``act_px``, ``act_py``, ``act_nx``, ``act_ny``
        (3-actuator variant: azimuths 0, 120, 240 deg: ``act_a``, ``act_b``, ``act_c``)
    skin: the rest of the curved surface (``skin``), traction free
    targets T1..T5: mesh vertices in the actuator plane z = 15 mm,
        T1 (0, 0), T2 (12, 0), T3 (0, 12), T4 (-12, 0), T5 (0, -12)
    volume: ``tissue``

``box`` is an axis-aligned block with faces ``xmin``, ``xmax``, ``ymin``, ``ymax``, ``zmin``,
``zmax``; ``rectangle`` is its 2D (plane strain) analogue with edges ``xmin`` .. ``ymax``.
"""
from __future__ import annotations

import contextlib
import math
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import CaseError
from .io import atomic_path, read_msh
from .mesh import MeshData

__all__ = [
    "BUILDERS",
    "MAX_CELLS",
    "PHANTOM",
    "PhantomGeometry",
    "box",
    "build",
    "check_cell_budget",
    "cook_membrane",
    "estimate_cells",
    "indent_block",
    "phantom",
    "phantom3",
    "rectangle",
]


@dataclass(frozen=True)
class PhantomGeometry:
    radius: float = 50.0
    height: float = 45.0
    actuator_height: float = 15.0
    patch_radius: float = 5.0
    targets: tuple = (("T1", (0.0, 0.0, 15.0)), ("T2", (12.0, 0.0, 15.0)),
                      ("T3", (0.0, 12.0, 15.0)), ("T4", (-12.0, 0.0, 15.0)),
                      ("T5", (0.0, -12.0, 15.0)))

    def side_point(self, azimuth_deg: float) -> np.ndarray:
        """Point of the dome surface at the actuator height and the given azimuth."""
        z = self.actuator_height
        r = self.radius * math.sqrt(1.0 - (z / self.height) ** 2)
        a = math.radians(azimuth_deg)
        return np.array([r * math.cos(a), r * math.sin(a), z])


PHANTOM = PhantomGeometry()
ACTUATORS_4 = (("act_px", 0.0), ("act_py", 90.0), ("act_nx", 180.0), ("act_ny", 270.0))
ACTUATORS_3 = (("act_a", 0.0), ("act_b", 120.0), ("act_c", 240.0))


_GMSH_STATE = {"on": False}


@contextlib.contextmanager
def _gmsh_session(name: str, size: float, *, order: int = 1):
    import gmsh

    if size <= 0 or not math.isfinite(size):
        raise CaseError(f"mesh size must be a positive length in mm, got {size!r}")
    started = not _GMSH_STATE["on"]
    if started:
        gmsh.initialize(readConfigFiles=False)
        _GMSH_STATE["on"] = True
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add(name)
        gmsh.option.setNumber("Mesh.CharacteristicLengthMin", size)
        gmsh.option.setNumber("Mesh.CharacteristicLengthMax", size)
        gmsh.option.setNumber("Mesh.CharacteristicLengthFromPoints", 0)
        gmsh.option.setNumber("Mesh.CharacteristicLengthExtendFromBoundary", 0)
        gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
        gmsh.option.setNumber("Mesh.Algorithm3D", 1)  # Delaunay
        gmsh.option.setNumber("Mesh.Optimize", 1)
        gmsh.option.setNumber("General.NumThreads", 1)
        gmsh.option.setNumber("Mesh.RandomFactor", 1e-9)
        yield gmsh
    finally:
        gmsh.model.remove()
        if started:
            gmsh.finalize()
            _GMSH_STATE["on"] = False


def _finish(gmsh, dim: int, out, *, curved: bool = False) -> MeshData:
    """Mesh, write a .msh (to ``out`` or a temporary) and read it back through ``read_msh``.
    curved: second-order mesh (mid-edge nodes on the true geometry), read as linear cells plus
    curved edges (meshes.curved)."""
    gmsh.model.mesh.generate(dim)
    if curved:
        gmsh.model.mesh.setOrder(2)
    gmsh.option.setNumber("Mesh.SaveAll", 0)
    gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
    if out is not None:
        with atomic_path(out, suffix=".msh") as tmp:
            gmsh.write(str(tmp))
        return read_msh(out, overlap_check=False)
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "mesh.msh"
        gmsh.write(str(p))
        return read_msh(p, overlap_check=False)


SITE_REACH = 15.0
"""Radius (mm) around each actuator site inside which ``site_size`` applies; the cells grow to
``size`` over the next SITE_REACH mm."""


def _phantom(size: float, actuators, out=None, geometry: PhantomGeometry = PHANTOM,
             site_size: float | None = None) -> MeshData:
    g = geometry
    if site_size is not None and not (math.isfinite(site_size) and 0 < site_size):
        raise CaseError(f"site_size must be a positive length in mm, got {site_size!r}")
    with _gmsh_session("phantom", size) as gmsh:
        occ = gmsh.model.occ
        s = occ.addSphere(0, 0, 0, g.radius)
        occ.dilate([(3, s)], 0, 0, 0, 1, 1, g.height / g.radius)
        cut = occ.addBox(-2 * g.radius, -2 * g.radius, -2 * g.height, 4 * g.radius, 4 * g.radius,
                         2 * g.height)
        dome, _ = occ.cut([(3, s)], [(3, cut)])
        # actuator plugs: short cylinders along the inward radial direction at each patch,
        # intersected with the dome; fragmenting imprints their outer faces on the skin.
        plugs = []
        depth = 3.0 * g.patch_radius
        for _, az in actuators:
            p = g.side_point(az)
            d = -p / np.linalg.norm(p)
            d[2] = 0.0
            d /= np.linalg.norm(d)
            start = p - 2.0 * g.patch_radius * d
            c = occ.addCylinder(*start, *(d * (depth + 2.0 * g.patch_radius)), g.patch_radius)
            plugs.append(c)
        occ.synchronize()
        inter = []
        for c in plugs:
            dcopy = occ.copy(dome)
            r, _ = occ.intersect(dcopy, [(3, c)])
            inter.extend(r)
        out_map = occ.fragment(dome, inter)[0]
        occ.synchronize()
        vols = [t for d, t in out_map if d == 3]
        # targets embedded as mesh vertices
        pts = [occ.addPoint(*xyz, size) for _, xyz in g.targets]
        occ.synchronize()
        main = max(vols, key=lambda v: gmsh.model.occ.getMass(3, v))
        gmsh.model.mesh.embed(0, pts, 3, main)
        gmsh.model.addPhysicalGroup(3, vols, 1)
        gmsh.model.setPhysicalName(3, 1, "tissue")
        # classify boundary surfaces
        bnd = gmsh.model.getBoundary([(3, v) for v in vols], combined=True, oriented=False)
        surfs = sorted({t for _, t in bnd})
        base, skin, patches = [], [], {n: [] for n, _ in actuators}
        centres = {n: g.side_point(az) for n, az in actuators}
        for sf in surfs:
            c = np.array(gmsh.model.occ.getCenterOfMass(2, sf))
            if abs(c[2]) < 1e-6 * g.height:
                base.append(sf)
                continue
            near = [n for n, pc in centres.items() if np.linalg.norm(c - pc) < 1.5 * g.patch_radius]
            (patches[near[0]] if near else skin).append(sf)
        tag = 10
        for name, group in [("base", base), ("skin", skin), *patches.items()]:
            if not group:
                raise CaseError(f"phantom geometry: no surface found for region {name!r} at "
                                f"size {size}")
            gmsh.model.addPhysicalGroup(2, group, tag)
            gmsh.model.setPhysicalName(2, tag, name)
            tag += 1
        for (name, _), p in zip(g.targets, pts):
            gmsh.model.addPhysicalGroup(0, [p], tag)
            gmsh.model.setPhysicalName(0, tag, name)
            tag += 1
        # finer patches so each actuator touches several vertices
        gmsh.model.mesh.setSize(gmsh.model.getBoundary([(2, s) for g_ in patches.values() for s in g_],
                                                       recursive=True), min(size, g.patch_radius))
        if site_size is not None and site_size < size:
            _refine_sites(gmsh, [g.side_point(az) for _, az in actuators], site_size, size)
        return _finish(gmsh, 3, out, curved=True)


def _refine_sites(gmsh, sites, fine: float, coarse: float):
    """Cells of size ``fine`` within SITE_REACH of every site, growing linearly to ``coarse``
    over the next SITE_REACH mm (a gmsh Distance + Threshold background field)."""
    f = gmsh.model.mesh.field
    pts = [gmsh.model.occ.addPoint(*p) for p in sites]
    gmsh.model.occ.synchronize()
    dist = f.add("Distance")
    f.setNumbers(dist, "PointsList", pts)
    th = f.add("Threshold")
    f.setNumber(th, "InField", dist)
    f.setNumber(th, "SizeMin", fine)
    f.setNumber(th, "SizeMax", coarse)
    f.setNumber(th, "DistMin", SITE_REACH)
    f.setNumber(th, "DistMax", 2 * SITE_REACH)
    f.setAsBackgroundMesh(th)
    gmsh.option.setNumber("Mesh.CharacteristicLengthMin", fine)


def phantom(size: float = 6.0, *, out=None, site_size: float | None = None) -> MeshData:
    """Seed 000 breast phantom with four side actuators (see module docstring). size in mm;
    site_size: the cell size (mm) near each actuator site (``SITE_REACH``), e.g. a third of an
    indenter's radius."""
    return _phantom(size, ACTUATORS_4, out, site_size=site_size)


def phantom3(size: float = 6.0, *, out=None, site_size: float | None = None) -> MeshData:
    """Seed 000 phantom with three actuators 120 deg apart (minimal positive basis)."""
    return _phantom(size, ACTUATORS_3, out, site_size=site_size)


def _axis_block(kind: str, size: float, lengths, out) -> MeshData:
    """Axis-aligned block (3D) or rectangle (2D) from the origin, with the cell group ``tissue``
    and one facet group per side: xmin, xmax, ymin, ymax (, zmin, zmax)."""
    d = len(lengths)
    with _gmsh_session(kind, size) as gmsh:
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
        return _finish(gmsh, d, out)


def box(size: float = 5.0, *, lengths=(10.0, 10.0, 10.0), out=None) -> MeshData:
    """Block [0, Lx] x [0, Ly] x [0, Lz] (mm) with faces xmin .. zmax."""
    return _axis_block("box", size, tuple(lengths), out)


def rectangle(size: float = 2.0, *, lengths=(10.0, 10.0), out=None) -> MeshData:
    """2D plane-strain rectangle [0, Lx] x [0, Ly] (mm) with edges xmin, xmax, ymin, ymax."""
    return _axis_block("rectangle", size, tuple(lengths), out)


def shell_octant(size: float = 2.5, *, inner: float = 10.0, outer: float = 20.0,
                 out=None) -> MeshData:
    """One octant (x, y, z >= 0) of a thick spherical shell, radii ``inner`` < ``outer`` (mm):
    the classic pressurized / inflated thick sphere, with closed-form (incompressible) and radial-
    ODE (compressible) answers. Facet regions: inner, outer, and the symmetry planes xsym (x = 0),
    ysym, zsym; cell group tissue."""
    if not (0 < inner < outer):
        raise CaseError(f"shell radii must satisfy 0 < inner < outer, got {inner!r}, {outer!r}")
    with _gmsh_session("shell-octant", size) as gmsh:
        occ = gmsh.model.occ
        big = occ.addSphere(0, 0, 0, outer)
        small = occ.addSphere(0, 0, 0, inner)
        shell, _ = occ.cut([(3, big)], [(3, small)])
        clip = occ.addBox(0, 0, 0, 2 * outer, 2 * outer, 2 * outer)
        octant, _ = occ.intersect(shell, [(3, clip)])
        occ.synchronize()
        vols = [t for d, t in octant if d == 3]
        gmsh.model.addPhysicalGroup(3, vols, 1)
        gmsh.model.setPhysicalName(3, 1, "tissue")
        groups = {"inner": [], "outer": [], "xsym": [], "ysym": [], "zsym": []}
        for _, f in gmsh.model.getBoundary([(3, v) for v in vols], oriented=False):
            c = np.array(occ.getCenterOfMass(2, f))
            planar = [k for k in range(3) if abs(c[k]) < 1e-9 * outer]
            if planar:
                groups["xyz"[planar[0]] + "sym"].append(f)
            else:
                groups["inner" if np.linalg.norm(c) < 0.5 * (inner + outer) else "outer"].append(f)
        for i, (name, fs) in enumerate(groups.items()):
            gmsh.model.addPhysicalGroup(2, fs, 10 + i)
            gmsh.model.setPhysicalName(2, 10 + i, name)
        return _finish(gmsh, 3, out, curved=True)


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
    with _gmsh_session("cook-membrane", size) as gmsh:
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
        return _finish(gmsh, 2, out)


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
    with _gmsh_session("indent-block", size) as gmsh:
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
        return _finish(gmsh, 3, out)


def _indent_block_cells(size: float, g: IndentBlock = INDENT_BLOCK) -> float:
    """Estimated cells of ``indent_block(size)``: CELLS_PER_VOLUME times the integral of
    1 / cell_size^3 over the block, by shells about the origin (their fraction inside the block
    sampled on a fixed set of directions)."""
    W, D = g.half_width, g.depth
    t = np.linspace(0.0, 1.0, 41)[1:] - 0.0125
    th, ph = np.meshgrid(np.arccos(1.0 - t), (np.pi / 2) * t)  # octant z <= 0 (cos spread)
    dirs = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1)
    dirs = dirs.reshape(-1, 3)
    ext = np.array([W, W, D])
    r = np.concatenate([np.linspace(0.0, g.core, 50, endpoint=False),
                        np.geomspace(g.core, float(np.linalg.norm(ext)), 400)])
    inside = np.array([np.mean(np.all(ri * dirs <= ext, axis=1)) for ri in r])
    f = inside * (np.pi / 2) * r ** 2 / g.cell_size(r, size) ** 3
    # x 1.2: the graded mesh has that many more cells than the uniform-mesh density (measured at
    # size 0.25 to 6 mm)
    return 1.2 * CELLS_PER_VOLUME[3] * float(np.sum(0.5 * (f[1:] + f[:-1]) * np.diff(r)))


BUILDERS = {"phantom": phantom, "phantom-3": phantom3, "box": box, "rectangle": rectangle,
            "shell-octant": shell_octant, "indent-block": indent_block}


# Volume (mm^3; area in mm^2 for the 2D rectangle) of each builder's body at its default
# dimensions, for the cell-count estimate.
BODY_VOLUMES = {
    "phantom": 2.0 / 3.0 * math.pi * PHANTOM.radius ** 2 * PHANTOM.height,
    "phantom-3": 2.0 / 3.0 * math.pi * PHANTOM.radius ** 2 * PHANTOM.height,
    "box": 1000.0,
    "rectangle": 100.0,
    "shell-octant": math.pi / 6.0 * (20.0 ** 3 - 10.0 ** 3),
}
BODY_DIMENSIONS = {"rectangle": 2}
# Cells per (volume / size^3): a regular tetrahedron of edge h has volume h^3 / (6 sqrt 2); gmsh's
# Delaunay meshes have about 0.55 times that many cells (measured on the phantom, box and shell
# at 0.55-0.59 for 5k-41k cells; coarse meshes have relatively more, up to 1.5x near 100 cells);
# triangles: 4 / sqrt 3 per (area / size^2), as measured on the rectangle.
CELLS_PER_VOLUME = {3: 0.55 * 6.0 * math.sqrt(2.0), 2: 4.0 / math.sqrt(3.0)}
MAX_CELLS = 2_000_000
"""Default limit on the estimated cells of a builtin mesh; ``build(max_cells=...)`` and the
command line's ``--max-cells`` raise it."""


def estimate_cells(name: str, size: float, *, site_size: float | None = None) -> int | None:
    """Estimated cells (tetrahedra, or triangles for the rectangle) of builder ``name`` at
    characteristic length ``size`` (mm): about CELLS_PER_VOLUME * V / size^d, within ~10 %
    above a few thousand cells; None for a builder whose body volume is not in BODY_VOLUMES."""
    if name not in BUILDERS:
        raise CaseError(f"unknown mesh builder {name!r}; builders: {sorted(BUILDERS)}")
    if isinstance(size, bool) or not isinstance(size, (int, float)) or not math.isfinite(size) \
            or size <= 0:
        raise CaseError(f"mesh size must be a positive length in mm, got {size!r}")
    if name == "indent-block":  # graded: cells concentrate near the indentation point
        with np.errstate(over="ignore"):
            est = _indent_block_cells(float(size))
        return int(min(est, 1e18)) if math.isfinite(est) else 10 ** 18
    if name not in BODY_VOLUMES:
        return None
    d = BODY_DIMENSIONS.get(name, 3)
    with np.errstate(over="ignore"):
        est = CELLS_PER_VOLUME[d] * BODY_VOLUMES[name] / float(size) ** d
        if site_size is not None and name in SITE_BUILDERS and site_size < size:
            # each site: a half ball of radius SITE_REACH at site_size, a graded shell to
            # 2 SITE_REACH (cells of about the mean size), at most the whole body
            n_sites = 4 if name == "phantom" else 3
            half = 2.0 / 3.0 * math.pi * SITE_REACH ** 3
            shell = 7.0 * half
            mid = (site_size + size) / 2.0
            local = n_sites * (half / site_size ** 3 + shell / mid ** 3)
            est += CELLS_PER_VOLUME[d] * min(local, BODY_VOLUMES[name] / site_size ** 3)
    return int(min(est, 1e18)) if math.isfinite(est) else 10 ** 18


def check_cell_budget(name: str, size: float, max_cells: int | None = MAX_CELLS) -> int | None:
    """The estimate of ``estimate_cells``; CaseError naming it when it exceeds ``max_cells``
    (None: no limit)."""
    est = estimate_cells(name, size)
    if est is not None and max_cells is not None and est > max_cells:
        raise CaseError(
            f"builtin mesh {name!r} at size {size:g} mm would have about {est:,} cells, more "
            f"than the limit of {int(max_cells):,} (--max-cells N raises it; a larger size "
            f"gives fewer cells)")
    return est


SITE_BUILDERS = ("phantom", "phantom-3")
"""The builders that take ``site_size`` (finer cells at the actuator sites)."""


def build(name: str, size: float, *, out=None, max_cells: int | None = MAX_CELLS,
          site_size: float | None = None) -> MeshData:
    """Build a named mesh (see ``BUILDERS``) with characteristic length ``size`` (mm).

    max_cells: refuse (CaseError with the estimate, before gmsh starts) a mesh whose estimated
    cell count (``estimate_cells``) exceeds it; None: no limit. site_size: finer cells at the
    actuator sites (``SITE_BUILDERS`` only)."""
    if name not in BUILDERS:
        raise CaseError(f"unknown mesh builder {name!r}; builders: {sorted(BUILDERS)}")
    if site_size is None:
        check_cell_budget(name, size, max_cells)
        return BUILDERS[name](size, out=out)
    if name not in SITE_BUILDERS:
        raise CaseError(f"site_size applies to the builders {list(SITE_BUILDERS)}, not {name!r}")
    est = estimate_cells(name, size, site_size=site_size)
    if max_cells is not None and est > max_cells:
        raise CaseError(f"builtin mesh {name!r} at size {size:g} mm, site_size {site_size:g} mm: "
                        f"about {est:,} cells (estimate), more than the limit {max_cells:,}")
    return BUILDERS[name](size, out=out, site_size=site_size)
