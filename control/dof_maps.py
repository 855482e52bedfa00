"""Where a Case's targets and regions sit in a displacement vector (node-major, dof = gdim *
node + component, the Case's vertex numbering; degree-2 node lists carry the edge nodes after the
vertices): the interpolation rows P that read the targets (``probe_matrix``, ``point_matrix`` at
P1, ``p2_interpolation`` at degree 2) and a region's nodes in a degree-2 node list
(``p2_region_nodes``). The control Jacobians (``control.jacobian``) read their rows through P.
Units: mm."""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from tissue_reference.errors import CaseError

__all__ = ["p2_interpolation", "p2_region_nodes", "point_matrix", "probe_matrix"]


def probe_matrix(case, targets=None, *, n_dofs=None) -> sp.csr_matrix:
    """P1 interpolation (gdim * n_targets, n_dofs) at the Case's probes (barycentric weights of
    ``case.probe_locations``); extra columns (degree-2 nodes) are zero.

    Parameters
    ----------
    case : Case
        The Case with its probes.
    targets : sequence of str or None
        Probe names; None: every probe.
    n_dofs : int or None
        Columns; None: gdim * n_vertices.

    Returns
    -------
    scipy.sparse.csr_matrix
        (gdim * n_targets, n_dofs).
    """
    d = case.mesh.gdim
    n_dofs = d * case.mesh.n_vertices if n_dofs is None else int(n_dofs)
    locs = {loc.name: loc for loc in case.probe_locations}
    tg = [p.name for p in case.probes] if targets is None else list(targets)
    rows, cols, vals = [], [], []
    for i, t in enumerate(tg):
        if t not in locs:
            case.probe(t)  # raises naming it
        loc = locs[t]
        verts = case.mesh.cells[loc.cell]
        for c in range(d):
            rows += [d * i + c] * len(verts)
            cols += (d * verts + c).tolist()
            vals += loc.weights.tolist()
    return sp.csr_matrix((vals, (rows, cols)), shape=(d * len(tg), n_dofs))


def point_matrix(mesh, points, *, n_dofs=None):
    """P1 interpolation (gdim * n_points, n_dofs) at arbitrary points (mm) and a mask of the
    points that lie inside the mesh (to 1e-9 in barycentric weights). Outside points get zero
    rows.

    Parameters
    ----------
    mesh : MeshData
        The mesh (mm).
    points : array_like
        (n_points, gdim) points (mm).
    n_dofs : int or None
        Columns; None: gdim * n_vertices.

    Returns
    -------
    tuple
        (P, inside): scipy CSR (gdim * n_points, n_dofs) and an (n_points,) bool mask.
    """
    from scipy.spatial import cKDTree

    X, cells = mesh.points, mesh.cells
    d = mesh.gdim
    pts = np.asarray(points, float).reshape(-1, d)
    n_dofs = d * len(X) if n_dofs is None else int(n_dofs)
    T = X[cells[:, 1:]] - X[cells[:, :1]]
    Tinv = np.linalg.inv(np.transpose(T, (0, 2, 1)))
    tree = cKDTree(X[cells].mean(axis=1))
    k = min(len(cells), 48)
    rows, cols, vals = [], [], []
    inside = np.zeros(len(pts), bool)
    for i, x in enumerate(pts):
        _, cand = tree.query(x, k=k)
        for c in np.atleast_1d(cand):
            lam = Tinv[c] @ (x - X[cells[c, 0]])
            w = np.concatenate([[1 - lam.sum()], lam])
            if w.min() >= -1e-9:
                inside[i] = True
                for cc in range(d):
                    rows += [d * i + cc] * (d + 1)
                    cols += (d * cells[c] + cc).tolist()
                    vals += w.tolist()
                break
    return sp.csr_matrix((vals, (rows, cols)), shape=(d * len(pts), n_dofs)), inside


def _edge_nodes(case, node_points, pairs):
    """Node ids (of a degree-2 node list: vertices first, then edge nodes) at the midpoints of the
    vertex pairs (k, 2); CaseError when one is missing."""
    from scipy.spatial import cKDTree

    X = case.mesh.points
    nv = case.mesh.n_vertices
    extra = np.asarray(node_points, float)[nv:]
    tree = cKDTree(extra)
    mid = 0.5 * (X[pairs[:, 0]] + X[pairs[:, 1]])
    dist, idx = tree.query(mid)
    h = np.linalg.norm(X[pairs[:, 0]] - X[pairs[:, 1]], axis=1)
    if np.any(dist > 1e-8 * np.maximum(h, 1.0)):
        raise CaseError("node_points do not hold an edge node at every edge midpoint "
                        "(not a degree-2 Lagrange node list in Case numbering)")
    return nv + idx


def p2_interpolation(case, node_points, targets=None) -> sp.csr_matrix:
    """Degree-2 Lagrange interpolation (gdim * n_targets, gdim * n_nodes) at the Case's probes:
    vertex shape functions l_i (2 l_i - 1), edge ones 4 l_i l_j (l: barycentric weights).

    Parameters
    ----------
    case : Case
        The Case with its probes.
    node_points : ndarray
        (n_nodes, gdim) degree-2 node coordinates (mm), vertices first.
    targets : sequence of str or None
        Probe names; None: every probe.

    Returns
    -------
    scipy.sparse.csr_matrix
        (gdim * n_targets, gdim * n_nodes).
    """
    d = case.mesh.gdim
    nn = len(node_points)
    locs = {loc.name: loc for loc in case.probe_locations}
    tg = [p.name for p in case.probes] if targets is None else list(targets)
    rows, cols, vals = [], [], []
    for i, t in enumerate(tg):
        if t not in locs:
            case.probe(t)
        loc = locs[t]
        v = case.mesh.cells[loc.cell]
        lam = loc.weights
        nodes = list(v)
        w = list(lam * (2 * lam - 1))
        pairs = np.array([(v[a], v[b]) for a in range(d + 1) for b in range(a + 1, d + 1)])
        nodes += _edge_nodes(case, node_points, pairs).tolist()
        w += [4 * lam[a] * lam[b] for a in range(d + 1) for b in range(a + 1, d + 1)]
        for c in range(d):
            rows += [d * i + c] * len(nodes)
            cols += [d * n + c for n in nodes]
            vals += w
    return sp.csr_matrix((vals, (rows, cols)), shape=(d * len(tg), d * nn))


def p2_region_nodes(case, node_points):
    """region -> node ids (vertices and edge nodes of the region's facets) for a degree-2 node
    list; point/cell regions give their vertices only. Use as ``region_nodes``.

    Parameters
    ----------
    case : Case
        The Case.
    node_points : ndarray
        (n_nodes, gdim) degree-2 node coordinates (mm), vertices first.

    Returns
    -------
    callable
        region name -> node ids.
    """
    cache = {}

    def nodes(region):
        if region not in cache:
            verts = case.mesh.region_vertices(region)
            facets = case.mesh.facet_regions.get(region)
            if facets is None or len(facets) == 0:
                cache[region] = verts
            else:
                f = np.asarray(facets)
                k = f.shape[1]
                pairs = np.unique(np.sort(np.concatenate(
                    [f[:, [a, b]] for a in range(k) for b in range(a + 1, k)]), axis=1), axis=0)
                cache[region] = np.concatenate([verts, np.unique(_edge_nodes(case, node_points,
                                                                             pairs))])
        return cache[region]
    return nodes
