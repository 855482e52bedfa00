"""The mesh as plain numpy arrays with named regions, and its geometric checks.

Lengths are in mm. Cells are linear tetrahedra (3D) or linear triangles (2D, plane strain).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
import scipy.sparse as sp

from tissue_reference.errors import CaseError, MeshQualityError

__all__ = ["EdgeTopology", "MeshData", "MeshQuality", "boundary_facets", "cell_jacobians",
           "cell_pairs", "cell_volumes", "check_cell_ids", "check_cells", "check_tangles",
           "deformation_state", "edge_topology", "quality"]


@dataclass(frozen=True)
class MeshData:
    """A simplex mesh with named regions. Its points and cells are read-only copies.

    points: (n, gdim) vertex coordinates, mm.
    cells: (m, gdim + 1) vertex ids of tetrahedra (gdim 3) or triangles (gdim 2).
    facet_regions: name -> (k, gdim) vertex ids of boundary facets (triangles / edges).
    point_regions: name -> vertex ids (gmsh point physical groups, e.g. targets T1..T5).
    cell_regions: name -> cell ids.
    curved_edges, curved_points: optional second-order geometry (see meshes.curved): the edges
        (k, 2 vertex ids) whose mid-edge node lies off the straight midpoint, and those nodes'
        coordinates (k, gdim) on the true curved boundary. The linear cells stay the mesh every
        solver uses; the reference builds isoparametric cells from them at degree >= 2.
    mirrored: how the mesh was joined from a symmetric part and its mirror images
        (``meshes.mirror.MirrorRecord``s, the last join first; () for any other mesh): the part
        is this mesh's first vertices and cells, so a solve of a symmetric load can be reduced
        to it (``model.symmetry``). A mesh derived from this one by refinement or another
        change of its vertices or cells is built without them.
    """

    points: np.ndarray
    cells: np.ndarray
    facet_regions: dict = field(default_factory=dict)
    point_regions: dict = field(default_factory=dict)
    cell_regions: dict = field(default_factory=dict)
    curved_edges: np.ndarray | None = None
    curved_points: np.ndarray | None = None
    mirrored: tuple = ()

    def __post_init__(self):
        object.__setattr__(self, "mirrored", tuple(self.mirrored or ()))
        pts = np.ascontiguousarray(self.points, dtype=np.float64)
        cells = np.ascontiguousarray(self.cells, dtype=np.int64)
        if pts.ndim != 2 or pts.shape[1] not in (2, 3):
            raise CaseError(f"points must be (n, 2) or (n, 3), got shape {pts.shape}")
        if cells.ndim != 2 or cells.shape[1] != pts.shape[1] + 1:
            raise CaseError(f"cells of shape {cells.shape} do not match {pts.shape[1]}D points "
                            f"(expected {pts.shape[1] + 1} vertices per cell)")
        check_cell_ids(cells, len(pts))
        # the mesh's own read-only arrays (what is derived from them is kept: edge_topology,
        # reference_volumes): a caller's array changed later does not change the mesh
        for name, a in (("points", pts), ("cells", cells)):
            if a.flags.writeable or a.base is not None:
                a = a.copy()
            a.setflags(write=False)
            object.__setattr__(self, name, a)

    @property
    def gdim(self) -> int:
        return self.points.shape[1]

    @property
    def geometry_order(self) -> int:
        """2 when the mesh carries curved (second-order) edge nodes, else 1."""
        return 2 if self.curved_edges is not None and len(self.curved_edges) else 1

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

    @cached_property
    def edge_topology(self) -> EdgeTopology:
        """The mesh's ``EdgeTopology``, computed on first use and kept (the cells of a MeshData
        are not to be changed in place)."""
        return edge_topology(self.cells, self.n_vertices)

    @cached_property
    def reference_volumes(self) -> np.ndarray:
        """``cell_volumes`` of the undeformed mesh (mm^3, mm^2 in 2D), computed on first use and
        kept (the points of a MeshData are not to be changed in place)."""
        return cell_volumes(self.points, self.cells)

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
    if cells.shape[1] == 4:   # (d0 x d1) . d2 / 6 written out: cheaper than np.linalg.det
        a, b, c = d[:, 0], d[:, 1], d[:, 2]
        return ((a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]) * c[:, 0]
                + (a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]) * c[:, 1]
                + (a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]) * c[:, 2]) / 6.0
    return 0.5 * (d[:, 0, 0] * d[:, 1, 1] - d[:, 0, 1] * d[:, 1, 0])


@dataclass(frozen=True)
class EdgeTopology:
    """The edges of a simplex mesh, where each cell's vertex pairs lie among them, and the
    pattern of the vertex adjacency (every vertex with itself and with each neighbour) as the
    CSR matrix of d x d blocks on node-major dofs (dof = d*i + c) that P1 vector fields use:
    all from the cells alone, computed once per mesh as a finite element code computes its dof
    map and sparsity pattern once.

    edges (e, 2): vertex ids, ``edges[:, 0] < edges[:, 1]``, rows sorted.
    pair_edge (m * p,): the edge of cell c's k-th vertex pair (``cell_pairs``), at c * p + k.
    pair_flipped (m * p,): whether that pair's first vertex is its edge's second.
    indptr (n d + 1,), indices: the CSR pattern; gather: the position, in the stacked blocks
    [vertex blocks (n, d, d); edge blocks (i, j) (e, d, d); their transposes (j, i)] read flat,
    of each CSR entry (``block_csr``)."""

    edges: np.ndarray
    pair_edge: np.ndarray
    pair_flipped: np.ndarray
    indptr: np.ndarray
    indices: np.ndarray
    gather: np.ndarray

    def block_csr(self, T_ii, T_ij) -> sp.csr_matrix:
        """The CSR matrix (n d, n d) with vertex blocks T_ii (n, d, d) on the diagonal, edge
        blocks T_ij (e, d, d) at (i, j) and their transposes at (j, i)."""
        n, d = T_ii.shape[0], T_ii.shape[1]
        data = np.concatenate([T_ii.reshape(-1), T_ij.reshape(-1),
                               np.transpose(T_ij, (0, 2, 1)).reshape(-1)])[self.gather]
        return sp.csr_matrix((data, self.indices, self.indptr), shape=(n * d, n * d))


def check_cell_ids(cells: np.ndarray, n_vertices: int) -> None:
    """CaseError naming the first cell with a vertex id outside [0, n_vertices)."""
    out = (cells < 0) | (cells >= n_vertices)
    if out.any():
        c = int(np.flatnonzero(out.any(axis=1))[0])
        raise CaseError(f"cell vertex ids out of range [0, {n_vertices}): cell {c} has "
                        f"{cells[c][out[c]].tolist()} (its vertices {cells[c].tolist()})")


def cell_pairs(d: int) -> tuple[np.ndarray, np.ndarray]:
    """The vertex pairs (a[k], b[k]), a < b, of a d-simplex's local vertices, in
    ``EdgeTopology.pair_edge``'s order."""
    return np.triu_indices(d + 1, 1)


def edge_topology(cells: np.ndarray, n_vertices: int) -> EdgeTopology:
    """The ``EdgeTopology`` of simplices ``cells`` (m, d+1) on ``n_vertices`` vertices."""
    cells = np.asarray(cells, np.int64)
    n, d = int(n_vertices), cells.shape[1] - 1
    check_cell_ids(cells, n)
    a, b = cell_pairs(d)
    i, j = cells[:, a].reshape(-1), cells[:, b].reshape(-1)
    key, pair_edge = np.unique(np.minimum(i, j) * n + np.maximum(i, j), return_inverse=True)
    edges = np.stack([key // n, key % n], axis=1)
    rows = np.concatenate([np.arange(n), edges[:, 0], edges[:, 1]])
    cols = np.concatenate([np.arange(n), edges[:, 1], edges[:, 0]])
    order = np.argsort(rows * n + cols)
    block_indptr = np.r_[0, np.cumsum(np.bincount(rows, minlength=n))]
    # the flat positions of the stacked blocks, laid out as CSR by scipy's BSR -> CSR
    pos = (order[:, None] * (d * d) + np.arange(d * d)).reshape(-1, d, d).astype(float)
    csr = sp.bsr_matrix((pos, cols[order], block_indptr), shape=(n * d, n * d)).tocsr()
    return EdgeTopology(edges=edges, pair_edge=pair_edge, pair_flipped=i > j,
                        indptr=csr.indptr, indices=csr.indices,
                        gather=csr.data.astype(np.int64))


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
        worst = int(bad[np.argmin(vol[bad])])
        raise MeshQualityError(
            f"{source}: {bad.size} inverted or zero-volume cells ({kinds}); first ids "
            f"{bad[:10].tolist()}, volumes {np.round(vol[bad[:3]], 6).tolist()}; worst cell "
            f"{worst} at {_at(mesh.points[mesh.cells[worst]].mean(axis=0))} mm, volume "
            f"{vol[worst]:.3g} mm^{mesh.gdim}")
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


# --------------------------------------------------------------------------- tangled meshes
DEGENERATE_RTOL = 1e-12
"""A cell whose |volume| is at most this fraction of the cube of the bounding box's largest side
(the square in 2D) is degenerate: flat, zero volume."""
OVERLAP_NEIGHBOURS = 16
"""Cells (nearest centroids) searched for each vertex by the vertex-in-cell overlap test."""


def _at(x) -> str:
    return "(" + ", ".join(f"{float(v):.4g}" for v in x) + ")"


def _n(count: int, word: str, plural: str | None = None) -> str:
    """'1 cell', '3 cells'."""
    return f"{count} {word if count == 1 else plural or word + 's'}"


def _facet_keys(cells: np.ndarray, n_vertices: int):
    """One integer key per (cell, facet): (k*m,) keys, owner cells, local opposite vertex."""
    m, k = cells.shape
    f = np.sort(np.concatenate([np.delete(cells, j, axis=1) for j in range(k)]), axis=1)
    owner = np.tile(np.arange(m), k)
    opp = np.repeat(np.arange(k), m)
    n = max(int(n_vertices), 1)
    if float(n) ** (k - 1) < 2.0 ** 62:
        key = f[:, 0].copy()
        for j in range(1, k - 1):
            key = key * n + f[:, j]
    else:  # too many vertices for one int64: number the distinct facets instead
        key = np.unique(f, axis=0, return_inverse=True)[1].reshape(-1)
    return key, owner, opp, f


def _side(points, facet, p):
    """Signed volume (area in 2D) of the simplex (facet vertices in the given order, p)."""
    x0 = points[facet[:, 0]]
    if facet.shape[1] == 3:
        return np.einsum("ij,ij->i", np.cross(points[facet[:, 1]] - x0, points[facet[:, 2]] - x0),
                         points[p] - x0)
    a, b = points[facet[:, 1]] - x0, points[p] - x0
    return a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]


def check_tangles(points: np.ndarray, cells: np.ndarray, *, source: str = "mesh",
                  overlap: bool = True) -> np.ndarray:
    """Refuse a tangled, inverted or degenerate mesh BEFORE any re-orientation; return its cells,
    every one with positive orientation. Lengths in mm.

    The sign of a cell's volume depends on the order of its vertices as well as on its shape, so a
    negative volume alone does not say that a cell is inverted; its neighbours do. In each
    connected body (cells joined through shared facets):

    - every cell negative: a consistently left-handed vertex ordering (another program's
      convention): accepted, and each cell re-oriented (two vertices swapped);
    - both signs present: some cells are inside out relative to the rest: tangled, refused (also
      a file whose ordering is merely inconsistent: it cannot be told from an inversion);

    and in the whole mesh:

    - a cell of zero volume (|V| <= ``DEGENERATE_RTOL`` times the bounding box's largest side
      cubed) is degenerate: refused;
    - cells overlap: a facet shared by more than two cells, two cells on the same side of the
      facet they share (a fold), or a vertex strictly inside a cell it does not belong to
      (searched among the ``OVERLAP_NEIGHBOURS`` cells with the nearest centroids; ``overlap=False``
      skips that search, e.g. for a mesher's own output): refused.

    Raises MeshQualityError with the count and the worst cell (its index among the mesh's cells,
    position in mm, volume).
    """
    points = np.asarray(points, float)
    cells = np.asarray(cells, np.int64)
    m = len(cells)
    if m == 0:
        return cells.copy()
    d = points.shape[1]
    unit = f"mm^{d}"
    vol = cell_volumes(points, cells)
    scale = float(np.ptp(points[np.unique(cells)], axis=0).max()) ** d
    flat = ~(np.abs(vol) > DEGENERATE_RTOL * scale)
    if flat.any():
        ids = np.flatnonzero(flat)
        w = int(ids[np.argmin(np.nan_to_num(np.abs(vol[ids]), nan=-1.0))])
        raise MeshQualityError(
            f"{source}: {_n(ids.size, 'degenerate (zero-volume) cell')} of {m}; worst cell {w} at "
            f"{_at(points[cells[w]].mean(axis=0))} mm, volume {vol[w]:.3g} {unit}")
    key, owner, opp, facet = _facet_keys(cells, len(points))
    order = np.argsort(key, kind="stable")
    ks = key[order]
    start = np.flatnonzero(np.r_[True, ks[1:] != ks[:-1]])
    count = np.diff(np.r_[start, len(ks)])
    many = start[count > 2]
    if many.size:
        f0 = order[many[0]]
        group = owner[order[many[0]:many[0] + count[count > 2][0]]]
        raise MeshQualityError(
            f"{source}: tangled mesh: {_n(many.size, 'facet')} shared by more than two cells "
            f"(cells overlap); e.g. cells {group.tolist()} share the facet at "
            f"{_at(points[facet[f0]].mean(axis=0))} mm")
    pair = start[count == 2]
    a, b = owner[order[pair]], owner[order[pair + 1]]
    # orientation per connected body
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    adj = coo_matrix((np.ones(len(a)), (a, b)), shape=(m, m))
    n_bodies, body = connected_components(adj, directed=False)
    pos = vol > 0
    n_pos = np.bincount(body, weights=pos, minlength=n_bodies)
    n_all = np.bincount(body, minlength=n_bodies)
    mixed = (n_pos > 0) & (n_pos < n_all)
    if mixed.any():
        majority_pos = n_pos > n_all - n_pos      # the smaller share counts as inverted
        inv = mixed[body] & (pos != majority_pos[body])
        ids = np.flatnonzero(inv)
        x = points[cells[ids]]
        lrms = np.sqrt(np.mean([np.sum((x[:, i] - x[:, j]) ** 2, axis=1)
                                for i in range(d + 1) for j in range(i)], axis=0))
        w = int(ids[np.argmax(np.abs(vol[ids]) / lrms ** d)])
        raise MeshQualityError(
            f"{source}: tangled mesh: {ids.size} of {_n(m, 'cell')} inverted (oriented opposite "
            f"to the rest of their connected body); worst cell {w} at "
            f"{_at(points[cells[w]].mean(axis=0))} mm, volume {vol[w]:.3g} {unit} "
            f"(checked before any re-orientation)")
    out = cells.copy()
    flip = ~pos                                      # bodies ordered left-handed throughout
    out[flip, 0], out[flip, 1] = cells[flip, 1], cells[flip, 0]
    # folds: the two cells of an interior facet must lie on opposite sides of it
    fa = facet[order[pair]]
    sa = _side(points, fa, cells[a, opp[order[pair]]])
    sb = _side(points, fa, cells[b, opp[order[pair + 1]]])
    fold = np.flatnonzero(np.sign(sa) * np.sign(sb) > 0)
    if fold.size:
        depth = np.minimum(np.abs(sa[fold]), np.abs(sb[fold]))
        k = int(fold[np.argmax(depth)])
        raise MeshQualityError(
            f"{source}: tangled mesh: {_n(fold.size, 'pair')} of neighbouring cells overlap "
            f"(both on the same side of the facet they share); worst: cells {int(a[k])} and "
            f"{int(b[k])} at {_at(points[fa[k]].mean(axis=0))} mm")
    if overlap:
        _check_vertices_outside_foreign_cells(points, out, source)
    return out


def _check_vertices_outside_foreign_cells(points, cells, source, chunk: int = 20000):
    from scipy.spatial import cKDTree

    m = len(cells)
    used = np.unique(cells)
    x0 = points[cells[:, 0]]
    T = np.transpose(points[cells[:, 1:]] - x0[:, None, :], (0, 2, 1))   # columns: edges
    Tinv = np.linalg.inv(T)
    tree = cKDTree(points[cells].mean(axis=1))
    k = min(m, OVERLAP_NEIGHBOURS)
    hits = []
    for s in range(0, len(used), chunk):
        v = used[s:s + chunk]
        _, cand = tree.query(points[v], k=k)
        cand = cand.reshape(len(v), k)
        lam = np.einsum("ckij,ckj->cki", Tinv[cand], points[v][:, None, :] - x0[cand])
        wmin = np.minimum(1.0 - lam.sum(axis=2), lam.min(axis=2))
        member = (cells[cand] == v[:, None, None]).any(axis=2)
        inside = (wmin > 1e-9) & ~member
        for i, j in zip(*np.nonzero(inside)):
            hits.append((float(wmin[i, j]), int(v[i]), int(cand[i, j])))
    if hits:
        _, v, c = max(hits)
        n = len({h[1] for h in hits})
        raise MeshQualityError(
            f"{source}: tangled mesh: {_n(n, 'vertex', 'vertices')} of some cells strictly "
            f"inside another cell (cells overlap); worst: vertex {v} at {_at(points[v])} mm "
            f"inside cell {c}")


# --------------------------------------------------------------------------- deformed states
RUNAWAY_FACTOR = 10.0
"""A displacement larger than this many times the body's diameter (bounding-box diagonal) is
runaway growth, not an answer."""


def cell_jacobians(points: np.ndarray, cells: np.ndarray, u, reference_volumes=None) -> np.ndarray:
    """J = det F of each cell under the vertex displacement ``u`` ((n, gdim), mm), interpolated
    linearly (P1): F = I + grad u is constant in a linear simplex and J is the ratio of the
    deformed cell's signed volume (area in 2D, plane strain) to the reference cell's.
    Dimensionless; J <= 0 is an inverted cell; a non-finite displacement gives nan.
    reference_volumes: the cells' ``cell_volumes`` when the caller keeps them."""
    points = np.asarray(points, float)
    u = np.asarray(u, float).reshape(points.shape)
    if reference_volumes is None:
        reference_volumes = cell_volumes(points, cells)
    with np.errstate(all="ignore"):
        return cell_volumes(points + u, cells) / reference_volumes


def deformation_state(mesh: MeshData, u, *, degree: int = 1,
                      runaway: float = RUNAWAY_FACTOR, cell_J=None) -> dict:
    """Whether the vertex displacement ``u`` ((n, gdim), mm) is an admissible final state.

    Returns what every solver reports of its final state (``valid``, ``invalid_reason`` and
    ``min_J`` as SolveResult fields, the rest in its ``extra``): ``inverted_cells`` (cells with
    J <= 0, see ``cell_jacobians``), ``min_J``, ``max_displacement_mm``, ``valid`` and
    ``invalid_reason`` (None when valid), and ``J_evaluated`` (how J was taken: per P1 cell, or
    for ``degree`` >= 2 from the P1 interpolant of the vertex values, unless ``cell_J`` gives
    each cell's smallest J of the field itself, e.g. ``fem_reference.field_jacobian``). A state
    is invalid when it is not finite, has an inverted cell, or its largest displacement exceeds
    ``runaway`` times the body's diameter (bounding-box diagonal, mm).
    """
    u = np.asarray(u, float).reshape(mesh.points.shape)
    J = cell_jacobians(mesh.points, mesh.cells, u, mesh.reference_volumes) if cell_J is None \
        else np.asarray(cell_J, float).reshape(mesh.n_cells)
    finite = bool(np.all(np.isfinite(u)))
    inverted = int(np.count_nonzero(~(J > 0)))
    with np.errstate(all="ignore"):
        umax = float(np.sqrt(np.max(np.sum(u * u, axis=1), initial=0.0)))
        lo, hi = mesh.points.min(axis=0), mesh.points.max(axis=0)
        diameter = float(np.linalg.norm(hi - lo))
    min_j = float(np.min(J)) if J.size and np.all(np.isfinite(J)) else None
    reasons = []
    if not finite:
        reasons.append("non-finite displacement (nan or inf)")
    else:
        if inverted:
            w = int(np.argmin(np.where(np.isfinite(J), J, -np.inf)))
            reasons.append(f"{_n(inverted, 'inverted cell')} (J <= 0; worst cell {w} at "
                           f"{_at(mesh.points[mesh.cells[w]].mean(axis=0))} mm, J = {J[w]:.3g})")
        if umax > runaway * diameter:
            reasons.append(f"runaway displacement: max |u| = {umax:.3g} mm, more than "
                           f"{runaway:g} x the body's diameter ({diameter:.3g} mm)")
    if cell_J is not None:
        how = (f"the degree-{degree} field's J = det(I + grad u), its smallest over the points "
               f"of each cell's degree-3 lattice")
    elif degree == 1:
        how = "per cell (P1: J constant in each cell)"
    else:
        how = "per cell of the P1 interpolant of the vertex displacements (edge nodes not used)"
    return {"inverted_cells": inverted, "min_J": min_j,
            "max_displacement_mm": umax if np.isfinite(umax) else None,
            "valid": not reasons, "invalid_reason": "; ".join(reasons) or None,
            "J_evaluated": how}
