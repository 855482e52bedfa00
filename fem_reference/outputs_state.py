"""The ReferenceSolver's displacement (and pressure) state in and out: the map from dolfinx's
nodes to the Case's vertices, loading a state (a SolveResult, a nodal array or vertex values),
the mixed formulation's unknown x assembled from and split into u and p, and the vertex and
nodal fields gathered on every rank. Units: displacement mm, pressure kPa (positive in
compression), coordinates mm. The ReferenceSolver owns one (``NodalState``).

Node order (the ``Tangent`` order): the Case's vertices in its own numbering, then the edge
nodes of degree 2.
"""
from __future__ import annotations

import dolfinx
import dolfinx.fem
import dolfinx.fem.petsc
import numpy as np
import ufl
from petsc4py import PETSc
from scipy.spatial import cKDTree

from tissue_reference.errors import CaseError
from tissue_reference.model.results import SolveResult

from .forms import volume_measure
from .jit import compile_form

__all__ = ["NodalState"]


class NodalState:
    """A ReferenceSolver's fields and their numbering: the unknown ``x`` (on W), the displacement
    ``u`` (on V) and the pressure ``p`` (on Q; None in the displacement formulation), ``umap`` /
    ``pmap`` the W dof of each V / Q dof; the map from dolfinx's nodes to the Case's
    ``n_vertices`` vertices (``node_vertex``), loading a state into the fields and reading them
    out. ``material``: the Case's (the mixed formulation's pressure equation); ``inv_kappa``: its
    1/kappa Constant; ``qdeg``: the solver's quadrature degree."""

    def __init__(self, *, V, Q, x, u, p, umap, pmap, dm, n_vertices: int, degree: int, comm,
                 material, inv_kappa, qdeg: int):
        self.V, self.Q, self.x, self.u, self.p = V, Q, x, u, p
        self.umap, self.pmap, self.dm, self.n_vertices = umap, pmap, dm, int(n_vertices)
        self.gdim = int(V.dofmap.index_map_bs)
        self.degree, self.comm, self.material = degree, comm, material
        self.inv_kappa, self.qdeg = inv_kappa, qdeg
        self._pproj = None   # the pressure equation's forms and factorization, built once
        self._p1 = None      # the P1 space that vertex values are interpolated from
        self._node_map()

    def _node_map(self):
        """Map dolfinx (local) dof nodes of V to Case vertices / extra nodes."""
        V, dm = self.V, self.dm
        tdim = dm.mesh.topology.dim
        nv = tdim + 1
        cell_dofs = V.dofmap.list.array.reshape(-1, V.dofmap.dof_layout.num_dofs)
        geo = dm.mesh.geometry.dofmap.array.reshape(len(cell_dofs), -1)[:, :nv]
        imap = V.dofmap.index_map
        n_local = imap.size_local + imap.num_ghosts
        node_vertex = -np.ones(n_local, np.int64)
        node_vertex[cell_dofs[:, :nv].ravel()] = dm.node_to_vertex[geo.ravel()]
        self.n_local_nodes = imap.size_local
        self.node_vertex = node_vertex  # -1 for edge nodes (degree 2)
        self.global_nodes = imap.local_to_global(np.arange(n_local, dtype=np.int32))
        self.n_global_nodes = imap.size_global
        self.p_vertex = None
        if self.Q is not None:  # pressure dofs at vertices (first nv per cell); -1 for others
            qd = self.Q.dofmap.list.array.reshape(-1, self.Q.dofmap.dof_layout.num_dofs)
            self.p_vertex = -np.ones(len(self.p.x.array), np.int64)
            self.p_vertex[qd[:, :nv].ravel()] = dm.node_to_vertex[geo.ravel()]

    # ------------------------------------------------------------------ mixed: u, p <-> x
    def sync(self):
        """Copy the unknown's displacement (and pressure) parts into ``u`` (and ``p``)."""
        if self.Q is None:
            return
        self.u.x.array[:] = self.x.x.array[self.umap]
        self.p.x.array[:] = self.x.x.array[self.pmap]

    def x_from_fields(self, pressure=None, *, exact=False):
        """Set the unknown from ``u`` and a pressure: ``pressure`` (Case-vertex values, kPa) when
        given (or a dolfinx Function on this mesh, interpolated: e.g. the P1 pressure of a P2/P1
        answer starting a P3/P2 solve), else the discrete pressure equation solved for u (exact
        when 1/kappa > 0), else (incompressible, or a warm start) the solver's current pressure."""
        if self.Q is None:
            return
        self.x.x.array[self.umap] = self.u.x.array
        if isinstance(pressure, dolfinx.fem.Function):
            self.p.interpolate(pressure)
        elif pressure is not None and np.all(self.p_vertex >= 0):
            pressure = np.asarray(pressure, float).reshape(-1)
            if pressure.shape != (self.n_vertices,):
                raise CaseError(f"pressure state must have one value per vertex "
                                f"({self.n_vertices}), got shape {pressure.shape}")
            self.p.x.array[:] = pressure[self.p_vertex]
        elif float(self.inv_kappa.value) > 0:
            self._recover_pressure()
        elif exact and np.any(self.u.x.array):
            raise CaseError("incompressible material: the pressure is not determined by the "
                            "displacements; pass the SolveResult of a mixed reference solve")
        self.x.x.array[self.pmap] = self.p.x.array
        self.x.x.scatter_forward()

    def _recover_pressure(self):
        """p solving the mixed form's pressure equation at ``u``: int (vol(u) + p/kappa) q = 0."""
        if self._pproj is None:
            dx = ufl.Measure("dx", domain=self.dm.mesh, metadata={"quadrature_degree": self.qdeg})
            q, pt = ufl.TestFunction(self.Q), ufl.TrialFunction(self.Q)
            vol = volume_measure(self.u, self.material.model, self.material.volumetric)
            M = dolfinx.fem.petsc.assemble_matrix(compile_form(pt * q * dx))
            M.assemble()
            ksp = PETSc.KSP().create(self.comm)
            ksp.setOperators(M)
            ksp.setType("preonly")
            ksp.getPC().setType("lu")
            ksp.getPC().setFactorSolverType("mumps")
            self._pproj = (compile_form(-vol * q * dx), ksp, M)
        L, ksp, _ = self._pproj
        rhs = dolfinx.fem.petsc.assemble_vector(L)
        rhs.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        ksp.solve(rhs, self.p.vector)
        rhs.destroy()
        self.p.x.scatter_forward()
        self.p.x.array[:] /= float(self.inv_kappa.value)

    def pressure_vertex_field(self) -> np.ndarray:
        """Pressure (kPa, positive in compression) at the Case vertices, on every rank."""
        n_own = self.Q.dofmap.index_map.size_local
        at = self.p_vertex[:n_own] >= 0
        ids = self.comm.allgather(self.p_vertex[:n_own][at])
        vals = self.comm.allgather(self.p.x.array[:n_own][at])
        out = np.zeros(self.n_vertices)
        for i, v in zip(ids, vals):
            out[i] = v
        return out

    def set_state(self, initial, *, exact: bool = False):
        """Load a displacement state into the solver's field.

        initial: a SolveResult of a reference solve (at degree 2 it carries the full nodal state,
            ``extra["node_u"]`` with ``extra["node_points"]``), a (n_nodes, gdim) nodal array in
            the ``Tangent`` node order (Case vertices first, then the edge nodes of
            ``Tangent.node_points``), or (n_vertices, gdim) vertex values.
        exact: the state itself is needed (tangent, internal forces), not a warm start. At degree
            2 vertex values do not determine the edge nodes: a warm start fills them with the mean
            of their end vertices (the P1 field), which is not the degree-2 solution away from
            rest, so ``exact`` refuses vertex values unless they are all zero.
        """
        n = self.n_vertices
        d = self.gdim
        arr = self.u.x.array.reshape(-1, d)
        if isinstance(initial, SolveResult):
            node_u = initial.node_u if self.degree >= 2 else None
            pressure = initial.pressure if self.Q is not None else None
            if node_u is not None:
                self._set_nodes(self._nodes_in_own_order(np.asarray(node_u, float),
                                                         initial.node_points))
                self.x_from_fields(pressure, exact=exact)
                return
            u0 = np.asarray(initial.u, float)
            source = f"a degree-{initial.degree} {initial.solver} SolveResult without the nodal " \
                     f"state (node_u)"
        else:
            u0 = np.asarray(initial, float)
            source = "vertex values"
            pressure = None
            if self.degree >= 2 and u0.shape == (len(self.node_vertex), d) and u0.shape[0] != n:
                if self.comm.size > 1:
                    raise CaseError("a full nodal state array is accepted in serial only")
                self._set_nodes(u0)
                self.x_from_fields(exact=exact)
                return
        if u0.shape != (n, d):
            shapes = f"{(n, d)}" if self.degree == 1 else \
                f"{(len(self.node_vertex), d)} (all degree-{self.degree} nodes) or {(n, d)}"
            raise CaseError(f"displacement state must have shape {shapes}, got {u0.shape}")
        if exact and self.degree >= 2 and np.any(u0):
            raise CaseError(
                f"degree-{self.degree} state from {source}: the nodes off the vertices are not "
                f"determined by the vertex values (the P1 interpolant is not the solver's state "
                f"away from rest); pass the SolveResult of a degree-{self.degree} reference "
                f"solve, the full nodal array "
                f"({len(self.node_vertex)}, {d}) in Tangent node order (vertices, then edge "
                f"nodes), or None for the solver's current state")
        if self.degree == 1:
            vmask = self.node_vertex >= 0
            arr[vmask] = u0[self.node_vertex[vmask]]
        else:  # the P1 field of the vertex values, interpolated
            self._from_p1(u0)
        self.u.x.scatter_forward()
        self.x_from_fields(pressure, exact=exact)

    def _set_nodes(self, nodes):
        """Set every node from a (n_nodes, gdim) array in the Tangent node order (serial)."""
        self.u.x.array.reshape(-1, self.gdim)[:] = nodes[self.out_permutation()[0]]
        self.u.x.scatter_forward()

    def node_points(self) -> np.ndarray:
        """(n_nodes, gdim) reference coordinates (mm) of the displacement nodes in the Tangent
        node order (Case vertices first, then the degree-2 edge nodes); serial."""
        out_node = self.out_permutation()[0]
        pts = np.empty((len(out_node), self.gdim))
        pts[out_node] = self.V.tabulate_dof_coordinates()[:, :self.gdim]
        return pts

    def _nodes_in_own_order(self, node_u, node_points):
        """A nodal state of some degree-2 reference solve on this mesh, reordered to this solver's
        node order by the node coordinates."""
        if self.comm.size > 1:
            raise CaseError("a degree-2 nodal state is accepted in serial only")
        own = self.node_points()
        if node_u.shape != own.shape or node_points is None or \
                np.shape(node_points) != own.shape:
            raise CaseError(f"nodal state of shape {node_u.shape} does not fit this degree-2 "
                            f"solver's {own.shape[0]} nodes")
        node_points = np.asarray(node_points, float)
        if np.array_equal(node_points, own):
            return node_u
        dist, idx = cKDTree(node_points).query(own)
        if np.any(dist > 1e-9 * max(1.0, np.abs(own).max())):
            raise CaseError("nodal state: its node points are not this solver's degree-2 nodes")
        return node_u[idx]

    def _from_p1(self, u0):
        """u = the P1 interpolant of vertex values u0 (n_vertices, gdim), in this degree."""
        if self._p1 is None:
            mesh = self.dm.mesh
            V1 = dolfinx.fem.VectorFunctionSpace(mesh, ("Lagrange", 1))
            nv = mesh.topology.dim + 1
            d1 = V1.dofmap.list.array.reshape(-1, nv)
            geo = mesh.geometry.dofmap.array.reshape(len(d1), -1)[:, :nv]
            vert = -np.ones(V1.dofmap.index_map.size_local + V1.dofmap.index_map.num_ghosts,
                            np.int64)
            vert[d1.ravel()] = self.dm.node_to_vertex[geo.ravel()]
            self._p1 = (dolfinx.fem.Function(V1), vert)
        u1, vert = self._p1
        u1.x.array.reshape(-1, self.gdim)[:] = u0[vert]
        self.u.interpolate(u1)

    def gather_nodes(self, local_array) -> np.ndarray:
        """(n_global_nodes, gdim) array of a nodal field (owned values), on every rank."""
        n_own = self.n_local_nodes
        vals = np.asarray(local_array).reshape(-1, self.gdim)[:n_own]
        gidx = self.global_nodes[:n_own]
        all_idx = self.comm.allgather(gidx)
        all_val = self.comm.allgather(vals)
        out = np.zeros((self.n_global_nodes, self.gdim))
        for i, v in zip(all_idx, all_val):
            out[i] = v
        return out

    def vertex_field(self) -> np.ndarray:
        """Displacement at the Case vertices (Case numbering), on every rank."""
        n_own = self.n_local_nodes
        arr = self.u.x.array.reshape(-1, self.gdim)[:n_own]
        nv = self.node_vertex[:n_own]
        mask = nv >= 0
        ids = self.comm.allgather(nv[mask])
        vals = self.comm.allgather(arr[mask])
        out = np.zeros((self.n_vertices, self.gdim))
        for i, v in zip(ids, vals):
            out[i] = v
        return out

    def out_permutation(self):
        """(the Tangent-order node of each local displacement node, the Tangent-order dof of
        each local displacement dof): the Case's vertices first, then the edge nodes."""
        nv = self.n_vertices
        out_node = np.empty(len(self.node_vertex), np.int64)
        vm = self.node_vertex >= 0
        out_node[vm] = self.node_vertex[vm]
        out_node[~vm] = nv + np.arange(np.count_nonzero(~vm))
        return out_node, (out_node[:, None] * self.gdim + np.arange(self.gdim)).ravel()

    def w_out(self) -> np.ndarray:
        """Output index (Tangent order: node-major displacements, then the pressure dofs by Case
        vertex) of every local dof of the unknown's space."""
        perm = self.out_permutation()[1]
        if self.Q is None:
            return perm
        out = np.empty(len(self.x.x.array), np.int64)
        out[self.umap] = perm
        pv = self.p_vertex.copy()
        extra = pv < 0  # pressure dofs away from the vertices (degree >= 2): after the vertices
        pv[extra] = self.n_vertices + np.arange(np.count_nonzero(extra))
        out[self.pmap] = len(perm) + pv
        return out
