"""Synthetic torso with a known muscle surface, and the tissue volume between skin and muscle
meshed with gmsh. Lengths in mm; body frame: x patient's left, y superior, z anterior.

Synthetic torso (for tests and the demo):

    muscle (chest wall): cylinder of radius R about the vertical axis through (0, y, -R),
        M(theta, y) = (R sin theta, y, R cos theta - R), outward normal n = (sin theta, 0, cos theta)
    skin: S = M + t(theta, y) n, an exact offset, so t is the true tissue thickness (the distance
        from a skin point to the muscle along n);
    t = t_base(arc) + breast(left) + breast(right), arc = R theta;
        t_base is linear in arc through (-arc_lat, A), (0, B), (+arc_lat, C), constant outside;
        breast(c) = height * (1 - (rho / radius)^2)^2 for rho < radius, rho the (arc, y) distance
        to the breast centre (+-arc_breast, y_breast).

The volume mesh: skin sheet, muscle sheet (same connectivity) and a side wall joining their
borders form a closed triangulated surface, handed to gmsh as discrete surfaces; gmsh's 3D
Delaunay fills it with tetrahedra. Facet regions ``skin``, ``muscle`` (the chest-wall interface)
and ``sides``; cell region ``tissue``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tissue_reference.errors import CaseError
from tissue_reference.meshes.builders import finish, gmsh_session
from tissue_reference.meshes.mesh import MeshData, check_cells

from .rbf import Thickness
from .surface import TriSurface, boundary_edges, check_single_sheet

__all__ = ["SyntheticTorso", "grid_triangles", "tissue_mesh"]


def grid_triangles(nu: int, nv: int) -> np.ndarray:
    """Triangles of a structured nu x nv vertex grid (row-major, index i * nv + j), alternating
    diagonals, counter-clockwise in (u, v)."""
    i, j = np.meshgrid(np.arange(nu - 1), np.arange(nv - 1), indexing="ij")
    i, j = i.ravel(), j.ravel()
    a, b, c, d = i * nv + j, (i + 1) * nv + j, (i + 1) * nv + j + 1, i * nv + j + 1
    flip = (i + j) % 2 == 1
    t1 = np.where(flip[:, None], np.column_stack([a, b, d]), np.column_stack([a, b, c]))
    t2 = np.where(flip[:, None], np.column_stack([b, c, d]), np.column_stack([a, c, d]))
    return np.concatenate([t1, t2])


@dataclass(frozen=True)
class SyntheticTorso:
    """Parametric chest wall with two breast mounds (all lengths mm).

    radius: chest-wall cylinder radius; half_width: half the arc length of the patch; half_height:
    half its vertical extent; A, B, C: true thickness at the right lateral, sternum and left
    lateral planes (arc -arc_lateral, 0, +arc_lateral); breasts centred at arc +-arc_breast,
    y = y_breast, with the given height (extra thickness) and radius; spacing: grid step.
    """

    radius: float = 250.0
    half_width: float = 190.0
    half_height: float = 140.0
    A: float = 16.0
    B: float = 12.0
    C: float = 16.0
    arc_lateral: float = 165.0
    arc_breast: float = 85.0
    y_breast: float = -25.0
    breast_height: float = 40.0
    breast_radius: float = 75.0
    spacing: float = 14.0

    def __post_init__(self):
        for k in ("radius", "half_width", "half_height", "A", "B", "C", "breast_radius",
                  "spacing", "arc_lateral", "arc_breast"):
            v = getattr(self, k)
            if not (np.isfinite(v) and v > 0):
                raise CaseError(f"SyntheticTorso.{k} must be > 0 mm, got {v!r}")
        if self.breast_height < 0:
            raise CaseError(f"SyntheticTorso.breast_height must be >= 0 mm, got {self.breast_height}")
        if self.half_width >= 0.5 * np.pi * self.radius:
            raise CaseError("SyntheticTorso.half_width must be below a quarter of the chest "
                            f"circumference ({0.5 * np.pi * self.radius:.0f} mm)")

    # --- parameters (arc, y) -> geometry
    def _grid(self):
        nu = int(np.ceil(2 * self.half_width / self.spacing)) + 1
        nv = int(np.ceil(2 * self.half_height / self.spacing)) + 1
        arc = np.linspace(-self.half_width, self.half_width, nu)
        y = np.linspace(-self.half_height, self.half_height, nv)
        A, Y = np.meshgrid(arc, y, indexing="ij")
        return A.ravel(), Y.ravel(), nu, nv

    def parameters(self):
        """(arc, y) in mm of every skin vertex (row-major grid)."""
        arc, y, _, _ = self._grid()
        return arc, y

    def base_thickness(self, arc) -> np.ndarray:
        return np.interp(arc, [-self.arc_lateral, 0.0, self.arc_lateral], [self.A, self.B, self.C])

    def breast(self, arc, y) -> np.ndarray:
        t = np.zeros(np.shape(arc))
        for s in (-1.0, 1.0):
            rho2 = ((arc - s * self.arc_breast) ** 2 + (y - self.y_breast) ** 2) / self.breast_radius ** 2
            t = t + self.breast_height * np.clip(1.0 - rho2, 0.0, None) ** 2
        return t

    def muscle_point(self, arc, y) -> np.ndarray:
        th = np.asarray(arc) / self.radius
        return np.column_stack([self.radius * np.sin(th), np.asarray(y) * np.ones_like(th),
                                self.radius * np.cos(th) - self.radius])

    def skin(self) -> TriSurface:
        """The skin sheet (triangles oriented with normals pointing anterior)."""
        arc, y, nu, nv = self._grid()
        th = arc / self.radius
        n = np.column_stack([np.sin(th), np.zeros_like(th), np.cos(th)])
        t = self.base_thickness(arc) + self.breast(arc, y)
        p = self.muscle_point(arc, y) + t[:, None] * n
        return TriSurface(p, grid_triangles(nu, nv))

    def true_breast_mask(self, arc_margin: float = 0.0) -> np.ndarray:
        arc, y, _, _ = self._grid()
        r = self.breast_radius + arc_margin
        return np.any([((arc - s * self.arc_breast) ** 2 + (y - self.y_breast) ** 2) < r ** 2
                       for s in (-1, 1)], axis=0)

    def thickness_estimates(self) -> Thickness:
        """The three estimates A, B, C at the x of the skin points of the lateral and sternum
        planes (exact, outside the breast mounds)."""
        x = [(self.radius + t) * np.sin(a / self.radius)
             for a, t in ((-self.arc_lateral, self.A), (0.0, self.B), (self.arc_lateral, self.C))]
        return Thickness(self.A, self.B, self.C, *x)

    def muscle_distance(self, points) -> np.ndarray:
        """Signed distance (mm) of points to the true muscle cylinder (> 0 in front of it)."""
        p = np.asarray(points, float)
        return np.hypot(p[:, 0], p[:, 2] + self.radius) - self.radius

    def muscle_normal(self, points) -> np.ndarray:
        """True outward muscle normal at the radial projection of the points."""
        p = np.asarray(points, float)
        v = np.column_stack([p[:, 0], np.zeros(len(p)), p[:, 2] + self.radius])
        return v / np.linalg.norm(v, axis=1, keepdims=True)

    def breast_centre(self, side: str) -> np.ndarray:
        """Muscle point under the breast centre on ``side`` ('left' = +x, 'right' = -x)."""
        s = 1.0 if side == "left" else -1.0
        return self.muscle_point(np.array([s * self.arc_breast]), np.array([self.y_breast]))[0]


def _side_triangles(tris: np.ndarray, n: int) -> np.ndarray:
    """Wall triangles joining the border of sheet ``tris`` (ids < n) to its copy (ids + n)."""
    be = boundary_edges(tris)
    if len(be) == 0:
        raise CaseError("skin sheet has no border; cannot close the tissue volume")
    a, b = be[:, 0], be[:, 1]
    return np.concatenate([np.column_stack([a, b, b + n]), np.column_stack([a, b + n, a + n])])


def tissue_mesh(skin: TriSurface, muscle: TriSurface, *, size: float | None = None,
                out=None) -> MeshData:
    """Tetrahedral mesh (gmsh) of the volume between the skin and muscle sheets (same
    connectivity). ``size`` (mm): target edge length inside (default: the skin's mean edge).

    Returns MeshData with facet regions ``skin``, ``muscle``, ``sides`` and cell region ``tissue``.
    """
    check_single_sheet(skin)
    if skin.points.shape != muscle.points.shape or not np.array_equal(skin.triangles,
                                                                       muscle.triangles):
        raise CaseError("skin and muscle sheets must share their triangles")
    n = skin.n_points
    tris = skin.triangles
    side = _side_triangles(tris, n)
    h = float(size) if size is not None else skin.mean_edge()
    pts = np.vstack([skin.points, muscle.points])
    with gmsh_session("tissue", h) as gmsh:
        surfs = [(1, "skin", tris), (2, "muscle", tris + n), (3, "sides", side)]
        for tag, _, _ in surfs:
            gmsh.model.addDiscreteEntity(2, tag)
        gmsh.model.mesh.addNodes(2, 1, np.arange(1, 2 * n + 1), pts.ravel())
        for tag, _, t in surfs:
            gmsh.model.mesh.addElementsByType(tag, 2, [], (t + 1).ravel())
        loop = gmsh.model.geo.addSurfaceLoop([1, 2, 3])
        vol = gmsh.model.geo.addVolume([loop])
        gmsh.model.geo.synchronize()
        for tag, name, _ in surfs:
            gmsh.model.addPhysicalGroup(2, [tag], 10 + tag)
            gmsh.model.setPhysicalName(2, 10 + tag, name)
        gmsh.model.addPhysicalGroup(3, [vol], 1)
        gmsh.model.setPhysicalName(3, 1, "tissue")
        try:
            mesh = finish(gmsh, 3, out)
        except Exception as exc:
            if isinstance(exc, CaseError):
                raise
            raise CaseError(f"gmsh could not mesh the tissue volume (skin/muscle sheets "
                            f"intersecting?): {exc}") from exc
    check_cells(mesh, source="tissue volume")
    return mesh
