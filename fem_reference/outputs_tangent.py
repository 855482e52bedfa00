"""The exact tangent stiffness and the internal forces of a ReferenceSolver as plain arrays:
``Tangent`` (a scipy matrix in the Case's node-major numbering, then the mixed formulation's
pressure dofs), ``internal_forces`` and the permutation from dolfinx's dofs to that order.
Units: K mN/mm (pressure rows mm^3), forces mN. Mixed into ReferenceSolver (through
``outputs.OutputsMixin``); serial only.
"""
from __future__ import annotations

from dataclasses import dataclass

import dolfinx
import dolfinx.fem
import dolfinx.fem.petsc
import numpy as np

from tissue_reference.meshes.errors import CaseError

__all__ = ["Tangent", "TangentMixin"]


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


class TangentMixin:
    """The exported tangent and internal forces of a ReferenceSolver, in the Tangent order."""

    def _w_out(self) -> np.ndarray:
        """Output index (Tangent order: node-major displacements, then the pressure dofs by Case
        vertex) of every local dof of the unknown's space."""
        perm = self._out_permutation()[1]
        if self.Q is None:
            return perm
        out = np.empty(len(self.x.x.array), np.int64)
        out[self._umap] = perm
        pv = self.p_vertex.copy()
        extra = pv < 0  # pressure dofs away from the vertices (degree >= 2): after the vertices
        pv[extra] = self.case.mesh.n_vertices + np.arange(np.count_nonzero(extra))
        out[self._pmap] = len(perm) + pv
        return out

    # ------------------------------------------------------------------ residual / tangent
    def _out_permutation(self):
        nv = self.case.mesh.n_vertices
        out_node = np.empty(len(self.node_vertex), np.int64)
        vm = self.node_vertex >= 0
        out_node[vm] = self.node_vertex[vm]
        out_node[~vm] = nv + np.arange(np.count_nonzero(~vm))
        return out_node, (out_node[:, None] * self.gdim + np.arange(self.gdim)).ravel()

    def internal_forces(self, u=None) -> np.ndarray:
        """Node-major residual f_int - f_ext (mN) at state ``u`` in the Case numbering (serial).

        u: as for :meth:`tangent`."""
        if self.comm.size > 1:
            raise CaseError("internal_forces export runs in serial")
        if u is not None:
            self.set_state(u, exact=True)
        r = dolfinx.fem.petsc.assemble_vector(self.R_int_form)
        out = np.empty(len(r.array))
        out[self._w_out()] = r.array
        r.destroy()
        return out[:len(self._umap)]

    def tangent(self, u=None, *, pushes=None) -> Tangent:
        """Exact tangent K at state ``u`` (default: the solver's current state).

        u: a SolveResult of a reference solve on this mesh, or an array: (n_vertices, gdim)
        vertex values at degree 1; at degree 2 the full (n_nodes, gdim) nodal state in the
        Tangent node order (vertices, then the edge nodes of ``Tangent.node_points``) -- degree-2
        vertex values alone raise CaseError unless all zero (see :meth:`set_state`).
        """
        if self.comm.size > 1:
            raise CaseError("tangent export runs in serial (it returns one scipy matrix)")
        import scipy.sparse as sp

        if u is not None:
            self.set_state(u, exact=True)
        case = self.case.with_pushes(pushes or {})
        self.load.value = 1.0
        A = dolfinx.fem.petsc.assemble_matrix(self.K_form)
        A.assemble()
        indptr, indices, data = A.getValuesCSR()
        n = A.getSize()[0]
        K = sp.csr_matrix((data, indices, indptr), shape=(n, n))
        A.destroy()
        # permutation: local dof -> output dof (vertices first in Case order, then edge nodes,
        # then the pressure dofs of the mixed formulation)
        nv = self.case.mesh.n_vertices
        perm = self._w_out()
        P = sp.csr_matrix((np.ones(len(perm)), (perm, np.arange(len(perm)))), shape=(n, n))
        K = (P @ K @ P.T).tocsr()
        node_points = self._output_node_points()
        bc_dofs = [perm[e[2]] for e in self.dirichlet_bcs(case, 1.0)]
        dd = np.unique(np.concatenate(bc_dofs)) if bc_dofs else np.zeros(0, np.int64)
        return Tangent(K, dd, node_points, nv, self.degree, n - len(self._umap),
                       self.formulation)
