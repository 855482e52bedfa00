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

``phantom-half`` and ``phantom-quarter`` are its parts y >= 0 and x >= 0, y >= 0, with the mirror
planes as regions ``sym_y0`` and ``sym_x0`` (patches on a plane cut in half; the targets on the
part): with sliding planes they stand for the whole phantom under symmetric loads at a half or a
quarter of the unknowns (meshes/cases/phantom-indenter-half.toml, -quarter.toml).
``phantom-symmetric`` is the whole phantom meshed as the quarter and its mirror images
(``meshes.mirror``): the regions of ``phantom`` on a mesh symmetric about x = 0 and y = 0.

``box`` is an axis-aligned block with faces ``xmin``, ``xmax``, ``ymin``, ``ymax``, ``zmin``,
``zmax``; ``rectangle`` is its 2D (plane strain) analogue with edges ``xmin`` .. ``ymax``.

Where each builder lives: ``meshes.builders_curved`` (``phantom``, ``phantom3``,
``shell_octant``, ``phantom_symmetric``: second-order curved bodies),
``meshes.builders_blocks`` (``box``, ``rectangle``, ``cook_membrane``, ``indent_block``;
``structured_box``, a gmsh-free block)
and ``meshes.builders_gmsh`` (the gmsh session they share). This module names them
(``BUILDERS``), estimates a build's cell count (``estimate_cells``, ``check_cell_budget``) and
builds by name (``build``); every builder is importable from here.
"""
from __future__ import annotations

import math

import numpy as np

from tissue_reference.errors import CaseError

from .builders_blocks import (
    INDENT_BLOCK,
    IndentBlock,
    box,
    cook_membrane,
    indent_block,
    rectangle,
    structured_box,
)
from .builders_curved import (  # noqa: F401  (re-exported)
    ACTUATORS_3,
    ACTUATORS_4,
    LOCAL_SIZES,
    PATH_DEPTH,
    PATH_REACH,
    PHANTOM,
    RIM_GRADING,
    SITE_REACH,
    PhantomGeometry,
    check_local_sizes,
    phantom,
    phantom3,
    phantom_half,
    phantom_quarter,
    phantom_symmetric,
    shell_octant,
)
from .builders_gmsh import GMSH_STATE, finish, gmsh_session  # noqa: F401  (re-exported)
from .mesh import MeshData
from .mesh_cache import cached
from .projection import DomeProjection, ShellProjection

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
    "phantom_half",
    "phantom_quarter",
    "phantom_symmetric",
    "rectangle",
    "structured_box",
]


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


BUILDERS = {"phantom": phantom, "phantom-half": phantom_half, "phantom-quarter": phantom_quarter,
            "phantom-symmetric": phantom_symmetric, "phantom-3": phantom3, "box": box,
            "rectangle": rectangle,
            "shell-octant": shell_octant, "indent-block": indent_block}
_SHIPPED = dict(BUILDERS)   # the builders whose meshes the disk cache may keep (not stand-ins)


# Volume (mm^3; area in mm^2 for the 2D rectangle) of each builder's body at its default
# dimensions, for the cell-count estimate.
BODY_VOLUMES = {
    "phantom": 2.0 / 3.0 * math.pi * PHANTOM.radius ** 2 * PHANTOM.height,
    "phantom-half": 1.0 / 3.0 * math.pi * PHANTOM.radius ** 2 * PHANTOM.height,
    "phantom-quarter": 1.0 / 6.0 * math.pi * PHANTOM.radius ** 2 * PHANTOM.height,
    "phantom-symmetric": 2.0 / 3.0 * math.pi * PHANTOM.radius ** 2 * PHANTOM.height,
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


def estimate_cells(name: str, size: float, *, site_size: float | None = None,
                   path_size: float | None = None, rim_size: float | None = None,
                   base_rim_size: float | None = None,
                   path_reach: float | None = None) -> int | None:
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
            n_sites = SITES[name]
            half = 2.0 / 3.0 * math.pi * SITE_REACH ** 3
            shell = 7.0 * half
            mid = (site_size + size) / 2.0
            local = n_sites * (half / site_size ** 3 + shell / mid ** 3)
            est += CELLS_PER_VOLUME[d] * min(local, BODY_VOLUMES[name] / site_size ** 3)
            if path_size is not None and path_size < site_size:
                # each path: a tube of cells of path_size in place of site_size; the size
                # field's grading and gmsh's own gradation widen it by about PATH_REACH
                # (fitted to builds of the quarter and whole phantoms, sites 3.2 and 2.26 mm,
                # paths half of them, the default reach: 9.5-10.0e3 mm^3 per path; a 10 mm
                # reach on the half phantom at size 8: 20 % over)
                tube = math.pi * ((path_reach or PATH_REACH) + PATH_REACH) ** 2 * PATH_DEPTH
                path = n_sites * tube * (1.0 / path_size ** 3 - 1.0 / site_size ** 3)
                est += CELLS_PER_VOLUME[d] * min(path, BODY_VOLUMES[name] / path_size ** 3)
        if rim_size is not None and name in SITE_BUILDERS and rim_size < size:
            est += CELLS_PER_VOLUME[d] * SITES[name] * _rim_cells(
                rim_size, size, 2.0 * math.pi * PHANTOM.patch_radius, math.pi, 1.2)
        if base_rim_size is not None and name in SITE_BUILDERS and base_rim_size < size:
            est += CELLS_PER_VOLUME[d] * _rim_cells(
                base_rim_size, size, 2.0 * math.pi * PHANTOM.radius * BASE_RIM[name],
                0.5 * math.pi, 1.0)
    return int(min(est, 1e18)) if math.isfinite(est) else 10 ** 18


def _rim_cells(rim: float, coarse: float, length: float, angle: float, fit: float) -> float:
    """Extra cells (in units of CELLS_PER_VOLUME) around a rim of ``length`` mm refined to
    ``rim``: a wedge of the tube along it (``angle``: pi for a patch rim on the skin, pi / 2
    for the base rim's right-angled corner) whose cells grow from ``rim`` at distance ``rim``
    by RIM_GRADING to ``coarse``, less the coarse cells it replaces: the integral of
    angle r L (1 / h(r)^3 - 1 / coarse^3) dr, times ``fit``. Patch rims: 1.2, gmsh's own
    gradation (builds of the quarter and whole phantoms at size 6, rims 0.6-1.6 mm: 1.15-1.38
    times the integral). Base rim: 1.0 (builds of the half and quarter phantoms at sizes 6-12
    mm, rims 1.5-3.2 mm: 0.94-1.07 times the integral; with finer sites, which already cover
    part of the rim, 0.57-0.79: an over-estimate, on the safe side of a budget)."""
    far = rim + (coarse - rim) / RIM_GRADING
    r = np.linspace(0.0, far, 2001)
    h = np.where(r < rim, rim, rim + RIM_GRADING * (r - rim))
    return fit * float(np.trapz(angle * r * length * (1.0 / h ** 3 - 1.0 / coarse ** 3), r))


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


SITES = {"phantom": 4, "phantom-half": 2, "phantom-quarter": 1, "phantom-symmetric": 4,
         "phantom-3": 3}
"""Actuator sites of each builder that takes ``site_size`` (in whole-site equivalents: a half
site on a mirror plane counts a half)."""
BASE_RIM = {"phantom": 1.0, "phantom-half": 0.5, "phantom-quarter": 0.25,
            "phantom-symmetric": 1.0, "phantom-3": 1.0}
"""The part of the base rim's circle each phantom builder keeps."""
SITE_BUILDERS = tuple(SITES)
"""The builders that take ``site_size`` (finer cells at the actuator sites)."""


def build(name: str, size: float, *, out=None, max_cells: int | None = MAX_CELLS,
          site_size: float | None = None, path_size: float | None = None,
          rim_size: float | None = None, base_rim_size: float | None = None,
          path_reach: float | None = None) -> MeshData:
    """Build a named mesh (see ``BUILDERS``) with characteristic length ``size`` (mm).

    max_cells: refuse (CaseError with the estimate, before gmsh starts) a mesh whose estimated
    cell count (``estimate_cells``) exceeds it; None: no limit. site_size: finer cells at the
    actuator sites (``SITE_BUILDERS`` only); path_size: finer still along each actuator's path
    into the tissue (with a site_size), within path_reach (mm) of its axis; rim_size: finer
    cells at the rims of the actuator patches (``SITE_BUILDERS`` only), where glued patches are
    singular; base_rim_size: finer cells at the base rim (``SITE_BUILDERS`` only), where the
    fixed base meets the free dome."""
    if name not in BUILDERS:
        raise CaseError(f"unknown mesh builder {name!r}; builders: {sorted(BUILDERS)}")
    if site_size is None and path_size is not None:
        raise CaseError(f"path_size {path_size!r} mm refines within the actuator sites: give a "
                        f"site_size too")
    local = {k: v for k, v in (("site_size", site_size), ("path_size", path_size),
                               ("path_reach", path_reach), ("rim_size", rim_size),
                               ("base_rim_size", base_rim_size)) if v is not None}
    check_local_sizes(local)
    if not local:
        check_cell_budget(name, size, max_cells)
        return _built(name, size, local, out)
    if name not in SITE_BUILDERS:
        raise CaseError(f"{next(iter(local))} applies to the builders {list(SITE_BUILDERS)}, "
                        f"not {name!r}")
    est = estimate_cells(name, size, **local)
    if max_cells is not None and est > max_cells:
        sizes = ", ".join(f"{k} {v:g} mm" for k, v in local.items())
        raise CaseError(f"builtin mesh {name!r} at size {size:g} mm, {sizes}: about {est:,} "
                        f"cells (estimate), more than the limit {max_cells:,}")
    return _built(name, size, local, out)


def _built(name, size, local, out):
    """The mesh from its builder; from the disk cache (``meshes.mesh_cache``) when no file is
    asked for and the builder is the shipped one (a stand-in, e.g. a test's, is not cached)."""
    builder = BUILDERS[name]
    if out is not None or builder is not _SHIPPED.get(name):
        return builder(size, out=out, **local)
    return cached(name, size, local, lambda: builder(size, **local))


def projector_for(builder: str):
    """The boundary projection of a builtin mesh (``BUILDERS``): a
    DomeProjection for the phantoms (whole, parts, symmetric, three actuators), a
    ShellProjection for ``shell-octant``, None for the flat ``box`` and ``rectangle``."""
    if builder not in BUILDERS:
        raise CaseError(f"unknown mesh builder {builder!r}; builders: {sorted(BUILDERS)}")
    if builder == "shell-octant":
        return ShellProjection()
    patches = {"phantom": ACTUATORS_4, "phantom-half": ACTUATORS_4,
               "phantom-quarter": ACTUATORS_4, "phantom-symmetric": ACTUATORS_4,
               "phantom-3": ACTUATORS_3}.get(builder)
    if patches is None:
        return None
    g = PHANTOM
    return DomeProjection(g.radius, g.height, g.actuator_height, g.patch_radius, tuple(patches))
