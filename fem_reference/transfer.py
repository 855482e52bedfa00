"""Transfer of a reference state from a mesh to its refinement (``meshes.refine_local`` or
``meshes.refine.refine_uniform``): the warm start of the solves of the next adaptive level.

Every cell of the refined mesh lies in one cell of the coarse mesh (its parent); the coarse
displacement field (any degree, on the coarse solver's straight or curved cells) is evaluated at
the refined solver's nodes in their parents. A refined node that the boundary projection moved
slightly outside its parent gets the parent's polynomial extended there. Where the refinement
left the cells alone the transferred field is the coarse one exactly (same cells, same or higher
degree), so Newton starts next to the answer there and has only the refined region to settle.

Displacement formulation only (the mixed formulation's pressure is not transferred). Serial.
``warm_settings`` gives the Newton settings of such warm starts. Units: mm.
"""
from __future__ import annotations

import dataclasses

import numpy as np
from scipy.spatial import cKDTree

from tissue_reference.errors import CaseError
from tissue_reference.model.results import SolveResult

__all__ = ["WARM_LINE_SEARCH", "dolfinx_cells", "field", "match_points", "prolong", "warm_settings"]


def match_points(source: np.ndarray, target: np.ndarray, what: str) -> np.ndarray:
    """Index into ``source`` (k, gdim) of each point of ``target`` (mm), equal to round-off."""
    dist, idx = cKDTree(source).query(target)
    scale = max(1.0, float(np.abs(target).max(initial=0.0)))
    if np.any(dist > 1e-9 * scale):
        raise CaseError(f"{what}: {np.count_nonzero(dist > 1e-9 * scale)} nodes do not match "
                        f"(largest distance {dist.max():.3g} mm)")
    return idx


def dolfinx_cells(solver) -> np.ndarray:
    """For each cell of ``solver.case.mesh`` (its own order), the solver's dolfinx cell index
    (matched by sorted vertex ids). Serial."""
    mesh = solver.dm.mesh
    tdim = mesh.topology.dim
    imap = mesh.topology.index_map(tdim)
    nloc = imap.size_local
    md = solver.case.mesh
    if nloc != md.n_cells or imap.num_ghosts:
        raise CaseError("serial runs only: the cells are split over ranks")
    geo = mesh.geometry.dofmap.array.reshape(nloc, -1)[:, :tdim + 1]
    both = _row_keys(np.sort(np.vstack([solver.dm.node_to_vertex[geo], md.cells]), axis=1),
                     md.n_vertices)
    ko, kt = both[:nloc], both[nloc:]
    order = np.argsort(ko)
    pos = order[np.minimum(np.searchsorted(ko[order], kt), nloc - 1)]
    if not np.array_equal(ko[pos], kt):
        raise CaseError("the solver's cells are not the case mesh's")
    return pos


def _row_keys(rows: np.ndarray, n: int) -> np.ndarray:
    """One integer per row of sorted vertex ids (a row index when n^k overflows int64)."""
    if float(n) ** rows.shape[1] >= 2.0 ** 62:
        return np.unique(rows, axis=0, return_inverse=True)[1].ravel()
    key = rows[:, 0].astype(np.int64)
    for j in range(1, rows.shape[1]):
        key = key * n + rows[:, j]
    return key


def _evaluate(u, cells, x):
    """u (a Lagrange Function) at points x (k, gdim), point i in dolfinx cell ``cells[i]``: the
    cell's polynomial, in the barycentric coordinates of its straight (vertex) simplex, fitted
    through the cell's nodes. Exact on straight cells; on curved cells the field is taken as a
    polynomial of those coordinates (a warm start needs no more). Points slightly outside
    their cell get the polynomial extended."""
    V = u.function_space
    mesh = V.mesh
    tdim = mesh.topology.dim
    gdim = x.shape[1]
    ncell = mesh.topology.index_map(tdim).size_local
    dofs = V.dofmap.list.array.reshape(ncell, -1)
    k = dofs.shape[1]
    q = {3: 1, 6: 2, 10: 3}[k] if tdim == 2 else {4: 1, 10: 2, 20: 3}[k]
    powers = np.array([e for e in np.ndindex(*(q + 1,) * tdim) if sum(e) <= q])   # (k, tdim)
    geo = mesh.geometry.dofmap.array.reshape(ncell, -1)[:, :tdim + 1]
    corners = mesh.geometry.x[geo][:, :, :gdim]                           # (ncell, tdim+1, gdim)
    used, inv = np.unique(cells, return_inverse=True)
    T = np.transpose(corners[used, 1:] - corners[used, :1], (0, 2, 1))    # (u, gdim, tdim)
    Tinv = np.linalg.inv(T)
    X = V.tabulate_dof_coordinates()[:, :gdim]
    ref = np.einsum("cij,cnj->cni", Tinv, X[dofs[used]] - corners[used, :1])  # (u, k, tdim)
    M = np.prod(ref[:, :, None, :] ** powers[None, None], axis=-1)          # (u, k, k)
    vals = u.x.array.reshape(-1, gdim)[dofs[used]]                           # (u, k, gdim)
    coef = np.linalg.solve(M, vals)                                          # (u, k, gdim)
    xi = np.einsum("pij,pj->pi", Tinv[inv], x - corners[used[inv], 0])      # (points, tdim)
    m = np.prod(xi[:, None, :] ** powers[None], axis=-1)                    # (points, k)
    return np.einsum("pk,pkg->pg", m, coef[inv])


def field(solver, result: SolveResult):
    """The displacement of ``result`` (a reference answer on ``solver``'s mesh, degree 1 or with
    its nodal state) as a dolfinx Function of ``solver.V`` (interpolated when its degree is
    lower)."""
    import dolfinx.fem

    gdim = solver.gdim
    p = int(result.degree)
    mesh = solver.dm.mesh
    Vp = solver.V if p == solver.degree else \
        dolfinx.fem.VectorFunctionSpace(mesh, ("Lagrange", p))
    up = dolfinx.fem.Function(Vp)
    xp = Vp.tabulate_dof_coordinates()[:, :gdim]
    if p == 1:
        up.x.array.reshape(-1, gdim)[:] = np.asarray(result.u, float)[
            match_points(solver.case.mesh.points, xp, "the answer's vertices")]
    else:
        node_u, node_points = result.node_u, result.node_points
        if node_u is None or node_points is None:
            raise CaseError(f"a degree-{p} answer without its nodal state (node_u, "
                            f"serial solves only)")
        up.x.array.reshape(-1, gdim)[:] = np.asarray(node_u, float)[
            match_points(np.asarray(node_points, float), xp, f"the degree-{p} answer's nodes")]
    if Vp is solver.V:
        return up
    u = dolfinx.fem.Function(solver.V)
    u.interpolate(up)
    return u


def prolong(coarse_solver, coarse: SolveResult, fine_solver, parents) -> SolveResult:
    """The state of ``coarse`` (a reference answer on ``coarse_solver``'s mesh) on the refined
    mesh of ``fine_solver``, as a SolveResult its ``solve(initial=...)`` takes (the nodal state
    ``node_u`` at ``node_points``, the fine solver's degree).

    parents: (fine cells,) the coarse cell (Case numbering) of each fine cell.
    """
    if coarse_solver.Q is not None or fine_solver.Q is not None:
        raise CaseError("prolong: the mixed formulation's pressure is not transferred")
    gdim = fine_solver.gdim
    u = field(coarse_solver, coarse)
    old_cells = dolfinx_cells(coarse_solver)
    new_cells = dolfinx_cells(fine_solver)
    parents = np.asarray(parents, np.int64)
    if len(parents) != len(new_cells):
        raise CaseError(f"prolong: {len(parents)} parents for {len(new_cells)} refined cells")
    # a coarse dolfinx cell holding each fine node: the parent of a fine cell that holds it
    V = fine_solver.V
    dofs = V.dofmap.list.array.reshape(len(new_cells), -1)
    host = np.empty(len(new_cells), np.int64)
    host[new_cells] = old_cells[parents]         # fine dolfinx cell -> coarse dolfinx cell
    owner = np.full(V.dofmap.index_map.size_local + V.dofmap.index_map.num_ghosts, -1, np.int64)
    owner[dofs.ravel()] = np.repeat(host, dofs.shape[1])
    x = V.tabulate_dof_coordinates()
    values = _evaluate(u, owner, x[:, :gdim])
    points = fine_solver.node_points()
    node_u = values[match_points(x[:, :gdim], points, "the refined nodes")]
    return SolveResult(u=node_u[:fine_solver.case.mesh.n_vertices].copy(), converged=True,
                       iterations=0, residual=0.0, wall_time_s=0.0, solver="fem",
                       reference=True,
                       degree=fine_solver.degree, case_name=coarse.case_name,
                       n_vertices=fine_solver.case.mesh.n_vertices,
                       n_cells=fine_solver.case.mesh.n_cells,
                       node_u=node_u, node_points=points)


WARM_LINE_SEARCH = 8
"""Halvings of a Newton correction allowed in a warm start (``warm_settings``)."""


def warm_settings(settings, max_iterations: int):
    """The Newton settings (``NewtonSettings``) of a warm start (at full load, from a state
    close to the answer) made from a solver's ``settings``: one try of at most
    ``max_iterations`` iterations (no cut-backs: with the boundary values already in place
    there is nothing to ramp) and corrections halved up to WARM_LINE_SEARCH times. Solve with
    them and ``residual_line_search=True`` (``ReferenceSolver.solve``), a line search that takes
    a correction only when it lowers the residual norm (the last halving taken): near a pushed
    patch's rim the tangent of a refined mesh can be nearly singular and a full correction of
    tens of mm, finite but far off, would otherwise be taken. A solver with indenters keeps its
    own (energy) line search.

        ref.solve(pushes, initial=start, settings=warm_settings(ref.settings, 12),
                  residual_line_search=True)
    """
    return dataclasses.replace(settings, min_fraction=0.75, max_iterations=max_iterations,
                               line_search=max(settings.line_search, WARM_LINE_SEARCH))
