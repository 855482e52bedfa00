"""A whole body's mesh from a symmetric part's: the part and its mirror image, joined on the
mirror plane.

A mesh built this way is exactly symmetric: every vertex, cell and region has its mirror image.
Under loads symmetric about the plane its solution is the part's with the plane sliding (the same
discrete problem), so nothing drifts across the plane for want of a symmetric mesh, and a solve
of the whole checks the part's sliding plane against an independent formulation.

The joined mesh records each join (``MirrorRecord`` in ``MeshData.mirrored``): the plane, its
axis, the region renames and the part's size. The part is the joined mesh's first vertices and
cells, so ``mirror_part`` gives it back (with its plane as a facet region again) and the image of
each of its vertices; ``model.symmetry`` reduces a solve of a symmetric load to it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tissue_reference.errors import CaseError

from .mesh import MeshData, boundary_facets

__all__ = ["MirrorPart", "MirrorRecord", "mirror", "mirror_part"]


@dataclass(frozen=True)
class MirrorRecord:
    """One join of ``mirror``: the plane region ``plane`` (dropped from the joined mesh) at
    ``x[axis] = 0``, the region renames (pairs: a region of the part, the name of its image),
    and the part's vertex and cell counts (the joined mesh's first ones are the part's)."""

    plane: str
    axis: int
    renames: tuple
    n_vertices: int
    n_cells: int

    def twin(self, region: str) -> str:
        """The name of ``region``'s mirror image (itself for a region that kept its name)."""
        for a, b in self.renames:
            if region == a:
                return b
            if region == b:
                return a
        return region

    def to_json(self) -> list:
        return [self.plane, self.axis, [list(r) for r in self.renames], self.n_vertices,
                self.n_cells]

    @classmethod
    def from_json(cls, data) -> MirrorRecord:
        plane, axis, renames, nv, nc = data
        return cls(str(plane), int(axis), tuple((str(a), str(b)) for a, b in renames), int(nv),
                   int(nc))


@dataclass(frozen=True)
class MirrorPart:
    """The part a joined mesh was mirrored from (``mirror_part``): ``mesh`` (with its plane
    region and the earlier joins' records), the join's ``record``, and ``image``: for each of
    the part's vertices, the joined mesh's vertex that is its mirror image (itself on the
    plane)."""

    mesh: MeshData
    record: MirrorRecord
    image: np.ndarray


def mirror_part(mesh: MeshData) -> MirrorPart | None:
    """The part of the last join that made ``mesh`` (``MeshData.mirrored``), or None when the
    mesh records none or is not that join's mirror image (then it was changed since). Kept on
    the mesh: the same part (the same object) on every call, so solvers kept per mesh are
    reused."""
    if not mesh.mirrored:
        return None
    memo = mesh.__dict__.get("_mirror_part")
    if memo is None:
        memo = mesh.__dict__.setdefault("_mirror_part", [_part_of(mesh)])
    return memo[0]


def _part_of(mesh: MeshData) -> MirrorPart | None:
    rec = mesh.mirrored[0]
    n, m, axis = rec.n_vertices, rec.n_cells, rec.axis
    x = mesh.points
    if not (0 < n <= mesh.n_vertices and 0 < m and 2 * m == mesh.n_cells):
        return None
    on = np.flatnonzero(x[:n, axis] == 0.0)
    rest = np.setdiff1d(np.arange(n), on)
    if n + rest.size != mesh.n_vertices:
        return None
    image = np.empty(n, dtype=np.int64)
    image[on] = on
    image[rest] = n + np.arange(rest.size)
    mirrored = x[rest].copy()
    mirrored[:, axis] *= -1.0
    part_cells = mesh.cells[:m]
    flipped = image[part_cells]
    flipped[:, [0, 1]] = flipped[:, [1, 0]]
    if not (np.array_equal(x[n:], mirrored) and np.array_equal(mesh.cells[m:], flipped)
            and part_cells.max(initial=-1) < n):
        return None
    facets = {k: f[np.all(f < n, axis=1)] for k, f in mesh.facet_regions.items()}
    outer = boundary_facets(part_cells)
    facets[rec.plane] = outer[np.all(x[outer, axis] == 0.0, axis=1)]
    facets = {k: f for k, f in facets.items() if len(f)}
    points = {k: ids[ids < n] for k, ids in mesh.point_regions.items()}
    cells = {k: ids[ids < m] for k, ids in mesh.cell_regions.items()}
    edges = curved = None
    if mesh.geometry_order == 2:
        keep = np.all(mesh.curved_edges < n, axis=1)
        edges, curved = mesh.curved_edges[keep], mesh.curved_points[keep]
    part = MeshData(x[:n], part_cells, facets, {k: v for k, v in points.items() if len(v)},
                    {k: v for k, v in cells.items() if len(v)}, edges, curved,
                    mirrored=mesh.mirrored[1:])
    return MirrorPart(part, rec, image)


def mirror(mesh: MeshData, plane: str, axis: int, renames: dict[str, str] | None = None,
           *, rtol: float = 1e-9) -> MeshData:
    """The mesh joined with its mirror image across the plane ``x[axis] = 0``.

    plane: the facet region on that plane (it becomes interior and is dropped; its vertices are
    shared by both halves and snapped onto the plane). renames: region name -> the name of its
    mirror image (e.g. a patch on the +x side -> its twin on the -x side); a region not named
    keeps its name, and its image joins it. Curved (second-order) edges are mirrored with their
    nodes. CaseError when the plane region is missing, when a vertex lies on the plane but not
    in that region, or when the mesh reaches across the plane.
    """
    renames = dict(renames or {})
    if plane not in mesh.facet_regions:
        raise CaseError(f"mirror plane {plane!r} is not a facet region; facet regions: "
                        f"{sorted(mesh.facet_regions)}")
    x = mesh.points
    n, m = mesh.n_vertices, mesh.n_cells
    tol = rtol * float(np.ptp(x, axis=0).max())
    on = np.unique(mesh.facet_regions[plane])
    off = np.abs(x[on, axis]) > tol
    if off.any():
        raise CaseError(f"mirror plane {plane!r}: {int(off.sum())} of its vertices are off the "
                        f"plane x[{axis}] = 0 (e.g. at {x[on[off][0]].tolist()} mm)")
    side = np.sign(np.median(x[:, axis]))
    if np.any(x[:, axis] * side < -tol):
        raise CaseError(f"mirror plane {plane!r}: the mesh reaches across x[{axis}] = 0")
    stray = np.setdiff1d(np.flatnonzero(np.abs(x[:, axis]) <= tol), on)
    if stray.size:
        raise CaseError(f"mirror plane {plane!r}: {stray.size} vertices lie on the plane but not "
                        f"on its facets (e.g. at {x[stray[0]].tolist()} mm)")

    # the image's vertex ids: a plane vertex is its own image, every other one is new
    image = np.full(n, -1, dtype=np.int64)
    image[on] = on
    rest = np.setdiff1d(np.arange(n), on)
    image[rest] = n + np.arange(rest.size)
    pts = x.copy()
    pts[on, axis] = 0.0
    mirrored = pts[rest].copy()
    mirrored[:, axis] *= -1.0
    points = np.vstack([pts, mirrored])

    def flipped(ids: np.ndarray) -> np.ndarray:
        """The image of cells or facets, two vertices swapped to keep their orientation."""
        out = image[ids]
        out[:, [0, 1]] = out[:, [1, 0]]
        return out

    cells = np.vstack([mesh.cells, flipped(mesh.cells)])

    def joined(regions: dict, image_of) -> dict:
        out = {name: [ids] for name, ids in regions.items() if name != plane}
        for name, ids in regions.items():
            if name != plane:
                out.setdefault(renames.get(name, name), []).append(image_of(ids))
        return out

    facets = {k: np.vstack(v) for k, v in joined(mesh.facet_regions, flipped).items()}
    point_regions = {k: np.unique(np.concatenate(v))
                     for k, v in joined(mesh.point_regions, lambda ids: image[ids]).items()}
    cell_regions = {k: np.concatenate(v)
                    for k, v in joined(mesh.cell_regions, lambda ids: ids + m).items()}
    edges = curved = None
    if mesh.geometry_order == 2:
        img_edges = image[mesh.curved_edges]
        img_nodes = mesh.curved_points.copy()
        img_nodes[:, axis] *= -1.0
        edges = np.vstack([mesh.curved_edges, img_edges])
        curved = np.vstack([mesh.curved_points, img_nodes])
        # an edge in the plane is its own image: keep one copy
        _, first = np.unique(np.sort(edges, axis=1), axis=0, return_index=True)
        first = np.sort(first)
        edges, curved = edges[first], curved[first]
    record = MirrorRecord(plane, int(axis), tuple(sorted(renames.items())), n, m)
    return MeshData(points, cells, facets, point_regions, cell_regions, edges, curved,
                    mirrored=(record, *mesh.mirrored))
