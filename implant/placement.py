"""Implant placement on the muscle surface and seed 001's boundary conditions (section 2.3).

Lengths in mm. Step 1: the implant's ground-plane points are target points at their projection
onto the muscle along the implant axis (the ground-plane normal); the rest of the implant is
free; its new equilibrium is its definitive (rigid) shape. Step 2: the tissue's muscle-interface
points under the implant are target points at their projection (along the implant axis) onto
the deformed implant's upper surface; the other interface points are border points, except,
optionally, those within ``free_ring`` mm (seed: 30 mm) of the implant, which are free; the
patch's cut sides are border points; the skin is free. Optionally the target points switch to
sliding on the implant's upper surface once they have reached their targets.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from tissue_reference.errors import CaseError
from tissue_reference.meshes.mesh import MeshData, boundary_facets

from .library import ImplantSpec
from .surface import boundary_edges, closest_points, ray_hits, triangle_normals

__all__ = [
    "SIDES",
    "ImplantBC",
    "Placement",
    "TissueBC",
    "implant_ground_targets",
    "place_implant",
    "tissue_boundary_conditions",
]

SIDES = ("left", "right")


@dataclass(frozen=True)
class Placement:
    """Implant frame on the muscle: ``centre`` (3,) mm on the muscle surface; ``frame`` (3, 3)
    rows = world directions of the implant's local x (width), y (height), z (projection, the
    muscle's outward normal at the centre); ``side`` 'left' (+x) or 'right' (-x)."""

    centre: np.ndarray
    frame: np.ndarray
    side: str
    gap_mm: float = 0.0  # largest distance from the flat ground plane to the muscle (mm)

    @property
    def axis(self) -> np.ndarray:
        return self.frame[2]

    def to_world(self, local) -> np.ndarray:
        return np.asarray(local, float) @ self.frame + self.centre


def _muscle(tissue: MeshData):
    if "muscle" not in tissue.facet_regions:
        raise CaseError(f"tissue mesh has no 'muscle' facet region; regions: {tissue.region_names}")
    return tissue.facet_regions["muscle"]


def _default_centre(tissue: MeshData, side: str, mid_x: float) -> np.ndarray:
    """Muscle point under the thickest tissue on ``side``: the breast's deepest point."""
    mt = _muscle(tissue)
    skin_v = tissue.region_vertices("skin")
    xs = tissue.points[skin_v]
    on = (xs[:, 0] > mid_x) if side == "left" else (xs[:, 0] < mid_x)
    if not on.any():
        raise CaseError(f"no skin on the {side} side of x = {mid_x:.1f} mm")
    cp, d, _ = closest_points(xs[on], tissue.points, mt)
    return cp[int(np.argmax(d))]


def place_implant(tissue: MeshData, spec: ImplantSpec, *, side: str, at=None,
                  mid_x: float | None = None, margin: float = 10.0) -> Placement:
    """Place the implant on the muscle surface of ``tissue`` (facet region ``muscle``).

    side: 'left' (patient's left, x > mid_x) or 'right'. at: (x, y) mm, the implant centre seen
    from the front (projected along z onto the muscle); default: under the thickest tissue of
    that side. mid_x: the midline (default: middle of the muscle patch).

    Fit rules (CaseError before any solve): the centre lies on the chosen side; the base's rim,
    projected along the implant axis, lands on the muscle patch at least ``margin`` mm inside its
    border; the muscle curves away from the flat base by at most half the implant's projection.
    """
    if side not in SIDES:
        raise CaseError(f"unknown side {side!r}; sides: {list(SIDES)}")
    mt = _muscle(tissue)
    X = tissue.points
    mv = np.unique(mt)
    if mid_x is None:
        mid_x = 0.5 * (X[mv, 0].min() + X[mv, 0].max())
    if at is None:
        c = _default_centre(tissue, side, mid_x)
    else:
        at = np.asarray(at, float).reshape(-1)
        if at.shape != (2,) or not np.all(np.isfinite(at)):
            raise CaseError(f"implant position must be (x, y) in mm, got {at!r}")
        o = np.array([[at[0], at[1], 0.0]])
        t, hit = ray_hits(o, np.array([[0.0, 0.0, 1.0]]), X, mt)
        if not hit[0]:
            raise CaseError(f"implant position (x, y) = {at.tolist()} mm is outside the muscle patch")
        c = o[0] + t[0] * np.array([0.0, 0.0, 1.0])
    if (side == "left") != (c[0] > mid_x):
        raise CaseError(f"implant centre x = {c[0]:.1f} mm is not on the {side} side "
                        f"(midline x = {mid_x:.1f} mm; left is x > midline)")
    w, h, p = spec.dimensions()
    # ground-plane normal: area-weighted muscle normal within half the base width
    tri_c = X[mt].mean(axis=1)
    near = np.linalg.norm(tri_c - c, axis=1) < 0.5 * w
    if near.sum() < 3:
        near = np.argsort(np.linalg.norm(tri_c - c, axis=1))[:6]
    nrm = triangle_normals(X, mt[near], unit=False).sum(axis=0)
    skin_v = tissue.region_vertices("skin")
    ref = X[skin_v][np.argmin(np.linalg.norm(X[skin_v] - c, axis=1))] - c
    ez = nrm / np.linalg.norm(nrm)
    if ez @ ref < 0:
        ez = -ez
    ex = np.array([1.0, 0.0, 0.0]) - ez[0] * ez
    if np.linalg.norm(ex) < 1e-6:
        raise CaseError("muscle normal at the implant centre is lateral; cannot orient the implant")
    ex /= np.linalg.norm(ex)
    ey = np.cross(ez, ex)
    frame = np.vstack([ex, ey, ez])
    # rim of the base, projected along the axis onto the muscle
    a = np.linspace(0, 2 * np.pi, 48, endpoint=False)
    rim = c + np.column_stack([0.5 * w * np.cos(a), 0.5 * h * np.sin(a), np.zeros_like(a)]) @ frame
    t, hit = ray_hits(rim, np.broadcast_to(ez, rim.shape), X, mt)
    if not hit.all():
        raise CaseError(f"the {spec.shape} {spec.volume_cc:g} cc implant (base {w:.0f} x {h:.0f} mm) "
                        f"does not fit at {np.round(c, 1).tolist()} mm: its base reaches outside the "
                        f"muscle patch on {int((~hit).sum())} of 48 rim directions")
    landed = rim + t[:, None] * ez
    border = np.unique(boundary_edges(mt))
    dist = cKDTree(X[border]).query(landed)[0]
    if dist.min() < margin:
        raise CaseError(f"the {spec.shape} {spec.volume_cc:g} cc implant (base {w:.0f} x {h:.0f} mm) "
                        f"does not fit at {np.round(c, 1).tolist()} mm: its base comes within "
                        f"{dist.min():.1f} mm of the muscle patch border (needs {margin:g} mm)")
    gap = float(np.abs(t).max())
    if gap > 0.5 * p:
        raise CaseError(f"the {spec.shape} {spec.volume_cc:g} cc implant does not fit at "
                        f"{np.round(c, 1).tolist()} mm: the muscle curves {gap:.1f} mm away from its "
                        f"flat base, more than half its projection ({p:.1f} mm)")
    return Placement(c, frame, side, gap)


@dataclass(frozen=True)
class ImplantBC:
    """Step 1: implant mesh in world coordinates, ground-plane vertex ids and their targets (mm)."""

    points: np.ndarray
    cells: np.ndarray
    base: np.ndarray
    targets: np.ndarray
    shell: np.ndarray  # (k, 3) upper-surface triangles


def implant_ground_targets(implant: MeshData, placement: Placement, tissue: MeshData) -> ImplantBC:
    """Step 1 boundary conditions: ground-plane points -> muscle, along the implant axis."""
    pts = placement.to_world(implant.points)
    base = implant.region_vertices("base")
    ax = placement.axis
    t, hit = ray_hits(pts[base], np.broadcast_to(ax, (len(base), 3)), tissue.points,
                      _muscle(tissue))
    if not hit.all():
        raise CaseError(f"{int((~hit).sum())} implant ground-plane points project outside the "
                        "muscle patch")
    shell = implant.facet_regions.get("shell")
    if shell is None:
        bf = boundary_facets(implant.cells)
        shell = bf[~np.all(np.isin(bf, base), axis=1)]
    return ImplantBC(pts, implant.cells, base, pts[base] + t[:, None] * ax, shell)


@dataclass(frozen=True)
class TissueBC:
    """Step 2 point types on the tissue mesh (vertex ids in its numbering).

    target: ids and their positions (mm) on the implant's upper surface; border: fixed ids;
    free_ring: interface ids released by the free ring; labels (n,) 'free' | 'border' | 'target'.
    """

    target: np.ndarray
    target_positions: np.ndarray
    border: np.ndarray
    free_ring: np.ndarray
    labels: np.ndarray
    contact_facets: np.ndarray
    extra: dict = field(default_factory=dict)

    @property
    def target_displacements(self) -> np.ndarray:
        """(k, 3) mm: target positions minus the reference positions."""
        return self.target_positions - self.extra["X"][self.target]


def tissue_boundary_conditions(tissue: MeshData, implant_points: np.ndarray, shell: np.ndarray,
                               placement: Placement, *, free_ring: float | None = 30.0,
                               fix_sides: bool = True) -> TissueBC:
    """Step 2 (seed 001 sec. 2.3): interface points under the (deformed) implant -> targets on
    its upper surface along the implant axis; other interface points border, except those within
    ``free_ring`` mm of a target point (None or 0: no ring); sides border if ``fix_sides``."""
    if free_ring is not None and not (np.isfinite(free_ring) and free_ring >= 0):
        raise CaseError(f"free ring must be >= 0 mm, got {free_ring!r}")
    X = tissue.points
    mt = _muscle(tissue)
    mv = np.unique(mt)
    ax = placement.axis
    t, hit = ray_hits(X[mv], np.broadcast_to(ax, (len(mv), 3)), implant_points, shell)
    under = hit & (t > -1e-6)
    if under.sum() < 3:
        raise CaseError("fewer than 3 interface points lie under the implant; the tissue mesh is "
                        "too coarse for this implant or the implant is misplaced")
    target = mv[under]
    pos = X[target] + t[under, None] * ax
    rest = mv[~under]
    ring = np.empty(0, np.int64)
    if free_ring:
        d = cKDTree(X[target]).query(X[rest])[0]
        ring = rest[d <= free_ring]
    border = np.setdiff1d(rest, ring)
    if fix_sides and "sides" in tissue.facet_regions:
        border = np.union1d(border, np.setdiff1d(tissue.region_vertices("sides"), target))
        ring = np.setdiff1d(ring, border)
    labels = np.array(["free"] * tissue.n_vertices, dtype=object)
    labels[border] = "border"
    labels[target] = "target"
    contact = mt[np.all(np.isin(mt, target), axis=1)]
    return TissueBC(target, pos, border, ring, labels, contact, {"X": X})
