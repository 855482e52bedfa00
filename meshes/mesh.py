"""The mesh as plain numpy arrays with named regions, and its geometric checks.

Lengths are in mm. Cells are linear tetrahedra (3D) or linear triangles (2D, plane strain).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .errors import CaseError, MeshQualityError

__all__ = ["MeshData", "MeshQuality", "boundary_facets", "cell_volumes", "quality"]


@dataclass(frozen=True)
class MeshData:
    """A simplex mesh with named regions.

    points: (n, gdim) vertex coordinates, mm.
    cells: (m, gdim + 1) vertex ids of tetrahedra (gdim 3) or triangles (gdim 2).
    facet_regions: name -> (k, gdim) vertex ids of boundary facets (triangles / edges).
    point_regions: name -> vertex ids (gmsh point physical groups, e.g. targets T1..T5).
    cell_regions: name -> cell ids.
    """

    points: np.ndarray
    cells: np.ndarray
    facet_regions: dict = field(default_factory=dict)
    point_regions: dict = field(default_factory=dict)
    cell_regions: dict = field(default_factory=dict)

    def __post_init__(self):
        pts = np.ascontiguousarray(self.points, dtype=np.float64)
        cells = np.ascontiguousarray(self.cells, dtype=np.int64)
        if pts.ndim != 2 or pts.shape[1] not in (2, 3):
            raise CaseError(f"points must be (n, 2) or (n, 3), got shape {pts.shape}")
        if cells.ndim != 2 or cells.shape[1] != pts.shape[1] + 1:
            raise CaseError(f"cells of shape {cells.shape} do not match {pts.shape[1]}D points "
                            f"(expected {pts.shape[1] + 1} vertices per cell)")
        if cells.size and (cells.min() < 0 or cells.max() >= len(pts)):
            raise CaseError(f"cell vertex ids out of range [0, {len(pts)})")
        object.__setattr__(self, "points", pts)
        object.__setattr__(self, "cells", cells)

    @property
    def gdim(self) -> int:
        return self.points.shape[1]

    @property
    def n_vertices(self) -> int:
        return len(self.points)

    @property
    def n_cells(self) -> int:
        return len(self.cells)

    @property
    def region_names(self) -> list[str]:
        return sorted({*self.facet_regions, *self.point_regions, *self.cell_regions})

    def region_vertices(self, name: str) -> np.ndarray:
        """Sorted vertex ids of a facet, point or cell region; CaseError listing names if unknown."""
        if name in self.facet_regions:
            return np.unique(self.facet_regions[name])
        if name in self.point_regions:
            return np.unique(self.point_regions[name])
        if name in self.cell_regions:
            return np.unique(self.cells[self.cell_regions[name]])
        raise CaseError(f"unknown region {name!r}; regions in this mesh: {self.region_names}")

    def facet_measures(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """(facets, areas): reference areas (mm^2, or lengths in 2D) of a facet region."""
        if name not in self.facet_regions:
            raise CaseError(f"{name!r} is not a boundary (facet) region; facet regions: "
                            f"{sorted(self.facet_regions)}")
        f = self.facet_regions[name]
        x = self.points[f]
        if self.gdim == 3:
            a = 0.5 * np.linalg.norm(np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0]), axis=1)
        else:
            a = np.linalg.norm(x[:, 1] - x[:, 0], axis=1)
        return f, a


def cell_volumes(points: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """Signed volumes (mm^3) of tetrahedra, or signed areas (mm^2) of triangles."""
    x = points[cells]
    d = x[:, 1:] - x[:, :1]
    if cells.shape[1] == 4:
        return np.linalg.det(d) / 6.0
    return 0.5 * (d[:, 0, 0] * d[:, 1, 1] - d[:, 0, 1] * d[:, 1, 0])


@dataclass(frozen=True)
class MeshQuality:
    n_vertices: int
    n_cells: int
    min_volume: float
    min_scaled_jacobian: float
    """Worst cell's volume over that of the equilateral cell with the same RMS edge length
    (1 for a regular simplex, 0 for a flat one)."""
    min_dihedral_deg: float


def quality(mesh: MeshData) -> MeshQuality:
    """Volume, normalized shape quality and smallest dihedral angle (3D) of the worst cells."""
    x = mesh.points[mesh.cells]
    vol = cell_volumes(mesh.points, mesh.cells)
    n = mesh.cells.shape[1]
    pairs = [(i, j) for i in range(n) for j in range(i + 1, n)]
    l2 = np.mean([np.sum((x[:, i] - x[:, j]) ** 2, axis=1) for i, j in pairs], axis=0)
    lrms = np.sqrt(l2)
    ideal = lrms ** 3 / (6 * np.sqrt(2)) if n == 4 else np.sqrt(3) / 4 * lrms ** 2
    sj = np.abs(vol) / np.where(ideal > 0, ideal, np.inf)
    if n == 4:
        faces = [(1, 2, 3), (0, 2, 3), (0, 1, 3), (0, 1, 2)]
        normals = [np.cross(x[:, b] - x[:, a], x[:, c] - x[:, a]) for a, b, c in faces]
        normals = [v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-300) for v in normals]
        # orient outward: face k is opposite vertex k
        for k, (a, _, _) in enumerate(faces):
            s = np.sign(np.sum(normals[k] * (x[:, a] - x[:, k]), axis=1))
            normals[k] = normals[k] * s[:, None]
        ang = [np.degrees(np.pi - np.arccos(np.clip(np.sum(normals[i] * normals[j], axis=1), -1, 1)))
               for i in range(4) for j in range(i + 1, 4)]
        mind = float(np.min(ang)) if len(vol) else 0.0
    else:
        mind = float("nan")
    return MeshQuality(mesh.n_vertices, mesh.n_cells, float(vol.min()) if len(vol) else 0.0,
                       float(sj.min()) if len(vol) else 0.0, mind)


def check_cells(mesh: MeshData, *, source: str = "mesh", rtol: float = 1e-12) -> None:
    """Raise MeshQualityError naming the count and first ids of inverted or zero-volume cells.
    A mesh that passed is remembered (MeshData is frozen): every Case built on it, e.g. by
    ``Case.with_pushes`` in a control loop, skips the volume computation."""
    key = (id(mesh.points), id(mesh.cells), rtol)
    if getattr(mesh, "_cells_checked", None) == key:
        return
    vol = cell_volumes(mesh.points, mesh.cells)
    scale = np.ptp(mesh.points, axis=0).max() ** mesh.gdim if mesh.n_vertices else 1.0
    bad = np.flatnonzero(vol <= rtol * scale)
    if bad.size:
        kinds = "inverted" if np.any(vol[bad] < -rtol * scale) else "zero-volume"
        raise MeshQualityError(
            f"{source}: {bad.size} inverted or zero-volume cells ({kinds}); first ids "
            f"{bad[:10].tolist()}, volumes {np.round(vol[bad[:3]], 6).tolist()}")
    try:
        object.__setattr__(mesh, "_cells_checked", key)
    except (AttributeError, TypeError):  # a mesh-like object without a __dict__
        pass


def boundary_facets(cells: np.ndarray) -> np.ndarray:
    """Facets (sorted vertex ids) that belong to exactly one cell."""
    n = cells.shape[1]
    faces = np.concatenate([np.delete(cells, k, axis=1) for k in range(n)])
    s = np.sort(faces, axis=1)
    uniq, counts = np.unique(s, axis=0, return_counts=True)
    return uniq[counts == 1]


def orient_cells(points: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """Return cells with positive signed volume (swaps two vertices of negative ones)."""
    cells = cells.copy()
    neg = cell_volumes(points, cells) < 0
    cells[neg, 0], cells[neg, 1] = cells[neg, 1], cells[neg, 0].copy()
    return cells
