"""A whole body's mesh from a symmetric part's: the part and its mirror image, joined on the
mirror plane.

A mesh built this way is exactly symmetric: every vertex, cell and region has its mirror image.
Under loads symmetric about the plane its solution is the part's with the plane sliding (the same
discrete problem), so nothing drifts across the plane for want of a symmetric mesh, and a solve
of the whole checks the part's sliding plane against an independent formulation.
"""
from __future__ import annotations

import numpy as np

from tissue_reference.errors import CaseError

from .mesh import MeshData

__all__ = ["mirror"]


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
    return MeshData(points, cells, facets, point_regions, cell_regions, edges, curved)
