"""MeshData -> dolfinx mesh with facet tags, and the maps back to the Case's own vertex numbering.

dolfinx reorders (and under MPI distributes) vertices; ``DolfinxMesh.node_to_vertex`` maps each
local geometry node back to the Case vertex id, so every array handed out of fem_reference is in
the Case's numbering.
"""
from __future__ import annotations

from dataclasses import dataclass

import dolfinx
import dolfinx.cpp
import numpy as np
import ufl
from dolfinx.mesh import meshtags_from_entities
from mpi4py import MPI

from tissue_reference.meshes.curved import p2_cells, p2_facets
from tissue_reference.meshes.mesh import MeshData

__all__ = ["DolfinxMesh", "to_dolfinx"]


@dataclass
class DolfinxMesh:
    mesh: dolfinx.mesh.Mesh
    facet_tags: object
    region_tags: dict          # facet region name -> tag value
    node_to_vertex: np.ndarray  # local geometry node -> Case vertex id
    h_min: float


def to_dolfinx(md: MeshData, comm=MPI.COMM_WORLD, *, geometry_order: int = 1) -> DolfinxMesh:
    """Create the distributed dolfinx mesh (rank 0 holds the input) with one tag per facet region.

    geometry_order 2: isoparametric cells whose mid-edge nodes lie on the curved boundary (the
    mesh's ``curved_edges``; straight elsewhere); node ids >= n_vertices are those edge nodes."""
    gdim = md.gdim
    shape = "tetrahedron" if gdim == 3 else "triangle"
    domain = ufl.Mesh(ufl.VectorElement("Lagrange", shape, geometry_order))
    names = sorted(md.facet_regions)
    tags = {n: i + 1 for i, n in enumerate(names)}
    nf = gdim if geometry_order == 1 else (6 if gdim == 3 else 3)
    nc = gdim + 1 if geometry_order == 1 else (10 if gdim == 3 else 6)
    if comm.rank == 0:
        cells, x = md.cells, md.points
        facets = [md.facet_regions[n] for n in names]
        facets = np.concatenate(facets).astype(np.int64) if facets else np.zeros((0, gdim), np.int64)
        values = np.concatenate([np.full(len(md.facet_regions[n]), tags[n], np.int32) for n in names]) \
            if names else np.zeros(0, np.int32)
        if geometry_order == 2:
            x, cells, edges = p2_cells(md)
            facets = p2_facets(md, facets, edges)
    else:
        cells, x = np.zeros((0, nc), np.int64), np.zeros((0, gdim))
        facets, values = np.zeros((0, nf), np.int64), np.zeros(0, np.int32)
    mesh = dolfinx.mesh.create_mesh(comm, cells, x, domain)
    tdim = mesh.topology.dim
    mesh.topology.create_connectivity(tdim - 1, tdim)
    mesh.topology.create_connectivity(tdim - 1, 0)
    ents, vals = dolfinx.cpp.io.distribute_entity_data(mesh._cpp_object if hasattr(mesh, "_cpp_object") else mesh._mesh, tdim - 1, facets, values)
    adj = dolfinx.cpp.graph.AdjacencyList_int32(ents)
    ft = meshtags_from_entities(mesh, tdim - 1, adj, vals.astype(np.int32))
    node_to_vertex = np.asarray(mesh.geometry.input_global_indices, dtype=np.int64)
    # smallest edge length (for the sliding penalty and step heuristics)
    xg = mesh.geometry.x[:, :gdim]
    cg = mesh.geometry.dofmap.array.reshape(-1, nc)[:, :tdim + 1]
    if len(cg):
        e = np.linalg.norm(xg[cg[:, 1:]] - xg[cg[:, :1]], axis=2)
        h_loc = float(e.min())
    else:
        h_loc = np.inf
    h_min = comm.allreduce(h_loc, op=MPI.MIN)
    return DolfinxMesh(mesh, ft, tags, node_to_vertex, h_min)
