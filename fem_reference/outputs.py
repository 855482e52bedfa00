"""What the reference hands out: the SolveResult of a solve (vertex displacements, probes,
reactions, strain energy, the deformation state and the contact report) and the
discretization it was solved with. Units: mm, mN, uJ (energy). Mixed into ReferenceSolver.

``OutputsMixin`` also carries the state in and out (``outputs_state.StateMixin``: Case vertex
numbering, degree-2 nodal states) and the exact tangent and internal forces as scipy matrices
(``outputs_tangent``: ``Tangent``, ``TangentMixin``); ``Tangent`` is importable from here.
"""
from __future__ import annotations

import dolfinx
import dolfinx.fem
import dolfinx.fem.petsc
import dolfinx.geometry
import numpy as np
from petsc4py import PETSc

from tissue_reference.meshes.case import Case
from tissue_reference.meshes.mesh import deformation_state
from tissue_reference.meshes.results import SolveResult
from tissue_reference.meshes.tips import through_surface_state

from .field_jacobian import cell_min_J
from .outputs_state import StateMixin
from .outputs_tangent import Tangent, TangentMixin

__all__ = ["OutputsMixin", "Tangent"]


def _no_converged_value(case: Case, contact) -> dict:
    """{"no_converged_value": [why, ...]} where the load is past the range in which answers are
    known to converge under refinement (a glued patch past one radius, an indenter past
    UNCONVERGED_RADII): any estimate of such an answer is a difference between degrees, not an
    error bar; {} otherwise."""
    why = [*case.glued_unconverged().values(), *contact.unconverged()]
    return {"no_converged_value": why} if why else {}


class OutputsMixin(StateMixin, TangentMixin):
    """State I/O and exported quantities of a ReferenceSolver."""

    def _probes(self, case: Case, u_vertices) -> dict:
        if self.degree == 1:
            return case.probe_values(u_vertices)
        mesh = self.dm.mesh
        out = {}
        tree = dolfinx.geometry.BoundingBoxTree(mesh, mesh.topology.dim)
        cells_all = case.mesh.cells
        for loc in case.probe_locations:
            # nudge the snapped point into its cell so the collision test is unambiguous
            c = case.mesh.points[cells_all[loc.cell]].mean(axis=0)
            y = loc.snapped_point + 1e-9 * (c - loc.snapped_point)
            p = np.zeros((1, 3))
            p[0, :self.gdim] = y
            cand = dolfinx.geometry.compute_collisions(tree, p)
            coll = dolfinx.geometry.compute_colliding_cells(mesh, cand, p)
            cells = coll.links(0)
            val = np.zeros(self.gdim)
            found = 0
            if len(cells):
                # mixed: evaluate the unknown's displacement part; dolfinx 0.5 evaluates the
                # collapsed P3 subspace with its edge dofs permuted (wrong values at points)
                val = (self.u if self.Q is None else self.x.sub(0)).eval(p, cells[:1])
                found = 1
            count = self.comm.allreduce(found)
            tot = self.comm.allreduce(np.asarray(val, float) * found)
            out[loc.name] = tot / max(count, 1)
        return out

    def _reactions(self, case: Case) -> dict:
        """Force (mN) the supports exert on the body, per Dirichlet region: sum of the internal-minus-
        external residual over the region's dofs (owned dofs only, summed over ranks)."""
        r = dolfinx.fem.petsc.assemble_vector(self.R_int_form)
        r.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        with r.localForm() as rl:  # owned + ghosts; only the owned entries are summed below
            arr = rl.array[self._umap].reshape(-1, self.gdim)
        out = {}
        seen = set()
        for b in case.boundaries:
            if b.type == "traction" or b.region in seen:
                continue
            seen.add(b.region)
            if b.region not in self.dm.region_tags:
                continue
            dofs = self.region_dofs(b.region)
            dofs = dofs[dofs < self.n_local_nodes]
            out[b.region] = self.comm.allreduce(arr[dofs].sum(axis=0))
        r.destroy()
        return out

    def discretization(self) -> dict:
        """What the reference solved: formulation, degrees, geometry order, cells and dofs."""
        return {"formulation": self.formulation, "degree": self.degree,
                "pressure_degree": self.degree - 1 if self.Q is not None else None,
                "geometry_order": self.geometry_order, "cells": self.case.mesh.n_cells,
                "dofs": int(self.W.dofmap.index_map.size_global * self.W.dofmap.index_map_bs),
                "quadrature_degree": self.qdeg}

    def _field_J(self):
        """Each cell's smallest J of the degree >= 2 field (``field_jacobian.cell_min_J``);
        None at degree 1 (J is constant in a cell: the vertices give it) and under MPI."""
        if self.degree < 2 or self.comm.size > 1:
            return None

        return cell_min_J(self)

    def _result(self, case, converged, iters, residual, wall, steps, history, lam) -> SolveResult:
        self._sync_fields()
        u_v = self._vertex_field()
        energy = self.comm.allreduce(dolfinx.fem.assemble_scalar(self.W_form))
        state = {}
        if self.degree >= 2 and self.comm.size == 1:
            # the full nodal state (u holds the vertices only): tangent / internal_forces / warm
            # starts from this result use it; arrays, so the JSON form leaves them out
            nodes = np.empty((len(self.node_vertex), self.gdim))
            nodes[self._out_permutation()[0]] = self.u.x.array.reshape(-1, self.gdim)
            state = {"node_u": nodes, "node_points": self._output_node_points()}
        if self.Q is not None:
            state["pressure"] = self._pressure_vertex_field()
        contact = self.contact.extra()
        cell_J = self._field_J()
        return SolveResult(
            u=u_v, converged=converged, iterations=iters, residual=float(residual),
            wall_time_s=wall, solver="fem", probes=self._probes(case, u_v),
            reactions=self._reactions(case), strain_energy=float(energy), load_steps=steps,
            degree=self.degree, case_name=case.name, n_vertices=case.mesh.n_vertices,
            n_cells=case.mesh.n_cells, history=history,
            extra={"load_fraction": lam, "discretization": self.discretization(),
                   "n_dofs": self.discretization()["dofs"],
                   "assemble_s": self.timings.assemble, "linear_solve_s": self.timings.solve,
                   "linear_solver": self.linear_solver,
                   "factorizations": self.timings.factorizations,
                   "krylov_iterations": self.timings.krylov_iterations,
                   "preconditioner_builds": self.timings.preconditioner_builds,
                   "tangent_shifts": self.timings.shifts, **state,
                   **contact,
                   **through_surface_state(deformation_state(case.mesh, u_v, degree=self.degree,
                                                        cell_J=cell_J), contact),
                   "warnings": case.glued_patch_warnings(u_v, cell_J) + self.contact.warnings(),
                   **_no_converged_value(case, self.contact)})
