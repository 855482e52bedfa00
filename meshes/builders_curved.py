"""Curved gmsh bodies, meshed at second order (mid-edge nodes on the true geometry). Lengths
in mm.

``phantom`` and ``phantom3``: the seed 000 breast phantom, a half-ellipsoid dome on a flat base
(``PhantomGeometry``: base radius 50 mm, height 45 mm) with four or three actuator patches on
its side and the targets T1..T5 as mesh vertices; the regions are listed in the
``meshes.builders`` module docstring. ``site_size`` gives finer cells within ``SITE_REACH`` mm
of each actuator site, ``path_size`` along each actuator's path into the tissue and
``rim_size`` at the rims of the actuator patches and ``base_rim_size`` at the base rim, where
the fixed base meets the free dome.

``shell_octant``: one octant of a thick spherical shell (radii 10 and 20 mm by default).
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from tissue_reference.errors import CaseError

from . import builders_gmsh
from .builders_gmsh import finish
from .mesh import MeshData, quality
from .mirror import mirror
from .projection import dome_side_point
from .writers import write_mesh

_LOG = logging.getLogger("tissue.meshes")

__all__ = [
    "ACTUATORS_3",
    "ACTUATORS_4",
    "LOCAL_SIZES",
    "MIN_DIHEDRAL_DEG",
    "PATH_DEPTH",
    "PATH_REACH",
    "PHANTOM",
    "RIM_GRADING",
    "SITE_REACH",
    "PhantomGeometry",
    "check_local_sizes",
    "phantom",
    "phantom3",
    "phantom_half",
    "phantom_quarter",
    "phantom_symmetric",
    "shell_octant",
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
        return dome_side_point(self.radius, self.height, self.actuator_height, azimuth_deg)


PHANTOM = PhantomGeometry()
ACTUATORS_4 = (("act_px", 0.0), ("act_py", 90.0), ("act_nx", 180.0), ("act_ny", 270.0))
ACTUATORS_3 = (("act_a", 0.0), ("act_b", 120.0), ("act_c", 240.0))


SITE_REACH = 15.0
"""Radius (mm) around each actuator site inside which ``site_size`` applies; the cells grow to
``size`` over the next SITE_REACH mm."""
PATH_DEPTH = 20.0
"""Length (mm) of each actuator's path refined by ``path_size``: from the site inward along the
actuator's direction, as deep as a 15 mm push of a 5 mm tip reaches."""
PATH_REACH = 6.0
"""Radius (mm) around each path inside which ``path_size`` applies by default (a 5 mm tip and
the skin wrapped around it; ``path_reach`` sets another); the cells grow to ``site_size`` over
the next half reach."""
RIM_GRADING = 0.25
"""Growth (mm of cell size per mm of distance) of the cells away from the actuator patches'
rims when ``rim_size`` refines them: the cells are ``rim_size`` within ``rim_size`` of the rim
and grow linearly to the size around them. ``base_rim_size`` grades the same way from the base
rim."""


MIN_DIHEDRAL_DEG = 8.0
"""The phantom meshes' quality floor (degrees): a mesh with a tetrahedron's dihedral angle below
this is meshed again (every shipped case's meshes hold it: tests/test_mesh_quality.py).
Where an actuator plug's seam (the line along which OCC closes its cylinder) meets the skin,
gmsh's surface mesh can leave slivers on the patch's rim that no volume optimizer moves (the
glued phantom had 1.6-5 degrees at sizes 6-14, and a nearly incompressible solve folded one);
a mesh below the floor is meshed again with the plugs' seams turned by ``SEAM_TURN_DEG``
about their axes (11-12 degrees at those sizes), and the better of the two is kept. Meshes
above the floor are left as they are."""
SEAM_TURN_DEG = 90.0


SYMMETRY_PLANES = {"full": (), "half": ("sym_y0",), "quarter": ("sym_y0", "sym_x0")}
"""The mirror planes each symmetric part of the phantom keeps as regions: ``sym_y0`` is the
plane y = 0 (the part keeps y >= 0), ``sym_x0`` the plane x = 0 (the part keeps x >= 0)."""


def check_local_sizes(local: dict) -> None:
    """CaseError naming the first of the local sizes ``local`` (name -> mm or None) that is not
    a positive finite length."""
    for name, v in local.items():
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float))
                              or not math.isfinite(v) or v <= 0):
            raise CaseError(f"{name} must be a positive length in mm, got {v!r}")


def _phantom(size: float, actuators, out=None, geometry: PhantomGeometry = PHANTOM,
             site_size: float | None = None, part: str = "full",
             path_size: float | None = None, rim_size: float | None = None,
             base_rim_size: float | None = None,
             path_reach: float | None = None) -> MeshData:
    """The phantom meshed as ``phantom_once``, and again with the plugs' seams turned when the
    first mesh has slivers below ``MIN_DIHEDRAL_DEG``; the better of the two (a warning when
    even that is below the floor, and the first when the second cannot be built)."""
    local = {"geometry": geometry, "site_size": site_size, "part": part,
             "path_size": path_size, "rim_size": rim_size, "base_rim_size": base_rim_size,
             "path_reach": path_reach}
    first = phantom_once(size, actuators, out, **local)
    angle = quality(first).min_dihedral_deg
    if angle >= MIN_DIHEDRAL_DEG:
        return first
    try:
        turned = phantom_once(size, actuators, out, seam_turn_deg=SEAM_TURN_DEG, **local)
        turned_angle = quality(turned).min_dihedral_deg
    except Exception as exc:   # noqa: BLE001 - OCC or gmsh failing on the turned plugs
        _LOG.warning("phantom at size %g mm: meshing with the plugs' seams turned failed (%s); "
                     "kept the first mesh, below the quality floor", size, exc)
        turned, turned_angle = None, -math.inf
    if max(angle, turned_angle) < MIN_DIHEDRAL_DEG:
        _LOG.warning("phantom at size %g mm: smallest dihedral angle %.1f degrees, below the "
                     "quality floor of %g", size, max(angle, turned_angle), MIN_DIHEDRAL_DEG)
    if turned_angle >= angle:
        return turned
    # the first mesh is kept; a file written meanwhile by the second is written again
    return phantom_once(size, actuators, out, **local) if out is not None else first


def phantom_once(size: float, actuators, out=None, geometry: PhantomGeometry = PHANTOM,
                  site_size: float | None = None, part: str = "full",
                  path_size: float | None = None, rim_size: float | None = None,
                  base_rim_size: float | None = None, path_reach: float | None = None,
                  seam_turn_deg: float = 0.0) -> MeshData:
    g = geometry
    check_local_sizes({"site_size": site_size, "path_size": path_size, "rim_size": rim_size,
                       "base_rim_size": base_rim_size, "path_reach": path_reach})
    if path_reach is not None and path_size is None:
        raise CaseError(f"path_reach {path_reach!r} mm is the reach of path_size: give a "
                        f"path_size too")
    if path_size is not None and (site_size is None or path_size > site_size):
        raise CaseError(f"path_size {path_size!r} mm refines within the actuator sites: it "
                        f"needs a site_size at least as large, got site_size={site_size!r}")
    planes = SYMMETRY_PLANES[part]
    keep = {"sym_y0": 1, "sym_x0": 0}  # the coordinate each plane bounds from below
    tol = 1e-6 * g.radius

    def inside(p) -> bool:
        return all(p[keep[pl]] >= -tol for pl in planes)

    def strictly(p) -> bool:
        return all(p[keep[pl]] > tol for pl in planes)

    actuators = [(n, az) for n, az in actuators if inside(g.side_point(az))]
    targets = [(n, xyz) for n, xyz in g.targets if inside(xyz)]
    with builders_gmsh.gmsh_session("phantom", size) as gmsh:
        occ = gmsh.model.occ
        s = occ.addSphere(0, 0, 0, g.radius)
        if planes:  # the sphere's seam (in the plane y = 0) away from the mirror planes: OCC's
            occ.rotate([(3, s)], 0, 0, 0, 0, 0, 1, math.pi / 4)  # cut along it removes nothing
        occ.dilate([(3, s)], 0, 0, 0, 1, 1, g.height / g.radius)
        cut = occ.addBox(-2 * g.radius, -2 * g.radius, -2 * g.height, 4 * g.radius, 4 * g.radius,
                         2 * g.height)
        dome, _ = occ.cut([(3, s)], [(3, cut)])
        for pl in planes:  # cut away the negative side of each mirror plane
            corner = [-2 * g.radius, -2 * g.radius, -g.height]
            extent = [4 * g.radius, 4 * g.radius, 3 * g.height]
            corner[keep[pl]], extent[keep[pl]] = -4 * g.radius, 4 * g.radius
            dome, _ = occ.cut(dome, [(3, occ.addBox(*corner, *extent))])
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
            if seam_turn_deg:
                occ.rotate([(3, c)], *start, *d, math.radians(seam_turn_deg))
            plugs.append(c)
        occ.synchronize()
        inter = []
        for c in plugs:
            dcopy = occ.copy(dome)
            r, _ = occ.intersect(dcopy, [(3, c)])
            inter.extend(r)
        # targets on a mirror plane are imprinted on it (gmsh cannot embed a point in a curve)
        on_plane = [occ.addPoint(*xyz, size) for _, xyz in targets if not strictly(xyz)]
        out_map = occ.fragment(dome, inter + [(0, p) for p in on_plane])[0]
        occ.synchronize()
        vols = [t for d, t in out_map if d == 3]
        # targets inside embedded as mesh vertices; those on a plane were imprinted above
        inner = iter([occ.addPoint(*xyz, size) for _, xyz in targets if strictly(xyz)])
        occ.synchronize()
        planar = iter(on_plane)
        pts = [next(inner) if strictly(xyz) else _vertex_at(gmsh, xyz, next(planar), tol)
               for _, xyz in targets]
        main = max(vols, key=lambda v: gmsh.model.occ.getMass(3, v))
        gmsh.model.mesh.embed(0, [p for p, (_, xyz) in zip(pts, targets) if strictly(xyz)], 3,
                              main)
        gmsh.model.addPhysicalGroup(3, vols, 1)
        gmsh.model.setPhysicalName(3, 1, "tissue")
        # classify boundary surfaces
        bnd = gmsh.model.getBoundary([(3, v) for v in vols], combined=True, oriented=False)
        surfs = sorted({t for _, t in bnd})
        base, skin, patches = [], [], {n: [] for n, _ in actuators}
        centres = {n: g.side_point(az) for n, az in actuators}
        mirrors = {pl: [] for pl in planes}
        for sf in surfs:
            c = np.array(gmsh.model.occ.getCenterOfMass(2, sf))
            if abs(c[2]) < 1e-6 * g.height:
                base.append(sf)
                continue
            lo, hi = np.split(np.array(gmsh.model.getBoundingBox(2, sf)), 2)
            flat = [pl for pl in planes if hi[keep[pl]] - lo[keep[pl]] <= tol
                    and abs(c[keep[pl]]) <= tol]
            if flat:
                mirrors[flat[0]].append(sf)
                continue
            near = [n for n, pc in centres.items() if np.linalg.norm(c - pc) < 1.5 * g.patch_radius]
            (patches[near[0]] if near else skin).append(sf)
        tag = 10
        for name, group in [("base", base), ("skin", skin), *patches.items(),
                            *mirrors.items()]:
            if not group:
                raise CaseError(f"phantom geometry: no surface found for region {name!r} at "
                                f"size {size}")
            gmsh.model.addPhysicalGroup(2, group, tag)
            gmsh.model.setPhysicalName(2, tag, name)
            tag += 1
        for (name, _), p in zip(targets, pts):
            gmsh.model.addPhysicalGroup(0, [p], tag)
            gmsh.model.setPhysicalName(0, tag, name)
            tag += 1
        # finer patches so each actuator touches several vertices
        gmsh.model.mesh.setSize(gmsh.model.getBoundary([(2, s) for g_ in patches.values() for s in g_],
                                                       recursive=True), min(size, g.patch_radius))
        sites = [g.side_point(az) for _, az in actuators]
        inward = [np.array([-math.cos(math.radians(az)), -math.sin(math.radians(az)), 0.0])
                  for _, az in actuators]
        paths = None if path_size is None else [(p, p + PATH_DEPTH * n)
                                                for p, n in zip(sites, inward)]

        def outline(surfaces):  # their boundary curves, less any cut along a mirror plane
            return [t for _, t in gmsh.model.getBoundary(
                [(2, s_) for s_ in surfaces], combined=True, oriented=False)
                if not any(abs(gmsh.model.occ.getCenterOfMass(1, t)[keep[pl]]) <= tol
                           for pl in planes)]

        rims = None if rim_size is None else outline([s_ for g_ in patches.values()
                                                      for s_ in g_])
        base_rim = None if base_rim_size is None else outline(base)
        if site_size is not None or rim_size is not None or base_rim_size is not None:
            _local_sizes(gmsh, sites, site_size, size, paths=paths, path_size=path_size,
                         path_reach=path_reach or PATH_REACH, rims=rims, rim_size=rim_size,
                         base_rim=base_rim, base_rim_size=base_rim_size)
        return finish(gmsh, 3, out, curved=True)


def _vertex_at(gmsh, xyz, tag: int, tol: float) -> int:
    """The tag of the geometry point at xyz after a fragment (which may renumber ``tag``)."""
    for _, t in gmsh.model.getEntities(0):
        if np.linalg.norm(np.array(gmsh.model.getValue(0, t, [])) - xyz) <= tol:
            return t
    raise CaseError(f"phantom geometry: the target at {list(xyz)} was lost on its mirror plane")


def _local_sizes(gmsh, sites, fine: float | None, coarse: float, *, paths=None,
                 path_size: float | None = None, path_reach: float = PATH_REACH, rims=None,
                 rim_size: float | None = None,
                 base_rim=None, base_rim_size: float | None = None):
    """A gmsh background size field, the smallest of: cells of size ``fine`` within SITE_REACH
    of every site, growing linearly to ``coarse`` over the next SITE_REACH mm; with ``paths``
    (segments (start, end), mm) and ``path_size``, cells of ``path_size`` within ``path_reach``
    of each segment, growing to ``fine`` over the next half reach; with ``rims`` (curve
    tags) and ``rim_size``, cells of ``rim_size`` within ``rim_size`` of those curves, growing
    by RIM_GRADING to ``coarse``; likewise with ``base_rim`` (curve tags) and ``base_rim_size``.
    The points and segments are free geometry, not part of the body: they are neither meshed
    into it nor written."""
    f = gmsh.model.mesh.field
    occ = gmsh.model.occ

    def threshold(dist, small, large, near, far):
        th = f.add("Threshold")
        f.setNumber(th, "InField", dist)
        f.setNumber(th, "SizeMin", small)
        f.setNumber(th, "SizeMax", large)
        f.setNumber(th, "DistMin", near)
        f.setNumber(th, "DistMax", far)
        return th

    fine = coarse if fine is None else min(fine, coarse)
    pts = [occ.addPoint(*p) for p in sites]
    lines = [occ.addLine(occ.addPoint(*a), occ.addPoint(*b)) for a, b in (paths or [])]
    occ.synchronize()
    fields, smallest = [], coarse
    if fine < coarse:
        dist = f.add("Distance")
        f.setNumbers(dist, "PointsList", pts)
        fields.append(threshold(dist, fine, coarse, SITE_REACH, 2 * SITE_REACH))
        smallest = fine
    if lines and path_size is not None and path_size < fine:
        along = f.add("Distance")
        f.setNumbers(along, "CurvesList", lines)
        f.setNumber(along, "NumPointsPerCurve", 200)
        fields.append(threshold(along, path_size, fine, path_reach, 1.5 * path_reach))
        smallest = path_size
    for curves, small, length in ((rims, rim_size, 2.0 * math.pi * PHANTOM.patch_radius),
                                  (base_rim, base_rim_size, 2.0 * math.pi * PHANTOM.radius)):
        if curves and small is not None and small < coarse:
            rim = f.add("Distance")
            f.setNumbers(rim, "CurvesList", curves)
            # samples closer than the rim cells, so the distance is smooth along the rim
            f.setNumber(rim, "NumPointsPerCurve", max(200, math.ceil(4.0 * length / small)))
            fields.append(threshold(rim, small, coarse, small,
                                    small + (coarse - small) / RIM_GRADING))
            smallest = min(smallest, small)
    if not fields:
        return
    field = fields[0]
    if len(fields) > 1:
        field = f.add("Min")
        f.setNumbers(field, "FieldsList", fields)
    f.setAsBackgroundMesh(field)
    gmsh.option.setNumber("Mesh.CharacteristicLengthMin", smallest)


LOCAL_SIZES = ("site_size", "path_size", "path_reach", "rim_size", "base_rim_size")
"""The phantom builders' optional local cell sizes and the paths' reach (mm, keywords)."""


def phantom(size: float = 6.0, *, out=None, **local: float | None) -> MeshData:
    """Seed 000 breast phantom with four side actuators (see module docstring). size in mm;
    ``local`` (``LOCAL_SIZES``): site_size, the cell size (mm) near each actuator site
    (``SITE_REACH``), e.g. a third of an indenter's radius; path_size, a finer size along each
    actuator's path into the tissue (``PATH_DEPTH``), where a tip pushed 10-15 mm crushes the
    tissue, within path_reach of its axis (default ``PATH_REACH``; a tip's contact radius at
    its deepest push at least); rim_size, the cell size at the rims of the actuator patches
    (``RIM_GRADING``), where a glued patch's pushed skin meets the free skin and the strain is
    singular; base_rim_size, the cell size at the base rim, where the fixed base meets the free
    dome (a clamped-free corner, singular under a sideways push)."""
    return _phantom(size, ACTUATORS_4, out, **local)


def phantom_half(size: float = 6.0, *, out=None, **local: float | None) -> MeshData:
    """The part y >= 0 of ``phantom``: its mirror plane is the region ``sym_y0``, and it keeps
    act_px, act_py and act_nx (the first and last cut in half) and T1..T4. With sliding on
    ``sym_y0`` it is the whole phantom under loads symmetric about y = 0 (A1 or A3 alone, or
    A2 with A4 equal), at about half the unknowns; forces on cut actuators are halves."""
    return _phantom(size, ACTUATORS_4, out, part="half", **local)


def phantom_quarter(size: float = 6.0, *, out=None, **local: float | None) -> MeshData:
    """The part x >= 0, y >= 0 of ``phantom``: mirror planes ``sym_y0`` and ``sym_x0``, halves
    of act_px and act_py, and T1..T3. With sliding on both planes it is the whole phantom under
    loads symmetric about both (A1 = A3 and A2 = A4, e.g. all four equal), at about a quarter
    of the unknowns."""
    return _phantom(size, ACTUATORS_4, out, part="quarter", **local)


def phantom_symmetric(size: float = 6.0, *, out=None, **local: float | None) -> MeshData:
    """The whole ``phantom`` meshed as ``phantom_quarter`` mirrored across x = 0 and then y = 0
    (``meshes.mirror``): the same regions and targets, and a mesh symmetric about both planes.
    Under loads symmetric about both (all four equal) its answer is the quarter's; under any
    other load nothing drifts sideways for want of a symmetric mesh (a gmsh mesh of the whole
    dome is not symmetric: at 5 mm its T1 drifts 0.003 mm). About four times the quarter's
    cells. out: also written there (.msh, second order)."""
    quarter = _phantom(size, ACTUATORS_4, None, part="quarter", **local)
    half = mirror(quarter, "sym_x0", 0, {"act_px": "act_nx", "T2": "T4"})
    whole = mirror(half, "sym_y0", 1, {"act_py": "act_ny", "T3": "T5"})
    if out is not None:
        write_mesh(whole, out, all_regions=True)
    return whole


def phantom3(size: float = 6.0, *, out=None, **local: float | None) -> MeshData:
    """Seed 000 phantom with three actuators 120 deg apart (minimal positive basis)."""
    return _phantom(size, ACTUATORS_3, out, **local)


def shell_octant(size: float = 2.5, *, inner: float = 10.0, outer: float = 20.0,
                 out=None) -> MeshData:
    """One octant (x, y, z >= 0) of a thick spherical shell, radii ``inner`` < ``outer`` (mm):
    the classic pressurized / inflated thick sphere, with closed-form (incompressible) and radial-
    ODE (compressible) answers. Facet regions: inner, outer, and the symmetry planes xsym (x = 0),
    ysym, zsym; cell group tissue."""
    if not (0 < inner < outer):
        raise CaseError(f"shell radii must satisfy 0 < inner < outer, got {inner!r}, {outer!r}")
    with builders_gmsh.gmsh_session("shell-octant", size) as gmsh:
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
        return finish(gmsh, 3, out, curved=True)

