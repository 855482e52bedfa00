"""Uniform (nested) refinement of simplex meshes by edge midpoints, with named regions carried.

Every tetrahedron is split into 8 (Bey's red refinement: 4 corner tetrahedra and the inner
octahedron cut along its shortest diagonal), every triangle into 4. The children of cell ``i`` are
cells ``8 i .. 8 i + 7`` (``4 i .. 4 i + 3`` in 2D); old vertices keep their ids and the edge
midpoints follow them. Each boundary facet of a region is replaced by its 4 (3D) or 2 (2D)
children, point regions keep their vertex ids, and cell regions list the children of their cells.
Without projection the children of an affine cell fill it exactly, so the volume is preserved.

A curved boundary is followed with ``project``: a callable ``project(x, regions) -> x'`` that
receives the midpoints ``x`` (k, gdim) mm of the boundary edges and, for each, the frozenset of
facet-region names of the boundary facets sharing that edge, and returns the points moved onto
the true geometry. ``projector_for(builder)`` (``meshes.builders``) gives the one of each
builtin mesh (None for the flat ``box`` and ``rectangle``). The old vertices never move (they
lie on the boundary already), so the meshes stay nested away from the curved boundary. Since a
midpoint can move by a good part of its edge (a patch rim drawn by a few chords goes onto its
circle), the moves are spread:

1. every boundary midpoint is projected;
2. the midpoints of edges inside one region follow the moves of the region borders along the
   surface (harmonic extension over the refined boundary facets, then projected again);
3. the new interior vertices follow the boundary (harmonic extension over the refined cells).

The cells are then checked: a mesh too coarse for its curved boundary (e.g. an actuator rim of
two or three chords) raises MeshQualityError naming the largest move. Lengths in mm.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from tissue_reference.errors import CaseError, MeshQualityError

from .builders import projector_for
from .curved import validate
from .mesh import MeshData, boundary_facets, check_cells, orient_cells
from .projection import DomeProjection, ShellProjection  # noqa: F401 (re-exported)

__all__ = ["DomeProjection", "curve_boundary", "mesh_hierarchy", "projector_for",
           "refine_uniform"]

# local edges of a cell and the local index (after the cell's own vertices) of their midpoints
_TET_EDGES = np.array([(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)])
_TRI_EDGES = np.array([(0, 1), (0, 2), (1, 2)])
# local numbering of a tetrahedron with its midpoints: 0-3 vertices, 4 m01, 5 m02, 6 m03,
# 7 m12, 8 m13, 9 m23
_TET_CORNERS = [(0, 4, 5, 6), (4, 1, 7, 8), (5, 7, 2, 9), (6, 8, 9, 3)]
# the inner octahedron around each of its three diagonals (m01-m23, m02-m13, m03-m12): the four
# tetrahedra (a, b, c_k, c_k+1) over the cycle of the other four midpoints
_TET_OCTA = {
    0: [(4, 9, 5, 6), (4, 9, 6, 8), (4, 9, 8, 7), (4, 9, 7, 5)],
    1: [(5, 8, 4, 6), (5, 8, 6, 9), (5, 8, 9, 7), (5, 8, 7, 4)],
    2: [(6, 7, 4, 5), (6, 7, 5, 9), (6, 7, 9, 8), (6, 7, 8, 4)],
}
_TET_DIAGONALS = [(4, 9), (5, 8), (6, 7)]
# triangle: 0-2 vertices, 3 m01, 4 m02, 5 m12
_TRI_CHILDREN = [(0, 3, 4), (3, 1, 5), (4, 5, 2), (3, 5, 4)]


def edge_keys(a: np.ndarray, b: np.ndarray, n: int) -> np.ndarray:
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    return lo.astype(np.int64) * n + hi.astype(np.int64)


def _lookup(keys: np.ndarray, table: np.ndarray, what: str) -> np.ndarray:
    idx = np.searchsorted(table, keys)
    idx = np.minimum(idx, len(table) - 1)
    bad = table[idx] != keys
    if np.any(bad):
        raise CaseError(f"refine_uniform: {np.count_nonzero(bad)} edges of {what} are not edges "
                        f"of any cell")
    return idx


def refine_uniform(mesh: MeshData, *, project=None) -> MeshData:
    """One level of uniform refinement: each tetrahedron into 8, each triangle into 4.

    mesh: tetrahedra or triangles with named regions (mm).
    project: optional ``project(x, regions)`` moving the midpoints of boundary edges onto the true
        (curved) boundary; see the module docstring. Cells are checked afterwards:
        MeshQualityError if a projection inverted or flattened one.
    Returns the refined MeshData; vertex ids 0..n-1 are the old vertices, n.. the edge midpoints.
    """
    X, cells = mesh.points, mesh.cells
    n, d = len(X), mesh.gdim
    local_edges = _TET_EDGES if d == 3 else _TRI_EDGES
    a = cells[:, local_edges[:, 0]]
    b = cells[:, local_edges[:, 1]]
    keys = edge_keys(a, b, n)                       # (m, n_edges)
    table, inv = np.unique(keys.ravel(), return_inverse=True)
    mid_ids = (n + inv).reshape(keys.shape)          # midpoint vertex id of each cell edge
    lo, hi = table // n, table % n
    points = np.concatenate([X, 0.5 * (X[lo] + X[hi])])
    full = np.concatenate([cells, mid_ids], axis=1)  # (m, 10) or (m, 6)
    if d == 3:
        xs = points[full]
        diag = np.stack([np.linalg.norm(xs[:, i] - xs[:, j], axis=1) for i, j in _TET_DIAGONALS],
                        axis=1)
        choice = np.argmin(diag, axis=1)
        children = np.empty((len(cells), 8, 4), np.int64)
        children[:, :4] = full[:, np.array(_TET_CORNERS)]
        for k, tets in _TET_OCTA.items():
            sel = choice == k
            children[sel, 4:] = full[sel][:, np.array(tets)]
        new_cells = children.reshape(-1, 4)
    else:
        new_cells = full[:, np.array(_TRI_CHILDREN)].reshape(-1, 3)
    new_cells = orient_cells(points, new_cells)  # positive volumes before any projection

    facet_regions = {}
    for name, f in mesh.facet_regions.items():
        f = np.asarray(f, np.int64)
        if len(f) == 0:
            facet_regions[name] = f.reshape(0, d)
            continue
        facet_regions[name] = _split_facets(
            f, lambda u, v, name=name: n + _lookup(edge_keys(u, v, n), table,
                                                   f"facet region {name!r}"), d)
    nchild = 8 if d == 3 else 4
    cell_regions = {name: (nchild * np.asarray(ids, np.int64)[:, None]
                           + np.arange(nchild)).ravel()
                    for name, ids in mesh.cell_regions.items()}
    point_regions = {name: np.asarray(ids, np.int64).copy()
                     for name, ids in mesh.point_regions.items()}

    moved = None
    if project is not None:
        edges, regions, bf = boundary_edges(mesh, table)

        def mid_of(u, v):
            return n + _lookup(edge_keys(u, v, n), table, "the boundary")

        if len(edges):
            moved = _projected(project, points[n + edges], regions)
            delta = np.zeros_like(points)
            delta[n + edges] = moved - points[n + edges]
            # midpoints inside one region follow the moves of the region borders (e.g. a patch
            # rim drawn from a chord onto its circle) along the surface: harmonic extension
            # over the refined boundary facets, then the projection again
            inner = np.array([len(r) == 1 for r in regions], bool)
            if np.any(inner) and np.any(delta[n + edges[~inner]]):
                ids = n + edges[inner]
                spread = harmonic_extension(_split_facets(bf, mid_of, d), delta, ids)
                moved[inner] = _projected(project, points[ids] + spread[ids],
                                          [regions[i] for i in np.flatnonzero(inner)])
                delta[ids] = moved[inner] - points[ids]
            # the new interior vertices follow the boundary
            interior = np.ones(len(points), bool)
            interior[:n] = False
            interior[n + edges] = False
            points += harmonic_extension(new_cells, delta, np.flatnonzero(interior))
    out = MeshData(points, new_cells, facet_regions, point_regions, cell_regions)
    if moved is None:
        check_cells(out, source="refine_uniform")
        return out
    try:
        check_cells(out, source="refine_uniform")
    except MeshQualityError as exc:
        move = np.linalg.norm(moved - 0.5 * (X[lo[edges]] + X[hi[edges]]), axis=1)
        k = int(np.argmax(move))
        length = float(np.linalg.norm(X[lo[edges[k]]] - X[hi[edges[k]]]))
        raise MeshQualityError(
            f"{exc} after projecting the boundary edge midpoints onto the curved boundary (the "
            f"largest move, {move[k]:.3g} mm on an edge of {length:.3g} mm, "
            f"{'/'.join(sorted(regions[k]))}): the mesh is too coarse to follow that boundary; "
            f"start from a finer one") from None
    return out


def _split_facets(f: np.ndarray, mid_of, d: int) -> np.ndarray:
    """Children of facets ``f`` (k, d): 4 triangles per triangle, 2 segments per segment, in the
    parent's orientation; ``mid_of(u, v)`` gives the midpoint ids of edges (u, v)."""
    if d == 3:
        m01, m12, m02 = mid_of(f[:, 0], f[:, 1]), mid_of(f[:, 1], f[:, 2]), mid_of(f[:, 0], f[:, 2])
        ch = np.stack([np.stack([f[:, 0], m01, m02], 1), np.stack([m01, f[:, 1], m12], 1),
                       np.stack([m02, m12, f[:, 2]], 1), np.stack([m01, m12, m02], 1)], 1)
        return ch.reshape(-1, 3)
    m = mid_of(f[:, 0], f[:, 1])
    return np.stack([np.stack([f[:, 0], m], 1), np.stack([m, f[:, 1]], 1)], 1).reshape(-1, 2)


def _boundary_facets(cells: np.ndarray, n: int) -> np.ndarray:
    """Sorted vertex ids of the facets that belong to exactly one cell (integer keys when they
    fit in 63 bits, else ``meshes.mesh.boundary_facets``)."""
    k = cells.shape[1]
    if n ** (k - 1) >= 2 ** 62:
        return boundary_facets(cells)
    faces = np.sort(np.concatenate([np.delete(cells, j, axis=1) for j in range(k)]), axis=1)
    key = np.zeros(len(faces), np.int64)
    for j in range(k - 1):
        key = key * n + faces[:, j]
    _, first, counts = np.unique(key, return_index=True, return_counts=True)
    return faces[first[counts == 1]]


def _projected(project, x: np.ndarray, regions) -> np.ndarray:
    """``project(x, regions)`` (module docstring) on a copy of the points ``x`` (k, gdim), checked:
    CaseError unless it returns k finite points."""
    moved = np.asarray(project(np.array(x, dtype=np.float64), regions), dtype=np.float64)
    if moved.shape != x.shape or not np.all(np.isfinite(moved)):
        raise CaseError(f"refine_uniform: project returned shape {moved.shape} or non-finite "
                        f"values for {len(x)} boundary midpoints")
    return moved


def boundary_edges(mesh: MeshData, table: np.ndarray):
    """Edge ids (into ``table``) of the boundary facets' edges, for each the frozenset of the
    facet regions whose boundary facets contain it, and the boundary facets."""
    n, d = mesh.n_vertices, mesh.gdim
    bf = _boundary_facets(mesh.cells, n)                  # sorted vertex ids
    pairs = [(0, 1), (0, 2), (1, 2)] if d == 3 else [(0, 1)]
    bkeys = np.unique(np.concatenate([edge_keys(bf[:, i], bf[:, j], n) for i, j in pairs]))
    edges = _lookup(bkeys, table, "the boundary")
    # the region facets that lie on the boundary, matched by their sorted vertex ids
    names = sorted(mesh.facet_regions)
    regs = [np.sort(np.asarray(mesh.facet_regions[nm], np.int64).reshape(-1, d), axis=1)
            for nm in names]
    rows = np.concatenate([bf, *regs])
    _, inv = np.unique(rows, axis=0, return_inverse=True)
    inv = inv.ravel()
    on_boundary = np.zeros(inv.max(initial=-1) + 1, bool)
    on_boundary[inv[:len(bf)]] = True
    tags = [[] for _ in range(len(bkeys))]
    start = len(bf)
    for r, f in enumerate(regs):
        f = f[on_boundary[inv[start:start + len(f)]]]
        start += len(regs[r])
        if len(f) == 0:
            continue
        ek = np.unique(np.concatenate([edge_keys(f[:, i], f[:, j], n) for i, j in pairs]))
        for e in np.searchsorted(bkeys, ek).tolist():
            tags[e].append(r)
    regions = tuple(frozenset(names[r] for r in t) for t in tags)
    return edges, regions, bf


def _cg_tolerance() -> dict:
    import inspect

    import scipy.sparse.linalg as spla

    name = "rtol" if "rtol" in inspect.signature(spla.cg).parameters else "tol"
    return {name: 1e-12, "atol": 0.0}


_CG_TOL = _cg_tolerance()


def harmonic_extension(cells: np.ndarray, delta: np.ndarray, free: np.ndarray) -> np.ndarray:
    """Moves (mm) of all vertices: ``delta`` for all but the ``free`` ones, which get the discrete
    harmonic extension of it over the graph of ``cells`` (cells or facets; uniform edge
    weights)."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    nv = len(delta)
    k = cells.shape[1]
    i = np.concatenate([cells[:, a] for a in range(k) for b in range(k) if a != b])
    j = np.concatenate([cells[:, b] for a in range(k) for b in range(k) if a != b])
    A = sp.csr_matrix((np.ones(len(i)), (i, j)), shape=(nv, nv))
    A.data[:] = 1.0                                   # adjacency (duplicates summed, then 1)
    L = (sp.diags(np.asarray(A.sum(axis=1)).ravel()) - A).tocsr()
    is_free = np.zeros(nv, bool)
    is_free[free] = True
    fi = np.flatnonzero(is_free)
    out = delta.copy()
    if len(fi) == 0 or not np.any(delta):
        return out
    ci = np.flatnonzero(~is_free)
    rhs = -(L[fi][:, ci] @ delta[ci])
    Lff = L[fi][:, fi].tocsr()
    # here the free vertices are edge midpoints, each one edge from a fixed old vertex, so Lff is
    # well conditioned: Jacobi-preconditioned CG converges in a few dozen iterations
    M = sp.diags(1.0 / Lff.diagonal())
    for c in range(delta.shape[1]):
        b = rhs[:, c]
        if not np.any(b):
            out[fi, c] = 0.0
            continue
        x, info = spla.cg(Lff, b, M=M, maxiter=2000, **_CG_TOL)
        if info != 0:
            x = spla.spsolve(Lff.tocsc(), b)
        out[fi, c] = x
    return out


def curve_boundary(mesh: MeshData, project) -> MeshData:
    """``mesh`` with second-order geometry on its curved boundary (``meshes.curved``): the
    midpoint of every boundary edge moved onto the true geometry by ``project`` (module
    docstring), kept as a curved edge where it lies off the straight midpoint by more than 1e-9
    of the edge's length. Curved edges that would fold a cell are straightened
    (``curved.validate``). Replaces any curved edges ``mesh`` had."""
    X, cells = mesh.points, mesh.cells
    n, d = len(X), mesh.gdim
    local_edges = _TET_EDGES if d == 3 else _TRI_EDGES
    table = np.unique(edge_keys(cells[:, local_edges[:, 0]], cells[:, local_edges[:, 1]], n))
    edges, regions, _ = boundary_edges(mesh, table)
    lo, hi = table[edges] // n, table[edges] % n
    mid = 0.5 * (X[lo] + X[hi])
    moved = _projected(project, mid, regions)
    off = np.linalg.norm(moved - mid, axis=1) > 1e-9 * np.linalg.norm(X[hi] - X[lo], axis=1)
    curved = replace(mesh, curved_edges=np.stack([lo, hi], axis=1)[off],
                     curved_points=moved[off])
    return validate(curved)[0]


def mesh_hierarchy(mesh: MeshData, levels: int, *, project=None) -> list:
    """``levels`` nested meshes: ``mesh`` and ``levels - 1`` successive uniform refinements.
    When ``mesh`` has curved (second-order) edges and ``project`` is given, every refinement gets
    its own on the true geometry (``curve_boundary``), so each level is as curved as the first."""
    if levels < 1:
        raise CaseError(f"mesh_hierarchy needs levels >= 1, got {levels}")
    curved = project is not None and mesh.geometry_order == 2
    out = [mesh]
    for k in range(1, levels):
        try:
            fine = refine_uniform(out[-1], project=project)
        except MeshQualityError as exc:
            raise MeshQualityError(f"refinement {k} of {levels - 1} (from {out[-1].n_cells:,} "
                                   f"cells): {exc}") from None
        out.append(curve_boundary(fine, project) if curved else fine)
    return out
