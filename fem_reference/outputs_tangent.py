"""The exact tangent stiffness and the internal forces of a ReferenceSolver as plain arrays:
``Tangent`` (a scipy matrix in the Case's node-major numbering, then the mixed formulation's
pressure dofs), ``internal_forces`` and the permutation from dolfinx's dofs to that order.
Units: K mN/mm (pressure rows mm^3), forces mN. ``ReferenceSolver.tangent`` and
``ReferenceSolver.internal_forces`` are these functions of the solver; serial only.
"""
from __future__ import annotations

from dataclasses import dataclass

import dolfinx
import dolfinx.fem
import dolfinx.fem.petsc
import numpy as np
import scipy.sparse as sp

from tissue_reference.errors import CaseError

__all__ = ["Tangent", "internal_forces", "tangent"]


@dataclass(frozen=True)
class Tangent:
    """Exact tangent stiffness K (mN/mm), node-major (dof = gdim*node + component).

    Nodes 0..n_vertices-1 are the Case's vertices in its own numbering; for degree 2 the edge
    nodes follow, with coordinates ``node_points``. ``dirichlet_dofs`` are the prescribed dofs.

    Mixed formulation: K is the saddle-point tangent of (u, p): the displacement dofs as above,
    then ``internal_dofs`` pressure dofs (one per Case vertex, in its numbering; rows in mm^3:
    d(volume-change residual)/d(u) and 1/kappa mass terms). They are free and unloaded: solving
    with K eliminates them, which is the exact static condensation onto the displacements.
    """

    K: object
    dirichlet_dofs: np.ndarray
    node_points: np.ndarray
    n_vertices: int
    degree: int
    internal_dofs: int = 0
    formulation: str = "displacement"


def internal_forces(solver, u=None) -> np.ndarray:
    """Node-major residual f_int - f_ext (mN) of the ReferenceSolver ``solver`` at state ``u``
    in the Case numbering (serial). u: as for ``tangent``."""
    if solver.comm.size > 1:
        raise CaseError("internal_forces export runs in serial")
    if u is not None:
        solver.state.set_state(u, exact=True)
    solver.refresh_fields()
    r = dolfinx.fem.petsc.assemble_vector(solver.R_int_form)
    out = np.empty(len(r.array))
    out[solver.state.w_out()] = r.array
    r.destroy()
    return out[:len(solver.state.umap)]

def tangent(solver, u=None, *, pushes=None) -> Tangent:
    """Exact tangent K of the ReferenceSolver ``solver`` at state ``u`` (default: its current
    state), with the Dirichlet dofs of its Case at ``pushes``.

    u: a SolveResult of a reference solve on this mesh, or an array: (n_vertices, gdim)
    vertex values at degree 1; at degree 2 the full (n_nodes, gdim) nodal state in the
    Tangent node order (vertices, then the edge nodes of ``Tangent.node_points``) -- degree-2
    vertex values alone raise CaseError unless all zero (``NodalState.set_state``).
    """
    if solver.comm.size > 1:
        raise CaseError("tangent export runs in serial (it returns one scipy matrix)")
    if u is not None:
        solver.state.set_state(u, exact=True)
    case = solver.case.with_pushes(pushes or {})
    solver.set_load_fraction(1.0)
    solver.refresh_fields()
    A = dolfinx.fem.petsc.assemble_matrix(solver.K_form)
    A.assemble()
    indptr, indices, data = A.getValuesCSR()
    n = A.getSize()[0]
    K = sp.csr_matrix((data, indices, indptr), shape=(n, n))
    A.destroy()
    # permutation: local dof -> output dof (vertices first in Case order, then edge nodes,
    # then the pressure dofs of the mixed formulation)
    nv = solver.case.mesh.n_vertices
    perm = solver.state.w_out()
    P = sp.csr_matrix((np.ones(len(perm)), (perm, np.arange(len(perm)))), shape=(n, n))
    K = (P @ K @ P.T).tocsr()
    node_points = solver.state.node_points()
    bc_dofs = [perm[e[2]] for e in solver.boundary.dirichlet_bcs(case, 1.0)]
    dd = np.unique(np.concatenate(bc_dofs)) if bc_dofs else np.zeros(0, np.int64)
    return Tangent(K, dd, node_points, nv, solver.degree, n - len(solver.state.umap),
                   solver.formulation)
