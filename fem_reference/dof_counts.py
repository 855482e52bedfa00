"""How many unknowns a reference solve will have, from a mesh's entity counts, before it is
built: the adaptive loop and the automatic error estimate decide with it whether a solve fits
their budget (``max_dofs``, ``AUTO_MAX_DOFS``)."""
from __future__ import annotations

import numpy as np

from tissue_reference.meshes.mesh import MeshData

__all__ = ["entity_counts", "predicted_dofs", "refined_counts"]


def entity_counts(mesh: MeshData) -> tuple:
    """(vertices, edges, faces, cells) of a simplex mesh (faces = cells in 2D)."""
    cells = mesh.cells
    k = cells.shape[1]
    pairs = [(i, j) for i in range(k) for j in range(i + 1, k)]
    edges = np.unique(np.sort(np.concatenate([cells[:, [i, j]] for i, j in pairs])), axis=0)
    if k == 4:
        tri = [(0, 1, 2), (0, 1, 3), (0, 2, 3), (1, 2, 3)]
        faces = len(np.unique(np.sort(np.concatenate([cells[:, list(t)] for t in tri])), axis=0))
    else:
        faces = len(cells)
    return mesh.n_vertices, len(edges), faces, len(cells)


def refined_counts(counts: tuple, gdim: int) -> tuple:
    """Counts after one uniform refinement (Bey's 1:8 tetrahedra, 1:4 triangles)."""
    v, e, f, c = counts
    if gdim == 3:
        return v + e, 2 * e + 3 * f + c, 4 * f + 8 * c, 8 * c
    return v + e, 2 * e + 3 * c, 4 * c, 4 * c


def predicted_dofs(counts: tuple, gdim: int, degree: int, formulation: str) -> int:
    """Unknowns of a reference solve of ``degree`` on a mesh with ``counts`` = (vertices, edges,
    faces, cells): vector Lagrange (plus the pressure one degree lower for "mixed")."""
    v, e, f, c = counts

    def nodes(k):
        if k == 1:
            return v
        if k == 2:
            return v + e
        return v + 2 * e + (f if gdim == 3 else c)   # k == 3

    return gdim * nodes(degree) + (nodes(degree - 1) if formulation == "mixed" else 0)
