"""What the reference hands out: the SolveResult of a solve (vertex displacements, probes,
reactions, strain energy, the deformation state and the contact report) and the
discretization it was solved with, as functions of a ReferenceSolver at its current state.
Units: mm, mN, uJ (energy). The state's numbering is ``outputs_state``, the exported tangent
``outputs_tangent``.
"""
from __future__ import annotations

import dolfinx
import dolfinx.fem
import dolfinx.fem.petsc
import dolfinx.geometry
import numpy as np
from petsc4py import PETSc

from tissue_reference.meshes.mesh import deformation_state
from tissue_reference.model.case import Case
from tissue_reference.model.results import SolveResult
from tissue_reference.model.tips import through_surface_state

from .field_jacobian import cell_min_J

__all__ = ["discretization", "probe_values", "reactions", "solve_result"]


def _no_converged_value(case: Case, contact) -> tuple:
    """Why no converged value is known (a line per actuator) where the load is past the range in
    which answers are known to converge under refinement (a glued patch past one radius, an
    indenter past UNCONVERGED_RADII): any estimate of such an answer is a difference between degrees, not an
    error bar; () otherwise."""
    return (*case.glued_unconverged().values(), *contact.unconverged())


def probe_values(solver, case: Case, u_vertices) -> dict:
    """Probe name -> displacement (mm) of ``solver``'s current state (degree >= 2: its field
    at the probe's point; degree 1: the Case's interpolation of ``u_vertices``)."""
    if solver.degree == 1:
        return case.probe_values(u_vertices)
    mesh = solver.dm.mesh
    out = {}
    tree = dolfinx.geometry.BoundingBoxTree(mesh, mesh.topology.dim)
    cells_all = case.mesh.cells
    for loc in case.probe_locations:
        # nudge the snapped point into its cell so the collision test is unambiguous
        c = case.mesh.points[cells_all[loc.cell]].mean(axis=0)
        y = loc.snapped_point + 1e-9 * (c - loc.snapped_point)
        p = np.zeros((1, 3))
        p[0, :solver.gdim] = y
        cand = dolfinx.geometry.compute_collisions(tree, p)
        coll = dolfinx.geometry.compute_colliding_cells(mesh, cand, p)
        cells = coll.links(0)
        val = np.zeros(solver.gdim)
        found = 0
        if len(cells):
            # mixed: evaluate the unknown's displacement part; dolfinx 0.5 evaluates the
            # collapsed P3 subspace with its edge dofs permuted (wrong values at points)
            val = (solver.u if solver.Q is None else solver.x.sub(0)).eval(p, cells[:1])
            found = 1
        count = solver.comm.allreduce(found)
        tot = solver.comm.allreduce(np.asarray(val, float) * found)
        out[loc.name] = tot / max(count, 1)
    return out

def reactions(solver, case: Case) -> dict:
    """Force (mN) the supports exert on the body, per Dirichlet region: sum of the internal-minus-
    external residual over the region's dofs (owned dofs only, summed over ranks)."""
    solver.refresh_fields()
    r = dolfinx.fem.petsc.assemble_vector(solver.R_int_form)
    r.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    with r.localForm() as rl:  # owned + ghosts; only the owned entries are summed below
        arr = rl.array[solver.state.umap].reshape(-1, solver.gdim)
    out = {}
    seen = set()
    for b in case.boundaries:
        if b.type == "traction" or b.region in seen:
            continue
        seen.add(b.region)
        if b.region not in solver.dm.region_tags:
            continue
        dofs = solver.boundary.region_dofs(b.region)
        dofs = dofs[dofs < solver.state.n_local_nodes]
        out[b.region] = solver.comm.allreduce(arr[dofs].sum(axis=0))
    r.destroy()
    return out

def discretization(solver) -> dict:
    """What the reference solved: formulation, degrees, geometry order, cells and dofs."""
    return {"formulation": solver.formulation, "degree": solver.degree,
            "pressure_degree": solver.degree - 1 if solver.Q is not None else None,
            "geometry_order": solver.geometry_order, "cells": solver.case.mesh.n_cells,
            "dofs": int(solver.W.dofmap.index_map.size_global * solver.W.dofmap.index_map_bs),
            "quadrature_degree": solver.qdeg}

def field_J(solver):
    """Each cell's smallest J of the degree >= 2 field (``field_jacobian.cell_min_J``);
    None at degree 1 (J is constant in a cell: the vertices give it) and under MPI."""
    if solver.degree < 2 or solver.comm.size > 1:
        return None
    return cell_min_J(solver)


def solve_result(solver, case, converged, iters, residual, wall, steps, history,
                 lam) -> SolveResult:
    """The SolveResult of ``solver``'s current state as the answer for ``case``: ``converged``,
    Newton ``iters``, final ``residual`` (mN), ``wall`` (s), load ``steps``, the load ``history``
    and the load fraction ``lam`` reached."""
    solver.state.sync()
    u_v = solver.state.vertex_field()
    solver.refresh_fields()
    energy = solver.comm.allreduce(dolfinx.fem.assemble_scalar(solver.W_form))
    state = {"node_u": None, "node_points": None, "pressure": None}
    if solver.degree >= 2 and solver.comm.size == 1:
        # the full nodal state (u holds the vertices only): tangent / internal_forces / warm
        # starts from this result use it; arrays, so the JSON form leaves them out
        nodes = np.empty((len(solver.state.node_vertex), solver.gdim))
        nodes[solver.state.out_permutation()[0]] = solver.u.x.array.reshape(-1, solver.gdim)
        state.update(node_u=nodes, node_points=solver.state.node_points())
    if solver.Q is not None:
        state["pressure"] = solver.state.pressure_vertex_field()
    contact = solver.contact.extra()
    cell_J = field_J(solver)
    disc = discretization(solver)
    checked = through_surface_state(deformation_state(case.mesh, u_v, degree=solver.degree,
                                                      cell_J=cell_J), contact)
    return SolveResult(
        u=u_v, converged=converged, iterations=iters, residual=float(residual),
        wall_time_s=wall, solver="fem", reference=True, probes=probe_values(solver, case, u_v),
        reactions=reactions(solver, case), strain_energy=float(energy), load_steps=steps,
        degree=solver.degree, case_name=case.name, n_vertices=case.mesh.n_vertices,
        n_cells=case.mesh.n_cells, history=history, discretization=disc,
        valid=checked.pop("valid"), invalid_reason=checked.pop("invalid_reason"),
        min_J=checked.pop("min_J"), no_converged_value=_no_converged_value(case, solver.contact),
        **state,
        indenters=contact.get("indenters", {}),
        warnings=tuple(case.glued_patch_warnings(u_v, cell_J) + solver.contact.warnings()),
        extra={"load_fraction": lam, "n_dofs": disc["dofs"],
               "assemble_s": solver.timings.assemble, "linear_solve_s": solver.timings.solve,
               "linear_solver": solver.linear_solver,
               "factorizations": solver.timings.factorizations,
               "krylov_iterations": solver.timings.krylov_iterations,
               "preconditioner_builds": solver.timings.preconditioner_builds,
               "tangent_shifts": solver.timings.shifts, **checked})
