"""A Function's values at points fixed once, as one sparse matrix of its nodal values.

``dolfinx.fem.Function.eval(points, cells)`` pulls every point back to its cell's reference
coordinates (a Newton iteration on a curved cell) and tabulates the element's basis there,
on every call. Where the points and their cells stay (the facet check of a solve with tips,
sampled after every solve), both are fixed: the value at point i is sum_j phi_j(xi_i) U_j
over the nodes j of its cell, with phi the scalar element's basis at the point's reference
coordinates xi_i, the same for every component of a blocked (vector) Function.
``evaluation_rows`` builds those rows once; each evaluation is then a sparse product, the same
numbers as ``Function.eval`` to round-off (tests/test_point_values.py) at a few thousandths of
its cost (the facet check of phantom-seed's four heads: 752 ms with ``eval``, 3.1 ms by the
rows; bench/bench_facet_check.py).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

__all__ = ["evaluation_rows"]


def evaluation_rows(V, points: np.ndarray, cells: np.ndarray) -> sp.csr_matrix:
    """Rows that evaluate a Function on ``V`` at ``points``.

    Parameters
    ----------
    V : dolfinx.fem.FunctionSpace
        A Lagrange space, scalar or blocked (vector); its element needs no dof transformations
        (Lagrange elements do not).
    points : ndarray
        (n, gdim) or (n, 3): the points (mm), each inside (or on the boundary of) its cell.
    cells : ndarray
        (n,): the local cell of each point.

    Returns
    -------
    scipy.sparse.csr_matrix
        M of shape (n, nodes), nodes the local and ghost nodes of V: for a Function f on V,
        ``M @ f.x.array.reshape(-1, bs)`` is (n, bs), f's values at the points (bs the block
        size: the components).
    """
    mesh = V.mesh
    gdim = mesh.geometry.dim
    if V.element.needs_dof_transformations:
        raise ValueError("evaluation_rows: the element needs dof transformations (not Lagrange)")
    points = np.asarray(points, float)[:, :gdim]
    cells = np.asarray(cells, np.int32)
    if len(points) != len(cells):
        raise ValueError(f"evaluation_rows: {len(points)} points but {len(cells)} cells")
    index_map = V.dofmap.index_map
    n_nodes = index_map.size_local + index_map.num_ghosts
    if not len(points):
        return sp.csr_matrix((0, n_nodes))
    x = mesh.geometry.x[:, :gdim]
    geometry = mesh.geometry.dofmap
    cmap = mesh.geometry.cmap
    basis = V.element.basix_element
    order = np.argsort(cells, kind="stable")
    unique, first = np.unique(cells[order], return_index=True)
    bounds = np.append(first, len(cells))
    rows, cols, vals = [], [], []
    for k, cell in enumerate(unique):
        idx = order[bounds[k]:bounds[k + 1]]
        xi = cmap.pull_back(np.ascontiguousarray(points[idx]),
                            np.ascontiguousarray(x[geometry.links(cell)]))
        phi = basis.tabulate(0, xi)[0, :, :, 0]            # (points, cell nodes)
        nodes = V.dofmap.cell_dofs(cell)
        rows.append(np.repeat(idx, len(nodes)))
        cols.append(np.tile(nodes, len(idx)))
        vals.append(phi.ravel())
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                         shape=(len(points), n_nodes))
